"""TESTBED: what a run of a scenario is judged by. ``Outcome`` holds a run's summary figures and
every node's event log (typed records); each predicate takes one and returns the unmet conditions
([] = success). Pure: importing this module starts nothing and needs no router, no process, no
network, so a verdict can be checked on records alone.

For the attack scenarios "the flight is unaffected" (``flight_unaffected``) means: hand-overs A->B
then B->A (ordinary, not emergency), the authority link never LOST, no failsafe, the delivery done
at B, landing at the take-off point, and no security violation (authority or pairing with anyone but
A and B). ``safety_invariants`` is what must hold in any run, whatever its faults.

The predicates of the scenarios are in modules by kind of scenario: ``zdrone.sil.attack_verdicts``
(the scenarios with an attacker), ``zdrone.sil.fault_verdicts`` (a fault injected: a process stopped,
killed or restarted, a link cut or lossy, a node revoked or rotated) and ``zdrone.sil.operator_verdicts``
(operator control through the GCS gateways).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

from pymavlink.dialects.v20 import common as mav

from gs.planner import AUTOPILOTS, reference_mission
from zdrone.core.geometry import GeoPoint, distance_m
from zdrone.core.records import (AnyRecord, AuthorityMoved, DroneState, Failsafe, HandoverComplete, HandoverFailed,
                                 LinkConfirmed, LinkStateChanged, MissionProgress, OwnerLinkLostOnGround, R, Restarted,
                                 Start, logged, only, record_type)
from zdrone.core.reference import DELIVERY
from zdrone.core.tbm import LinkState
from zdrone.sil.moments import RETURNING


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
    # on the ground at the delivery point in B's area, by the drone's own signed status or as a GS heard
    # it (B alone hearing the vehicle's short stop there is a matter of luck on a lossy radio: a CI failure)
    why += _need(delivered(o), "no delivery at B")
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


def _failsafe_confirmed(o: Outcome) -> list[str]:
    """The autopilot showed the failsafe (the drone's ``failsafe_confirmed``): a failsafe commanded into
    a link someone else holds (a hijacked port, a relay) is none."""
    from zdrone.core.records import FailsafeConfirmed

    return _need(bool(only(o.drone, FailsafeConfirmed)), "the autopilot never showed the failsafe (no failsafe_confirmed)")
