"""TESTBED: what a run of a scenario is judged by. ``Outcome`` holds a run's summary figures and
every node's event log (typed records); each predicate takes one and returns the unmet conditions
([] = success). Pure: importing this module starts nothing and needs no router, no process, no
network, so a verdict can be checked on records alone.

For the attack scenarios "the flight is unaffected" (``flight_unaffected``) means: hand-overs A->B
then B->A (ordinary, not emergency), the authority link never LOST, no failsafe, the delivery done
at B, landing at the take-off point, and no security violation (authority or pairing with anyone but
A and B). ``safety_invariants`` is what must hold in any run, whatever its faults.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

from pymavlink.dialects.v20 import common as mav

from gs.planner import AUTOPILOTS, reference_mission

from ..core.geometry import GeoPoint, distance_m
from ..core.pairing import PAIR_BURST, PAIR_RATE
from ..core.records import (AnyRecord, OperatorConsentRefused, OperatorRequestDeclined, OwnerLinkLostOnGround,
                            AuthorityMoved, AuthorityStatus, ControlRequested, DroneState, DroneStatus, Drop, Failsafe,
                            GsState, HandoverComplete, HandoverFailed, GsLinkConfirmed, LinkConfirmed, LinkInstalled,
                            LinkkeyReceived, LinkStateChanged, MissionProgress, Paired, R, Restarted, RevisionApplied,
                            Start, logged, only, record_type)
from .testbed_records import Captured, UnauthorizedAttempt
from ..core.reference import COVERAGE_RADIUS_M, DELIVERY, GS_B
from ..core.tbm import LinkState
from .moments import RETURNING


@dataclass
class Outcome:
    """What a scenario's predicate looks at: the summary figures and every node's event log (typed
    records, in the order written)."""

    summary: dict[str, Any]
    drone: list[AnyRecord]
    gs: dict[str, list[AnyRecord]]
    rogue: list[AnyRecord]

    @property
    def pairs(self) -> list[tuple[str, str]]:
        return [(h["from"], h["to"]) for h in self.summary["handovers"]]

    def gs_counters(self, gs: str) -> dict[str, int]:
        return self.summary["gs_counters"].get(gs, {})

    def drone_counter(self, name: str) -> int:
        return int(self.summary["drone_counters"].get(name, 0))

    def drops(self, reason: str) -> int:
        return int(self.summary["security_drops"].get(reason, 0))

    def ha_drops(self, reason: str) -> int:
        return int(self.summary["ha_drops"].get(reason, 0))

    def rogue_done(self, mode: str) -> dict[str, Any]:
        """The attacker's own account of what it did (its ``attack_done`` event as logged: the fields
        differ per attack), {} if none."""
        return next((logged(e) for e in self.rogue if record_type(e) == "attack_done" and e.node == f"rogue-{mode}"), {})

    def rogue_events(self, mode: str, cls: type[R]) -> list[R]:
        """The attacker ``mode``'s records of one class."""
        return [e for e in only(self.rogue, cls) if e.node == f"rogue-{mode}"]

    def confirmed(self, gs: str, how: str) -> list[LinkConfirmed]:
        """The drone's ``link_confirmed`` records: a new key of ``gs`` proven (``how``: pair, grant)."""
        return [e for e in only(self.drone, LinkConfirmed) if e.gs == gs and e.how == how]


def _need(cond: bool, text: str) -> list[str]:
    return [] if cond else [text]


def flight_unaffected(o: Outcome) -> list[str]:
    """Both hand-overs (ordinary ones), the authority link never LOST, no failsafe, the delivery at
    B, landing at home."""
    s = o.summary
    why = _need(o.pairs == [("A", "B"), ("B", "A")], f"hand-overs {o.pairs}, expected A->B, B->A")
    why += _need(all(h["kind"] == "handover" for h in s["handovers"]), "an emergency hand-over")
    why += _need(s["failsafe"] is None, "failsafe triggered")
    why += _need(s["authority_link"]["worst_state"] != "lost", "the authority link was LOST")
    why += _need(s["delivered_at_b"], "no delivery at B")
    why += _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0,
                 f"not landed at home ({s['distance_from_home_m']} m)")
    return why


#: A delivery counts where the vehicle is on the ground this near the delivery point.
DELIVERY_RADIUS_M = 5.0


def delivered_at(gs_records: Sequence[AnyRecord], autopilot: str | None, point: GeoPoint = DELIVERY) -> bool:
    """The reference mission went past its DO_GRIPPER item (MISSION_CURRENT beyond it, or
    MISSION_ITEM_REACHED of it) while the vehicle was on the ground within ``DELIVERY_RADIUS_M`` of
    ``point``, as a GS heard it: what both autopilots send (ArduCopter says "Gripper Released", PX4
    says nothing)."""
    items = reference_mission(autopilot=autopilot if autopilot in AUTOPILOTS else "px4")
    gripper = next(i for i, it in enumerate(items) if it.command == mav.MAV_CMD_DO_GRIPPER)
    for e in only(gs_records, MissionProgress):
        past = e.seq >= gripper if e.reached else e.seq > gripper
        if not past or e.position is None:
            continue
        on_ground = e.landed_state == mav.MAV_LANDED_STATE_ON_GROUND or e.position[2] < 1.0
        if on_ground and distance_m(point, GeoPoint(e.position[0], e.position[1])) <= DELIVERY_RADIUS_M:
            return True
    return False


def delivered(o: Outcome) -> bool:
    """The vehicle landed at the delivery point (the drone's own status), or a GS heard it say so."""
    return bool(o.summary.get("delivered")) or bool(o.summary.get("delivered_at_b"))


def flight_completes(o: Outcome) -> list[str]:
    """Delivered, no failsafe, landed at home, authority with A (the GS that covers home)."""
    s = o.summary
    why = _need(delivered(o), "not delivered")
    why += _need(s["failsafe"] is None, "failsafe triggered")
    why += _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0,
                 f"not landed at home ({s['distance_from_home_m']} m)")
    return why + _need(s["final_owner"] == "A", f"final authority {s['final_owner']}, expected A (home's GS)")


def return_time(o: Outcome) -> float:
    """When the drone turned for home: the first of its re-entry into the overlap after the delivery,
    an RTL a GS commanded, the failsafe; else the end of the run."""
    times = [t for t in (o.summary.get("moments", {}).get(RETURNING),) if t is not None]
    times += [e.t for g in o.gs.values() for e in only(g, HandoverFailed) if e.action == "RTL"]
    times += [e.t for e in only(o.drone, Failsafe)]
    return min(times) if times else float(o.summary.get("ended_at") or 0.0)


def active_faults(o: Outcome, t: float) -> list[str]:
    """The faults (as the summary lists them) still active at time ``t`` (never ended, or later)."""
    return [f["text"] for f in o.summary.get("faults", []) if f["ends"] is None or f["ends"] > t]


def fault_over_check(o: Outcome) -> list[str]:
    """What holds wherever a fault lands: the safety invariants; and if no fault is still active when
    the drone returns, the flight completes (``flight_completes``)."""
    why = safety_invariants(o)
    if not o.summary.get("faults"):
        return why + ["the fault never landed (its moment never came)"]
    if not active_faults(o, return_time(o)):
        why += flight_completes(o)
    return why


def _owners_by_epoch(drone: list[AnyRecord]) -> dict[int, str]:
    """Who held authority in each epoch: the GS it moved to, else a restarted node's saved owner."""
    owners: dict[int, str] = {}
    for e in drone:
        if isinstance(e, AuthorityMoved):
            owners[e.epoch] = e.to
        elif isinstance(e, Restarted) and e.owner:
            owners.setdefault(e.epoch, e.owner)
    return owners


#: The failsafe must be commanded within this long after the loss threshold.
FAILSAFE_LATE_MS = 100.0
#: A LOST authority link must be followed by a hand-over or the failsafe within this long.
SILENT_AUTHORITY_S = 0.1


def safety_invariants(o: Outcome, frozen: tuple[float, float] | None = None) -> list[str]:
    """The safety invariants of one run, whatever its faults; [] = safe:

    1. one commander per epoch: the commanding frames forwarded in each epoch all came from one GS,
       the one that held authority in that epoch;
    2. the failsafe on time: commanded within threshold + ``FAILSAFE_LATE_MS``;
    3. no silent authority: whenever the authority's link was LOST, the drone handed over or entered
       its failsafe within ``SILENT_AUTHORITY_S`` (on the ground: recorded that the owner keeps it).
    (Clean exits and the timeout are checked by the launcher for every run.) ``frozen``: from when
    to when the companion itself was stopped (SIGSTOP): a failsafe it commands then (as it wakes)
    is as late as the stop made it, not late by its own doing."""
    why: list[str] = []
    owners = _owners_by_epoch(o.drone)
    last_by_run: list[dict[str, int]] = []
    for e in o.drone:  # forwarded per epoch, summed over the node's runs (a restart counts from zero)
        if isinstance(e, Start):
            last_by_run.append({})
        elif isinstance(e, DroneState) and last_by_run:
            last_by_run[-1] = e.forwarded_epochs
    per_epoch: dict[int, set[str]] = {}
    for run in last_by_run:
        for key, n in run.items():
            epoch, gs = key.split(":", 1)
            if n:
                per_epoch.setdefault(int(epoch), set()).add(gs)
    for epoch, senders in sorted(per_epoch.items()):
        if len(senders) > 1:
            why.append(f"epoch {epoch}: commands forwarded from {sorted(senders)}")
        elif owners.get(epoch) not in senders:
            why.append(f"epoch {epoch}: commands from {sorted(senders)}, authority was {owners.get(epoch)}")
    for fs in only(o.drone, Failsafe):
        if frozen is not None and frozen[0] <= fs.t <= frozen[1]:
            continue
        if fs.detect_to_command_ms is not None and fs.detect_to_command_ms > FAILSAFE_LATE_MS:
            why.append(f"failsafe {fs.detect_to_command_ms:.0f} ms after the threshold")
    owner: str | None = None
    failsafe = False  # in the failsafe nobody holds authority: a LOST link then asks for nothing more
    for i, e in enumerate(o.drone):
        if isinstance(e, AuthorityMoved):
            owner, failsafe = e.to, False
        elif isinstance(e, Restarted):
            owner, failsafe = e.owner, False
        elif isinstance(e, Failsafe):
            failsafe = True
        elif isinstance(e, LinkStateChanged) and e.state is LinkState.LOST and e.gs == owner and not failsafe:
            # on the ground no failsafe is due: the drone records that the owner keeps authority
            acted = any(isinstance(x, (Failsafe, HandoverComplete, OwnerLinkLostOnGround)) and x.t - e.t <= SILENT_AUTHORITY_S
                        for x in o.drone[i:i + 40])
            if not acted:
                why.append(f"authority link to {owner} LOST without hand-over or failsafe")
    return why


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


def _failsafe_confirmed(o: Outcome) -> list[str]:
    """The autopilot showed the failsafe (the drone's ``failsafe_confirmed``): a failsafe commanded into
    a link someone else holds (a hijacked port, a relay) is none."""
    from ..core.records import FailsafeConfirmed

    return _need(bool(only(o.drone, FailsafeConfirmed)), "the autopilot never showed the failsafe (no failsafe_confirmed)")


def check_link_loss(o: Outcome) -> list[str]:
    return _need(o.summary["failsafe"] is not None, "no failsafe") + _failsafe_confirmed(o)


def check_gs_crash(o: Outcome) -> list[str]:
    s = o.summary
    why = _need(all(h["to"] != "B" or h["kind"] == "emergency" for h in s["handovers"]), "authority went to a dead B")
    why += _need(s["final_owner"] == "A", f"final authority {s['final_owner']}, expected A")
    return why + _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0, "not landed at home")


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
    message 2 it sent the first time (``pair_repeated``): no new key. Once older than 30 s (its tagged
    stamp) a replay is ``stale``: dropped before any work. The only pairing proven is A's genuine one."""
    done = o.rogue_done("pair-replay")
    seen = (o.drone_counter("pair_answered") + o.drone_counter("pair_repeated") + o.drone_counter("pair_refused:stale")
            + o.drone_counter("pair_refused:rate_limited") + o.drone_counter("pair_deferred"))
    why = flight_unaffected(o)
    why += _need(bool(o.rogue_events("pair-replay", Captured)) and done.get("replayed", 0) > 0, "nothing captured or replayed")
    why += _need(seen >= 1 + done.get("replayed", 0) // 2, f"the drone saw {seen} pairing queries of A")
    why += _need(len(o.confirmed("A", "pair")) == 1, "a replayed pairing key was proven")
    why += _need(o.drone_counter("pair_repeated") > 0, "no replay was answered from the response cache")
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


def check_gs_hang(o: Outcome) -> list[str]:
    """``gs-hang``: the hung authority loses authority by the emergency rule, learns it when it wakes,
    and never gets a command through in an epoch that is not its own."""
    s = o.summary
    kinds = [(h["from"], h["to"], h["kind"]) for h in s["handovers"]]
    why = _need(bool(kinds) and kinds[0] == ("A", "B", "emergency"), f"no emergency hand-over to B: {kinds}")
    why += _need(s["failsafe"] is None, "failsafe")
    woke = next((e.t for e in only(o.gs["A"], AuthorityStatus) if e.owner == "B"), None)
    why += _need(woke is not None, "A never learned that B holds authority")
    c = s["commands"]
    why += _need(c["forwarded"].get("A", 0) <= c["sent_as_authority"].get("A", 0), "more forwarded from A than it sent")
    why += _need(not s["violations"], f"violations {s['violations']}")
    why += _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0, "not landed at home")
    return why


def check_lossy_radio(o: Outcome) -> list[str]:
    """``lossy-radio``: 20 % loss is no reason for a failsafe (TBM: DEGRADED after 1 s, LOST after 3 s
    of silence; with 2 Hz heartbeats and the command stream, 3 s of silence at 20 % loss is ~1e-7)."""
    lost = o.summary.get("radio_lost", {})
    why = flight_unaffected(o)
    why += _need(sum(lost.values()) > 100, f"the radio lost almost nothing: {lost}")
    return why


def check_companion_restart(o: Outcome) -> list[str]:
    """``companion-restart``: the restarted node restores LINKED(A, epoch 1), A pairs again in time (no
    failsafe), the flight goes on with both hand-overs."""
    restored = only(o.drone, Restarted)
    why = flight_unaffected(o)
    why += _need(len(restored) == 1 and restored[0].owner == "A" and restored[0].epoch == 1,
                 f"not restored as A, epoch 1: {[logged(e) for e in restored]}")
    paired = [e.t for e in only(o.drone, Paired) if e.gs == "A"]
    why += _need(len(paired) == 2, "A did not pair again")
    if restored and len(paired) == 2:  # the owner is back well inside the loss threshold (bench restart: <= 0.5 s)
        why += _need(paired[1] - restored[0].t < 2.0, f"A re-paired {paired[1] - restored[0].t:.2f} s after the restart")
    return why


def check_site_router_down(o: Outcome) -> list[str]:
    """``site-router-down``: the other site carries the C2 link; the hand-over happens, no failsafe."""
    s = o.summary
    kinds = [(h["from"], h["to"], h["kind"]) for h in s["handovers"]]
    why = _need(bool(kinds) and kinds[0][:2] == ("A", "B"), f"no hand-over to B: {kinds}")
    why += _need(s["failsafe"] is None, "failsafe")
    why += _need(any("router restarted" in n for n in s["notes"]), "site 1's router did not die")
    why += _need(s["final_owner"] == "A" and s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0,
                 f"not back home under A: {s['final_owner']}, {s['distance_from_home_m']} m")
    return why


def check_site_router_down_alone(o: Outcome) -> list[str]:
    """``site-router-down-alone``: no other site reaches the drone: the failsafe, on time."""
    s, fs = o.summary, o.summary["failsafe"]
    why = _need(any("router restarted" in n for n in s["notes"]), "site 1's router did not die")
    why += _need(fs is not None, "no failsafe") + _failsafe_confirmed(o)
    why += _need(fs is not None and fs.get("detect_to_command_ms") is not None and fs["detect_to_command_ms"] <= 100,
                 f"failsafe late: {fs}")
    return why + _need(not s["handovers"], f"a hand-over out of the overlap: {s['handovers']}")


def check_backhaul_cut_early(o: Outcome) -> list[str]:
    """``backhaul-cut``: A could not share B's key over the cut backhaul: the hand-over is refused
    cleanly, A keeps authority and brings the drone home; no failsafe, B never holds a link."""
    s = o.summary
    why = _need(not s["handovers"], f"a hand-over happened: {s['handovers']}")
    why += _need(s["final_owner"] == "A", f"final authority {s['final_owner']}, expected A")
    why += _need(s["failsafe"] is None, "failsafe")
    why += _need(not any(e.gs == "B" for e in only(o.drone, LinkInstalled)), "B got a key")
    why += _need(bool(only(o.gs.get("A", []), HandoverFailed)), "A did not report the failed hand-over")
    return why + _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0, "not landed at home")


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


def check_router_restart(o: Outcome) -> list[str]:
    """``router-restart``: an outage shorter than the loss threshold costs nothing: no failsafe, no
    new pairing, the same authority and both hand-overs."""
    s = o.summary
    why = flight_unaffected(o)
    why += _need(any("router restarted" in n for n in s["notes"]), "the router was not restarted")
    why += _need(s["failsafe"] is None, "failsafe")
    why += _need(len(only(o.drone, Paired)) == 1, "paired again")
    return why


def check_failsafe_recover(o: Outcome) -> list[str]:
    """``failsafe-recover``: the failsafe fires; A, back, takes control by its operator's request (never
    automatically: only a GS that asks gets it), in the next epoch; exactly one authority throughout."""
    s = o.summary
    fs_t = next((e.t for e in only(o.drone, Failsafe)), None)
    fs_epoch = next((e.epoch for e in reversed(only(o.drone, AuthorityMoved)) if fs_t is not None and e.t <= fs_t),
                    None)  # the epoch the failsafe ended
    regained = s.get("regained", [])
    why = _need(s["failsafe"] is not None, "no failsafe") + _failsafe_confirmed(o)
    why += _need(len(regained) == 1 and regained[0]["to"] == "A", f"control not regained by A: {regained}")
    why += _need(bool(regained) and fs_epoch is not None and regained[0]["epoch"] == fs_epoch + 1,
                 f"regained in epoch {regained[0]['epoch'] if regained else None}, failsafe epoch {fs_epoch}")
    why += _need(bool(only(o.gs["A"], ControlRequested)), "A never asked for control")
    why += _need(s["final_owner"] == "A", f"final authority {s['final_owner']}")
    return why


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


def check_operator_consent(o: Outcome) -> list[str]:
    """``operator-consent``: MAVLink operator control through the gateways (``zdrone.sil.operator``).
    B's request without consent moves nothing; with A's consent B takes control within the 10 s
    window; with takeover allowed each takes it at once; back with A, the flight goes on (its own
    hand-overs), with no emergency hand-over, no failsafe and the authority link never LOST."""
    s, op = o.summary, o.summary.get("operator", {})
    done = op.get("operator_done", {})
    why = _need(done.get("ok") is True, f"the operators' script failed: {done.get('failed') or 'it did not finish'}")
    window = op.get("no_consent", {}).get("window")
    moved = [h for h in s["handovers"] if window and window[0] <= (h["time"] or 0) <= window[1]]
    why += _need(window is not None and not moved, f"authority moved without consent: {moved}")
    why += _need(op.get("consent", {}).get("within_window") is True, f"consent: {op.get('consent')}")
    pairs = o.pairs
    why += _need(pairs[:5] == [("A", "B"), ("B", "A"), ("A", "B"), ("B", "A"), ("A", "B")],
                 f"hand-overs {pairs}: expected A->B (consent), B->A, A->B (takeover), B->A (release), then the flight's")
    why += _need(pairs[-1:] == [("B", "A")], f"the flight did not end under A: {pairs}")
    why += _need(all(h["kind"] == "handover" for h in s["handovers"]), "an emergency hand-over")
    why += _need(s["failsafe"] is None, "failsafe triggered")
    why += _need(s["authority_link"]["worst_state"] != "lost", "the authority link was LOST")
    why += _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0,
                 f"not landed at home ({s['distance_from_home_m']} m)")
    return why


def check_consent_bound(o: Outcome) -> list[str]:
    """``consent-bound``: three authorized GSs (``zdrone.sil.consent_ops``). A consent goes to the requester
    the operator was shown and named (B, though X asked last), a decline holds X off, an allow-takeover
    given in an earlier epoch moves nothing; X never holds authority; then the flight goes on and lands
    at home, no emergency hand-over, no failsafe."""
    s, op = o.summary, o.summary.get("operator", {})
    done = op.get("operator_done", {})
    why = _need(done.get("ok") is True, f"the operators' script failed: {done.get('failed') or 'it did not finish'}")
    pairs = o.pairs
    why += _need(all("X" not in p for p in pairs), f"X held authority: {pairs}")
    why += _need(pairs[:4] == [("A", "B"), ("B", "A"), ("A", "B"), ("B", "A")],
                 f"hand-overs {pairs}: expected A->B (consent), B->A (takeover), A->B (consent), B->A (release)")
    why += _need(pairs[-1:] == [("B", "A")], f"the flight did not end under A: {pairs}")
    why += _need(all(h["kind"] == "handover" for h in s["handovers"]), "an emergency hand-over")
    refused = [e for e in only(o.gs.get("A", []), OperatorConsentRefused) if e.named == "X"]
    why += _need(bool(refused), "A's consent naming X was not refused")
    declined = [e for e in only(o.gs.get("B", []), OperatorRequestDeclined) if e.requester == "X"]
    why += _need(bool(declined), "B's operator's decline of X is not on record")
    why += _need(s["failsafe"] is None, "failsafe triggered")
    why += _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0,
                 f"not landed at home ({s['distance_from_home_m']} m)")
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
    from ..core.records import FailsafeConfirmed, VehicleFound

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
    from ..core.records import OperatorRequestGranted

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


def _revision_applied(o: Outcome, **want: Any) -> RevisionApplied | None:
    return next((e for e in only(o.drone, RevisionApplied) if all(getattr(e, k) == v for k, v in want.items())), None)


def _forwarded_after(o: Outcome, gs: str, t: float) -> int:
    """Commanding frames of ``gs`` the drone forwarded after ``t`` (from its periodic status)."""
    seen = [e.forwarded_commands.get(gs, 0) for e in only(o.drone, DroneStatus) if e.t >= t]
    return seen[-1] - seen[0] if seen else 0


def check_revoke_in_flight(o: Outcome) -> list[str]:
    """``revoke-in-flight``: B, holding authority on the way back, is revoked: the drone applies the
    signed revision, drops B's link and keys, and A (proven inside its coverage) takes authority in
    an emergency hand-over; no failsafe; no frame of B forwarded after the revision; B never holds
    authority again; the routers were restarted on the regenerated files and the flight did not notice."""
    s = o.summary
    why = safety_invariants(o)
    rev = _revision_applied(o, revoked=("B",))
    why += _need(rev is not None, "the drone never applied the revision revoking B")
    if rev is None:
        return why
    why += _need(_forwarded_after(o, "B", rev.t) == 0, "a command of B was forwarded after the revision")
    why += _need(not any(isinstance(e, AuthorityMoved) and e.to == "B" and e.t > rev.t for e in o.drone),
                 "B held authority after its revocation")
    why += _need(s["final_owner"] == "A", f"final authority {s['final_owner']}, expected A")
    why += _need(s["failsafe"] is None, "failsafe: A covered the drone and should have taken over")
    why += _need(any("routers restarted" in n for n in s["notes"]), "the routers were not restarted on the new files")
    return why + _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0, "not landed at home")


def check_revoke_uncovered(o: Outcome) -> list[str]:
    """``revoke-uncovered``: B, holding authority at the delivery point where no other authorized GS's
    coverage holds the drone, is revoked: the drone applies the revision, drops B's link and keys and,
    with no heir proven inside its coverage, enters its failsafe at once (within a second of the
    revision); authority never moves after it (A never takes it from outside its coverage); no command
    of B forwarded after the revision, none of anyone in the failsafe; the routers restarted on the
    regenerated files."""
    s = o.summary
    why = safety_invariants(o)
    rev = _revision_applied(o, revoked=("B",))
    why += _need(rev is not None, "the drone never applied the revision revoking B")
    if rev is None:
        return why
    why += _need(_forwarded_after(o, "B", rev.t) == 0, "a command of B was forwarded after the revision")
    moved = [e for e in only(o.drone, AuthorityMoved) if e.t >= rev.t]
    why += _need(not moved, f"authority moved after the revision ({', '.join(f'to {e.to}' for e in moved)}): "
                            "no authorized GS covered the drone")
    fs = next((e for e in only(o.drone, Failsafe) if e.t >= rev.t), None)
    why += _need(fs is not None and fs.t - rev.t <= 1.0, "no failsafe within 1 s of the revision (no heir covered the drone)")
    if fs is not None:  # in FAILSAFE nobody commands (the revoked owner stays only as the epoch's name)
        why += _need(_forwarded_after(o, "A", fs.t) == 0, "a command of A was forwarded in the failsafe")
    return why + _need(any("routers restarted" in n for n in s["notes"]), "the routers were not restarted on the new files")


#: ``revoked-alone``'s lease: three of a GS's stamp periods (``zdrone.fleet.revisions.STAMP_PERIOD_S``) and more
REVOKED_ALONE_LEASE_S = 16.0


def check_revoked_alone(o: Outcome) -> list[str]:
    """``revoked-alone``: B holds authority at the delivery point, the backhaul is cut and B revoked on
    A's side only: the drone never hears the revision, and B's own stamps renew nothing, so the owner
    lease lapses within the lease (and one stamp period) of the cut; no authorized GS covers the drone:
    its failsafe (in the air or on the ground), and no command of B forwarded after the lapse."""
    from ..fleet.revisions import STAMP_PERIOD_S

    s = o.summary
    why = safety_invariants(o)
    cut = next((f for f in s["faults"] if f["target"] == "backhaul"), None)
    why += _need(cut is not None, "the backhaul was never cut")
    why += _need(_revision_applied(o, revoked=("B",)) is None, "the revision reached the drone across the cut")
    why += _need(any("revoking B" in n for n in s["notes"]), "B was not revoked on A's side")
    lapse = next((e for e in only(o.drone, Drop) if e.reason == "lease_lapsed" and e.gs == "B"), None)
    why += _need(lapse is not None, "B's lease never lapsed: B kept the drone")
    if cut is None or lapse is None:
        return why
    within = REVOKED_ALONE_LEASE_S + STAMP_PERIOD_S + 1.0
    why += _need(lapse.t - cut["t"] <= within, f"B's lease lapsed {lapse.t - cut['t']:.1f} s after the cut "
                                                f"(lease {REVOKED_ALONE_LEASE_S:g} s: at most {within:g} s)")
    why += _need(_forwarded_after(o, "B", lapse.t + 0.5) == 0, "a command of B was forwarded after its lease lapsed")
    after = [e for e in only(o.drone, DroneStatus) if e.t >= lapse.t + 1.0]
    why += _need(bool(after) and all(e.state.value == "failsafe" or e.owner != "B" for e in after),
                 f"after the lapse: {sorted({(e.owner, e.state) for e in after})}")
    why += _need(not any(isinstance(e, AuthorityMoved) and e.to == "B" and e.t > lapse.t for e in o.drone),
                 "B held authority again after its lease lapsed")
    return why


def check_rotate_in_flight(o: Outcome) -> list[str]:
    """``rotate-in-flight``: A's static key is rotated while A holds authority: A re-pairs under its
    new key (a new pairing key proven on the drone after the revision), authority never moves
    because of it (no failsafe, no emergency hand-over), and the flight is the reference one."""
    why = flight_unaffected(o)
    rev = _revision_applied(o, rotated=("A",))
    why += _need(rev is not None, "the drone never applied the revision rotating A")
    if rev is not None:
        why += _need(any(e.t >= rev.t for e in o.confirmed("A", "pair")), "A never re-paired under its new key")
    return why


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
