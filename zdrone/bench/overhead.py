"""``zdrone bench overhead``: what zdrone costs over bare Zenoh, the same fleet flown twice.

For each K (and the layout: one router, or ``--sites N`` meshed site routers), one invocation flies:

* **zdrone**: ``bench scale``'s run (``scale._one``): K drone nodes in one drones host, the G GSs in a
  stations host, the router(s) with the fleet's ACL, authentication, downsampling and size filters
  (mutual TLS over sites), every frame in an envelope, the authority machine, pairing and key sharing
  on the ground, then the shuttle, until every vehicle has landed or ``flight`` seconds after the take-off;
* **bare**: ``zdrone.bench.bare``: the same processes, layout, keys, QoS, vehicles, flight and
  application traffic (telemetry down, heartbeats and commands up, the GSs' backhaul) on plain Zenoh
  (plain TCP routers, nothing checked), until every vehicle has landed or ``flight`` seconds after the
  take-off.

Over a flight shorter than the shuttle (300 drones fly at speed-up 1: 120 s is the way out, past B to C)
the hand-overs back are not in the window; the figures are per second either way.

Per process class (drones host, GSs host, routers summed) over the flight: CPU in milliseconds per
second per drone (100 % of a core = 1000 ms/s), and per vehicle frame carried (the in-process simulators
stream at most one of each message per step: a host whose passes are slower carries fewer frames a
second, so the per-drone figure alone flatters the slower half), resident memory at the end (MB); latency GS -> vehicle
and vehicle -> GS, p50 and p99 (``zdrone.bench.latency``: a sample of the messages, matched by their
bytes; the zdrone half's hosts note them through an opt-in hook, ``--latency``); samples delivered to
the nodes per second (the traffic the two halves carried). The table prints zdrone / bare for each.

Goals (measured, not asserted): zdrone <= 1.5 x bare Zenoh's CPU in every process class at 300 x 3 over
sites; GS -> vehicle latency added <= 1 ms at p50 and <= 5 ms at p99.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

#: The goals (docs above): CPU ratio per class, latency added GS -> vehicle (ms).
CPU_RATIO_GOAL = 1.5
ADDED_P50_MS_GOAL = 1.0
ADDED_P99_MS_GOAL = 5.0
#: The flight measured per half (s from the take-off) by default, and with ``--quick``.
FLIGHT_S = 120.0
QUICK_FLIGHT_S = 30.0
QUICK_K = 25
#: The process classes, as the rows name them, and how the runs' process names map onto them.
CLASSES = ("drones host", "GSs host", "routers")
#: The latencies compared, as ``latency.summary`` names them, and as the table says them: GS -> vehicle
#: whole, then split where the drone's host takes the message from Zenoh: the wire (the GS's pacing and
#: session, the routers, the drone's session) and the host (the wait for the drone's turn in a pass over
#: every drone of the host, then the drone's own handling); vehicle -> GS.
LATENCY_LABELS = {"gs_to_vehicle": "GS -> vehicle", "gs_to_vehicle_wire": "  GS -> drone's host (wire)",
                  "gs_to_vehicle_gs": "    of which the GS's pass and pacing",
                  "gs_to_vehicle_host": "  drone's host -> vehicle", "vehicle_to_gs": "vehicle -> GS",
                  "vehicle_to_gs_drone": "  vehicle -> put (the drone)", "vehicle_to_gs_wire": "  put -> GS's inbox (wire)",
                  "vehicle_to_gs_host": "  GS's inbox -> GS (its loop)"}
#: The split, which an older run's notes do not have.
SPLIT_WAYS = ("gs_to_vehicle_wire", "gs_to_vehicle_gs", "gs_to_vehicle_host", "vehicle_to_gs_drone", "vehicle_to_gs_wire", "vehicle_to_gs_host")
#: The messages each half carried per second (``latency.rates``): direction, side, the row's name.
MESSAGES = (("down", "sent", "vehicle frames out of the vehicles"), ("down", "got", "vehicle frames into the GSs"),
            ("up", "sent", "GS frames put"), ("up", "got", "GS frames into the vehicles"))


class OverheadArgsError(ValueError):
    """Bad arguments: one line for the command line."""


def parse_drones(text: str | None, quick: bool) -> list[int]:
    """``--drones 100,300`` as numbers (default: 100 and 300; ``--quick``: 25)."""
    from zdrone.fleet.files import MAX_SCALE_DRONES

    if not text:
        return [QUICK_K] if quick else [100, 300]
    try:
        ks = [int(x) for x in text.split(",")]
    except ValueError:
        raise OverheadArgsError(f"--drones {text!r}: expected numbers like 100,300") from None
    if not ks or not all(1 <= k <= MAX_SCALE_DRONES for k in ks):
        raise OverheadArgsError(f"--drones {text}: each 1..{MAX_SCALE_DRONES}")
    return ks


def check_args(sites: int, stations: int, flight: float | None) -> None:
    """``--sites`` 0 (one router) or 2..G; ``--stations`` 2..26; ``--flight`` 10..1200 s."""
    if not 2 <= stations <= 26:
        raise OverheadArgsError(f"--stations {stations}: must be 2..26")
    if sites and not 2 <= sites <= stations:
        raise OverheadArgsError(f"--sites {sites}: must be 2..{stations} (a site per ground station at most), or 0 for one router")
    if flight is not None and not 10.0 <= flight <= 1200.0:
        raise OverheadArgsError(f"--flight {flight:g}: must be 10..1200 seconds")


# ------------------------------------------------------------------ the figures
def by_class(row: dict[str, Any], field: str) -> dict[str, float | None]:
    """A run's per-process ``field`` (``cpu_percent``, or ``memory_mb``'s RSS) summed per process class;
    None where a process of the class was not measured."""
    out: dict[str, float | None] = {}
    for name, v in row.get(field, {}).items():
        cls = "drones host" if name.startswith("drones") else "GSs host" if name.startswith("stations") else \
            "routers" if name.startswith("router") else None
        if cls is None:
            continue
        if isinstance(v, dict):
            v = v.get("rss")
        if v is None or out.get(cls, 0.0) is None:
            out[cls] = None
        else:
            out[cls] = round((out.get(cls) or 0.0) + float(v), 1)
    return out


#: A host process above this share of a core is saturated (``zdrone bench overhead`` says so).
SATURATED_SHARE = 0.6


def ms_per_s_per_drone(cpu_percent: float | None, k: int) -> float | None:
    """100 % of a core is 1000 ms of CPU per second; per drone of the K."""
    return None if cpu_percent is None or k <= 0 else round(10.0 * cpu_percent / k, 3)


def ratio(zdrone: float | None, bare: float | None) -> float | None:
    """zdrone / bare, two decimals; None if either is missing or bare is 0."""
    if zdrone is None or bare is None or bare <= 0:
        return None
    return round(zdrone / bare, 2)


def added(zdrone: float | None, bare: float | None) -> float | None:
    if zdrone is None or bare is None:
        return None
    return round(zdrone - bare, 2)


def compare(k: int, zd: dict[str, Any], bare: dict[str, Any]) -> dict[str, Any]:
    """The comparison of one K and layout: per class and per measure, bare, zdrone, ratio (and for the
    latencies the milliseconds added)."""
    cpu_z, cpu_b = by_class(zd, "cpu_percent"), by_class(bare, "cpu_percent")
    mem_z, mem_b = by_class(zd, "memory_mb"), by_class(bare, "memory_mb")
    cls: dict[str, Any] = {}
    for c in CLASSES:
        z, b = ms_per_s_per_drone(cpu_z.get(c), k), ms_per_s_per_drone(cpu_b.get(c), k)
        cls[c] = {"cpu_ms_per_s_per_drone": {"bare": b, "zdrone": z, "ratio": ratio(z, b)},
                  "rss_mb": {"bare": mem_b.get(c), "zdrone": mem_z.get(c), "ratio": ratio(mem_z.get(c), mem_b.get(c))}}
    lat: dict[str, Any] = {}
    for way in LATENCY_LABELS:
        lz, lb = zd.get("latency", {}).get(way, {}), bare.get("latency", {}).get(way, {})
        if not lz and not lb and way in SPLIT_WAYS:
            continue
        lat[way] = {p: {"bare": lb.get(f"{p}_ms"), "zdrone": lz.get(f"{p}_ms"),
                        "ratio": ratio(lz.get(f"{p}_ms"), lb.get(f"{p}_ms")), "added_ms": added(lz.get(f"{p}_ms"), lb.get(f"{p}_ms"))}
                    for p in ("p50", "p99")}
        lat[way]["n"] = {"bare": lb.get("n"), "zdrone": lz.get("n")}
    # per vehicle frame carried: the simulators stream at most one of each message per step, so a host
    # that steps its vehicles less often (more work per pass) carries fewer frames a second
    frames_z = zd.get("messages_per_s", {}).get("down", {}).get("sent")
    frames_b = bare.get("messages_per_s", {}).get("down", {}).get("sent")
    for c in CLASSES:
        z = None if cpu_z.get(c) is None or not frames_z else round(10_000.0 * cpu_z[c] / frames_z, 1)  # type: ignore[operator]
        b = None if cpu_b.get(c) is None or not frames_b else round(10_000.0 * cpu_b[c] / frames_b, 1)  # type: ignore[operator]
        cls[c]["cpu_us_per_vehicle_frame"] = {"bare": b, "zdrone": z, "ratio": ratio(z, b)}
    samples = {"bare": bare.get("samples_per_s"), "zdrone": zd.get("samples_per_s"),
               "ratio": ratio(zd.get("samples_per_s"), bare.get("samples_per_s"))}
    messages: dict[str, Any] = {}
    for way, side, name in MESSAGES:
        mz = zd.get("messages_per_s", {}).get(way, {}).get(side)
        mb = bare.get("messages_per_s", {}).get(way, {}).get(side)
        messages[name] = {"bare": mb, "zdrone": mz, "ratio": ratio(mz, mb)}
    ratios = [cls[c]["cpu_ms_per_s_per_drone"]["ratio"] for c in CLASSES]
    def within(way: dict[str, Any], p: str, goal: float) -> bool:
        return way[p]["added_ms"] is not None and way[p]["added_ms"] <= goal

    up = lat["gs_to_vehicle"]
    goals = {"cpu_ratio_max": max((r for r in ratios if r is not None), default=None),
             "cpu_within": all(r is not None and r <= CPU_RATIO_GOAL for r in ratios),
             "added_p50_within": within(up, "p50", ADDED_P50_MS_GOAL), "added_p99_within": within(up, "p99", ADDED_P99_MS_GOAL)}
    wire = lat.get("gs_to_vehicle_wire")
    if wire is not None:  # the same goals on the way from the GS to the drone's host alone
        goals["wire_added_p50_within"] = within(wire, "p50", ADDED_P50_MS_GOAL)
        goals["wire_added_p99_within"] = within(wire, "p99", ADDED_P99_MS_GOAL)
    hosts = {h: host_load(r) for h, r in (("zdrone", zd), ("bare", bare))}
    lat["catch_up_age"] = zd.get("latency", {}).get("catch_up_age")  # zdrone alone: bare has no hand-over
    return {"classes": cls, "latency_ms": lat, "samples_per_s": samples, "messages_per_s": messages, "goals": goals,
            "hosts": hosts, "saturated": {h: x["saturated"] for h, x in hosts.items()}}


def host_load(row: dict[str, Any]) -> dict[str, Any]:
    """Each host process's share of a core over the flight, how often the drones host stepped a drone, and which
    hosts ran above ``SATURATED_SHARE`` (saturated: they fall behind their own pace, so their CPU per
    drone reads low; a figure from them is reported, not counted as cheap)."""
    shares = row.get("drone_host_shares")
    if isinstance(shares, dict):
        shares = list(shares.values())
    drones = [float(x) for x in shares] if shares else (
        [row["cpu_percent"]["drones host"] / 100.0] if row.get("cpu_percent", {}).get("drones host") is not None else [])
    cpu = row.get("cpu_percent", {})
    stations = cpu.get("stations host")
    routers = {n: v / 100.0 for n, v in cpu.items() if n.startswith("router") and v is not None}
    out: dict[str, Any] = {"drones hosts": [round(x, 2) for x in drones],
                           "GSs host": None if stations is None else round(stations / 100.0, 2),
                           "routers": {n: round(v, 2) for n, v in routers.items()},
                           "drones_host_passes_per_s": row.get("drones_host_passes_per_s"),
                           "drones_host_step_late": row.get("drones_host_step_late")}
    sat = [f"drones host {i}" for i, x in enumerate(drones) if x > SATURATED_SHARE]
    if stations is not None and stations / 100.0 > SATURATED_SHARE:
        sat.append("GSs host")
    sat += [n for n, v in routers.items() if v > SATURATED_SHARE]
    out["saturated"] = sat
    return out


# ------------------------------------------------------------------ running
def run(ks: list[int], stations: int = 3, sites: int = 0, flight: float | None = None, quick: bool = False,
        speedup: float | None = None, progress: bool = True, hosts_nice: int | None = None, runs: int = 1,
        drone_hosts: int = 1) -> dict[str, Any]:
    """Fly each K twice (zdrone, then bare) in the layout, ``runs`` times; the rows, their comparison and
    (several runs) the spread. ``hosts_nice``: the drones and GSs hosts' niceness in both halves (default
    ``scale.HOSTS_NICE``); ``drone_hosts``: the drones stepped in that many host processes, both halves."""
    from zdrone.bench import bare as bare_mod
    from zdrone.bench import scale
    from zdrone.bench.table import ProgressLine

    nice = scale.HOSTS_NICE if hosts_nice is None else hosts_nice
    flight_s = flight if flight is not None else (QUICK_FLIGHT_S if quick else FLIGHT_S)
    base = Path(tempfile.mkdtemp(prefix="zdrone-bench-overhead-"))
    where = f"{sites} sites" if sites else "1 router"
    rows = []
    status = ProgressLine(progress)
    try:
        for k, run_no in [(k, i) for k in ks for i in range(runs)]:
            sp = speedup if speedup is not None else scale.speedup_for(k)
            status.say(f"zdrone: {k} drones x {stations} GSs, {where}, {flight_s:g} s of flight (speed-up {sp:g})…")
            zd = scale._one(k, stations, base / f"run{run_no}", timeout=flight_s, sites=sites, speedup=sp, hosts_nice=nice,
                            latency=True, drone_hosts=drone_hosts)
            if "runs" in zd:
                from zdrone.bench import latency as lat

                files = sorted(Path(zd["runs"]).glob("latency-*.json"))
                zd["latency"] = {**lat.summary(lat.load(files)), "catch_up_age": lat.catch_up(files)}
                zd["messages_per_s"] = lat.rates(files, zd.get("window_s") or 0.0)
            status.say(f"bare Zenoh: {k} drones x {stations} GSs, {where}, {flight_s:g} s of flight (speed-up {sp:g})…")
            bz = bare_mod.one(k, stations, base / f"run{run_no}", flight_s, sites=sites, speedup=sp, hosts_nice=nice,
                              drone_hosts=drone_hosts)
            rows.append({"k": k, "run": run_no, "drone_hosts": drone_hosts, "g": stations, "sites": sites or 1, "layout": where, "speedup": sp, "flight_s": flight_s,
                         "zdrone": _slim(zd), "bare": bz, "compare": compare(k, zd, bz),
                         "errors": {h: r["error"] for h, r in (("zdrone", zd), ("bare", bz)) if r.get("error")}})
    finally:
        status.close()
    return {"rows": rows, "spread": spread(rows), "stations": stations, "sites": sites, "flight_s": flight_s, "runs": str(base),
            "runs_per_k": runs, "drone_hosts": drone_hosts, "hosts_nice": nice,
            "goals": {"cpu_ratio": CPU_RATIO_GOAL, "added_gs_to_vehicle_p50_ms": ADDED_P50_MS_GOAL,
                      "added_gs_to_vehicle_p99_ms": ADDED_P99_MS_GOAL, "at": {"k": 300, "g": 3, "sites": 3}}}


def spread(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per K over its runs: (min, median, max) of each class's CPU ratio, of the vehicle -> GS and GS ->
    vehicle added p50/p99, and of each half's time on the ground until every link was made."""
    def mmm(xs: list[float | None]) -> list[float] | None:
        ys = sorted(x for x in xs if x is not None)
        return [ys[0], ys[(len(ys) - 1) // 2], ys[-1]] if ys else None

    out: dict[str, Any] = {}
    for k in sorted({r["k"] for r in rows}):
        mine = [r for r in rows if r["k"] == k]
        cmp = [r["compare"] for r in mine]
        out[str(k)] = {
            "runs": len(mine),
            "cpu_ratio": {c: mmm([x["classes"][c]["cpu_ms_per_s_per_drone"]["ratio"] for x in cmp]) for c in CLASSES},
            "rss_ratio": {c: mmm([x["classes"][c]["rss_mb"]["ratio"] for x in cmp]) for c in CLASSES},
            "added_ms": {f"{way} {p}": mmm([x["latency_ms"].get(way, {}).get(p, {}).get("added_ms") for x in cmp])
                         for way in ("gs_to_vehicle", "vehicle_to_gs") for p in ("p50", "p99")},
            "ground_s": {"zdrone": mmm([r["zdrone"].get("ground_s") for r in mine]),
                         "bare": mmm([r["bare"].get("ground_s") for r in mine])},
            "saturated": sorted({f"{h}: {n}" for x in cmp for h, ns in x.get("saturated", {}).items() for n in ns})}
    return out


def _slim(row: dict[str, Any]) -> dict[str, Any]:
    """The zdrone run's row without what only ``bench scale`` reads (per-drone detail)."""
    keep = ("layout", "k", "g", "sites", "tls", "correct", "all_correct", "wall_s", "ground_s", "released", "window_s",
            "cpu_percent", "memory_mb", "samples_per_s", "latency", "handovers", "worst_owner_silence_s", "error", "runs",
            "hosts_given_way", "mesh", "messages_per_s", "drone_host_shares", "drones_host_passes_per_s", "drones_host_step_late", "drone_hosts")
    return {f: row[f] for f in keep if f in row}


# ------------------------------------------------------------------ the table
def _num(v: Any, digits: int = 2) -> str:
    return "-" if v is None else f"{v:,.{digits}f}"


def table_rows(cmp: dict[str, Any]) -> list[list[str]]:
    """The rows of one K's table: measure, class, bare, zdrone, zdrone / bare, added."""
    rows: list[list[str]] = []
    for c in CLASSES:
        x = cmp["classes"][c]["cpu_ms_per_s_per_drone"]
        rows.append(["CPU ms/s per drone", c, _num(x["bare"], 3), _num(x["zdrone"], 3), _num(x["ratio"]), ""])
    for c in CLASSES:
        x = cmp["classes"][c].get("cpu_us_per_vehicle_frame")
        if x is not None:
            rows.append(["CPU µs per vehicle frame", c, _num(x["bare"], 1), _num(x["zdrone"], 1), _num(x["ratio"]), ""])
    for c in CLASSES:
        x = cmp["classes"][c]["rss_mb"]
        rows.append(["RSS MB", c, _num(x["bare"], 1), _num(x["zdrone"], 1), _num(x["ratio"]), ""])
    for way, label in LATENCY_LABELS.items():
        if way not in cmp["latency_ms"]:
            continue
        for p in ("p50", "p99"):
            x = cmp["latency_ms"][way][p]
            rows.append([f"latency {p} ms", label, _num(x["bare"]), _num(x["zdrone"]), _num(x["ratio"]),
                         "-" if x["added_ms"] is None else f"{x['added_ms']:+.2f} ms"])
    age = cmp["latency_ms"].get("catch_up_age")
    if age and age.get("n"):
        rows.append(["catch-up frames' age ms, p50 / max", "new owner's first view", "-",
                     f"{_num(age['p50_ms'])} / {_num(age['max_ms'])} (n {age['n']})", "", ""])
    for name, x in cmp.get("messages_per_s", {}).items():
        rows.append(["messages /s", name, _num(x["bare"], 0), _num(x["zdrone"], 0), _num(x["ratio"]), ""])
    s = cmp["samples_per_s"]
    rows.append(["Zenoh samples delivered /s", "all nodes", _num(s["bare"], 0), _num(s["zdrone"], 0), _num(s["ratio"]), ""])
    h = cmp.get("hosts")
    if h:
        def share(x: Any) -> str:
            return "-" if x is None else f"{x:.2f}{' SATURATED' if x > SATURATED_SHARE else ''}"

        for i in range(max(len(h["zdrone"]["drones hosts"]), len(h["bare"]["drones hosts"]))):
            z, b = (h[x]["drones hosts"][i] if i < len(h[x]["drones hosts"]) else None for x in ("zdrone", "bare"))
            rows.append(["share of a core", f"drones host {i}", share(b), share(z), "", ""])
        rows.append(["share of a core", "GSs host", share(h["bare"]["GSs host"]), share(h["zdrone"]["GSs host"]), "", ""])
        for n in sorted(set(h["zdrone"]["routers"]) | set(h["bare"]["routers"])):
            rows.append(["share of a core", n, share(h["bare"]["routers"].get(n)), share(h["zdrone"]["routers"].get(n)), "", ""])
        rows.append(["steps /s a drone", "drones host (slowest)", _num(h["bare"]["drones_host_passes_per_s"], 1),
                     _num(h["zdrone"]["drones_host_passes_per_s"], 1), "", ""])
        late = {x: h[x].get("drones_host_step_late") or {} for x in ("zdrone", "bare")}
        for p in ("p50", "p99"):  # how long after its deadline (or input) a drone's step began: a host's own wait
            rows.append([f"a step's lateness {p} ms", "drones host (latest)", _num(late["bare"].get(f"{p}_ms")),
                         _num(late["zdrone"].get(f"{p}_ms")), "", ""])
    return rows


def render(r: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    for row in r["rows"]:
        cmp, zd, bz = row["compare"], row["zdrone"], row["bare"]
        g = cmp["goals"]
        caption = (f"flight from the take-off until landed, {row['flight_s']:g} s at most: zdrone {zd.get('window_s', '-')} s, "
                   f"bare {bz.get('window_s', '-')} s; speed-up {row['speedup']:g}; zdrone "
                   f"{'mutual TLS, ' if zd.get('tls') else ''}ACL, auth, envelopes, authority; bare: plain TCP, nothing "
                   f"checked; latency n = {cmp['latency_ms']['gs_to_vehicle']['n']['zdrone']}/"
                   f"{cmp['latency_ms']['gs_to_vehicle']['n']['bare']} up, {cmp['latency_ms']['vehicle_to_gs']['n']['zdrone']}/"
                   f"{cmp['latency_ms']['vehicle_to_gs']['n']['bare']} down (zdrone/bare); zdrone's ground (key sharing) "
                   f"{zd.get('ground_s', '-')} s, bare vehicles flown {bz.get('flew', '-')}/{row['k']}. Goals (measured, not "
                   f"asserted; at 300 x 3 over sites): CPU <= {r['goals']['cpu_ratio']:g} x per class: "
                   f"{'met' if g['cpu_within'] else 'not met'} (worst {_num(g['cpu_ratio_max'])}); GS -> vehicle added <= "
                   f"{r['goals']['added_gs_to_vehicle_p50_ms']:g} ms p50: {'met' if g['added_p50_within'] else 'not met'}, <= "
                   f"{r['goals']['added_gs_to_vehicle_p99_ms']:g} ms p99: {'met' if g['added_p99_within'] else 'not met'}")
        if "wire_added_p50_within" in g:
            caption += (f"; on the wire alone (GS -> the drone's host): p50 {'met' if g['wire_added_p50_within'] else 'not met'}, "
                        f"p99 {'met' if g['wire_added_p99_within'] else 'not met'}")
        caption += f"; drones and GSs hosts at nice {r.get('hosts_nice', '-')}"
        if row["errors"]:
            caption += "; errors: " + "; ".join(f"{h}: {e}" for h, e in row["errors"].items())
        print_table(f"Overhead: zdrone vs bare Zenoh, {row['k']} drones x {row['g']} GSs, {row['layout']}"
                    + (f", run {row['run'] + 1}" if r.get("runs_per_k", 1) > 1 else ""),
                    ["measure", "process class", "bare Zenoh", "zdrone", "zdrone / bare", "added"], table_rows(cmp),
                    caption=caption)
    sp = r.get("spread") or {}
    if r.get("runs_per_k", 1) > 1 and sp:
        rows = []
        for k, x in sp.items():
            def f(v: Any) -> str:
                return "-" if not v else " / ".join(_num(y) for y in v)

            for c, v in x["cpu_ratio"].items():
                rows.append([k, f"CPU ratio, {c}", f(v)])
            for c, v in x["rss_ratio"].items():
                rows.append([k, f"RSS ratio, {c}", f(v)])
            for w, v in x["added_ms"].items():
                rows.append([k, f"added ms, {w.replace('_', ' ')}", f(v)])
            rows.append([k, "on the ground until linked, s (zdrone / bare)", f"{f(x['ground_s']['zdrone'])} | {f(x['ground_s']['bare'])}"])
            rows.append([k, "saturated hosts", ", ".join(x["saturated"]) or "none"])
        print_table("Spread over the runs (min / median / max)", ["K", "measure", "spread"], rows)
