"""TESTBED: ``zdrone demo`` starts router, simulator, drone and ground stations as separate OS
processes, flies the reference flight (or an attack / fault scenario), shows it live, writes the
event logs and a summary, and shuts everything down.

Every scenario is one row of ``SCENARIO_TABLE``: its attackers (each a separate process,
``python -m zdrone.sil.rogue --mode ...``, with real router credentials from the run's fleet
directory), the moment each is started and told to attack, an optional fault (a GS stopped or
killed), and its success predicate. A scenario succeeds (``zdrone demo`` exits 0) only if the
flight turned out as the row expects *and* the counters show every attack was seen and refused;
the attackers write what they did to ``rogue.jsonl`` so both sides are checked.

For the attack scenarios "the flight is unaffected" means: hand-overs A->B then B->A (ordinary,
not emergency), the authority link never LOST, no failsafe, the delivery done at B, landing at the
take-off point, and no security violation (authority or pairing with anyone but A and B).
"""

from __future__ import annotations

import ast
import json
import os
import re
import signal
import socket
import subprocess
import sys
import textwrap
import time
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

from pymavlink.dialects.v20 import common as mav

from gs.planner import AUTOPILOTS, reference_mission

from ..core.geometry import GeoPoint, distance_m
from ..core.pairing import PAIR_BURST, PAIR_RATE
from ..core.records import (AnyRecord, OperatorConsentRefused, OperatorRequestDeclined, OwnerLinkLostOnGround,
                            AuthorityChange, AuthorityMoved, AuthorityStatus, AutopilotFound,
                            ControlRequested, Drop, DroneState, DroneStatus, DroneStop, Failsafe, GsState,
                            HandoverComplete, HandoverFailed, HandoverStart, GsLinkConfirmed, LinkConfirmed,
                            LinkInstalled, LinkkeyReceived, LinkStateChanged, MissionFailed, MissionProgress,
                            MissionStarted, Paired, PathState, R, RegionEntered, Restarted, Start, Subscribe,
                            Unsubscribe, fields_of, logged, only, record_type)
from .records import Captured, LinkFault, RadioLinkChanged, UnauthorizedAttempt
from ..core.reference import COVERAGE_RADIUS_M, DEFAULT_NODES, DELIVERY, GS_B, HOME
from ..core.tbm import LinkState, TbmThresholds
from ..fleet.files import init_fleet, load_sites
from ..net.eventlog import EventLog, LogTail, read_records
from . import procs
from .netns import NetnsTopology
from .ports import free_port
from .radiolink import RadioLink, SiteCoverage, SwitchedLink, TruthReceiver, site_circles

PY = sys.executable

# ------------------------------------------------------------------ scenario table
#: Moments of the flight at which an attacker is started, told to attack, or a fault is injected.
BEFORE_GS_A = "before_gs_a"  # after the drone and GS B are up, before GS A starts (and pairs)
MISSION_STARTED = "mission_started"  # GS A's mission started (the drone is taking off)
AIRBORNE = "airborne"  # armed and above 15 m
REGION_ENTERED = "region_entered"  # first entry into the hand-over region
HANDOVERS_DONE = "handovers_done"  # both hand-overs done: authority back at A, drone still in the overlap
FAILSAFE_FIRED = "failsafe_fired"  # the drone entered its failsafe
HANDOVER_STARTED = "handover_started"  # the drone took the first release (the hand-over A->B begins)
RETURNING = "returning"  # on the way back: the first entry into the hand-over region after the delivery point
DRONE_RESTARTED = "drone_restarted"  # a fault restarted the drone's companion (just started again)
BEFORE_DRONE = "before_drone"  # the simulator is up, the drone's companion not yet started
TRIGGERS = (BEFORE_DRONE, BEFORE_GS_A, MISSION_STARTED, AIRBORNE, REGION_ENTERED, HANDOVERS_DONE, FAILSAFE_FIRED, HANDOVER_STARTED,
            RETURNING, DRONE_RESTARTED)
#: The moments of the flight a scenario's fault can be moved to (``zdrone demo --moment``, ``zdrone bench
#: sweep``): name -> (trigger, wall seconds after it).
MOMENTS: dict[str, tuple[str, float]] = {
    "before_overlap": (AIRBORNE, 0.5),  # climbing out near home, only A's coverage
    "in_overlap": (REGION_ENTERED, 0.5),  # inside both coverages, before the hand-over
    "handover": (HANDOVER_STARTED, 0.0),  # as the drone takes A's release
    "way_back": (RETURNING, 0.5),  # back in the overlap after the delivery, B holding authority
}
#: GS A's GCS application key file in the run folder (``Scenario.app_signing``), mode 0600.
GCS_KEYS = "gcs-keys"
#: Within this distance of the delivery point the vehicle has reached it (``RETURNING`` can come next).
NEAR_DELIVERY_M = 60.0


@dataclass(frozen=True)
class RogueSpec:
    """One attacker process: its mode, when it starts, when it is told to attack (SIGUSR2; ``None``:
    at once), for how long (``max(min_wall, sim_s / speedup)`` wall seconds) and at what rate."""

    mode: str
    launch: str
    go: str | None = None
    sim_s: float = 40.0
    min_wall: float = 10.0
    rate: float | None = None
    args: tuple[str, ...] = ()  # further options of the attacker

    def duration(self, speedup: float) -> float:
        return max(self.min_wall, self.sim_s / speedup)


@dataclass(frozen=True)
class Fault:
    """A GS process stopped (SIGSTOP), resumed (SIGCONT) or killed (SIGKILL) at a moment of the flight."""

    trigger: str
    target: str  # child name: gsA, gsB, router
    sig: int  # or RESTART: killed, then started again after ``down`` seconds
    text: str
    down: float = 0.0
    after: float = 0.0  # wall seconds after the trigger

@dataclass(frozen=True)
class Scenario:
    name: str
    description: str  # one line: what happens (README, --help)
    expected: str  # one line: what counts as success
    check: "Callable[[Outcome], list[str]]"  # the unmet conditions; [] = success
    rogues: tuple[RogueSpec, ...] = ()
    faults: tuple[Fault, ...] = ()
    gs_a_extra: tuple[str, ...] = ()  # further options of GS A
    sites: bool = False  # needs a router per site (``zdrone demo --sites``)
    tls: bool = False  # needs mutual TLS (``zdrone demo --tls``; a router per site has it anyway)
    radio: tuple[str, ...] = ()  # the drone's emulated radio (``--sil-loss 0.2`` ...)
    gs_x: bool = False  # start GS X (in the fleet, not authorized) as a real node
    gcs_a: bool = False  # give GS A a GCS gateway endpoint (udpin on a free port)
    telem2: bool = False  # give the simulator a second MAVLink endpoint (its TELEM2, udpin on a free port)
    fixed_moment: bool = False  # its fault's moment is what the scenario is (``moments()`` gives none to move to)
    operators: str | None = None  # at this moment, start the two operators (``zdrone.sil.operator``) on A's and B's gateways
    consent_ops: str | None = None  # at this moment, start the three operators (``zdrone.sil.consent_ops``)
    x_authorized: bool = False  # X is a third GS authorized for d1 (started, with a GCS gateway, without pairing)
    linger: float = 0.0  # wall seconds the run goes on after the vehicle landed (what happens on the ground)
    plain_router: bool = False  # its attacker holds router passwords only: no --tls, no --sites (no certificate)
    app_signing: bool = False  # GS A's gateway requires signed applications (a key file the launcher writes); B has one
    vehicle_udpin: bool = False  # the companion listens for its autopilot on UDP (PX4's onboard link): the simulator sends to it

    def own_moment(self) -> str | None:
        """The moment (of ``MOMENTS``) its first fault lands at, None if none matches (or no fault)."""
        if not self.faults:
            return None
        f = self.faults[0]
        return next((m for m, (trig, _) in MOMENTS.items() if trig == f.trigger), None)

    def moments(self) -> tuple[str, ...]:
        """The moments its fault can land at and still be this scenario (none without a fault)."""
        return () if not self.faults or self.fixed_moment or self.own_moment() is None else tuple(MOMENTS)

    def at_moment(self, moment: str) -> "Scenario":
        """The scenario with its faults moved to ``moment``: the faults of its first fault's trigger move,
        their offsets kept relative to the first; at its own moment, the scenario itself. Away from
        it, success is what holds at any moment: the safety invariants, and a completed flight
        whenever no fault is still active when the drone returns (``fault_over_check``)."""
        if moment not in MOMENTS:
            raise ValueError(f"unknown moment {moment!r}: one of {', '.join(MOMENTS)}")
        if moment not in self.moments():
            raise ValueError(f"{self.name}: its fault does not move (moments: {', '.join(self.moments()) or 'none'})")
        if moment == self.own_moment():
            return self
        trigger, after = MOMENTS[moment]
        first = self.faults[0]
        moved = tuple(replace(f, trigger=trigger, after=round(after + f.after - first.after, 3))
                      if f.trigger == first.trigger else f for f in self.faults)
        return replace(self, faults=moved, check=fault_over_check,
                       description=f"{self.description} — the fault moved to {moment}")


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


#: The deadline of a flight with an autopilot already running (``--vehicle``) allows for its start-up.
EXTERNAL_BOOT_S = 60.0
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


def safety_invariants(o: Outcome) -> list[str]:
    """The safety invariants of one run, whatever its faults; [] = safe:

    1. one commander per epoch: the commanding frames forwarded in each epoch all came from one GS,
       the one that held authority in that epoch;
    2. the failsafe on time: commanded within threshold + ``FAILSAFE_LATE_MS``;
    3. no silent authority: whenever the authority's link was LOST, the drone handed over or entered
       its failsafe within ``SILENT_AUTHORITY_S`` (on the ground: recorded that the owner keeps it).
    (Clean exits and the timeout are checked by the launcher for every run.)"""
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


def _check_no_key(o: Outcome) -> list[str]:
    return flight_unaffected(o) + _need(o.drops("auth_failed") + o.drops("unknown_epoch") > 0, "no security drops") \
        + _need(bool(o.rogue_done("no-key")), "the attacker did not report")


def _check_unauthorized(o: Outcome) -> list[str]:
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


def _check_link_loss(o: Outcome) -> list[str]:
    return _need(o.summary["failsafe"] is not None, "no failsafe") + _failsafe_confirmed(o)


def _check_gs_crash(o: Outcome) -> list[str]:
    s = o.summary
    why = _need(all(h["to"] != "B" or h["kind"] == "emergency" for h in s["handovers"]), "authority went to a dead B")
    why += _need(s["final_owner"] == "A", f"final authority {s['final_owner']}, expected A")
    return why + _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0, "not landed at home")


def _check_key_injection(o: Outcome) -> list[str]:
    """``key-injection``: started before A, so that A's first key-sharing query (right after its
    pairing on the ground) meets it. The forged replies are made ahead and leave before the real B's;
    A must refuse them and accept the real B's, which the drone then sees B prove (hand-over A->B)."""
    a, done = o.gs_counters("A"), o.rogue_done("key-injection")
    why = flight_unaffected(o)
    why += _need(done.get("random", 0) > 0 and done.get("noise_own_key", 0) > 0, "the attacker sent no forged reply")
    why += _need(a.get("linkkey_reply:bad_mac", 0) > 0, "A counted no linkkey_reply:bad_mac")
    why += _need(any(e.gs == "B" for e in only(o.gs["A"], LinkkeyReceived)), "A never got B's key")
    return why


def _check_linkkey_knockout(o: Outcome) -> list[str]:
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


def _check_pair_replay(o: Outcome) -> list[str]:
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


def _check_pair_flood(o: Outcome) -> list[str]:
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


def _check_uplink_policy(o: Outcome) -> list[str]:
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


def _check_gateway_flood(o: Outcome) -> list[str]:
    """``gateway-flood``: a local process floods GS A's GCS gateway with 320 applications and garbage.
    A's table holds 16; the rest are counted (``app_table_full`` in A's status) and A flies on."""
    done, gw = o.rogue_done("gateway-flood"), o.summary["gateway_A"]
    why = flight_unaffected(o)
    why += _need(done.get("source_ports", 0) >= 300 and done.get("garbage", 0) > 0, "the attacker sent too little")
    why += _need(gw.get("app_table_full", 0) > 0, "A's gateway counted no app_table_full")
    return why


def _check_gs_hang(o: Outcome) -> list[str]:
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


def _check_lossy_radio(o: Outcome) -> list[str]:
    """``lossy-radio``: 20 % loss is no reason for a failsafe (TBM: DEGRADED after 1 s, LOST after 3 s
    of silence; with 2 Hz heartbeats and the command stream, 3 s of silence at 20 % loss is ~1e-7)."""
    lost = o.summary.get("radio_lost", {})
    why = flight_unaffected(o)
    why += _need(sum(lost.values()) > 100, f"the radio lost almost nothing: {lost}")
    return why


def _check_companion_restart(o: Outcome) -> list[str]:
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


def _forwarded_over_restarts(drone_events: list[AnyRecord]) -> dict[str, int]:
    """Commands the drone node forwarded, per GS, summed over every run of the node (a restarted
    node counts from zero; the last report of each run is its total)."""
    total: dict[str, int] = {}
    last: dict[str, int] = {}
    for e in drone_events:
        if isinstance(e, Start):
            for g, n in last.items():
                total[g] = total.get(g, 0) + n
            last = {}
        elif isinstance(e, DroneState):
            last = {g: int(n) for g, n in e.forwarded_commands.items()}
    for g, n in last.items():
        total[g] = total.get(g, 0) + n
    return total


def _commands_sent(gs_state: GsState | None, drone: str) -> dict[str, int]:
    """The commands a GS sent to ``drone`` (per MAVLink command id), as its status reports them."""
    report = gs_state.drones.get(drone) if gs_state else None
    return report.commands_sent if report else {}


def _check_site_router_down(o: Outcome) -> list[str]:
    """``site-router-down``: the other site carries the C2 link; the hand-over happens, no failsafe."""
    s = o.summary
    kinds = [(h["from"], h["to"], h["kind"]) for h in s["handovers"]]
    why = _need(bool(kinds) and kinds[0][:2] == ("A", "B"), f"no hand-over to B: {kinds}")
    why += _need(s["failsafe"] is None, "failsafe")
    why += _need(any("router restarted" in n for n in s["notes"]), "site 1's router did not die")
    why += _need(s["final_owner"] == "A" and s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0,
                 f"not back home under A: {s['final_owner']}, {s['distance_from_home_m']} m")
    return why


def _check_site_router_down_alone(o: Outcome) -> list[str]:
    """``site-router-down-alone``: no other site reaches the drone: the failsafe, on time."""
    s, fs = o.summary, o.summary["failsafe"]
    why = _need(any("router restarted" in n for n in s["notes"]), "site 1's router did not die")
    why += _need(fs is not None, "no failsafe") + _failsafe_confirmed(o)
    why += _need(fs is not None and fs.get("detect_to_command_ms") is not None and fs["detect_to_command_ms"] <= 100,
                 f"failsafe late: {fs}")
    return why + _need(not s["handovers"], f"a hand-over out of the overlap: {s['handovers']}")


def _check_backhaul_cut_early(o: Outcome) -> list[str]:
    """``backhaul-cut``: A could not share B's key over the cut backhaul: the hand-over is refused
    cleanly, A keeps authority and brings the drone home; no failsafe, B never holds a link."""
    s = o.summary
    why = _need(not s["handovers"], f"a hand-over happened: {s['handovers']}")
    why += _need(s["final_owner"] == "A", f"final authority {s['final_owner']}, expected A")
    why += _need(s["failsafe"] is None, "failsafe")
    why += _need(not any(e.gs == "B" for e in only(o.drone, LinkInstalled)), "B got a key")
    why += _need(bool(only(o.gs.get("A", []), HandoverFailed)), "A did not report the failed hand-over")
    return why + _need(s["distance_from_home_m"] is not None and s["distance_from_home_m"] < 5.0, "not landed at home")


def _check_no_cert(o: Outcome) -> list[str]:
    """``rogue-no-cert``: no certificate and another CA's are refused at connect; X's certificate with
    A's password gets nothing through on A's keys; the flight is unaffected."""
    done = o.rogue_done("no-cert")
    why = flight_unaffected(o) + _need(bool(done), "the attacker did not report")
    why += _need(done.get("no_certificate") == "refused", f"no certificate: {done.get('no_certificate')}")
    why += _need(done.get("other_ca") == "refused", f"another CA's certificate: {done.get('other_ca')}")
    why += _need(done.get("x_certificate") == "refused" or (done.get("pair_answered") == 0 and done.get("captured") == 0),
                 f"X's certificate as A: {done}")
    return why + _need(o.drops("auth_failed") + o.drops("unknown_epoch") == 0, "its frames reached the drone")


def _check_router_restart(o: Outcome) -> list[str]:
    """``router-restart``: an outage shorter than the loss threshold costs nothing: no failsafe, no
    new pairing, the same authority and both hand-overs."""
    s = o.summary
    why = flight_unaffected(o)
    why += _need(any("router restarted" in n for n in s["notes"]), "the router was not restarted")
    why += _need(s["failsafe"] is None, "failsafe")
    why += _need(len(only(o.drone, Paired)) == 1, "paired again")
    return why


def _check_failsafe_recover(o: Outcome) -> list[str]:
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


def _check_big_flood(o: Outcome) -> list[str]:
    """``big-flood``: oversized payloads from B's stolen password must cost the nodes nothing: the
    router drops those over 64 KiB, the nodes refuse the rest by length before copying them."""
    done, a = o.rogue_done("big-flood"), o.gs_counters("A")
    dropped = o.summary.get("drone_inbox_dropped", {})
    why = flight_unaffected(o)
    why += _need(done.get("big", 0) > 0 and done.get("huge", 0) > 0, "the attacker sent nothing")
    why += _need(dropped.get("up:oversize", 0) > 0, f"the drone counted no up:oversize ({dropped})")
    why += _need(o.drone_counter("pair_refused:oversize") > 0, "the drone counted no pair_refused:oversize")
    why += _need(a.get("linkkey_refused:oversize", 0) > 0, "A counted no linkkey_refused:oversize")
    why += _need(o.summary["authority_link"]["longest_silence_s"] <= 2.0,
                 f"authority link silent {o.summary['authority_link']['longest_silence_s']} s")
    return why


def _check_operator_consent(o: Outcome) -> list[str]:
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


def _check_consent_bound(o: Outcome) -> list[str]:
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


def _check_insider_heir(o: Outcome) -> list[str]:
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


def _check_key_escrow(o: Outcome) -> list[str]:
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


def repair_after_restart(drone: list[AnyRecord]) -> float | None:
    """Seconds from the restarted companion's ``restarted`` event to the owner's pairing (None: none)."""
    restarted = next((e for e in only(drone, Restarted)), None)
    if restarted is None:
        return None
    paired = next((e.t for e in only(drone, Paired) if e.t >= restarted.t and e.gs == restarted.owner), None)
    return None if paired is None else round(paired - restarted.t, 3)


def _check_stale_pairing(o: Outcome) -> list[str]:
    """``stale-pairing``: A's pairing message 1s, recorded earlier and captured in this flight, are
    replayed right after a companion restart. A replay must spend none of A's pairing tokens: the
    owner re-pairs in time (no failsafe) and no pairing query of A is refused for its rate."""
    done = o.rogue_done("stale-pairing")
    why = _check_companion_restart(o)
    why += _need(done.get("held", 0) >= 3 and done.get("replayed", 0) > 0, f"the attacker replayed nothing: {done}")
    why += _need(o.drone_counter("pair_refused:rate_limited") == 0,
                 f"{o.drone_counter('pair_refused:rate_limited')} pairing queries of A refused for their rate: "
                 "replays spent A's tokens")
    return why


_STOP_A = Fault(AIRBORNE, "gsA", signal.SIGSTOP, "GS A goes silent (SIGSTOP)")
_KILL_B = Fault(REGION_ENTERED, "gsB", signal.SIGKILL, "GS B crashes (SIGKILL)")
_RESUME_A = Fault(FAILSAFE_FIRED, "gsA", signal.SIGCONT, "GS A wakes up (SIGCONT)")
RESTART = -1
LINK_DOWN, LINK_UP = -2, -3  # a testbed link (``backhaul``) cut or mended
_HANG_A = Fault(REGION_ENTERED, "gsA", signal.SIGSTOP, "GS A hangs (SIGSTOP) in the overlap", after=0.5)
_WAKE_A = Fault(REGION_ENTERED, "gsA", signal.SIGCONT, "GS A wakes up (SIGCONT) 5 s later", after=5.5)
_RESTART_DRONE = Fault(AIRBORNE, "drone", RESTART, "the companion is killed (SIGKILL) and started again", down=0.3,
                       after=1.0)
_SLOW_RESTART_DRONE = Fault(AIRBORNE, "drone", RESTART, "the companion is killed (SIGKILL), back 1.5 s later",
                            down=1.5, after=1.0)
_SITE1_DOWN = Fault(REGION_ENTERED, "router", RESTART, "site 1's router dies; back 6 s later", down=6.0, after=0.5)
_SITE1_DOWN_ALONE = Fault(AIRBORNE, "router", RESTART, "site 1's router dies before the overlap; back 6 s later",
                          down=6.0, after=0.5)
_BACKHAUL_CUT_EARLY = Fault(BEFORE_GS_A, "backhaul", LINK_DOWN, "the backhaul between the sites is cut before A pairs")
_BACKHAUL_CUT = Fault(AIRBORNE, "backhaul", LINK_DOWN, "the backhaul between the sites is cut in flight")
_RESTART_ROUTER = Fault(AIRBORNE, "router", RESTART, "the router is killed and started again 0.8 s later", down=0.8)

def _check_fc_rogue_radio(o: Outcome) -> list[str]:
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


def _check_fake_autopilot(o: Outcome) -> list[str]:
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
    why += _need(drops.get("dropped:before_autopilot", 0) > 0 and drops.get("dropped:foreign_endpoint", 0) > 0,
                 f"the fake's datagrams were not dropped by reason: {drops}")
    near_b = [e.position for e in only(o.drone, DroneStatus)
              if e.position and distance_m(GS_B, GeoPoint(e.position[0], e.position[1])) < COVERAGE_RADIUS_M]
    why += _need(not near_b, f"the drone believed it was in B's coverage {len(near_b)} times")
    to_b = [h for h in s["handovers"] if h["to"] == "B"]
    why += _need(not to_b, f"authority followed the forged position: {to_b}")
    why += _need(s["failsafe"] is not None and s["failsafe"]["action"] == "LAND", f"no failsafe LAND: {s['failsafe']}")
    why += _need(bool(only(o.drone, FailsafeConfirmed)), "the autopilot never showed the failsafe")
    why += _need("LAND" in (s["vehicle"].get("modes") or []), f"the real autopilot never went to LAND: {s['vehicle']}")
    return why


def _check_local_app(o: Outcome) -> list[str]:
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


SCENARIO_TABLE: tuple[Scenario, ...] = (
    Scenario("nominal", "the reference flight", "A->B and B->A in the overlap, landing at home", flight_unaffected),
    Scenario("rogue-no-key",
             "A's stolen router password (no keys): pairs with its own key, sends unsealed and forged-sealed LAND, "
             "replays captured frames; tries a wrong router password",
             "all dropped (unknown_epoch, auth_failed, replay; its pairing fails the tag: pair_refused:bad_mac); flight unaffected",
             _check_no_key, rogues=(RogueSpec("no-key", MISSION_STARTED, sim_s=40.0, min_wall=10.0),)),
    Scenario("rogue-unauthorized",
             "GS X (in the fleet, not authorized) pairs and flies, asks for B's link key, publishes on A's key",
             "no answer: the router ACL stops its queries (the drone would refuse them before crypto); flight unaffected",
             _check_unauthorized, rogues=(RogueSpec("unauthorized", MISSION_STARTED, sim_s=30.0, min_wall=8.0),), gs_x=True),
    Scenario("link-loss", "GS A goes silent after take-off", "failsafe LAND <= 100 ms after the 3 s threshold",
             _check_link_loss, faults=(_STOP_A,)),
    Scenario("gs-crash", "GS B dies as the drone enters the overlap",
             "the hand-over times out, authority stays with A, A brings it home", _check_gs_crash, faults=(_KILL_B,)),
    Scenario("router-restart",
             "the router dies in flight (SIGKILL) and is started again on the same endpoint 0.8 s later",
             "every node reconnects by itself; links and authority unchanged, no failsafe; both hand-overs",
             _check_router_restart, faults=(_RESTART_ROUTER,)),
    Scenario("gs-hang",
             "GS A, the authority, hangs in the overlap (SIGSTOP for 5 s) and wakes up (SIGCONT)",
             "the emergency hand-over to B (proven link); A learns it is no longer the authority and none of its "
             "commands is forwarded; B hands back to A as usual",
             _check_gs_hang, faults=(_HANG_A, _WAKE_A)),
    Scenario("lossy-radio",
             "every radio link loses 20 % of frames at random and delays the rest by 50 ± 20 ms",
             "no false failsafe, the authority link never LOST; both hand-overs; landing at home",
             _check_lossy_radio, radio=("--sil-loss", "0.2", "--sil-delay-ms", "50", "--sil-jitter-ms", "20")),
    Scenario("companion-restart",
             "the drone's companion node is killed in flight (SIGKILL) and started again",
             "the vehicle flies on; the node comes back with owner A and its epoch, A re-pairs (fresh keys) within "
             "the loss threshold, shares B's key again; both hand-overs; nobody else gets authority",
             _check_companion_restart, faults=(_RESTART_DRONE,)),
    Scenario("site-router-down",
             "two sites (a router each, meshed); the router of A's site dies in the overlap while A holds authority, "
             "and is back 6 s later",
             "the drone moves to site 2's router at once; A is cut off: the emergency hand-over to B (proven), no "
             "failsafe; B hands back to A when the flight returns",
             _check_site_router_down, faults=(_SITE1_DOWN,), sites=True),
    Scenario("site-router-down-alone",
             "two sites; the router of A's site dies after take-off, before the overlap (only site 1 in range)",
             "A's link is silent: failsafe LAND <= 100 ms after the 3 s threshold; no hand-over",
             _check_site_router_down_alone, faults=(_SITE1_DOWN_ALONE,), sites=True, fixed_moment=True),
    Scenario("backhaul-cut",
             "two sites; the backhaul between their routers is cut before A pairs (before key sharing)",
             "A cannot share B's key: the hand-over is refused cleanly, authority stays with A, which brings the "
             "drone home; no failsafe",
             _check_backhaul_cut_early, faults=(_BACKHAUL_CUT_EARLY,), sites=True, fixed_moment=True),
    Scenario("backhaul-cut-late",
             "two sites; the backhaul between their routers is cut after take-off (after key sharing)",
             "both hand-overs still complete (they need no backhaul: each site's radio reaches the drone); "
             "gap 0, no failsafe",
             flight_unaffected, faults=(_BACKHAUL_CUT,), sites=True),
    Scenario("rogue-no-cert",
             "mutual TLS (--tls): with A's stolen password, a client without a certificate, one with another CA's "
             "certificate for A, and one with X's real certificate, in flight",
             "the first two refused at connect; X's certificate as A gets nothing through (ACL: CN and user); "
             "flight unaffected",
             _check_no_cert, rogues=(RogueSpec("no-cert", MISSION_STARTED, go=AIRBORNE, sim_s=20.0, min_wall=5.0),),
             tls=True),
    Scenario("failsafe-recover",
             "GS A goes silent after take-off (SIGSTOP), the drone enters its failsafe; A wakes (SIGCONT) and its "
             "operator's standing request (--take-control) asks for control back",
             "failsafe LAND, then LINKED(A, epoch+1) by A's explicit request; the vehicle goes on landing",
             _check_failsafe_recover, faults=(_STOP_A, _RESUME_A), gs_a_extra=("--take-control",), fixed_moment=True),
    Scenario("key-injection",
             "B's router password only: a second queryable on backhaul/B/linkkey/* answers A's key-sharing "
             "queries with forged replies (random bytes, a Noise message 2 made with its own key)",
             "A refuses them by their tag (linkkey_reply:bad_mac), takes the real B's key; flight unaffected",
             _check_key_injection, rogues=(RogueSpec("key-injection", BEFORE_GS_A, sim_s=1600.0, min_wall=400.0),)),
    Scenario("linkkey-knockout",
             "B's router password only: key-sharing queries to A claiming to be B (message 1 made with its own key) "
             "and junk, 5/s in flight",
             "A refuses them before any crypto (linkkey_refused:bad_mac / malformed), its live link untouched",
             _check_linkkey_knockout,
             rogues=(RogueSpec("linkkey-knockout", MISSION_STARTED, go=AIRBORNE, sim_s=80.0, min_wall=15.0, rate=5.0),)),
    Scenario("pair-replay",
             "the drone's router password captures A's pairing message 1 before A starts; A's password replays it "
             "every second in flight",
             "the drone answers with its first message 2 again (pair_repeated): no new key; authority and A's link untouched",
             _check_pair_replay, rogues=(RogueSpec("pair-replay", BEFORE_GS_A, go=AIRBORNE, sim_s=48.0, min_wall=12.0),)),
    Scenario("pair-flood",
             "B's private key and router password: >= 2000 valid pairing queries/s for 10 s in flight",
             "refused before any crypto (pair_refused:rate_limited), at most a few answered; telemetry never stops",
             _check_pair_flood,
             rogues=(RogueSpec("pair-flood", MISSION_STARTED, go=AIRBORNE, sim_s=0.0, min_wall=10.0, rate=2500.0),)),
    Scenario("uplink-policy",
             "B's private key: pairs as B after both hand-overs and sends 12 dangerous message ids sealed; A's "
             "router password: the same ids unsealed and with a random key, all flight",
             "dropped by the handover authority (not_authority, denied_by_policy) and the security module; "
             "nothing reaches the vehicle",
             _check_uplink_policy,
             rogues=(RogueSpec("uplink-unsealed", MISSION_STARTED, go=AIRBORNE, sim_s=100.0, min_wall=10.0),
                     RogueSpec("uplink-sealed", MISSION_STARTED, go=HANDOVERS_DONE, sim_s=0.0, min_wall=1.5))),
    Scenario("gateway-flood",
             "a local process floods GS A's GCS gateway: HEARTBEATs from 320 UDP source ports and garbage, in flight",
             "A keeps flying and counts the refused applications (app_table_full)",
             _check_gateway_flood, rogues=(RogueSpec("gateway-flood", MISSION_STARTED, go=AIRBORNE, sim_s=100.0, min_wall=10.0),),
             gcs_a=True),
    Scenario("operator-consent",
             "MAVLink operator control through A's and B's GCS gateways (pymavlink applications) in the overlap: B "
             "asks without consent, then with A's consent, then each takes control with takeover allowed; B "
             "releases back to A and the mission goes on",
             "nothing moves without consent; B in control within the 10 s window after consent and at once with "
             "takeover allowed; no emergency hand-over, no failsafe, landing at home",
             _check_operator_consent, operators=MISSION_STARTED),
    Scenario("consent-bound",
             "three authorized GSs, an operator application on each gateway, in the overlap: B asks, X asks 1.1 s "
             "later, A's operator consents naming X (refused) then B; B's operator declines X, X asks again; B "
             "allows takeover in its epoch, A takes it, gives it back by consent, then asks again",
             "control goes to B, the requester named; X is not shown while B's request stands nor after its "
             "decline, and never holds authority; an earlier epoch's allow-takeover moves nothing; landing at home",
             _check_consent_bound, consent_ops=MISSION_STARTED, x_authorized=True),
    Scenario("big-flood",
             "B's router password only: 60 KiB envelopes, pairing and key-sharing queries (20/s each) and 4 MiB "
             "ones (1/s each), from the overlap on (through the hand-over)",
             "the router drops > 64 KiB, the nodes refuse the rest by length (oversize); telemetry never stops",
             _check_big_flood,
             rogues=(RogueSpec("big-flood", MISSION_STARTED, go=REGION_ENTERED, sim_s=40.0, min_wall=10.0, rate=20.0),)),
    Scenario("insider-heir",
             "two sites (mutual TLS, meshed); B's own key, router password and certificate (an authorized GS "
             "gone bad): pairs about once a second from take-off on, outside its coverage, sends RETURN_TO_LAUNCH, "
             "asks for control, and once in command ARM and TAKEOFF; A, the authority, hangs (SIGSTOP) after "
             "take-off; watched 3 s on after the landing",
             "never B: the failsafe (or A keeps authority); no authority to B outside its coverage, in the air or "
             "landed, none of B's commands forwarded",
             _check_insider_heir, rogues=(RogueSpec("insider-heir", MISSION_STARTED, sim_s=120.0, min_wall=30.0),),
             faults=(Fault(AIRBORNE, "gsA", signal.SIGSTOP, "GS A hangs (SIGSTOP) after take-off"),),
             sites=True, linger=3.0, fixed_moment=True),
    Scenario("key-escrow",
             "B's own key and router password, the drone's password: genuine key-sharing queries to A for link "
             "(drone, A), again and again from take-off to landing; under any secret A hands out, frames to A as "
             "the drone and to the drone as A",
             "A's live link is never replaced (no link_confirmed of a secret it handed out); flight unaffected",
             _check_key_escrow,
             rogues=(RogueSpec("key-escrow", MISSION_STARTED, go=AIRBORNE, sim_s=240.0, min_wall=60.0),),
             plain_router=True),
    Scenario("stale-pairing",
             "A's pairing message 1s (recorded in earlier flights, and captured all flight long with the drone's "
             "password) replayed with A's password around a companion restart (killed, back 1.5 s later: A is "
             "re-pairing while it boots)",
             "no replay spends A's pairing tokens (no pair_refused:rate_limited): A re-pairs in time, no failsafe; "
             "both hand-overs",
             _check_stale_pairing, faults=(_SLOW_RESTART_DRONE,),
             rogues=(RogueSpec("stale-pairing", BEFORE_GS_A, go=DRONE_RESTARTED, sim_s=24.0, min_wall=6.0),),
             plain_router=True),
    Scenario("local-app",
             "A's gateway requires signed applications (--gcs-signing require, a key the launcher provisions); in the "
             "overlap, with A in control, B's operator asks for control and an unsigned local application on A's "
             "host (a fresh UDP socket, sysid 42) consents, allows takeover, sends LAND, disarm, a mode change, "
             "MISSION_CLEAR_ALL and a consent signed with a guessed key; A's operator's signed application holds the "
             "vehicle meanwhile and resumes the mission",
             "nothing the local application sends moves authority or reaches the vehicle (DENIED / NOT_IN_CONTROL / "
             "MISSION_ACK DENIED, counted; the guessed key dropped); its parameter read answered; the signed "
             "application obeyed; flight unaffected",
             _check_local_app, rogues=(RogueSpec("local-app", MISSION_STARTED, go=HANDOVERS_DONE, sim_s=0.0, min_wall=60.0),),
             app_signing=True),
    Scenario("fc-rogue-radio",
             "a radio on the autopilot's TELEM2 (no keys) sends arm, a mode change to LAND and MISSION_CLEAR_ALL once "
             "a second in flight (with --fc-signing off: the control, the same attack on an unsigned autopilot)",
             "the autopilot link is MAVLink-signed: the autopilot obeys and answers none of it; flight unaffected "
             "(--fc-signing off: the autopilot obeys, the flight does not complete)",
             _check_fc_rogue_radio,
             rogues=(RogueSpec("fc-radio", MISSION_STARTED, go=AIRBORNE, sim_s=20.0, min_wall=8.0),), telem2=True),
    Scenario("fake-autopilot",
             "a local process on the companion host writes into its UDP vehicle link (the companion listening, as on "
             "PX4's onboard link): a fake autopilot (sysid 7) with positions at B's centre from before the drone "
             "starts; in flight the autopilot's own ids, positions at B's centre and LAND mode, while GS A goes "
             "silent (SIGSTOP)",
             "the drone adopts system 1 only and sends the fake nothing (dropped: before_autopilot, "
             "foreign_endpoint); its position and authority never follow the forged one (no hand-over to B); the "
             "failsafe LAND reaches the real autopilot, which shows it",
             _check_fake_autopilot,
             rogues=(RogueSpec("fake-autopilot", BEFORE_DRONE, go=AIRBORNE, sim_s=60.0, min_wall=15.0),),
             faults=(Fault(AIRBORNE, "gsA", signal.SIGSTOP, "GS A goes silent (SIGSTOP)", after=1.0),),
             vehicle_udpin=True, fixed_moment=True),
)
SCENARIO_BY_NAME: dict[str, Scenario] = {s.name: s for s in SCENARIO_TABLE}
#: Scenarios that need a router per site.
SCENARIO_SITES: dict[str, bool] = {s.name: s.sites for s in SCENARIO_TABLE}
#: Scenarios that need mutual TLS.
SCENARIO_TLS: dict[str, bool] = {s.name: s.tls for s in SCENARIO_TABLE}
SCENARIOS = tuple(SCENARIO_BY_NAME)
ATTACK_SCENARIOS = tuple(s.name for s in SCENARIO_TABLE if s.rogues)
assert len(SCENARIOS) == len(SCENARIO_TABLE) and all(
    t in TRIGGERS for s in SCENARIO_TABLE for t in [r.launch for r in s.rogues] + [r.go for r in s.rogues if r.go])


def scenario_help() -> str:
    """The scenario list for ``zdrone demo --help``."""
    width = max(len(s.name) for s in SCENARIO_TABLE)
    lines = ["scenarios:"]
    for s in SCENARIO_TABLE:
        text = textwrap.wrap(f"{s.description}. Success: {s.expected}.", 96 - width)
        lines += [f"  {s.name:<{width}}  {text[0]}", *(f"  {'':<{width}}  {t}" for t in text[1:])]
    return "\n".join(lines)


@dataclass
class DemoOptions:
    out: Path | None = None
    scenario: str = "nominal"
    speedup: float = 2.0
    live: bool | None = None  # None: only when stdout is a terminal
    timeout: float | None = None
    command_rate: float = 5.0
    report: bool = True
    # for the benches
    cipher: str = "zdrone"
    paper_heartbeat: bool = False
    tap: bool = False
    quiet: bool = False
    max_wall: float | None = None  # stop measuring after this many wall seconds (not a failure)
    mission: str = "reference"
    autopilot: str = "px4"  # personality of the built-in simulator
    radio: tuple[str, ...] = ()  # the drone's --sil-loss/--sil-bursts/--sil-delay-ms/--sil-jitter-ms options
    spec: "Scenario | None" = None  # a scenario made on the fly (bench chaos) instead of ``scenario``
    moment: str | None = None  # the scenario's fault moved to this moment (``MOMENTS``); None: its own
    sites: bool = False  # a router per GS site (two, meshed) instead of one
    tls: bool = False  # one router, mutual TLS only (a fleet CA and certificates)
    vehicle: str | None = None  # an autopilot already running (no simulator started)
    ready_after: float | None = None  # the built-in simulator's start-up, simulated s (None: its short default)
    netns: bool = False  # with sites: each site and the drone in their own network namespace (root)
    fc_signing: str = "prefer"  # the drone's --fc-signing (require | prefer | off)


@dataclass
class Child:
    name: str
    proc: subprocess.Popen
    log: Path
    stopped: bool = False
    args: list[str] = field(default_factory=list)
    ns: str | None = None  # the network namespace it runs in (``--netns``)


@dataclass
class Demo:
    opts: DemoOptions
    out: Path
    children: dict[str, Child] = field(default_factory=dict)
    t0: float = field(default_factory=time.monotonic)
    notes: list[str] = field(default_factory=list)
    progress: dict[str, Any] = field(default_factory=dict)
    router: str = ""
    gcs_port: int | None = None
    gcs_port_b: int | None = None  # GS B's gateway, for the operators
    gcs_port_x: int | None = None  # GS X's gateway (``consent-bound``)
    telem2_port: int | None = None  # the simulator's TELEM2 (UDP), when the scenario wants one
    vehicle_port: int | None = None  # the UDP port the companion listens on for its autopilot (``vehicle_udpin``)
    fired: set[str] = field(default_factory=set)
    fired_at: dict[str, float] = field(default_factory=dict)  # trigger -> time of day it came
    fault_log: list[dict[str, Any]] = field(default_factory=list)  # each fault injected: t, target, text, ends
    pending_go: set[str] = field(default_factory=set)
    restarting: dict[str, tuple[str, int]] = field(default_factory=dict)  # restarted child -> (ready line, count before)
    scheduled: list[tuple[float, Fault]] = field(default_factory=list)  # (monotonic due time, fault)
    sites: dict[str, dict[str, Any]] = field(default_factory=dict)  # with --sites: site -> endpoint, GSs
    links: dict[str, SwitchedLink] = field(default_factory=dict)  # with --sites: radio per site, backhaul per pair
    coverage: "SiteCoverage | None" = None
    truth: "TruthReceiver | None" = None
    radio_log: "EventLog | None" = None
    site_of_endpoint: dict[str, str] = field(default_factory=dict)  # the drone's path endpoint -> site
    netns: "NetnsTopology | None" = None  # with --netns: the namespaces of the sites and the drone
    _a_tail: "LogTail | None" = None  # GS A's log, read as it grows until the mission starts

    @property
    def spec(self) -> Scenario:
        spec = self.opts.spec or SCENARIO_BY_NAME[self.opts.scenario]
        return spec.at_moment(self.opts.moment) if self.opts.moment else spec

    # --------------------------------------------------------------- processes
    def start(self, name: str, args: list[str], append: bool = False, ns: str | None = None) -> Child:
        log = self.out / f"{name}.log"
        fh = open(log, "a" if append else "w")
        prefix = self.netns.exec_prefix(ns) if (ns and self.netns) else []  # ``ip netns exec`` execs: same PID
        try:  # dies with the launcher, however it ends (zdrone.sil.procs)
            proc = procs.spawn([*prefix, PY, *args], stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                               cwd=self.out)
        finally:
            fh.close()
        child = Child(name, proc, log, args=list(args), ns=ns)
        self.children[name] = child
        return child

    def restart(self, name: str, down: float) -> None:
        """Kill ``name`` (SIGKILL), wait ``down`` seconds, start it again with the same arguments."""
        child = self.children[name]
        if child.proc.poll() is None:
            os.kill(child.proc.pid, signal.SIGKILL)
        child.proc.wait(5.0)
        time.sleep(down)
        needle = _ready_line(name)
        if needle:
            self.restarting[name] = (needle, child.log.read_text(errors="replace").count(needle))
        self.start(name, child.args, append=True, ns=child.ns)

    def _wait_restarted(self, timeout: float) -> None:
        """Before the end: every restarted child has finished starting (its ready line is there again),
        so that SIGTERM finds its handler in place (a router stopped mid-start dies of the signal)."""
        deadline = time.monotonic() + timeout
        for name, (needle, before) in self.restarting.items():
            child = self.children[name]
            while time.monotonic() < deadline and child.proc.poll() is None:
                if child.log.read_text(errors="replace").count(needle) > before:
                    break
                time.sleep(0.05)
        self.restarting.clear()

    def wait_line(self, child: Child, needle: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if needle in child.log.read_text(errors="replace"):
                return
            if child.proc.poll() is not None:
                raise RuntimeError(f"{child.name} exited ({child.proc.returncode}): {child.log.read_text()[-600:]}")
            time.sleep(0.05)
        raise RuntimeError(f"{child.name}: {needle!r} not seen within {timeout:.0f} s")

    def signal(self, name: str, sig: int) -> None:
        child = self.children.get(name)
        if child is not None and child.proc.poll() is None:
            os.kill(child.proc.pid, sig)

    def shutdown(self, timeout: float = 10.0) -> dict[str, int | None]:
        """SIGTERM the nodes first (so they close their sessions while the router is still up), then
        the simulator and the router; SIGKILL only what does not exit in time; return exit codes."""
        codes: dict[str, int | None] = {}
        self._wait_restarted(timeout)
        nodes = [c for n, c in self.children.items() if n != "sim" and not n.startswith("router")]
        infra = [c for n, c in self.children.items() if n == "sim" or n.startswith("router")]
        for group in (nodes, infra):
            for child in reversed(group):
                if child.proc.poll() is None:
                    try:
                        os.kill(child.proc.pid, signal.SIGCONT)  # a stopped process cannot handle SIGTERM
                        child.proc.terminate()
                    except ProcessLookupError:
                        pass
            deadline = time.monotonic() + timeout
            for child in group:
                try:
                    child.proc.wait(max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    try:
                        os.kill(child.proc.pid, signal.SIGUSR1)  # its stacks go to its log, for diagnosis
                        time.sleep(0.5)
                    except ProcessLookupError:
                        pass
                    child.proc.kill()
                    child.proc.wait(5)
                    self.notes.append(f"{child.name} had to be killed (stacks in {child.log.name})")
                procs.forget(child.proc)
                codes[child.name] = child.proc.returncode
        self._report_crashes(codes)
        self.close_links()
        return {n: codes.get(n) for n in self.children}

    def _report_crashes(self, codes: dict[str, int | None]) -> None:
        """A child that died of a crash signal (SIGSEGV, SIGABRT, ...): a note with the signal and the
        end of its log, where faulthandler left its stacks (``zdrone.crashes``)."""
        from ..crashes import crash_report

        for name, code in codes.items():
            report = crash_report(name, code, self.children[name].log.read_text(errors="replace"))
            if report is not None:
                self.notes.append(report)

    # ----------------------------------------------------------------- running
    def start_core(self) -> None:
        """Fleet, router, simulator and drone node (every scenario and bench starts with these)."""
        o = self.opts
        rport, sport = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM)
        self.router = f"tcp/127.0.0.1:{rport}"
        if o.sites or self.spec.sites:  # a router per site, meshed; GS A (and X) at site 1, B at site 2
            self._start_sites(rport)
        else:
            tls = o.tls or self.spec.tls
            if tls:
                self.router = f"tls/127.0.0.1:{rport}"
            init_fleet(self.out / "fleet", tls=tls, nodes_spec=self._nodes_spec())
            self._export_bundles(["router"])
            r = self.start("router", self._z() + ["router", "-c", "bundles/router/router/router.json5", "--listen", self.router]
                           + (["--tap", "tap.json"] if o.tap else []))
            self.wait_line(r, "listening", 20)
        telem2: list[str] = []
        if self.spec.telem2 and o.vehicle is None:
            self.telem2_port = free_port(socket.SOCK_DGRAM)
            telem2 = ["--telem2", f"udpin:127.0.0.1:{self.telem2_port}"]
        if o.vehicle is not None:
            vehicle = o.vehicle
        elif self.spec.vehicle_udpin:  # the companion listens, the simulator (either personality) sends to it
            self.vehicle_port = free_port(socket.SOCK_DGRAM)
            sim = self.start("sim", self._z() + ["sim", "--autopilot", o.autopilot, "--mavlink",
                                                 f"udpout:127.0.0.1:{self.vehicle_port}", "--speedup", str(o.speedup)]
                             + self._truth_args() + telem2 + self._ready_args(), ns=self._ns())
            self.wait_line(sim, "zdrone sim:", 20)
            vehicle = f"udpin:127.0.0.1:{self.vehicle_port}"
        elif o.autopilot == "ardupilot":  # like ArduPilot SITL: a TCP server that boots on the first client
            tport = free_port(socket.SOCK_STREAM)
            sim = self.start("sim", self._z() + ["sim", "--autopilot", "ardupilot", "--mavlink", f"tcpin:127.0.0.1:{tport}",
                                                 "--speedup", str(o.speedup)] + self._truth_args() + telem2
                             + self._ready_args(), ns=self._ns())
            self.wait_line(sim, "zdrone sim:", 20)
            vehicle = f"tcp:127.0.0.1:{tport}"
        else:
            sim = self.start("sim", self._z() + ["sim", "--autopilot", "px4", "--mavlink", f"udpin:127.0.0.1:{sport}",
                                                 "--speedup", str(o.speedup)] + self._truth_args() + telem2
                             + self._ready_args(), ns=self._ns())
            self.wait_line(sim, "zdrone sim:", 20)
            self._wait_coverage()
            vehicle = f"udpout:127.0.0.1:{sport}"
        # Timers are wall-clock while the simulator may run faster: scale the hand-over timeout so that
        # a failed hand-over is still noticed while the vehicle is inside the overlap (5 s at 1x).
        ho_timeout = max(1.5, 5.0 / o.speedup)
        coverage = [] if self.links else ["--sil-coverage"]  # with sites: the radio links are the coverage
        self._fire(BEFORE_DRONE, None)
        for r in self.spec.rogues:  # attackers racing the companion's start
            if r.launch == BEFORE_DRONE:
                self.wait_line(self.children[f"rogue-{r.mode}"], "rogue: ready", 30)
        trust: list[str] = []
        if o.fc_signing == "off":  # an unsigned link's positions grant no authority unless opted in (issue 29)
            trust = ["--trust-unsigned-position"]
            self.notes.append("--fc-signing off: the drone trusts unsigned positions (--trust-unsigned-position): "
                              "any process that can write into its vehicle link can move its authority")
        drone = self.start("drone", self._zn() + ["drone", "--id", "d1", *self._common(), "--vehicle", vehicle,
                                                  *coverage, "--events", "drone.jsonl", "--handover-timeout",
                                                  str(ho_timeout), "--fc-signing", o.fc_signing, *trust,
                                                  *self._bench_extra(),
                                                  *self.spec.radio, *o.radio],
                           ns=self._ns())
        self.wait_line(drone, "ready", 40)

    def _start_sites(self, rport: int) -> None:
        """A router per site, meshed through a backhaul link per pair of sites; the drone reaches each
        site through that site's radio link, up only while the vehicle is inside the site's coverage
        (from the simulator's true position). No frame filter: coverage is which links exist.
        On loopback the links are relays the testbed opens and closes; with ``--netns`` each site and
        the drone have their own network namespace and the links are veth pairs."""
        if self.opts.netns:
            self._start_sites_netns()
            return
        site_eps = [f"tls/127.0.0.1:{rport}", f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]
        self.router = site_eps[0]
        fleet = init_fleet(self.out / "fleet", sites=site_eps, nodes_spec=self._nodes_spec())
        self.sites = load_sites(self.out / "fleet")
        self._export_bundles(list(self.sites))
        names = list(self.sites)
        ports = {site: int(self.sites[site]["endpoint"].rsplit(":", 1)[1]) for site in names}
        for n, site in enumerate(names):
            connect: list[str] = []
            for earlier in names[:n]:  # site N reaches sites < N over its backhaul link to each
                link = RadioLink(f"backhaul-{earlier}-{site}", ("127.0.0.1", ports[earlier]), up=True)
                self.links[link.name] = link
                connect += ["--connect", f"tls/{link.endpoint}"]
            name = "router" if n == 0 else f"router{n + 1}"
            r = self.start(name, self._z() + ["router", "-c", f"bundles/{site}/router/{site}.json5", *connect])
            self.wait_line(r, "listening", 20)
        radios = {site: RadioLink(site, ("127.0.0.1", ports[site]), up=self.opts.vehicle is not None) for site in names}
        self.links.update(radios)
        self.site_of_endpoint = {f"tls/{link.endpoint}": site for site, link in radios.items()}
        self._start_coverage(fleet, radios, "127.0.0.1")

    def _start_sites_netns(self) -> None:
        """Each site and the drone in their own namespace: the site's router listens on 127.0.0.1
        (its GSs) and on its radio address (the drone, and the higher sites over the backhaul)."""
        names = ["site-1", "site-2"]
        topo = self.netns = NetnsTopology(names)
        topo.create()
        port = 7447  # each router alone in its namespace
        fleet = init_fleet(self.out / "fleet", sites=[f"tls/{topo.radio_ip[site]}:{port}" for site in names],
                           nodes_spec=self._nodes_spec())
        self.sites = load_sites(self.out / "fleet")
        self._export_bundles(list(self.sites))
        self.router = f"tls/127.0.0.1:{port}"  # inside site 1's namespace (the attackers run there)
        for n, site in enumerate(names):
            name = "router" if n == 0 else f"router{n + 1}"
            r = self.start(name, self._z() + ["router", "-c", f"bundles/{site}/router/{site}.json5", "--listen",
                                              f"tls/127.0.0.1:{port}", "--listen", f"tls/{topo.radio_ip[site]}:{port}"],
                           ns=topo.site_ns[site])
            self.wait_line(r, "listening", 20)
        self.links.update(topo.backhauls)
        self.links.update(topo.radios)
        self.site_of_endpoint = {f"tls/{topo.radio_ip[site]}:{port}": site for site in names}
        if self.opts.vehicle is not None:
            raise RuntimeError("--netns runs the built-in simulator in the drone's namespace: no --vehicle")
        self._start_coverage(fleet, dict(topo.radios), topo.control_host)

    def _start_coverage(self, fleet: Any, radios: dict[str, SwitchedLink], truth_host: str) -> None:
        self.radio_log = EventLog(self.out / "radio.jsonl", "radio")
        if self.opts.vehicle is None:  # the built-in simulator tells where the vehicle truly is
            log_ = self.radio_log
            self.coverage = SiteCoverage(site_circles(fleet, self.sites), radios,
                                         lambda site, up, p: log_.write_record(RadioLinkChanged(
                                             site=site, up=up, position=(round(p.lat, 7), round(p.lon, 7), round(p.alt, 2)))))
            self.truth = TruthReceiver(self.coverage.update, truth_host)
        else:
            self.notes.append("--vehicle with --sites: no true position, every site's radio stays up")

    def _ns(self, gs: str | None = None) -> str | None:
        """With --netns: the drone's namespace, or GS ``gs``'s site's."""
        if self.netns is None:
            return None
        if gs is None:
            return self.netns.drone_ns
        return next(self.netns.site_ns[site] for site, info in self.sites.items() if gs in info["ground_stations"])

    def _ready_args(self) -> list[str]:
        """The simulator's start-up (``--ready-after``), if one was given."""
        return [] if self.opts.ready_after is None else ["--ready-after", f"{self.opts.ready_after:g}"]

    def _truth_args(self) -> list[str]:
        return ["--truth", f"{self.truth.host}:{self.truth.port}"] if self.truth is not None else []

    def _wait_coverage(self, timeout: float = 20.0) -> None:
        """With radio links: the first true position has set them (the drone starts in range)."""
        deadline = time.monotonic() + timeout
        while self.coverage is not None and self.coverage.updates == 0:
            if time.monotonic() > deadline:
                raise RuntimeError("no true position from the simulator: radio links cannot be set")
            time.sleep(0.05)

    def link_fault(self, target: str, up: bool) -> None:
        """Cut or mend a testbed link (``backhaul``: every backhaul link; a site's name: its radio, held
        down whatever the vehicle's position until mended, when the position decides again)."""
        for name, link in self.links.items():
            if name == target or (target == "backhaul" and name.startswith("backhaul-")):
                if self.coverage is not None and name in self.coverage.links:
                    self.coverage.jam(name, not up)
                else:
                    link.set_up(up)
                if self.radio_log is not None:
                    self.radio_log.write_record(LinkFault(link=name, up=up))

    def close_links(self) -> None:
        if self.truth is not None:
            self.truth.close()
            self.truth = None
        for link in self.links.values():
            link.close()
        self.links.clear()
        if self.netns is not None:
            self.netns.destroy()
            self.netns = None
        if self.radio_log is not None:
            self.radio_log.close()

    def _nodes_spec(self) -> list[tuple[str, str, int, Any, list[str]]] | None:
        """The fleet's nodes: the reference fleet, with X authorized for d1 if the scenario says so."""
        if not self.spec.x_authorized:
            return None
        return [(n, r, sid, c, [*a, "X"] if n == "d1" else a) for n, r, sid, c, a in DEFAULT_NODES]

    def start_gs(self, gs: str, *extra: str) -> Child:
        child = self.start(f"gs{gs}", self._zn() + ["gs", "--id", gs, *self._common(gs), "--events", f"{gs}.jsonl", *extra],
                           ns=self._ns(gs))
        self.wait_line(child, f"zdrone gs {gs}", 20)
        return child

    def start_rogue(self, r: RogueSpec, duration: float | None = None) -> Child:
        args = ["-m", "zdrone.sil.rogue", "--mode", r.mode, "--fleet", "fleet", "--router", self.router,
                "--duration", f"{duration if duration is not None else r.duration(self.opts.speedup):.2f}",
                "--events", "rogue.jsonl"]
        args += ["--wait-go"] if r.go else []
        args += ["--rate", str(r.rate)] if r.rate else []
        args += ["--gcs-port", str(self.gcs_port)] if self.gcs_port else []
        args += ["--fc-port", str(self.telem2_port)] if self.telem2_port else []
        args += ["--gcs-port-b", str(self.gcs_port_b)] if self.gcs_port_b else []
        args += ["--gcs-keys", GCS_KEYS] if self.spec.app_signing else []
        args += ["--vehicle-port", str(self.vehicle_port)] if self.vehicle_port else []
        return self.start(f"rogue-{r.mode}", args + list(r.args), ns=self._ns("A"))  # beside A, on site 1

    def run(self) -> dict[str, Any]:
        """Fly the run; whatever ends it (a child that fails to start, an exception, a signal turned
        into one) stops every process it started before the exception goes on."""
        try:
            return self._run()
        except BaseException as exc:  # a signal asks for a quick end: 2 s per group before SIGKILL
            self.shutdown(timeout=2.0 if isinstance(exc, (KeyboardInterrupt, procs.Terminated)) else 10.0)
            raise

    def _run(self) -> dict[str, Any]:
        o, spec = self.opts, self.spec
        self.start_core()
        gs_extra = ["--command-rate", str(o.command_rate), *self._bench_extra()] + (["--paper-heartbeat"] if o.paper_heartbeat else [])
        b_extra = list(gs_extra)
        if spec.operators or spec.app_signing or spec.consent_ops:
            self.gcs_port_b = free_port(socket.SOCK_DGRAM)
            b_extra += ["--gcs", f"udpin:127.0.0.1:{self.gcs_port_b}"]
        self.start_gs("B", *b_extra)
        self._fire(BEFORE_GS_A, None)
        for r in spec.rogues:  # attackers that must be in place before A starts (and pairs)
            if r.launch == BEFORE_GS_A:
                self.wait_line(self.children[f"rogue-{r.mode}"], "rogue: ready", 30)
        a_extra = ["--pair", "--mission", o.mission, *gs_extra, *spec.gs_a_extra]
        if spec.app_signing:  # A's operator application's key, as an operator provisions one (gs.appkeys)
            keys = self.out / GCS_KEYS
            keys.write_text(f"opsA hex:{os.urandom(32).hex()}\n")
            keys.chmod(0o600)
            a_extra += ["--gcs-signing", "require", "--gcs-keys", GCS_KEYS]
        if spec.gcs_a or spec.operators or spec.app_signing or spec.consent_ops:
            self.gcs_port = free_port(socket.SOCK_DGRAM)
            a_extra += ["--gcs", f"udpin:127.0.0.1:{self.gcs_port}"]
        self.start_gs("A", *a_extra)
        if spec.x_authorized:  # a third authorized GS: its key comes from A's key sharing, its operator on a gateway
            self.gcs_port_x = free_port(socket.SOCK_DGRAM)
            self.start_gs("X", *gs_extra, "--gcs", f"udpin:127.0.0.1:{self.gcs_port_x}")
        elif spec.gs_x:
            self.start("gsX", self._z() + ["gs", "--id", "X", *self._common("X"), "--drone", "d1", "--pair", "--mission",
                                           "reference", "--events", "X.jsonl"], ns=self._ns("X"))
        return self._watch()

    def _z(self) -> list[str]:
        return ["-m", "zdrone", "-v"]

    @property
    def _bench(self) -> bool:
        return self.opts.cipher != "zdrone" or self.opts.paper_heartbeat

    def _zn(self) -> list[str]:
        """The drone and GS command: production nodes have no cipher option, so the bench harness
        alone runs them with plain/Fernet (or the paper's separate heartbeat)."""
        return ["-m", "zdrone.harness", "-v"] if self._bench else self._z()

    def _bench_extra(self) -> list[str]:
        return ["--cipher", self.opts.cipher] if self._bench else []

    def _common(self, node: str | None = None) -> list[str]:
        """Fleet and router options of a node: with sites, a GS uses its site's router and the drone
        every site's (Zenoh moves it to another when its router dies)."""
        bundle = ["--fleet", f"bundles/{node or 'd1'}"]  # every node runs from its own bundle alone
        if self.sites and node is None:  # the drone: one session per site, through that site's radio
            return bundle + [a for ep in self.site_of_endpoint for a in ("--router", ep)]
        router = self.router
        if self.netns is not None:  # each GS reaches its own site's router inside the site's namespace
            return bundle + ["--router", router]
        if self.sites:
            router = next(s["endpoint"] for s in self.sites.values() if node in s["ground_stations"])
        return bundle + ["--router", router]

    def _export_bundles(self, routers: list[str]) -> None:
        """A bundle per host from the run's fleet (``bundles/<node>``: ``zdrone fleet export``), which
        each node and router runs from: nothing of the run's nodes sees another's secret. The
        attackers keep the whole fleet directory (they stand for stolen secrets)."""
        from ..fleet.bundle import export_bundle
        from ..fleet.files import load_fleet

        for node in [*load_fleet(self.out / "fleet").nodes, *routers]:
            export_bundle(self.out / "fleet", node, self.out / "bundles" / node)

    def _fire(self, trigger: str, live: "LiveView | None", t: float | None = None) -> None:
        """The flight reached ``trigger``: start, unleash or fault what the scenario ties to it."""
        if trigger in self.fired:
            return
        self.fired.add(trigger)
        self.fired_at[trigger] = time.time()
        spec = self.spec
        for r in spec.rogues:
            if r.launch == trigger:
                self.start_rogue(r)
                if live is not None:
                    live.event(t or time.time(), f"scenario: attacker {r.mode} starts")
            if r.go == trigger:
                self.pending_go.add(f"rogue-{r.mode}")
        for fault in spec.faults:
            if fault.trigger == trigger:
                self.scheduled.append((time.monotonic() + fault.after, fault))
        if spec.operators == trigger and self.gcs_port and self.gcs_port_b:
            self.start("operators", ["-m", "zdrone.sil.operator", "--a-port", str(self.gcs_port), "--b-port",
                                     str(self.gcs_port_b), "--events", "operator.jsonl"], ns=self._ns("A"))
            if live is not None:
                live.event(t or time.time(), "scenario: the operators of A and B start")
        if spec.consent_ops == trigger and self.gcs_port and self.gcs_port_b and self.gcs_port_x:
            self.start("operators", ["-m", "zdrone.sil.consent_ops", "--a-port", str(self.gcs_port), "--b-port",
                                     str(self.gcs_port_b), "--x-port", str(self.gcs_port_x), "--events", "operator.jsonl"],
                       ns=self._ns("A"))
            if live is not None:
                live.event(t or time.time(), "scenario: the operators of A, B and X start")
        self._inject_due(live)
        self._send_go(live)

    def _inject_due(self, live: "LiveView | None") -> None:
        """Carry out the faults whose time has come."""
        now = time.monotonic()
        due = [f for (when, f) in self.scheduled if when <= now]
        self.scheduled = [(w, f) for (w, f) in self.scheduled if w > now]
        for fault in due:
            t = time.time()
            if live is not None:
                live.event(t, f"scenario: {fault.text}")
            ends_one = fault.sig in (LINK_UP, signal.SIGCONT)  # the end of an earlier fault, not one of its own
            if ends_one:
                for entry in reversed(self.fault_log):
                    if entry["target"] == fault.target and entry["ends"] is None:
                        entry["ends"] = t
                        break
            else:
                entry = {"t": t, "target": fault.target, "text": fault.text, "ends": None}  # SIGKILL: never ends
                self.fault_log.append(entry)
            if fault.sig in (LINK_DOWN, LINK_UP):
                self.link_fault(fault.target, fault.sig == LINK_UP)
            elif fault.sig == RESTART:
                self.restart(fault.target, fault.down)
                entry["ends"] = time.time()
                self.notes.append(f"{fault.target} restarted after {fault.down} s down")
                if fault.target == "drone":
                    self._fire(DRONE_RESTARTED, live)
            else:
                self.signal(fault.target, fault.sig)
                self.children[fault.target].stopped = fault.sig != signal.SIGCONT

    def _send_go(self, live: "LiveView | None") -> None:
        """SIGUSR2 to each attacker whose moment came, once it has set up (its handler is in place)."""
        for name in sorted(self.pending_go):
            child = self.children.get(name)
            if child is None or child.proc.poll() is not None:
                continue
            if "rogue: ready" in child.log.read_text(errors="replace"):
                self.signal(name, signal.SIGUSR2)
                self.pending_go.discard(name)
                if live is not None:
                    live.event(time.time(), f"scenario: attacker {name.removeprefix('rogue-')} attacks")

    def _watch(self) -> dict[str, Any]:
        o = self.opts
        # the flight at the speed-up, plus a real autopilot's own start-up (ArduCopter: ~40 s until its EKF uses GPS)
        timeout = o.timeout or (60.0 + 240.0 / o.speedup + (EXTERNAL_BOOT_S if o.vehicle is not None else 0.0))
        deadline = time.monotonic() + timeout
        drone_log = self.out / "drone.jsonl"
        live = LiveView(o.scenario, enabled=o.live if o.live is not None else sys.stdout.isatty(), quiet=o.quiet)
        if o.max_wall is not None:
            deadline = min(deadline, time.monotonic() + o.max_wall)
        state = watch_state()
        self.progress = {}  # the last status as logged ("status"): read by the benches' progress displays
        drone_tail = LogTail(drone_log)  # only what is new each turn: the cost is flat in the flight's length
        with live:
            while time.monotonic() < deadline and not state["done"]:
                for ev in drone_tail.read():
                    self._on_event(ev, state, live)
                self._on_gs_events(live, state)
                self._inject_due(live)
                self._send_go(live)
                live.update(state["status"], time.monotonic() - self.t0)
                for name, child in self.children.items():
                    if child.proc.poll() is not None and name not in ("gsB", "gsA", "operators") and not name.startswith("rogue") \
                            and not child.stopped:
                        self.notes.append(f"{name} exited early ({_exit_text(child.proc.returncode)})")
                        state["done"] = True
                time.sleep(0.1)
        drone_tail.close()
        if self._a_tail is not None:
            self._a_tail.close()
        wall = time.monotonic() - self.t0
        codes = self.shutdown()
        return self._summarize(state, wall, codes, timed_out=not state["done"] and o.max_wall is None)

    def _on_gs_events(self, live: "LiveView", state: dict[str, Any]) -> None:
        if MISSION_STARTED in self.fired:
            return
        if self._a_tail is None:
            self._a_tail = LogTail(self.out / "A.jsonl")
        for e in self._a_tail.read():
            if isinstance(e, MissionStarted):
                self._fire(MISSION_STARTED, live)
            elif isinstance(e, MissionFailed):  # the GS gave up (it said why): the demo ends, not ok
                self.notes.append(f"GS A: mission failed: {e.reason}")
                live.event(e.t, f"GS A: mission failed: {e.reason}")
                state["done"] = True
                state["mission_failed"] = e.reason
                return

    def _on_event(self, ev: AnyRecord, state: dict[str, Any], live: "LiveView") -> None:
        """Follow one drone event: the flight's progress in ``state``, the scenario's moments, the live view."""
        if isinstance(ev, DroneStatus):
            state["status"] = ev
            self.progress["status"] = fields_of(ev)  # the benches' displays read the status as logged
            pos = ev.position
            if ev.armed:
                state["armed_seen"] = True
                if pos and pos[2] > 5.0:
                    state["flown"] = True  # an arm refused or undone on the ground is not the end
                if pos and pos[2] > 15.0:
                    self._fire(AIRBORNE, live, ev.t)
            if pos and distance_m(DELIVERY, GeoPoint(pos[0], pos[1])) < NEAR_DELIVERY_M:
                state["near_delivery"] = True
                if ev.landed_state == 1 and pos[2] < 1.0 and \
                        distance_m(DELIVERY, GeoPoint(pos[0], pos[1])) <= DELIVERY_RADIUS_M:
                    state["delivered"] = True  # on the ground at the delivery point (the drone's own status)
            landed = ev.landed_state == 1 and not ev.armed
            if state.get("flown") and landed:  # the end (or, with ``linger``, that much later)
                state.setdefault("final_position", list(pos) if pos else pos)
                landed_at = state.setdefault("landed_at", time.monotonic())
                state["done"] = time.monotonic() >= landed_at + self.spec.linger
            return
        if isinstance(ev, RegionEntered):
            state["region_entered"] += 1
            self._fire(REGION_ENTERED, live, ev.t)
            if state.get("near_delivery"):
                self._fire(RETURNING, live, ev.t)
        if isinstance(ev, HandoverStart):
            self._fire(HANDOVER_STARTED, live, ev.t)
        if isinstance(ev, HandoverComplete):
            state["handovers"].append(_picked(ev, ("from", "to", "epoch", "time", "kind", "position")))
            if len(state["handovers"]) == 2:
                self._fire(HANDOVERS_DONE, live, ev.t)
        if isinstance(ev, Failsafe):
            state["failsafe"] = ev
            self._fire(FAILSAFE_FIRED, live, ev.t)
        if isinstance(ev, AuthorityChange) and ev.kind == "regained":
            state.setdefault("regained", []).append(_picked(ev, ("from", "to", "epoch", "time", "position")))
        quiet = isinstance(ev, (Subscribe, Unsubscribe, LinkStateChanged, Drop))
        if not quiet or (isinstance(ev, Drop) and len(live.lines) < 200):
            live.event(ev.t, _describe(ev))

    # ----------------------------------------------------------------- summary
    def _summarize(self, state: dict[str, Any], wall: float, codes: dict[str, int | None], timed_out: bool) -> dict[str, Any]:
        sc = self.opts.scenario
        drone_events = self._records("drone.jsonl")
        # the drone's last word: its final status, else the last status the watch loop saw
        final: DroneState | None = next((e for e in reversed(drone_events) if isinstance(e, DroneStop)), state["status"])
        gs_events = {g: self._records(f"{g}.jsonl") for g in ("A", "B", "X")}
        gs_final = {g: next((e for e in reversed(evs) if isinstance(e, GsState)), None)
                    for g, evs in gs_events.items() if evs}
        rogue_events = self._records("rogue.jsonl")
        sent = {g: sum(int(v) for v in _commands_sent(f, "d1").values()) for g, f in gs_final.items()}
        forwarded = _forwarded_over_restarts(drone_events)
        ha_drops = final.ha_drops if final else {}
        drops: dict[str, int] = {}
        for link in (final.links if final else {}).values():
            for reason, n in link.dropped.items():
                drops[reason] = drops.get(reason, 0) + n
        unlinked: dict[str, int] = {}
        for slot in (final.keys if final else {}).values():
            for reason, n in slot.dropped_unlinked.items():
                unlinked[reason] = unlinked.get(reason, 0) + n
        pos = state.get("final_position") or (list(final.position) if final and final.position else None)
        home_dist = distance_m(HOME, GeoPoint(pos[0], pos[1])) if pos else None
        violations = [f"authority to {h['to']}" for h in state["handovers"] if h["to"] not in ("A", "B")]
        violations += [f"paired with {e.gs}" for e in only(drone_events, Paired) if e.gs not in ("A", "B")]
        history = [(e.t, e.owner) for e in only(drone_events, DroneStatus)]
        gap_ms = 0.0
        first_owned = next((i for i, (_, o) in enumerate(history) if o), None)
        if first_owned is not None:
            for (t1, o1), (t2, _) in zip(history[first_owned:], history[first_owned + 1:]):
                if not o1:
                    gap_ms += (t2 - t1) * 1000
        cmd_sent = sum(sent.get(g, 0) for g in ("A", "B"))
        cmd_fwd = sum(int(forwarded.get(g, 0)) for g in ("A", "B"))
        # The HA counts not_authority refusals per drone, not per sender: attackers add theirs. Only as
        # many as the authority's own shortfall can be its commands refused (the rest are attackers').
        refused = min(int(ha_drops.get("not_authority", 0)), max(0, cmd_sent - cmd_fwd))
        summary: dict[str, Any] = {
            "scenario": sc, "ok": False, "timed_out": timed_out, "wall_time_s": round(wall, 2), "speedup": self.opts.speedup,
            "handovers": state["handovers"], "authority_gap_ms": gap_ms, "regained": state.get("regained", []),
            "failsafe": None if state["failsafe"] is None
            else _picked(state["failsafe"], ("action", "reason", "detect_to_command_ms", "position")),
            "final_position": pos, "distance_from_home_m": None if home_dist is None else round(home_dist, 2),
            "final_owner": final.owner if final else None,
            "authority_link": authority_link(drone_events),
            "delivered_at_b": delivered_at(gs_events["B"], next((e.autopilot for e in only(gs_events["A"], AutopilotFound)),
                                                                 None)),
            "delivered": bool(state.get("delivered")) or delivered_at(gs_events["A"] + gs_events["B"], next(
                (e.autopilot for e in only(gs_events["A"], AutopilotFound)), None)),
            "moment": self.opts.moment, "moments": dict(self.fired_at), "faults": list(self.fault_log),
            "ended_at": time.time(),
            "commands": {"sent_as_authority": sent, "forwarded": forwarded, "lost": cmd_sent - cmd_fwd - refused,
                         "refused_not_authority": ha_drops.get("not_authority", 0)},
            "security_drops": drops, "security_drops_unlinked": unlinked, "ha_drops": ha_drops,
            "ha_rejects": final.rejects if final else {},
            "pairing": final.counters if final else {}, "drone_counters": final.counters if final else {},
            "keys": fields_of(final)["keys"] if final else {},
            "drone_inbox_dropped": final.inbox_dropped if final else {}, "radio_lost": final.radio_lost if final else {},
            "gs_counters": {g: f.counters if f else {} for g, f in gs_final.items()},
            "gateway_A": self._gateway_counters(gs_final.get("A")),
            "out_of_coverage": final.out_of_coverage if final else {}, "vehicle": self._vehicle_counters(),
            "fc_signing": final.fc_signing if final else {},
            "attacks": {e.node.removeprefix("rogue-"): fields_of(e) for e in rogue_events if record_type(e) == "attack_done"},
            "operator": {str(f.get("step", record_type(e))): f for e in self._records("operator.jsonl")
                         if (f := fields_of(e))},
            "violations": violations, "exit_codes": codes, "notes": self.notes,
            "radio_links": self._radio_summary(drone_events),
            "repair_after_restart_s": repair_after_restart(drone_events),
        }
        why: list[str] = []
        if timed_out:
            why.append("timed out")
        if state.get("mission_failed"):
            why.append(f"mission failed: {state['mission_failed']}")
        if violations:
            why.append("security violations")
        bad_exit = {n: c for n, c in codes.items() if c != 0 and not self.children[n].stopped}
        if bad_exit:
            why.append(f"non-zero exit codes {({n: _exit_text(c) for n, c in bad_exit.items()})}")
        outcome = Outcome(summary, drone_events, gs_events, rogue_events)
        summary["flight_problems"] = flight_unaffected(outcome)  # [] = the flight completed unaffected
        why += self.spec.check(outcome)
        summary["ok"] = not why
        summary["why_not_ok"] = why
        (self.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        return summary

    def _records(self, name: str) -> list[AnyRecord]:
        """The records of the run's event log ``name`` ([] if it was never written)."""
        path = self.out / name
        return read_records(path).records if path.exists() else []

    def _radio_summary(self, drone_events: list[AnyRecord]) -> dict[str, Any]:
        """With sites: each radio/backhaul link change; for each site's radio taken down, whether
        another path was connected at that moment (then the C2 link went on through it without a
        break: the drone sends through every connected path and hears on each) and how long the drone
        took to notice the lost path."""
        path = self.out / "radio.jsonl"
        if not path.exists():
            return {}
        changes = [e for e in read_records(path).records if isinstance(e, (RadioLinkChanged, LinkFault))]
        states = only(drone_events, PathState)
        losses = []
        for ch in changes:
            if not isinstance(ch, RadioLinkChanged) or ch.up is not False:
                continue
            endpoint = next((ep for ep, site in self.site_of_endpoint.items() if site == ch.site), None)
            others_up = []
            for ep in self.site_of_endpoint:
                last = [e for e in states if e.router == ep and e.t <= ch.t]
                if ep != endpoint and last and last[-1].connected:
                    others_up.append(self.site_of_endpoint[ep])
            noticed = next((e.t for e in states if e.router == endpoint and not e.connected and e.t >= ch.t - 0.05), None)
            losses.append({"site": ch.site, "other_paths_connected": others_up,
                           "noticed_ms": round(max(0.0, noticed - ch.t) * 1000.0, 1) if noticed else None})
        final = self._drone_final(drone_events)
        inbox_dropped = final.inbox_dropped if final else {}
        return {"changes": [_picked(e, ("t", "site", "link", "up")) for e in changes], "site_losses": losses,
                "path_duplicates": sum(v for k, v in inbox_dropped.items() if k.endswith("duplicate_path"))}

    @staticmethod
    def _drone_final(drone_events: list[AnyRecord]) -> DroneStop | None:
        """The drone node's final status (None if it wrote none)."""
        return next((e for e in reversed(drone_events) if isinstance(e, DroneStop)), None)

    def _vehicle_counters(self) -> dict[str, Any]:
        """What the simulator counted (frames it ignored, refused, could not parse), from its log: the
        vehicle's own account of what reached it."""
        log = self.out / "sim.log"
        text = log.read_text(errors="replace") if log.exists() else ""
        found = re.search(r"sim stopped; counters (\{.*?\}), stream", text)
        try:
            counters = ast.literal_eval(found.group(1)) if found else None
        except (ValueError, SyntaxError):
            counters = None
        return {"counters": counters, "ignored": sorted(set(re.findall(r"sim: ignored (\w+)", text))),
                "modes": re.findall(r"sim: mode \S+ -> (\S+)", text)}

    def _gateway_counters(self, a_final: GsState | None) -> dict[str, int]:
        """GS A's GCS gateway drop counters: from its status when the station reports them, else the
        gateway's (rate-limited) table-full warnings in A's log, which give a lower bound."""
        gw = a_final.gateway if a_final else None
        if isinstance(gw, dict) and isinstance(gw.get("counters"), dict):
            return dict(gw["counters"])
        log = self.out / "gsA.log"
        if not self.spec.gcs_a or not log.exists():
            return {}
        found = re.findall(r"applications already .*?: (\d+) frame\(s\) of new applications dropped", log.read_text(errors="replace"))
        return {"app_table_full": sum(int(n) for n in found), "from_log": 1} if found else {}


def authority_link(drone_events: list[AnyRecord], thresholds: TbmThresholds = TbmThresholds()) -> dict[str, Any]:
    """The worst TBM state of the link to the GS holding authority at each instant, its longest
    silence (from the DEGRADED->OK transitions, and the 0.5 s status samples for shorter ones) and
    how many times it went DEGRADED."""
    rank = {LinkState.OK: 0, LinkState.DEGRADED: 1, LinkState.LOST: 2}
    owner: str | None = None
    worst, longest, episodes = LinkState.OK, 0.0, 0
    degraded_at: float | None = None
    for e in drone_events:
        if isinstance(e, AuthorityMoved):
            owner, degraded_at = e.to, None
        elif isinstance(e, DroneState):
            owner = e.owner or owner
            link = e.links.get(owner or "")
            if link is not None:
                longest = max(longest, float(link.since_last))
        elif isinstance(e, LinkStateChanged) and owner is not None and e.gs == owner:
            st = e.state
            if rank[st] > rank[worst]:
                worst = st
            if st is LinkState.DEGRADED:
                episodes += 1
                degraded_at = e.t
            elif st is LinkState.OK and degraded_at is not None:
                longest = max(longest, e.t - degraded_at + thresholds.degraded)
                degraded_at = None
            elif st is LinkState.LOST:
                longest = max(longest, thresholds.lost)
    return {"worst_state": worst.value, "longest_silence_s": round(longest, 3), "degraded_episodes": episodes}


def watch_state() -> dict[str, Any]:
    """What the watch loop gathers from the drone's log as the flight goes (read by the summary):
    the hand-overs and regained controls (their fields as logged), the failsafe and the last status
    (records), the moments seen."""
    return {"handovers": [], "failsafe": None, "armed_seen": False, "status": None, "region_entered": 0, "done": False}


def _ready_line(name: str) -> str | None:
    """What a child's log says once it has started (None: nothing known to wait for)."""
    if name.startswith("router"):
        return "listening"
    if name == "drone":
        return "ready"
    if name.startswith("gs"):
        return f"zdrone gs {name[2:]}"
    return None


def _picked(rec: AnyRecord, names: tuple[str, ...]) -> dict[str, Any]:
    """Some fields of an event as logged (JSON values; None for one it lacks): for the summary."""
    line = logged(rec)
    return {k: line.get(k) for k in names}


def _describe(ev: AnyRecord) -> str:
    """One line of the live view for a drone event."""
    t = record_type(ev)
    if isinstance(ev, AuthorityMoved):
        return f"authority {ev.from_} -> {ev.to} (epoch {ev.epoch}, {ev.kind})"
    if isinstance(ev, Failsafe):
        return f"FAILSAFE {ev.action}: {ev.reason} ({ev.detect_to_command_ms or 0:.0f} ms after threshold)"
    fields = fields_of(ev)
    if "detail" in fields:
        return f"{t}: {fields['detail']}"
    if "gs" in fields:
        return f"{t}: {fields['gs']}" + (f" ({fields['reason']})" if "reason" in fields else "")
    return t


class LiveView:
    """A rich live panel when on a terminal; plain event lines otherwise."""

    def __init__(self, scenario: str, enabled: bool, quiet: bool = False) -> None:
        self.scenario = scenario
        self.enabled = enabled and not quiet
        self.quiet = quiet
        self.lines: deque[str] = deque(maxlen=200)  # the last lines only: the view's cost stays flat
        self._live: Any = None
        self._t0: float | None = None

    def __enter__(self) -> "LiveView":
        if self.enabled:
            from rich.live import Live

            self._live = Live(self._render(None, 0.0), refresh_per_second=4, transient=False)
            self._live.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)

    def event(self, t: float, text: str) -> None:
        if self._t0 is None:
            self._t0 = t
        line = f"{t - self._t0:7.2f}s  {text}"
        self.lines.append(line)
        if not self.enabled and not self.quiet:
            print(line, flush=True)

    def update(self, status: DroneStatus | None, elapsed: float) -> None:
        if self._live is not None:
            self._live.update(self._render(status, elapsed))

    def _render(self, st: DroneStatus | None, elapsed: float) -> Any:
        from rich.console import Group
        from rich.table import Table

        top = Table(title=f"zdrone demo — {self.scenario} — {elapsed:5.1f} s", show_header=False, expand=True)
        top.add_column(style="bold")
        top.add_column()
        pos = st.position if st else None
        if pos:
            n_e = _ne(pos)
            top.add_row("position", f"{pos[0]:.6f}, {pos[1]:.6f}  alt {pos[2]:.1f} m  ({n_e[1]:+.0f} m east of A)")
        if st is None:  # no status yet
            top.add_row("authority", "None (epoch None, None)")
            top.add_row("vehicle", "disarmed  mode None  region no")
        else:
            top.add_row("authority", f"{st.owner} (epoch {st.epoch}, {st.state.value})"
                        + (f" -> {st.pending_to}" if st.pending_to else ""))
            top.add_row("vehicle", f"{'ARMED' if st.armed else 'disarmed'}  mode {st.mode}  region {'yes' if st.in_region else 'no'}")
        links = Table(title="links (TBM)", expand=True)
        for col in ("GS", "state", "silence s", "opened", "sent", "dropped"):
            links.add_column(col)
        for gs, ln in (st.links if st else {}).items():
            links.add_row(gs, ln.state.value, f"{ln.since_last:.2f}", str(ln.opened), str(ln.sent),
                          ", ".join(f"{k}={v}" for k, v in ln.dropped.items()) or "-")
        ev = Table(title="events", show_header=False, expand=True)
        ev.add_column()
        for line in list(self.lines)[-10:]:
            ev.add_row(line)
        return Group(top, links, ev)


def _ne(pos: Sequence[float]) -> tuple[float, float]:
    from ..core.geometry import ne_of

    return ne_of(HOME, GeoPoint(pos[0], pos[1]))


def _exit_text(code: int | None) -> str:
    """An exit code in words: ``1``, ``SIGSEGV (-11)``."""
    from ..crashes import exit_text

    return exit_text(code)


def run_demo(opts: DemoOptions) -> int:
    if opts.scenario not in SCENARIOS:
        raise ValueError(opts.scenario)
    out = opts.out or Path("runs") / time.strftime(f"demo-{opts.scenario}-%Y%m%d-%H%M%S")
    out.mkdir(parents=True, exist_ok=True)
    out = out.resolve()
    print(f"zdrone demo: scenario {opts.scenario}, speed-up {opts.speedup:g}, output in {out}", flush=True)
    demo = Demo(opts, out)
    try:  # Demo.run has stopped every child whatever ends it
        summary = demo.run()
    except (RuntimeError, OSError) as exc:
        print(f"zdrone demo: failed: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("zdrone demo: interrupted; every process of the run stopped", file=sys.stderr)
        return 130
    except procs.Terminated as exc:
        print(f"zdrone demo: {exc}; every process of the run stopped", file=sys.stderr)
        return 128 + exc.signum
    if opts.report:
        try:
            from ..report import write_report

            path = write_report(out)
            print(f"report: {path}")
        except ImportError:
            pass
    hv = ", ".join(f"{h['from']}->{h['to']}" for h in summary["handovers"]) or "none"
    print(f"{'OK' if summary['ok'] else 'FAILED'}: {opts.scenario} in {summary['wall_time_s']:.1f} s; hand-overs: {hv}; "
          f"authority gap {summary['authority_gap_ms']:.0f} ms; commands lost {summary['commands']['lost']}; "
          f"security drops {summary['security_drops']}; HA refusals {summary['ha_rejects']}; "
          f"failsafe {summary['failsafe']['detect_to_command_ms'] if summary['failsafe'] else '-'} ms; "
          f"final position {summary['distance_from_home_m']} m from home")
    radio = summary.get("radio_links") or {}
    if radio:
        lost = "; ".join(f"{x['site']} lost (noticed in {x['noticed_ms']} ms), carried on through "
                         f"{', '.join(x['other_paths_connected']) or 'nothing'}" for x in radio["site_losses"])
        print(f"radio links: {len(radio['changes'])} changes; {lost or 'no site lost'}; copies dropped at the drone "
              f"{radio['path_duplicates']}")
    print(f"summary: {out / 'summary.json'}; events: {out / 'drone.jsonl'}")
    return 0 if summary["ok"] else 1
