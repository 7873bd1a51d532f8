"""TESTBED: the summary of a run (``summary.json``) and its verdict, computed from what the run's
processes wrote (``RunLogs``: the records of their event logs, the simulator's and GS A's text logs)
and what the launcher knows that no log holds (``RunFacts``: exit codes, faults injected, moments
seen, notes). Needs no process: ``summarize`` works on records read from a run folder or made by a
test. The predicates it applies are in ``zdrone.sil.verdicts``.
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from zdrone.core.geometry import GeoPoint, distance_m
from zdrone.core.records import (AnyRecord, AuthorityChange, AuthorityMoved, AutopilotFound, DroneState, DroneStatus, DroneStop,
                            Failsafe, GsState, HandoverComplete, HandoverStart, LinkStateChanged, Paired, PathState,
                            RegionEntered, Restarted, Start, fields_of, logged, only, record_type)
from zdrone.core.reference import DELIVERY, HOME
from zdrone.core.tbm import LinkState, TbmThresholds
from zdrone.crashes import exit_text
from zdrone.net.eventlog import read_records
from zdrone.sil.moments import AIRBORNE, AT_DELIVERY, FAILSAFE_FIRED, HANDOVER_STARTED, HANDOVERS_DONE, REGION_ENTERED, RETURNING
from zdrone.sil.testbed_records import LinkFault, RadioLinkChanged
from zdrone.sil.verdicts import DELIVERY_RADIUS_M, Outcome, delivered_at, flight_unaffected

if TYPE_CHECKING:
    from zdrone.sil.scenarios import Scenario


@dataclass
class RunLogs:
    """What a run's processes wrote, all a summary reads: every node's event log (typed records, in
    the order written; [] for one never written), the radio links' log (None: no radio links) and
    the simulator's and GS A's text logs ("" / None when absent)."""

    drone: list[AnyRecord] = field(default_factory=list)
    gs: dict[str, list[AnyRecord]] = field(default_factory=lambda: {"A": [], "B": [], "X": []})
    rogue: list[AnyRecord] = field(default_factory=list)
    operator: list[AnyRecord] = field(default_factory=list)
    radio: list[AnyRecord] | None = None
    sim_log: str = ""
    gs_a_log: str | None = None

    @classmethod
    def read(cls, out: Path) -> "RunLogs":
        """The logs of the run folder ``out``."""

        def records(name: str) -> list[AnyRecord]:
            path = out / name
            return read_records(path).records if path.exists() else []

        def text(name: str) -> str | None:
            path = out / name
            return path.read_text(errors="replace") if path.exists() else None

        radio = out / "radio.jsonl"
        return cls(drone=records("drone.jsonl"), gs={g: records(f"{g}.jsonl") for g in ("A", "B", "X")},
                   rogue=records("rogue.jsonl"), operator=records("operator.jsonl"),
                   radio=read_records(radio).records if radio.exists() else None, sim_log=text("sim.log") or "",
                   gs_a_log=text("gsA.log"))


@dataclass
class RunFacts:
    """What the launcher knows of a run that no log holds."""

    scenario: str
    speedup: float
    wall: float  # wall seconds of the run
    timed_out: bool
    ended_at: float  # time of day the run ended
    moment: str | None = None  # the moment its fault was moved to (None: its own)
    moments: dict[str, float] = field(default_factory=dict)  # trigger -> time of day it came
    faults: list[dict[str, Any]] = field(default_factory=list)  # each fault injected: t, target, text, ends
    notes: list[str] = field(default_factory=list)
    exit_codes: dict[str, int | None] = field(default_factory=dict)
    stopped: frozenset[str] = frozenset()  # children stopped by a fault: their exit codes are no failure
    site_of_endpoint: dict[str, str] = field(default_factory=dict)  # with sites: the drone's path endpoint -> site


#: Within this distance of the delivery point the vehicle has reached it (``RETURNING`` can come next).
NEAR_DELIVERY_M = 60.0


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


def repair_after_restart(drone: list[AnyRecord]) -> float | None:
    """Seconds from the restarted companion's ``restarted`` event to the owner's pairing (None: none)."""
    restarted = next((e for e in only(drone, Restarted)), None)
    if restarted is None:
        return None
    paired = next((e.t for e in only(drone, Paired) if e.t >= restarted.t and e.gs == restarted.owner), None)
    return None if paired is None else round(paired - restarted.t, 3)


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


def follow(state: dict[str, Any], ev: AnyRecord, now: float, linger: float = 0.0) -> list[str]:
    """Fold one drone record into the watch state (``watch_state``): the flight's progress, its end
    (landed and disarmed after having flown; with ``linger``, that many seconds of ``now``'s clock
    later). Returns the moments of the flight the record reached, in order (the launcher fires each
    the first time only)."""
    reached: list[str] = []
    if isinstance(ev, DroneStatus):
        state["status"] = ev
        pos = ev.position
        if ev.armed:
            state["armed_seen"] = True
            if pos and pos[2] > 5.0:
                state["flown"] = True  # an arm refused or undone on the ground is not the end
            if pos and pos[2] > 15.0:
                reached.append(AIRBORNE)
        if pos and distance_m(DELIVERY, GeoPoint(pos[0], pos[1])) < NEAR_DELIVERY_M:
            state["near_delivery"] = True
            reached.append(AT_DELIVERY)
            if ev.landed_state == 1 and pos[2] < 1.0 and \
                    distance_m(DELIVERY, GeoPoint(pos[0], pos[1])) <= DELIVERY_RADIUS_M:
                state["delivered"] = True  # on the ground at the delivery point (the drone's own status)
        landed = ev.landed_state == 1 and not ev.armed
        if state.get("flown") and landed:  # the end (or, with ``linger``, that much later)
            state.setdefault("final_position", list(pos) if pos else pos)
            landed_at = state.setdefault("landed_at", now)
            state["done"] = now >= landed_at + linger
        return reached
    if isinstance(ev, RegionEntered):
        state["region_entered"] += 1
        reached.append(REGION_ENTERED)
        if state.get("near_delivery"):
            reached.append(RETURNING)
    if isinstance(ev, HandoverStart):
        reached.append(HANDOVER_STARTED)
    if isinstance(ev, HandoverComplete):
        state["handovers"].append(picked(ev, ("from", "to", "epoch", "time", "kind", "position")))
        if len(state["handovers"]) == 2:
            reached.append(HANDOVERS_DONE)
    if isinstance(ev, Failsafe):
        state["failsafe"] = ev
        reached.append(FAILSAFE_FIRED)
    if isinstance(ev, AuthorityChange) and ev.kind == "regained":
        state.setdefault("regained", []).append(picked(ev, ("from", "to", "epoch", "time", "position")))
    return reached


def watch(drone: list[AnyRecord], linger: float = 0.0) -> dict[str, Any]:
    """The watch state of a whole drone log, as the watch loop would have gathered it (the records'
    own times as the clock)."""
    state = watch_state()
    for ev in drone:
        follow(state, ev, ev.t, linger)
    return state


def picked(rec: AnyRecord, names: tuple[str, ...]) -> dict[str, Any]:
    """Some fields of an event as logged (JSON values; None for one it lacks): for the summary."""
    line = logged(rec)
    return {k: line.get(k) for k in names}


def summarize(spec: "Scenario", logs: RunLogs, state: dict[str, Any], run: RunFacts) -> dict[str, Any]:
    """The run's summary (``summary.json``): its figures, ``flight_problems`` (what ``flight_unaffected``
    finds), and its verdict: ``ok`` and ``why_not_ok`` (the launcher's own conditions, then the
    scenario's predicate on the ``Outcome``). ``state`` is what the watch loop gathered
    (``watch_state``)."""
    drone_events = logs.drone
    # the drone's last word: its final status, else the last status the watch loop saw
    final: DroneState | None = next((e for e in reversed(drone_events) if isinstance(e, DroneStop)), state["status"])
    gs_events = {g: logs.gs.get(g, []) for g in ("A", "B", "X")}
    gs_final = {g: next((e for e in reversed(evs) if isinstance(e, GsState)), None)
                for g, evs in gs_events.items() if evs}
    rogue_events = logs.rogue
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
        "scenario": run.scenario, "ok": False, "timed_out": run.timed_out, "wall_time_s": round(run.wall, 2),
        "speedup": run.speedup,
        "handovers": state["handovers"], "authority_gap_ms": gap_ms, "regained": state.get("regained", []),
        "failsafe": None if state["failsafe"] is None
        else picked(state["failsafe"], ("action", "reason", "detect_to_command_ms", "position")),
        "final_position": pos, "distance_from_home_m": None if home_dist is None else round(home_dist, 2),
        "final_owner": final.owner if final else None,
        "authority_link": authority_link(drone_events),
        "delivered_at_b": delivered_at(gs_events["B"], next((e.autopilot for e in only(gs_events["A"], AutopilotFound)),
                                                             None)),
        "delivered": bool(state.get("delivered")) or delivered_at(gs_events["A"] + gs_events["B"], next(
            (e.autopilot for e in only(gs_events["A"], AutopilotFound)), None)),
        "moment": run.moment, "moments": dict(run.moments), "faults": list(run.faults),
        "ended_at": run.ended_at,
        "commands": {"sent_as_authority": sent, "forwarded": forwarded, "lost": cmd_sent - cmd_fwd - refused,
                     "refused_not_authority": ha_drops.get("not_authority", 0)},
        "security_drops": drops, "security_drops_unlinked": unlinked, "ha_drops": ha_drops,
        "ha_rejects": final.rejects if final else {},
        "pairing": final.counters if final else {}, "drone_counters": final.counters if final else {},
        "keys": fields_of(final)["keys"] if final else {},
        "drone_inbox_dropped": final.inbox_dropped if final else {}, "radio_lost": final.radio_lost if final else {},
        "gs_counters": {g: f.counters if f else {} for g, f in gs_final.items()},
        "gateway_A": gateway_counters(gs_final.get("A"), logs.gs_a_log if spec.gcs_a else None),
        "out_of_coverage": final.out_of_coverage if final else {}, "vehicle": vehicle_counters(logs.sim_log),
        "fc_signing": final.fc_signing if final else {},
        "attacks": {e.node.removeprefix("rogue-"): fields_of(e) for e in rogue_events if record_type(e) == "attack_done"},
        "operator": {str(f.get("step", record_type(e))): f for e in logs.operator
                     if (f := fields_of(e))},
        "violations": violations, "exit_codes": run.exit_codes, "notes": run.notes,
        "radio_links": radio_summary(logs.radio, drone_events, run.site_of_endpoint),
        "repair_after_restart_s": repair_after_restart(drone_events),
    }
    why: list[str] = []
    if run.timed_out:
        why.append("timed out")
    if state.get("mission_failed"):
        why.append(f"mission failed: {state['mission_failed']}")
    if violations:
        why.append("security violations")
    bad_exit = {n: c for n, c in run.exit_codes.items() if c != 0 and n not in run.stopped}
    if bad_exit:
        why.append(f"non-zero exit codes {({n: exit_text(c) for n, c in bad_exit.items()})}")
    outcome = Outcome(summary, drone_events, gs_events, rogue_events)
    summary["flight_problems"] = flight_unaffected(outcome)  # [] = the flight completed unaffected
    why += spec.check(outcome)
    summary["ok"] = not why
    summary["why_not_ok"] = why
    return summary


def radio_summary(radio: list[AnyRecord] | None, drone_events: list[AnyRecord],
                  site_of_endpoint: dict[str, str]) -> dict[str, Any]:
    """With sites: each radio/backhaul link change; for each site's radio taken down, whether
    another path was connected at that moment (then the C2 link went on through it without a
    break: the drone sends through every connected path and hears on each) and how long the drone
    took to notice the lost path. ``radio``: the radio log's records (None: no radio links)."""
    if radio is None:
        return {}
    changes = [e for e in radio if isinstance(e, (RadioLinkChanged, LinkFault))]
    states = only(drone_events, PathState)
    losses = []
    for ch in changes:
        if not isinstance(ch, RadioLinkChanged) or ch.up is not False:
            continue
        endpoint = next((ep for ep, site in site_of_endpoint.items() if site == ch.site), None)
        others_up = []
        for ep in site_of_endpoint:
            last = [e for e in states if e.router == ep and e.t <= ch.t]
            if ep != endpoint and last and last[-1].connected:
                others_up.append(site_of_endpoint[ep])
        noticed = next((e.t for e in states if e.router == endpoint and not e.connected and e.t >= ch.t - 0.05), None)
        losses.append({"site": ch.site, "other_paths_connected": others_up,
                       "noticed_ms": round(max(0.0, noticed - ch.t) * 1000.0, 1) if noticed else None})
    final = drone_final(drone_events)
    inbox_dropped = final.inbox_dropped if final else {}
    return {"changes": [picked(e, ("t", "site", "link", "up")) for e in changes], "site_losses": losses,
            "path_duplicates": sum(v for k, v in inbox_dropped.items() if k.endswith("duplicate_path"))}


def drone_final(drone_events: list[AnyRecord]) -> DroneStop | None:
    """The drone node's final status (None if it wrote none)."""
    return next((e for e in reversed(drone_events) if isinstance(e, DroneStop)), None)


def vehicle_counters(text: str) -> dict[str, Any]:
    """What the simulator counted (frames it ignored, refused, could not parse), from its log
    (``text``, "" without one): the vehicle's own account of what reached it."""
    found = re.search(r"sim stopped; counters (\{.*?\}), stream", text)
    try:
        counters = ast.literal_eval(found.group(1)) if found else None
    except (ValueError, SyntaxError):
        counters = None
    return {"counters": counters, "ignored": sorted(set(re.findall(r"sim: ignored (\w+)", text))),
            "modes": re.findall(r"sim: mode \S+ -> (\S+)", text)}


def gateway_counters(a_final: GsState | None, a_log: str | None) -> dict[str, int]:
    """GS A's GCS gateway drop counters: from its status when the station reports them, else the
    gateway's (rate-limited) table-full warnings in A's log (``a_log``; None: not read), which give
    a lower bound."""
    gw = a_final.gateway if a_final else None
    if isinstance(gw, dict) and isinstance(gw.get("counters"), dict):
        return dict(gw["counters"])
    if a_log is None:
        return {}
    found = re.findall(r"applications already .*?: (\d+) frame\(s\) of new applications dropped", a_log)
    return {"app_table_full": sum(int(n) for n in found), "from_log": 1} if found else {}
