"""TESTBED: the predicates of the attack scenarios (those with an attacker process, ``ATTACK_SCENARIOS``):
each checks that the flight turned out as its row expects *and* that the counters show every attack
seen and refused (the attacker's own account, ``Outcome.rogue_done``, beside the nodes' records). Pure,
as ``zdrone.sil.verdicts``.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import common as mav

from zdrone.core.geometry import GeoPoint, distance_m
from zdrone.core.pairing import PAIR_BURST, PAIR_RATE
from zdrone.core.records import AuthorityMoved, DroneState, DroneStatus, GsLinkConfirmed, GsState, LinkkeyReceived, only
from zdrone.core.reference import COVERAGE_RADIUS_M, GS_B
from zdrone.sil.fault_verdicts import _revision_applied, check_companion_restart
from zdrone.sil.testbed_records import Captured, UnauthorizedAttempt
from zdrone.sil.verdicts import Outcome, _need, _owners_by_epoch, flight_unaffected, safety_invariants


def check_no_key(o: Outcome) -> list[str]:
    return flight_unaffected(o) + _need(o.drops("auth_failed") + o.drops("unknown_epoch") > 0, "no security drops") \
        + _need(bool(o.rogue_done("no-key")), "the attacker did not report")


def check_unauthorized(o: Outcome) -> list[str]:
    """The router's ACL stops X's pairing and key-sharing queries (no reply at all); were they let
    through, the drone would refuse X before any crypto (``pair_refused:unauthorized``)."""
    tries = o.rogue_events("unauthorized", UnauthorizedAttempt)
    x_linked = any(s.drones["d1"].linked for s in only(o.gs.get("X", []), GsState) if "d1" in s.drones)
    why = flight_unaffected(o) + _need(bool(tries), "the attacker made no attempt")
    why += _need(all(e.pair_answered == 0 and e.linkkey_replies == 0 for e in tries), "X got a pairing answer or a key")
    return why + _need(not x_linked, "GS X holds a link")


def check_key_injection(o: Outcome) -> list[str]:
    """``key-injection``: started before A, so that A's first key-sharing query (right after its
    pairing on the ground) meets it. The forged replies are made ahead and leave before the real B's;
    A must refuse them and accept the real B's, which the drone then sees B prove (hand-over A->B)."""
    a, done = o.gs_counters("A"), o.rogue_done("key-injection")
    why = flight_unaffected(o)
    why += _need(done.get("random", 0) > 0 and done.get("noise_own_key", 0) > 0, "the attacker sent no forged reply")
    why += _need(a.get("linkkey_reply:bad_mac", 0) > 0, "A counted no linkkey_reply:bad_mac")
    why += _need(any(e.gs == "B" for e in only(o.gs["A"], LinkkeyReceived)), "A never got B's key")
    return why


def check_linkkey_knockout(o: Outcome) -> list[str]:
    """``linkkey-knockout``: were answering a key-sharing query to replace the answering GS's live
    key, one query in B's name would knock A's link out. A forged message 1 fails before any secret
    is drawn (and an answered one only adds a candidate key): A's live link and the flight must not
    notice."""
    a, done = o.gs_counters("A"), o.rogue_done("linkkey-knockout")
    why = flight_unaffected(o)
    why += _need(done.get("forged_m1", 0) > 0 and done.get("junk", 0) > 0, "the attacker sent nothing")
    why += _need(done.get("replies", {}).get("ok", 0) == 0, "A answered a forged query with a secret")
    why += _need(a.get("linkkey_refused:bad_mac", 0) > 0, "A counted no linkkey_refused:bad_mac")
    why += _need(a.get("linkkey_refused:malformed", 0) > 0, "A counted no linkkey_refused:malformed")
    return why


def check_pair_replay(o: Outcome) -> list[str]:
    """``pair-replay``: Noise KK cannot tell a replayed message 1, so the drone answers it with the
    message 2 it sent the first time (``pair_repeated``): no new key; while it hears A under A's live
    key it refuses it as ``linked`` before any handshake. Once older than 30 s (its tagged
    stamp) a replay is ``stale``: dropped before any work. The only pairing proven is A's genuine one."""
    done = o.rogue_done("pair-replay")
    seen = (o.drone_counter("pair_answered") + o.drone_counter("pair_repeated") + o.drone_counter("pair_refused:stale")
            + o.drone_counter("pair_refused:rate_limited") + o.drone_counter("pair_deferred")
            + o.drone_counter("pair_refused:linked"))
    why = flight_unaffected(o)
    why += _need(bool(o.rogue_events("pair-replay", Captured)) and done.get("replayed", 0) > 0, "nothing captured or replayed")
    why += _need(seen >= 1 + done.get("replayed", 0) // 2, f"the drone saw {seen} pairing queries of A")
    why += _need(len(o.confirmed("A", "pair")) == 1, "a replayed pairing key was proven")
    # while the drone hears A under its live key a replay is refused as ``linked`` (no handshake, no key);
    # else it is answered from the response cache: either way, never a new key
    why += _need(o.drone_counter("pair_repeated") + o.drone_counter("pair_refused:linked") > 0,
                 "no replay was answered from the response cache nor refused as linked")
    return why


def check_pair_flood(o: Outcome) -> list[str]:
    """``pair-flood``: an authorized GS's key (B's) floods valid pairing queries. The drone refuses all
    beyond B's allowance (5/s, burst 10), and every one older than a message 1 of B's it answered
    (``stale``), before any crypto and does at most 2 handshakes per loop turn;
    the authority link must never go silent for more than 2 s (DEGRADED at most 1 s). Counts, not
    speed: the flood is more queries than the allowance answers, however fast the machine sent them."""
    done = o.rogue_done("pair-flood")
    answered = o.drone_counter("pair_answered")
    allowance = 1 + PAIR_BURST + PAIR_RATE * (int(done.get("seconds", 0)) + 1)  # A's first + B's bucket
    why = flight_unaffected(o)
    why += _need(done.get("sent", 0) > allowance, f"no flood: {done.get('sent', 0)} queries sent, {allowance:.0f} allowed")
    refused = o.drone_counter("pair_refused:rate_limited") + o.drone_counter("pair_refused:stale")
    why += _need(refused > 0, "no pairing query refused as rate_limited or stale")
    why += _need(answered <= allowance, f"{answered} pairings answered, {allowance:.0f} allowed")
    why += _need(not o.confirmed("B", "pair"), "a flood key was proven")
    why += _need(o.summary["authority_link"]["longest_silence_s"] <= 2.0,
                 f"authority link silent {o.summary['authority_link']['longest_silence_s']} s")
    return why


def check_uplink_policy(o: Outcome) -> list[str]:
    """``uplink-policy``. (a) An attacker with B's private key *is* B for the drone: once it proves a
    pairing key, that key replaces the real B's, and the real B can no longer talk to the drone. Done
    before the A->B hand-over, the hand-over would go to the attacker (it would then command as B)
    or fail; so it attacks right after the B->A hand-over, while the drone is still in B's coverage
    (about 2 s of wall time at speed-up 4), when B is a linked GS without authority and is no longer
    needed. Its sealed frames are authentic: the handover authority must drop them (``not_authority``;
    ``denied_by_policy`` for SERIAL_CONTROL and SETUP_SIGNING). (b) Without a key, the same ids are
    dropped by the security module. The simulator must have received none of them (it logs every
    frame it ignores) and the drone must have forwarded no command beyond the authorities' own."""
    sealed, unsealed = o.rogue_done("uplink-sealed"), o.rogue_done("uplink-unsealed")
    c = o.summary["commands"]
    why = flight_unaffected(o)
    why += _need(sealed.get("total", 0) > 0, "the B-key attacker sent nothing (did it pair?)")
    why += _need(unsealed.get("unsealed", 0) > 0 and unsealed.get("random_key", 0) > 0, "the no-key attacker sent nothing")
    why += _need(o.ha_drops("not_authority") > 0, "no not_authority drops")
    why += _need(o.ha_drops("denied_by_policy") > 0, "no denied_by_policy drops")
    why += _need(o.drops("auth_failed") > 0, "no auth_failed drops")
    why += _need(o.drops("unknown_epoch") + o.drops("malformed") > 0, "no drops of unsealed frames")
    why += _need(c["forwarded"] == {g: n for g, n in c["sent_as_authority"].items() if n},
                 f"forwarded {c['forwarded']} != sent by the authority {c['sent_as_authority']}")
    vehicle = o.summary["vehicle"]
    why += _need(vehicle["counters"] is not None and not vehicle["ignored"],
                 f"the vehicle got frames it does not use: {vehicle['ignored'] or 'no simulator counters'}")
    return why


def check_gateway_flood(o: Outcome) -> list[str]:
    """``gateway-flood``: a local process floods GS A's GCS gateway with 320 applications and garbage.
    A's table holds 16; the rest are counted (``app_table_full`` in A's status) and A flies on."""
    done, gw = o.rogue_done("gateway-flood"), o.summary["gateway_A"]
    why = flight_unaffected(o)
    why += _need(done.get("source_ports", 0) >= 300 and done.get("garbage", 0) > 0, "the attacker sent too little")
    why += _need(gw.get("app_table_full", 0) > 0, "A's gateway counted no app_table_full")
    return why


def check_no_cert(o: Outcome) -> list[str]:
    """``rogue-no-cert``: no certificate and another CA's are refused at connect; X's certificate with
    A's password gets nothing through on A's keys; the flight is unaffected."""
    done = o.rogue_done("no-cert")
    why = flight_unaffected(o) + _need(bool(done), "the attacker did not report")
    why += _need(done.get("no_certificate") == "refused", f"no certificate: {done.get('no_certificate')}")
    why += _need(done.get("other_ca") == "refused", f"another CA's certificate: {done.get('other_ca')}")
    why += _need(done.get("x_certificate") == "refused" or (done.get("pair_answered") == 0 and done.get("captured") == 0),
                 f"X's certificate as A: {done}")
    return why + _need(o.drops("auth_failed") + o.drops("unknown_epoch") == 0, "its frames reached the drone")


def check_big_flood(o: Outcome) -> list[str]:
    """``big-flood``: oversized payloads from B's stolen password must cost the nodes nothing: the
    router drops uplink puts and pairing queries over the drone's own limits where they enter it
    (its size limits: none reaches the drone), and everything over 64 KiB; A refuses the key-sharing
    queries by length before copying them."""
    done, a = o.rogue_done("big-flood"), o.gs_counters("A")
    dropped = o.summary.get("drone_inbox_dropped", {})
    why = flight_unaffected(o)
    why += _need(done.get("big", 0) > 0 and done.get("huge", 0) > 0, "the attacker sent nothing")
    why += _need(dropped.get("up:oversize", 0) == 0, f"an oversized uplink put reached the drone ({dropped})")
    why += _need(o.drone_counter("pair_refused:oversize") == 0, "an oversized pairing query reached the drone")
    why += _need(a.get("linkkey_refused:oversize", 0) > 0, "A counted no linkkey_refused:oversize")
    why += _need(o.summary["authority_link"]["longest_silence_s"] <= 2.0,
                 f"authority link silent {o.summary['authority_link']['longest_silence_s']} s")
    return why


def _outside_b(position: Any) -> bool:
    """The vehicle's position (as logged) lies outside GS B's coverage (the reference fleet's)."""
    return position is None or distance_m(GS_B, GeoPoint(position[0], position[1])) > COVERAGE_RADIUS_M


def insider_takeovers(o: Outcome) -> tuple[list[AuthorityMoved], list[AuthorityMoved], int]:
    """Authority moves to B while the vehicle was outside B's coverage: in the air, on the ground, and
    how many of B's commands the drone forwarded in those epochs."""
    to_b = [e for e in only(o.drone, AuthorityMoved) if e.to == "B" and _outside_b(e.position)]
    final = next((e for e in reversed(o.drone) if isinstance(e, DroneState)), None)
    by_epoch = final.forwarded_epochs if final else {}
    forwarded = sum(int(by_epoch.get(f"{e.epoch}:B", 0)) for e in to_b)
    in_air = [e for e in to_b if e.position is None or e.position[2] > 1.0]
    return in_air, [e for e in to_b if e not in in_air], forwarded


def check_insider_heir(o: Outcome) -> list[str]:
    """``insider-heir``: B (its own key, password and certificate) pairs again and again from outside
    its coverage while A, the authority, hangs. Authority may go to an heir only inside its
    coverage: the outcome is the failsafe (or A keeping authority), never B -- neither in the air
    nor once the failsafe has landed the vehicle -- and none of B's commands reaches the vehicle."""
    s, done = o.summary, o.rogue_done("insider-heir")
    in_air, landed, forwarded = insider_takeovers(o)

    def where(moves: list[AuthorityMoved]) -> str:
        return "; ".join(f"{e.kind} epoch {e.epoch} "
                         f"{distance_m(GS_B, GeoPoint(e.position[0], e.position[1])) if e.position else 0:.0f} m from B"
                         for e in moves)

    why = _need(done.get("pairings", 0) >= 2 and done.get("commands", 0) > 0,
                f"the attacker did not pair again and again: {done}")
    why += _need(not in_air, f"authority to B in the air outside its coverage: {where(in_air)}")
    why += _need(not landed, f"authority to B on the ground outside its coverage: {where(landed)}")
    why += _need(forwarded == 0, f"{forwarded} of B's commands forwarded ({done.get('command_acks')})")
    why += _need(s["failsafe"] is not None or s["final_owner"] == "A",
                 f"neither the failsafe nor A: final authority {s['final_owner']}")
    return why


def escrow_left_standing(confirmed: list[GsLinkConfirmed]) -> list[GsLinkConfirmed]:
    """A's key replacements by a secret it handed out over the backhaul that no ``revert`` (the drone
    speaking under A's own key again) undid."""
    standing: list[GsLinkConfirmed] = []
    for e in confirmed:
        if e.how.startswith("linkkey"):
            standing.append(e)
        elif e.how == "revert":
            standing.clear()
    return standing


def check_key_escrow(o: Outcome) -> list[str]:
    """``key-escrow``: B asks A for keys of link (drone, A) all flight long. While A's link is alive A
    answers none; while it is LOST (the drone away at B) A answers, and a frame under the secret, forged
    with the drone's router password, replaces A's LOST key — but A keeps its own key as the fallback
    and takes it back with the drone's first frame under it (``revert``): A's link and the flight must
    not notice."""
    done = o.rogue_done("key-escrow")
    confirmed = only(o.gs["A"], GsLinkConfirmed)
    why = flight_unaffected(o)
    why += _need(done.get("queries", 0) > 0 and (done.get("secrets", 0) == 0 or done.get("injected_down", 0) > 0),
                 f"the attacker asked nothing, or injected nothing under the secrets it got: {done}")
    standing = escrow_left_standing(confirmed)
    why += _need(not standing, f"A's live link replaced for good by a secret it handed out ({len(standing)}x)")
    return why


def check_stale_pairing(o: Outcome) -> list[str]:
    """``stale-pairing``: A's pairing message 1s, recorded earlier and captured in this flight, are
    replayed right after a companion restart. A replay must spend none of A's pairing tokens: the
    owner re-pairs in time (no failsafe) and no pairing query of A is refused for its rate."""
    done = o.rogue_done("stale-pairing")
    why = check_companion_restart(o)
    why += _need(done.get("held", 0) >= 3 and done.get("replayed", 0) > 0, f"the attacker replayed nothing: {done}")
    why += _need(o.drone_counter("pair_refused:rate_limited") == 0,
                 f"{o.drone_counter('pair_refused:rate_limited')} pairing queries of A refused for their rate: "
                 "replays spent A's tokens")
    return why


def check_fc_rogue_radio(o: Outcome) -> list[str]:
    """``fc-rogue-radio``: with the autopilot's link signed, nothing the radio on TELEM2 sends is
    obeyed (no answer, every command refused by the autopilot) and the flight is unaffected; with
    ``--fc-signing off`` (the control) the autopilot obeys it and the flight does not complete."""
    done, fc = o.rogue_done("fc-radio"), o.summary.get("fc_signing", {})
    sent = done.get("sent", {})
    why = _need(all(sent.get(k, 0) > 0 for k in ("arm", "mode_land", "mission_clear")),
                f"the attacker did not send arm, mode change and mission clear: {sent}")
    why += _need(done.get("autopilot") is not None, "the attacker heard no telemetry on TELEM2")
    if fc.get("mode") == "off":
        why += _need(done.get("obeyed", 0) > 0, f"no command of the attacker obeyed: no takeover shown ({done.get('answers')})")
        why += _need(bool(o.summary["flight_problems"]), "the flight completed: no takeover shown")
        return why
    refused = int((o.summary["vehicle"].get("counters") or {}).get("signing_refused", 0))
    why += _need(fc.get("signed") is True, f"the autopilot link is not signed ({fc.get('state')}: {fc.get('reason')})")
    why += _need(done.get("answered", 1) == 0, f"the autopilot answered the attacker: {done.get('answers')}")
    why += _need(refused >= sum(sent.values()), f"the autopilot refused {refused} frames, the attacker sent {sum(sent.values())}")
    return why + flight_unaffected(o)


#: ``fake-autopilot``: a position the drone reports this close to B's centre (where the attacker puts it) is
#: the forged one; the real flight never comes within 300 m of it.
FORGED_NEAR_M = 100.0


def check_fake_autopilot(o: Outcome) -> list[str]:
    """``fake-autopilot``: a local process writes into the companion's UDP vehicle link: a fake autopilot
    (sysid 7) from before the drone starts, then in flight the autopilot's own ids with positions at B's
    centre and LAND mode, while A goes silent. The drone adopts system 1 only and sends the fake nothing;
    its position never follows the forged one (no authority to B); the failsafe LAND goes to the real
    autopilot, which shows it (the drone's ``failsafe_confirmed``) and says so itself (its own log)."""
    from zdrone.core.records import FailsafeConfirmed, VehicleFound

    done, s = o.rogue_done("fake-autopilot"), o.summary
    sent = done.get("sent", {})
    why = _need(sent.get("raced", 0) > 0 and sent.get("forged_own_ids", 0) > 0,
                f"the attacker did not race the start and forge in flight: {sent}")
    found = only(o.drone, VehicleFound)
    why += _need(bool(found) and all(e.sysid == 1 for e in found), f"vehicle adopted: {[e.sysid for e in found]}")
    why += _need(done.get("heard_total", 1) == 0, f"the companion sent the fake autopilot {done.get('heard')}")
    final = next((e for e in reversed(o.drone) if isinstance(e, DroneState)), None)
    ep = ((final.vehicle_streams or {}).get("endpoint") or {}) if final else {}
    drops = ep.get("counters", {})
    # dropped by reason: before the autopilot was found (if a datagram of the fake came first: the race's
    # winner is the machine's timing, the unit tests of the endpoint pin that rule) and from a foreign
    # endpoint (the fake goes on in flight: always)
    why += _need(drops.get("dropped:foreign_endpoint", 0) > 0, f"the fake's datagrams were not dropped by reason: {drops}")
    # the forged positions are B's centre; the real flight lands far from it (its failsafe comes 3 s after A
    # stops, at the top of the climb), though at speed-up 4 it may drift into the edge of B's coverage while
    # it brakes: a position near the forged point is the forged one
    forged = [e.position for e in only(o.drone, DroneStatus)
              if e.position and distance_m(GS_B, GeoPoint(e.position[0], e.position[1])) < FORGED_NEAR_M]
    why += _need(not forged, f"the drone took the forged position (within {FORGED_NEAR_M:g} m of B's centre) "
                             f"{len(forged)} times")
    to_b = [h for h in s["handovers"] if h["to"] == "B"]
    why += _need(not to_b, f"authority followed the forged position: {to_b}")
    why += _need(s["failsafe"] is not None and s["failsafe"]["action"] == "LAND", f"no failsafe LAND: {s['failsafe']}")
    why += _need(bool(only(o.drone, FailsafeConfirmed)), "the autopilot never showed the failsafe")
    why += _need("LAND" in (s["vehicle"].get("modes") or []), f"the real autopilot never went to LAND: {s['vehicle']}")
    return why


def check_local_app(o: Outcome) -> list[str]:
    """``local-app``: an unsigned local application on GS A's host (the attack of issue 29) consents,
    allows takeover and commands while B's request is pending, A's gateway requiring signed
    applications. Nothing it sends moves authority (no grant at A, B never told it is in control, the
    flight's own two hand-overs only) or reaches the vehicle (every command refused the MAVLink way,
    counted by A's gateway; the flight completes); its reads are answered; A's operator's signed
    application holds the vehicle, commands it and resumes the mission."""
    from zdrone.core.records import OperatorRequestGranted

    done, gw = o.rogue_done("local-app"), o.summary["gateway_A"]
    sent = done.get("sent", {})
    why = _need(done.get("shown_p4") is not None, f"B's request was never pending at A's applications: {done}")
    why += _need(all(sent.get(k, 0) > 0 for k in ("consent", "allow_takeover", "mode_land", "disarm", "mission_clear")),
                 f"the attacker did not consent, allow takeover and command: {sent}")
    why += _need(done.get("accepted", 1) == 0, f"the attacker's commands were accepted: {done.get('answers')}")
    commands = sum(sent.get(k, 0) for k in ("consent", "allow_takeover", "mode_land", "nav_land", "disarm"))
    why += _need(done.get("refused_commands", 0) == commands and done.get("mission_denied", 0) == sent.get("mission_clear"),
                 f"not every command refused: {done.get('refused_commands')} of {commands}, "
                 f"{done.get('mission_denied')} MISSION_ACK DENIED of {sent.get('mission_clear')}")
    refused = sum(n for k, n in gw.items() if k.startswith("unsigned_refused:"))
    why += _need(refused >= commands + sent.get("mission_clear", 0) + sent.get("set_mode", 0),
                 f"A's gateway counted {refused} refusals of unsigned frames: {gw}")
    why += _need(gw.get("signing_dropped:bad_signature", 0) >= sent.get("guessed_key_consent", 1),
                 f"A's gateway did not drop the consent signed with a guessed key: {gw}")
    why += _need(not done.get("b_in_control") and not only(o.gs["A"], OperatorRequestGranted),
                 "authority moved on the attacker's consent")
    why += _need(done.get("param_values", 0) > 0, "the attacker's parameter read was not answered (read-only access)")
    why += _need(done.get("held") is True and done.get("signed_command") == mav.MAV_RESULT_ACCEPTED
                 and done.get("signed_in_control") is True and done.get("resumed") is True,
                 f"A's operator's signed application did not work: {done}")
    return why + flight_unaffected(o)


def check_view_truth(o: Outcome) -> list[str]:
    """``view-truth``, its flight side (the page is checked by tests/integration/test_view_truth.py):
    the safety invariants; both hand-overs before the companion stops, A's rotation taken; X never
    linked nor holding authority; both liars published; the insider captured the drone's word of B's
    epoch early and replayed it after authority moved on (the hand-back). The companion wakes to
    links silent longer than its loss threshold: it may enter its failsafe then (at once, as it
    wakes: whether its GSs' frames or its timer come first), or go on."""
    stop = next((f for f in o.summary.get("faults", []) if f["target"] == "drone" and f["ends"] is not None), None)
    why = safety_invariants(o, frozen=None if stop is None else (stop["t"], stop["ends"] + 1.0))
    why += _need(stop is not None, "the companion never stopped and went on")
    why += _need(o.pairs[:2] == [("A", "B"), ("B", "A")], f"hand-overs {o.pairs}, expected A->B, B->A first")
    why += _need(_revision_applied(o, rotated=("A",)) is not None, "the drone never applied the revision rotating A")
    owners = set(_owners_by_epoch(o.drone).values())
    why += _need("X" not in owners, "X held authority")
    x, b = o.rogue_done("ops-unauthorized"), o.rogue_done("ops-insider")
    why += _need(x.get("parts", 0) > 0 and x.get("bursts", 0) > 0, f"X published no parts (or no burst): {x}")
    why += _need(b.get("parts", 0) > 0, f"the insider published no parts: {b}")
    replayed = b.get("replayed") or {}
    why += _need(replayed.get("owner") == "B", f"the insider replayed no word of B's epoch: {replayed}")
    back = [e.t for e in only(o.drone, AuthorityMoved) if e.to == "A" and e.epoch > replayed.get("epoch", 0)]
    why += _need(bool(back) and replayed.get("at", float("inf")) < back[0],
                 "the replayed word is not older than the hand-back")
    return why
