"""``zdrone bench attack``: the attack scenarios, measured; and the failsafe's lateness under a pairing flood.

Part 1 flies every attack scenario of ``zdrone demo`` (one after the other, speed-up 4) and reports
per scenario: whether the flight completed unaffected, the worst TBM state and the longest silence
of the link to the GS holding authority, the security module's drops by reason, the handover
authority's drops, the refusals counted by the drone, the GSs and A's GCS gateway, and what the
attacker says it sent.

Part 2 measures what a pairing flood costs the drone's loop. Router, simulator, drone and GS A only:
A pairs on the ground and holds authority. An attacker holding B's private key and router password
sends valid Noise KK pairing queries at ``--rate`` per second for 10 s; 3 s into the flood GS A is
stopped (SIGSTOP). The drone's ``failsafe`` event gives ``detect_to_command_ms``: how long after the
3 s threshold the vehicle was commanded to LAND (goal: <= 100 ms under any input load). The drone's
CPU time (``/proc/PID/stat`` utime + stime) over the flood, divided by the pairing queries it
handled, is the cost of one refused query; "net" subtracts the CPU the drone spent per second just
before the flood. A trial without a flood gives the baseline lateness.

Part 3 floods another GS's key. Router, simulator, drone, GS A and GS B; the vehicle stands on the
ground inside both coverages, nearer A (``JUNK_EAST_M`` east of home), so A pairs, holds authority,
shares B's key, and the drone listens to B's uplink too. An attacker holding B's router password
publishes junk on ``zdrone/<drone>/up/B`` at ``--junk-rate`` puts per second (80 000) for 10 s. From
the drone's log: the worst TBM state of A's link and its longest stretch out of OK during the flood,
the longest silence of A's link seen in its status, and how much of the flood reached the drone
(its security module's drops on B's link). Goal: A never LOST, never out of OK for more than 1 s.

Part 4 floods over a slow radio (root: a network namespace). The drone and its simulator alone in a
namespace behind one veth pair shaped to ``RADIO_KBIT`` (4 Mbit/s) each way (``tc tbf``, a 200 ms
queue: ``sil.netns.ShapedRadio``); the router, A, B and the attacker on the host. As in part 3 A
holds authority in the overlap and the drone listens to B's uplink; an attacker with B's router
password floods every lane of ``up/B`` with ``--size`` bytes per envelope, far above the radio
(``RADIO_FLOOD_RATE`` puts/s), for 10 s: 500 bytes (under the uplink's size limit: the router passes
B's budget, ``UPLINK_MAX_BYTES_S``, a fifth of the radio), 1 000 and 60 000 bytes (over it: none
enters the router). From the drone's log: A's frames lost over the flood (its link's ``missing``
count), A's worst TBM state, the owners (no hand-over) and failsafes. Goal: A loses 0 frames.
"""

from __future__ import annotations

import json
import signal
import socket
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import json5

from pymavlink.dialects.v20.common import MAV_LANDED_STATE_IN_AIR

from zdrone.core.geometry import offset
from zdrone.core.records import (AnyRecord, DroneStatus, Failsafe, LinkConfirmed, LinkStateChanged, Paired, R, fields_of,
                            only, record_type)
from zdrone.core.reference import HOME
from zdrone.net.eventlog import read_records
from zdrone.sil.launcher import ATTACK_SCENARIOS, Demo, DemoOptions, RogueSpec, free_port
from zdrone.fleet.routerconfig import UPLINK_MAX_HZ
from zdrone.bench.stallwatch import cpu_seconds
from zdrone.bench.table import ProgressLine

SPEEDUP = 4.0
FLOOD_SECONDS = 10.0
STOP_AFTER = 3.0  # seconds into the flood at which GS A goes silent
DEFAULT_RATE = 2500.0
JUNK_RATE = 80_000.0
JUNK_SECONDS = 10.0
#: Where the vehicle stands during the junk flood: inside A's and B's coverage, nearer A (A releases
#: authority only toward a GS nearer than itself by the hysteresis).
JUNK_EAST_M = 200.0
#: A's link may leave OK for at most this long under the flood (and never be LOST).
JUNK_NOT_OK_GOAL_S = 1.0
#: The shaped radio's rate each way (kbit/s), the flood's puts per second and its envelope sizes.
RADIO_KBIT = 4000
RADIO_FLOOD_RATE = 4000.0
RADIO_FLOOD_SIZES = (500, 1000, 60_000)


# ----------------------------------------------------------------- part 1: scenarios
def _scenario(base: Path, name: str) -> dict[str, Any]:
    d = base / name
    d.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    s = Demo(DemoOptions(out=d, scenario=name, speedup=SPEEDUP, quiet=True, live=False, report=False), d.resolve()).run()
    refusals: dict[str, int] = {}
    for k, v in s["drone_counters"].items():
        if k.startswith(("pair_refused", "pair_failed", "pair_deferred", "bad_grant", "stamp_refused")):
            refusals[f"drone {k}"] = int(v)
    for g, counters in s["gs_counters"].items():
        for k, v in counters.items():
            if k.startswith(("linkkey_refused", "linkkey_reply", "pair_bad_reply")):
                refusals[f"{g} {k}"] = int(v)
    for k, v in s["gateway_A"].items():
        if k != "from_log":
            refusals[f"A gateway {k}"] = int(v)
    for k, v in s["ha_rejects"].items():
        refusals[f"HA reject {k}"] = int(v)
    return {"scenario": name, "ok": s["ok"], "flight_completed": not s["flight_problems"],
            "authority_link": s["authority_link"], "security_drops": {**s["security_drops"], **{
                f"{k} (no live key)": v for k, v in s["security_drops_unlinked"].items()}},
            "ha_drops": s["ha_drops"], "refusals": refusals, "attack": s["attacks"],
            "handovers": [f"{h['from']}->{h['to']}" for h in s["handovers"]], "why_not_ok": s["why_not_ok"],
            "wall_s": round(time.monotonic() - t0, 1), "run": str(d)}


# --------------------------------------------------------- part 2: failsafe under a flood
def _cpu_seconds(pid: int) -> float:
    """The drone's CPU time (``stallwatch.cpu_seconds``); it is alive while measured."""
    cpu = cpu_seconds(pid)
    if cpu is None:
        raise RuntimeError(f"process {pid} ended while its CPU was measured")
    return cpu


def _pairing_queries(events: list[AnyRecord], until: float) -> int:
    """Pairing queries the drone had handled by wall time ``until`` (its last status before it)."""
    st = [e for e in only(events, DroneStatus) if e.t <= until]
    if not st:
        return 0
    c = st[-1].counters
    return sum(int(v) for k, v in c.items() if k.startswith(("pair_refused", "pair_answered", "pair_failed", "pair_deferred")))


def _wait_event(path: Path, cls: type[R], timeout: float) -> R | None:
    """The first record of class ``cls`` in the log at ``path``, waiting up to ``timeout`` s for it."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists():
            ev = next(iter(only(read_records(path).records, cls)), None)
            if ev is not None:
                return ev
        time.sleep(0.05)
    return None


def _wait_airborne(path: Path, timeout: float) -> bool:
    """The drone's status says the vehicle is armed and in the air (within ``timeout`` s)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and any(e.armed and e.landed_state == MAV_LANDED_STATE_IN_AIR
                                 for e in only(read_records(path).records, DroneStatus)):
            return True
        time.sleep(0.1)
    return False


def _failsafe_trial(base: Path, i: int, rate: float | None) -> dict[str, Any]:
    """One trial: A pairs and the vehicle takes off (no link-loss failsafe on the ground); optionally
    the flood; A stops; the drone's failsafe."""
    d = base / (f"flood-{i}" if rate else f"baseline-{i}")
    d.mkdir(parents=True, exist_ok=True)
    demo = Demo(DemoOptions(out=d, speedup=SPEEDUP, quiet=True, live=False, report=False, command_rate=0.0), d.resolve())
    row: dict[str, Any] = {"flood": bool(rate)}
    try:
        demo.start_core()
        demo.start_gs("A", "--pair", "--mission", "reference")
        if _wait_event(d / "drone.jsonl", Paired, 30.0) is None:
            raise RuntimeError("A did not pair")
        if not _wait_airborne(d / "drone.jsonl", 60.0):
            raise RuntimeError("the vehicle did not take off")
        pid = demo.children["drone"].proc.pid
        time.sleep(1.0)
        c0, t0 = _cpu_seconds(pid), time.time()
        time.sleep(2.0)
        base_rate = (_cpu_seconds(pid) - c0) / (time.time() - t0)  # drone CPU s per s, no flood
        row["drone_cpu_idle_pct"] = round(100 * base_rate, 2)
        if rate:
            rogue = demo.start_rogue(RogueSpec("pair-flood", "bench", rate=rate), duration=FLOOD_SECONDS)
            demo.wait_line(rogue, "rogue: flooding", 30)
            f_cpu0, f_t0 = _cpu_seconds(pid), time.time()
        time.sleep(STOP_AFTER if rate else 1.0)
        demo.signal("gsA", signal.SIGSTOP)
        demo.children["gsA"].stopped = True
        fs = _wait_event(d / "drone.jsonl", Failsafe, 10.0)
        row["detect_to_command_ms"] = None if fs is None else round(float(fs.detect_to_command_ms), 2)
        if rate:
            demo.wait_line(rogue, "rogue: flood done", FLOOD_SECONDS + 20)
            f_cpu1, f_t1 = _cpu_seconds(pid), time.time()
            time.sleep(0.7)  # the drone's next status carries its counters
            events = read_records(d / "drone.jsonl").records
            n = _pairing_queries(events, f_t1 + 0.6) - _pairing_queries(events, f_t0)
            done = next((fields_of(e) for e in read_records(d / "rogue.jsonl").records
                         if record_type(e) == "attack_done"), {})
            cpu = f_cpu1 - f_cpu0
            row |= {"flood_rate_per_s": done.get("rate"), "queries_sent": done.get("sent"), "queries_handled": n,
                    "drone_cpu_pct_during_flood": round(100 * cpu / (f_t1 - f_t0), 2),
                    "cpu_us_per_query": round(1e6 * cpu / n, 2) if n else None,
                    "cpu_us_per_query_net": round(1e6 * (cpu - base_rate * (f_t1 - f_t0)) / n, 2) if n else None,
                    "pair_answered": _counter(events, "pair_answered"),
                    "pair_refused_rate_limited": _counter(events, "pair_refused:rate_limited")}
    except RuntimeError as exc:
        row["error"] = str(exc)
    finally:
        demo.shutdown()
    return row


# ------------------------------------------------------------ part 3: junk on another GS's key
def _not_ok_periods(events: list[AnyRecord], gs: str, t0: float, t1: float) -> tuple[str, float]:
    """The worst TBM state of ``gs``'s link in [t0, t1] (wall time) and its longest stretch out of OK
    (a stretch that began before t0 or lasts past t1 counts from or until then)."""
    rank = {"ok": 0, "degraded": 1, "lost": 2}
    changes = [(e.t, str(getattr(e.state, "value", e.state))) for e in only(events, LinkStateChanged) if e.gs == gs]
    state = "ok"  # the state at t0
    for t, st in changes:
        if t < t0:
            state = st
    worst, since, longest = state, (t0 if state != "ok" else None), 0.0
    for t, st in changes:
        if not t0 <= t <= t1:
            continue
        worst = st if rank.get(st, 0) > rank.get(worst, 0) else worst
        if st == "ok" and since is not None:
            longest, since = max(longest, t - since), None
        elif st != "ok" and since is None:
            since = t
    if since is not None:
        longest = max(longest, t1 - since)
    return worst, round(longest, 3)


def _junk_flood_trial(base: Path, i: int, rate: float) -> dict[str, Any]:
    """One trial: A holds authority with the vehicle in the overlap, B linked; junk on up/B."""
    d = base / f"junk-flood-{i}"
    d.mkdir(parents=True, exist_ok=True)
    port = free_port(socket.SOCK_DGRAM)
    spot = offset(HOME, 0.0, JUNK_EAST_M)
    demo = Demo(DemoOptions(out=d, speedup=1.0, quiet=True, live=False, report=False, command_rate=0.0,
                            vehicle=f"udpout:127.0.0.1:{port}"), d.resolve())
    row: dict[str, Any] = {"target_rate_per_s": rate}
    try:
        sim = demo.start("sim", ["-m", "zdrone", "-v", "sim", "--mavlink", f"udpin:127.0.0.1:{port}",
                                 "--home", f"{spot.lat:.7f},{spot.lon:.7f}"])
        demo.wait_line(sim, "zdrone sim:", 20)
        demo.start_core()
        demo.start_gs("B")
        demo.start_gs("A", "--pair")
        if _wait_event(d / "drone.jsonl", Paired, 30.0) is None:
            raise RuntimeError("A did not pair")
        deadline = time.monotonic() + 30.0
        while not _b_heard(d / "drone.jsonl"):  # B's shared key proven and B's uplink listened to
            if time.monotonic() > deadline:
                raise RuntimeError("the drone never listened to B's uplink")
            time.sleep(0.2)
        pid = demo.children["drone"].proc.pid
        time.sleep(2.0)
        rogue = demo.start_rogue(RogueSpec("junk-flood", "bench", rate=rate), duration=JUNK_SECONDS)
        demo.wait_line(rogue, "rogue: flooding", 30)
        c0, t0 = _cpu_seconds(pid), time.time()
        demo.wait_line(rogue, "rogue: flood done", JUNK_SECONDS + 30)
        c1, t1 = _cpu_seconds(pid), time.time()
        time.sleep(1.5)  # the drone's next statuses
        events = read_records(d / "drone.jsonl").records
        done = next((fields_of(e) for e in read_records(d / "rogue.jsonl").records if record_type(e) == "attack_done"), {})
        worst, not_ok = _not_ok_periods(events, "A", t0, t1 + 1.0)
        during = [e for e in only(events, DroneStatus) if t0 <= e.t <= t1 + 1.0]
        silence = max((e.links["A"].since_last for e in during if "A" in e.links), default=None)
        owners = sorted({e.owner or "-" for e in during})
        last = during[-1] if during else None
        b_drops = dict(last.links["B"].dropped) if last is not None and "B" in last.links else {}
        b_drops_before = next((dict(e.links["B"].dropped) for e in reversed(only(events, DroneStatus))
                               if e.t < t0 and "B" in e.links), {})
        reached = sum(b_drops.values()) - sum(b_drops_before.values())
        row |= {"flood_rate_per_s": done.get("rate"), "sent": done.get("sent"), "a_worst_state": worst.upper(),
                "a_longest_not_ok_s": not_ok, "a_longest_silence_s": silence, "owners": owners,
                "junk_reached_drone": reached, "junk_reached_per_s": round(reached / (t1 - t0), 1),
                "drone_cpu_pct_during_flood": round(100 * (c1 - c0) / (t1 - t0), 1),
                "subscribed_b": bool(last is not None and "B" in last.subscribed),
                "inbox_dropped": dict(last.inbox_dropped) if last is not None else {}}
        row["ok"] = (worst != "lost" and not_ok <= JUNK_NOT_OK_GOAL_S and owners == ["A"] and row["subscribed_b"])
    except RuntimeError as exc:
        row |= {"error": str(exc), "ok": False}
    finally:
        demo.shutdown()
    return row


def _a_missing(events: list[AnyRecord], before: float | None = None) -> int | None:
    """A's frames the drone counted missing, in its last status (before ``before``)."""
    st = [e for e in only(events, DroneStatus) if "A" in e.links and (before is None or e.t < before)]
    return st[-1].links["A"].missing if st else None


def _shaped_radio_trial(base: Path, i: int, size: int, rate: float = RADIO_FLOOD_RATE, budget: bool = True,
                        tls: bool = False) -> dict[str, Any]:
    """One trial: the drone behind a 4 Mbit/s radio, A holding authority, ``size``-byte junk on up/B.
    Without ``budget`` (a what-if, the control): the router's rate budgets taken out of its config.
    With ``tls``: a site router (mutual TLS: B's certificate and password, budgets per credential)."""
    from zdrone.fleet.files import init_fleet
    from zdrone.fleet.routerconfig import UPLINK_MAX_BYTES, UPLINK_MAX_BYTES_S
    from zdrone.sil.netns import NetnsError, ShapedRadio

    d = base / f"shaped-radio-{size}-{i}{'' if budget else '-no-budget'}{'-tls' if tls else ''}"
    d.mkdir(parents=True, exist_ok=True)
    row: dict[str, Any] = {"size": size, "budget": budget, "tls": tls, "target_rate_per_s": rate, "radio_kbit": RADIO_KBIT,
                           "passes_router": size <= UPLINK_MAX_BYTES,
                           "budget_kbit": (round(UPLINK_MAX_BYTES_S * 8 / 1000) if budget else None) if size <= UPLINK_MAX_BYTES else 0}
    radio = ShapedRadio(RADIO_KBIT)
    try:
        radio.create()
    except NetnsError as exc:
        return row | {"error": f"no shaped radio here: {exc}", "ok": False, "skipped": True}
    demo = Demo(DemoOptions(out=d, speedup=1.0, quiet=True, live=False, report=False, command_rate=0.0), d.resolve())
    demo.netns = radio  # type: ignore[assignment]  # children with ns= run behind the radio; shutdown removes it
    spot = offset(HOME, 0.0, JUNK_EAST_M)
    try:
        port, sport = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM)
        if tls:  # the site router of the radio's host (its certificate names the radio address); GSs reach it there too
            init_fleet(d / "fleet", sites=[f"tls/{radio.host_ip}:{port}", f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"])
            cfg_path = d / "fleet" / "router" / "site-1.json5"
            local = far = f"tls/{radio.host_ip}:{port}"
            listen: list[str] = []  # the site config's own: the radio address (and the mesh's, unused)
        else:
            init_fleet(d / "fleet")
            cfg_path = d / "fleet" / "router" / "router.json5"
            local, far = f"tcp/127.0.0.1:{port}", f"tcp/{radio.host_ip}:{port}"
            listen = ["--listen", local, "--listen", far]
        if not budget:
            cfg = json5.loads(cfg_path.read_text())
            cfg.pop("downsampling", None)
            cfg_path.write_text(json.dumps(cfg, indent=2))
        z = ["-m", "zdrone", "-v"]
        r = demo.start("router", z + ["router", "-c", str(cfg_path.relative_to(d)), *listen])
        demo.wait_line(r, "listening", 20)
        sim = demo.start("sim", z + ["sim", "--mavlink", f"udpin:127.0.0.1:{sport}", "--home", f"{spot.lat:.7f},{spot.lon:.7f}"],
                         ns=radio.ns)
        demo.wait_line(sim, "zdrone sim:", 20)
        drone = demo.start("drone", z + ["drone", "--id", "d1", "--fleet", "fleet", "--router", far, "--vehicle",
                                         f"udpout:127.0.0.1:{sport}", "--events", "drone.jsonl"], ns=radio.ns)
        demo.wait_line(drone, "ready", 40)
        for gs, extra in (("B", []), ("A", ["--pair"])):
            demo.wait_line(demo.start(f"gs{gs}", z + ["gs", "--id", gs, "--fleet", "fleet", "--router", local,
                                                       "--events", f"{gs}.jsonl", *extra]), f"zdrone gs {gs}", 20)
        if _wait_event(d / "drone.jsonl", Paired, 30.0) is None:
            raise RuntimeError("A did not pair")
        deadline = time.monotonic() + 30.0
        while not _b_heard(d / "drone.jsonl"):
            if time.monotonic() > deadline:
                raise RuntimeError("the drone never listened to B's uplink")
            time.sleep(0.2)
        time.sleep(2.0)  # A's link settled (two statuses)
        rogue = demo.start("rogue-junk-flood", ["-m", "zdrone.sil.rogue", "--mode", "junk-flood", "--fleet", "fleet",
                                                "--router", local, "--duration", f"{JUNK_SECONDS:.2f}", "--rate",
                                                str(rate), "--size", str(size), "--events", "rogue.jsonl"])
        demo.wait_line(rogue, "rogue: flooding", 30)
        t0 = time.time()
        demo.wait_line(rogue, "rogue: flood done", JUNK_SECONDS + 60)
        t1 = time.time()
        time.sleep(2.0)  # the drone's next statuses (and frames still queued in the radio)
        events = read_records(d / "drone.jsonl").records
        done = next((fields_of(e) for e in read_records(d / "rogue.jsonl").records if record_type(e) == "attack_done"), {})
        worst, not_ok = _not_ok_periods(events, "A", t0, t1 + 2.0)
        during = [e for e in only(events, DroneStatus) if t0 <= e.t <= t1 + 2.0]
        m0, m1 = _a_missing(events, t0), _a_missing(events)
        b = [e.links["B"] for e in during if "B" in e.links]
        row |= {"flood_rate_per_s": done.get("rate"), "sent": done.get("sent"),
                "offered_kbit": round((done.get("rate") or 0) * size * 8 / 1000),
                "a_lost": None if m0 is None or m1 is None else m1 - m0, "a_worst_state": worst.upper(),
                "a_longest_not_ok_s": not_ok, "owners": sorted({e.owner or "-" for e in during}),
                "failsafes": len(only(events, Failsafe)),
                "junk_reached_drone": (sum(b[-1].dropped.values()) - sum(b[0].dropped.values())) if len(b) > 1 else None}
        row["ok"] = (row["a_lost"] == 0 and worst == "ok" and row["owners"] == ["A"] and row["failsafes"] == 0)
        if not budget:  # the control: the flood must hurt A when nothing bounds it, or the radio shapes nothing
            row["ok"] = bool(row["a_lost"]) or worst != "ok"
    except RuntimeError as exc:
        row |= {"error": str(exc), "ok": False}
    finally:
        demo.shutdown()  # and the radio's namespace
    return row


def _credential_ok(t: dict[str, Any]) -> bool:
    """K sessions with one certificate and password get one budget; a password thief's sessions never
    spend the real GS's (its frames arrive); no envelope over the size limit reaches the drone."""
    budgets = 1 if t["tls"] else t["sessions"]
    return (t["junk_reached"] <= budgets * 1.2 * UPLINK_MAX_HZ * t["seconds"] + 20 * budgets
            and t["a_reached"] >= 0.9 * t["a_sent"] and t["big_reached"] == 0)


def _b_heard(path: Path) -> bool:
    """B's key is proven on the drone and the drone listens to B's uplink."""
    if not path.exists():
        return False
    events = read_records(path).records
    confirmed = any(e.gs == "B" for e in only(events, LinkConfirmed)) or any(
        "B" in e.links for e in only(events, DroneStatus))
    st = only(events, DroneStatus)
    return confirmed and bool(st) and "B" in st[-1].subscribed and "B" in st[-1].links


def _counter(events: list[AnyRecord], name: str) -> int:
    """The drone's counter ``name`` in its last status (0 if none)."""
    st = only(events, DroneStatus)
    return int(st[-1].counters.get(name, 0)) if st else 0


def _stats(vals: list[float]) -> dict[str, float | None]:
    return {"max": round(max(vals), 2) if vals else None, "median": round(statistics.median(vals), 2) if vals else None}


def run(quick: bool = False, scenarios: list[str] | None = None, trials: int | None = None, rate: float = DEFAULT_RATE,
        progress: bool = True, junk_rate: float = JUNK_RATE, junk_trials: int | None = None,
        radio_sizes: list[int] | None = None, sessions: tuple[int, ...] | None = None) -> dict[str, Any]:
    base = Path(tempfile.mkdtemp(prefix="zdrone-bench-attack-"))
    names = scenarios if scenarios is not None else (["pair-flood"] if quick else list(ATTACK_SCENARIOS))
    m = trials if trials is not None else (1 if quick else 3)
    t0 = time.monotonic()
    status = ProgressLine(progress)
    rows = []
    for name in names:
        status.say(f"scenario {name} ({len(rows) + 1}/{len(names)})")
        rows.append(_scenario(base, name))
    flood = []
    for i in range(m):
        status.say(f"failsafe under a {rate:.0f}/s pairing flood: trial {i + 1}/{m}")
        flood.append(_failsafe_trial(base, i, rate))
    baseline = []
    if not quick and m > 0:
        status.say("failsafe without a flood (baseline)")
        baseline.append(_failsafe_trial(base, 0, None))
    junk = []
    for i in range(junk_trials if junk_trials is not None else (0 if quick else 3)):
        status.say(f"A's link under {junk_rate:.0f}/s junk on up/B: trial {i + 1}")
        junk.append(_junk_flood_trial(base, i, junk_rate))
    radio = []
    for size in radio_sizes if radio_sizes is not None else ([] if quick else list(RADIO_FLOOD_SIZES)):
        status.say(f"A's link over a {RADIO_KBIT / 1000:g} Mbit/s radio under {size}-byte junk on up/B")
        radio.append(_shaped_radio_trial(base, 0, size))
    for size in [] if quick or radio_sizes is not None else [RADIO_FLOOD_SIZES[0], RADIO_FLOOD_SIZES[-1]]:
        status.say(f"the same over a site router with mutual TLS: {size}-byte junk with B's certificate and password")
        radio.append(_shaped_radio_trial(base, 0, size, tls=True))
    if radio and not quick and radio_sizes is None:
        status.say("the control: the same flood of 500-byte junk with the router's budgets taken out")
        radio.append(_shaped_radio_trial(base, 0, 500, budget=False))
    from zdrone.bench import sessions as per_credential

    cred = per_credential.run(sessions if sessions is not None else ((1, 4) if quick else (1, 4, 16)), status.say)
    status.close()
    late = [r["detect_to_command_ms"] for r in flood if r.get("detect_to_command_ms") is not None]
    per_q = [r["cpu_us_per_query"] for r in flood if r.get("cpu_us_per_query") is not None]
    per_q_net = [r["cpu_us_per_query_net"] for r in flood if r.get("cpu_us_per_query_net") is not None]
    return {"scenarios": rows,
            "failsafe_under_pairing_flood": {
                "target_rate_per_s": rate, "flood_s": FLOOD_SECONDS, "trials": flood, "baseline_trials": baseline,
                "detect_to_command_ms": {"values": late, **_stats(late)},
                "baseline_ms": [r.get("detect_to_command_ms") for r in baseline],
                "flood_rate_per_s": [r.get("flood_rate_per_s") for r in flood],
                "cpu_us_per_query": {"values": per_q, **_stats(per_q)},
                "cpu_us_per_query_net": {"values": per_q_net, **_stats(per_q_net)},
                "missing": m - len(late), "goal_ms": 100.0},
            "authority_link_under_junk_flood": {"target_rate_per_s": junk_rate, "flood_s": JUNK_SECONDS,
                                                "goal_not_ok_s": JUNK_NOT_OK_GOAL_S, "trials": junk},
            "sessions_per_credential": {"budget_per_s": UPLINK_MAX_HZ, "trials": cred},
            "shaped_radio_floods": {"radio_kbit": RADIO_KBIT, "flood_s": JUNK_SECONDS, "goal_a_lost": 0, "trials": radio},
            "all_ok": all(r["ok"] for r in rows) and len(late) == m and all(v <= 100.0 for v in late)
            and all(t["ok"] for t in junk) and all(t["ok"] or t.get("skipped") for t in radio)
            and all(_credential_ok(t) for t in cred),
            "wall_s": round(time.monotonic() - t0, 1), "runs": str(base)}


def _fmt_counts(d: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in d.items()) or "-"


def render(r: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    rows = []
    for s in r["scenarios"]:
        al = s["authority_link"]
        rows.append([s["scenario"], "yes" if s["flight_completed"] else "NO", al["worst_state"].upper(),
                     f"{al['longest_silence_s']:.2f}", _fmt_counts(s["security_drops"]), _fmt_counts(s["ha_drops"]),
                     _fmt_counts(s["refusals"]), "OK" if s["ok"] else "FAILED: " + "; ".join(s["why_not_ok"])])
    if rows:
        print_table("Attack scenarios (zdrone demo, speed-up 4)",
                    ["scenario", "flight completed", "authority link worst", "longest silence s", "security drops",
                     "HA drops", "refusals", "result"], rows)
    f = r["failsafe_under_pairing_flood"]
    rows = []
    for i, t in enumerate(f["trials"]):
        rows.append([f"flood {i + 1}", t.get("flood_rate_per_s", "-"), t.get("queries_handled", "-"),
                     t.get("detect_to_command_ms", t.get("error", "-")), t.get("cpu_us_per_query", "-"),
                     t.get("cpu_us_per_query_net", "-"), t.get("drone_cpu_pct_during_flood", "-"),
                     t.get("pair_answered", "-")])
    for i, t in enumerate(f["baseline_trials"]):
        rows.append([f"no flood {i + 1}", "-", "-", t.get("detect_to_command_ms", t.get("error", "-")), "-", "-",
                     t.get("drone_cpu_idle_pct", "-"), "-"])
    if rows:
        print_table("Failsafe lateness under a pairing flood (router, sim, drone, GS A; A stopped 3 s into the flood)",
                    ["trial", "queries/s sent", "queries handled", "LAND after threshold ms", "drone CPU µs/query",
                     "net µs/query", "drone CPU %", "answered"], rows,
                    caption="goal: LAND <= threshold + 100 ms under any input load")
    j = r.get("authority_link_under_junk_flood")
    if j and j["trials"]:
        rows = [[f"junk {i + 1}", round(t["flood_rate_per_s"]) if t.get("flood_rate_per_s") else "-",
                 round(t["junk_reached_per_s"]) if t.get("junk_reached_per_s") is not None else "-",
                 t.get("a_worst_state", "-"), t.get("a_longest_not_ok_s", "-"), t.get("a_longest_silence_s", "-"),
                 ",".join(t.get("owners", [])) or "-", t.get("drone_cpu_pct_during_flood", "-"),
                 "OK" if t["ok"] else "FAILED" + (f": {t['error']}" if "error" in t else "")]
                for i, t in enumerate(j["trials"])]
        print_table(f"A's link under junk on up/B ({j['target_rate_per_s']:.0f} puts/s for {j['flood_s']:.0f} s; "
                    "A holds authority, vehicle in the overlap, B linked)",
                    ["trial", "junk/s sent", "junk/s at drone", "A worst", "A out of OK s", "A silence s",
                     "authority", "drone CPU %", "result"], rows,
                    caption=f"goal: A never LOST, out of OK <= {j['goal_not_ok_s']:.0f} s")
    q = r.get("shaped_radio_floods")
    if q and q["trials"]:
        rows = [[f"{t['size']} B" + (", TLS site" if t.get("tls") else "") + ("" if t.get("budget", True) else " (control: no budget)"),
                 "yes" if t.get("passes_router") else "no (size)", t.get("budget_kbit") or "-",
                 t.get("offered_kbit", "-"), t.get("junk_reached_drone", "-"), t.get("a_lost", "-"),
                 t.get("a_worst_state", "-"), t.get("a_longest_not_ok_s", "-"), ",".join(t.get("owners", [])) or "-", t.get("failsafes", "-"),
                 "OK" if t["ok"] else ("skipped: " if t.get("skipped") else "FAILED") + (f": {t['error']}" if "error" in t else "")]
                for t in q["trials"]]
        print_table(f"A's link over a {q['radio_kbit'] / 1000:g} Mbit/s shaped radio under junk on up/B with B's password (TLS: and certificate) "
                    f"({q['flood_s']:.0f} s; A holds authority, vehicle in the overlap, B linked)",
                    ["envelope", "enters router", "B's budget kbit/s", "offered kbit/s", "junk at drone", "A lost",
                     "A worst", "A out of OK s", "authority", "failsafes", "result"], rows,
                    caption="goal: A loses 0 frames, no hand-over, no failsafe; the control (the router's budgets "
                            "taken out) must hurt A, or the radio shaped nothing")
    c = r.get("sessions_per_credential")
    if c and c["trials"]:
        rows = [[("B's certificate and password (TLS)" if t["tls"] else "A's password alone, a thief"), t["sessions"],
                 f"{t['sent']:,}", t["junk_reached"], t["junk_per_s"], t["big_reached"], f"{t['a_reached']}/{t['a_sent']}",
                 "OK" if _credential_ok(t) else "FAILED"] for t in c["trials"]]
        print_table(f"K parallel sessions with one credential flooding its uplink to the drone for 2 s "
                    f"(budget {c['budget_per_s']:.0f} puts/s per uplink)",
                    ["credential", "K", "junk sent", "junk at drone", "junk/s at drone", "1000-byte at drone",
                     "A's frames at drone", "result"], rows,
                    caption="with TLS: one budget whatever K; a password alone: a budget per session, never A's")
