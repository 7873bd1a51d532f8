"""TESTBED: the predicates of the fault scenarios: a GS stopped, hung or killed, a router restarted or
down, the backhaul cut, a lossy radio, the companion restarted, the failsafe and control regained after
it, a node revoked or rotated by a signed fleet revision in flight. Pure, as ``zdrone.sil.verdicts``.
"""

from __future__ import annotations

from typing import Any

from zdrone.core.records import (AuthorityMoved, AuthorityStatus, ControlRequested, DroneStatus, Drop, Failsafe,
                                 HandoverFailed, LinkInstalled, Paired, Restarted, RevisionApplied, logged, only)
from zdrone.sil.verdicts import Outcome, _failsafe_confirmed, _need, flight_unaffected, safety_invariants


def check_link_loss(o: Outcome) -> list[str]:
    return _need(o.summary["failsafe"] is not None, "no failsafe") + _failsafe_confirmed(o)


def check_gs_crash(o: Outcome) -> list[str]:
    s = o.summary
    why = _need(all(h["to"] != "B" or h["kind"] == "emergency" for h in s["handovers"]), "authority went to a dead B")
    why += _need(s["final_owner"] == "A", f"final authority {s['final_owner']}, expected A")
    return why + _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0, "not landed at home")


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


def _revision_applied(o: Outcome, **want: Any) -> RevisionApplied | None:
    return next((e for e in only(o.drone, RevisionApplied) if all(getattr(e, k) == v for k, v in want.items())), None)


def _forwarded_after(o: Outcome, gs: str, t: float) -> int:
    """Commanding frames of ``gs`` the drone forwarded after ``t`` (from its periodic status)."""
    seen = [e.forwarded_commands.get(gs, 0) for e in only(o.drone, DroneStatus) if e.t >= t]
    return seen[-1] - seen[0] if seen else 0


def _b_revoked(o: Outcome) -> tuple[list[str], RevisionApplied | None]:
    """What every flight revoking B needs: the safety invariants, the drone applying the revision
    (None: it never did) and no command of B forwarded after it."""
    why = safety_invariants(o)
    rev = _revision_applied(o, revoked=("B",))
    why += _need(rev is not None, "the drone never applied the revision revoking B")
    if rev is not None:
        why += _need(_forwarded_after(o, "B", rev.t) == 0, "a command of B was forwarded after the revision")
    return why, rev


def check_revoke_in_flight(o: Outcome) -> list[str]:
    """``revoke-in-flight``: B, holding authority on the way back, is revoked: the drone applies the
    signed revision, drops B's link and keys, and A (proven inside its coverage) takes authority in
    an emergency hand-over; no failsafe; no frame of B forwarded after the revision; B never holds
    authority again; the routers were restarted on the regenerated files and the flight did not notice."""
    s = o.summary
    why, rev = _b_revoked(o)
    if rev is None:
        return why
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
    why, rev = _b_revoked(o)
    if rev is None:
        return why
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
    from zdrone.fleet.revisions import STAMP_PERIOD_S

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


#: ``lease-stamper``: X's stamps, one every this many seconds (faster than a GS's ``STAMP_PERIOD_S``)
LEASE_STAMPER_PERIOD_S = 2.0
#: ... of which at least this many between the cut and the lapse
LEASE_STAMPER_MIN_STAMPS = 3


def check_lease_stamper(o: Outcome) -> list[str]:
    """``lease-stamper``: ``revoked-alone`` with GS X (in the fleet, authorized for no drone) on the
    drone's side of the split, putting a genuine stamp signed with its own key, naming the revision in
    force and the drone, every ``LEASE_STAMPER_PERIOD_S`` from the cut on. Everything
    ``check_revoked_alone`` asks (the lapse within the lease and one stamp period of the cut, the
    failsafe, nothing of B after it), and: X put at least ``LEASE_STAMPER_MIN_STAMPS`` stamps between
    the cut and the lapse, and the drone refused X's stamps as unauthorized while B's lease ran (its
    status before the lapse counts ``stamp_refused:unauthorized``; no GS of this flight other than X
    is authorized for no drone). That reason comes after every other check of a stamp but the owner's
    and the clock's (``OwnerLease.stamp``): such a stamp was X's own, signed under its key in force, on
    its own key, naming the revision in force and the drone; only X's authorization refused it."""
    from zdrone.sil.testbed_records import StampPut

    s = o.summary
    why = check_revoked_alone(o)
    stamps = o.rogue_events("lease-stamper", StampPut)
    why += _need(bool(stamps), "X put no stamp")
    why += _need(all(e.gs == "X" and e.drones == ("d1",) for e in stamps), "a stamp not X's naming d1")
    cut = next((f for f in s["faults"] if f["target"] == "backhaul"), None)
    lapse = next((e for e in only(o.drone, Drop) if e.reason == "lease_lapsed" and e.gs == "B"), None)
    if cut is None or lapse is None:
        return why
    during = [e for e in stamps if cut["t"] <= e.t <= lapse.t]
    why += _need(len(during) >= LEASE_STAMPER_MIN_STAMPS,
                 f"X put {len(during)} stamps between the cut and the lapse (at least {LEASE_STAMPER_MIN_STAMPS})")
    why += _need(o.drone_counter("stamp_refused:unauthorized") >= 1,
                 "the drone refused none of X's stamps (its final counters: no stamp_refused:unauthorized)")
    before = [e for e in only(o.drone, DroneStatus) if e.t <= lapse.t]
    refused = before[-1].counters.get("stamp_refused:unauthorized", 0) if before else 0
    return why + _need(refused >= 1, "none of X's stamps was refused while B's lease ran (the drone's last status "
                                     "before the lapse counts no stamp_refused:unauthorized)")


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
