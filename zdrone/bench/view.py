"""``zdrone bench view``: the operations picture (``zdrone view``) measured in a real browser.

The page is opened in headless Chromium (Debian's ``/usr/bin/chromium``, through Playwright, launched
as ``tests/integration/test_view.py`` launches it: its own profile, no outside request). Three
measurements, every clock this host's wall clock:

**Latency** (over one shuttle flight, ``zdrone demo --view``): for every hand-over the drone records
(``drone.jsonl``: ``authority``, ``handover_complete``; not the first pairing) after the page is up, the time until
the page's DOM shows the new owner (a MutationObserver on the drone's row stamps ``data-owner``
changes with ``Date.now()``). p50/p95/max; goal p95 <= ``GOAL_P95_MS``. A hand-over the page never
shows is listed as missed; one it showed before the drone's record (a GS's word ahead of the drone's
log) counts as a negative delay, not skipped.

**Memory** (the same flight): the view server's resident memory sampled every ``interval`` seconds
from ``/proc``: start, max, end and the growth per hour (least-squares slope after a warm-up). The
full form flies ``FULL_CROSSINGS`` crossings at speed-up 4 (about 10 minutes) under a 20 Hz command
stream (the soak's flight).

**Fleet** (the scale bench's fleet, its hosts driven directly: one router, a process hosting K drone
nodes, one hosting 3 GSs, ``zdrone view`` beside them, the simulators at speed-up 1 so every drone
reports at its normal rate): from take-off (``--quick``: from when the page first shows every drone live,
paired on the ground), once a second, what the page shows: how many drone rows,
how many stale, each drone's report age as shown plus the time since that picture arrived (the age
of its newest report as the operator sees it); for every picture event, how long after the server
took its snapshot the page had rendered it (the stream's lag); the server's unsent stream bytes
(``Send-Q`` of its sockets to the page, ``ss``), its CPU and RSS. The page *kept up* if every drone
was shown in every sample over a live stream, the lag's p95 under ``KEPT_UP_LAG_S`` and at most one
picture left unsent in the socket at the end. Drones shown stale are counted apart: the page shows
what the server's picture says, and a drone is stale there when no GS's word of it is fresher than
1 s (the fleet's lateness, not the page's).

**Under attack** (``--only attack``; another shuttle flight with the view): a real page is opened and
every picture event it gets is stamped (``Date.now()``, an ``EventSource`` wrapped by an init script);
once it shows d1 live, a control window, then the load, each in a process of its own
(``zdrone.bench.viewload``): ``--clients`` raw clients of the page's stream (``GET /api/stream``, each
trying again about a second after it was refused or cut) and GS X (in the fleet, authorized for no
drone: its own key and router password) sealing ``--forged-rate`` parts a second for the viewer on
its lanes; then a window under the load. Per window: the view's RSS max and CPU (% of one core), the
real page's picture gap (the longest interval between consecutive pictures, and its p95), whether
its stream stayed live and d1 shown live; the clients held open and served, X's parts sent and those
that opened at the view (its own counters, in the picture). Targets beside: RSS <= ``TARGET_RSS_MB``,
CPU <= ``TARGET_CPU_PCT``, gap <= ``TARGET_GAP_S``.

**Under a flood of half-open connections** (``--only flood``; no flight, no browser: the fleet's viewer on
a router of its own): the real ``zdrone view`` with a token, over plain HTTP under ``HEADS`` connections
with half a request head, and over TLS under ``HANDSHAKES`` half-open handshakes, all from one address
and each reopened as soon as cut; the operator's page loads and stream opens served (of those asked),
the view's RSS, open files and CPU (``zdrone.bench.viewflood``).

The attack part is ``zdrone.bench.viewattack``, the flood part ``zdrone.bench.viewflood``; the browser,
the stream probe and the timing summary the parts share, ``zdrone.bench.viewpage``.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from zdrone.bench.background import BackgroundFlight
from zdrone.bench.soak import _slope_per_h, sample
from zdrone.bench.stallwatch import cpu_seconds
from zdrone.bench.table import ProgressLine
from zdrone.bench.viewattack import (ATTACK_CLIENTS, ATTACK_RATE, ATTACK_WINDOW_S, QUICK_ATTACK_CLIENTS,
                                     QUICK_ATTACK_RATE, QUICK_ATTACK_WINDOW_S, _attack, render_attack)
from zdrone.bench.viewflood import render_flood, run_flood
from zdrone.bench.viewpage import CHROMIUM, STREAM_PROBE, Browser, _stats, start_in_order

GOAL_P95_MS = 250.0
SPEEDUP = 4.0
QUICK_CROSSINGS = 2
#: About 10 minutes of flight at speed-up 4 (a crossing is about 40 simulated seconds).
FULL_CROSSINGS = 60
QUICK_DRONES = 25
FULL_DRONES = 300
STATIONS = 3
#: Seconds the fleet is followed: the full form from take-off, ``--quick`` from when the page first shows
#: every drone live (paired, on the ground: the same reports, without the minute of key sharing before take-off).
QUICK_WINDOW_S = 10.0
FULL_WINDOW_S = 120.0
KEPT_UP_LAG_S = 1.0
#: Samples of the window the bench must have taken (its sampler shares the loaded machine: 119 of 120).
SAMPLED_SHARE = 0.95
#: Unsent stream bytes at the end that still count as no backlog (one picture on its way).
BACKLOG_SLACK_B = 1024

#: Every data-owner change of a drone row, with the browser's wall clock (as the view's test).
OWNER_OBSERVER = """
window.__seen = [];
new MutationObserver((muts) => {
  for (const m of muts) {
    const tr = m.target;
    if (tr.tagName !== 'TR' || !tr.dataset || !tr.dataset.drone) continue;
    window.__seen.push([Date.now() / 1000, tr.dataset.drone, tr.getAttribute('data-owner')]);
  }
}).observe(document, {subtree: true, attributes: true, attributeFilter: ['data-owner']});
"""
#: What the page shows of every drone row now.
READ_ROWS = """() => {
  const rows = document.querySelectorAll('#rows tr[data-drone]');
  const ages = [];
  let stale = 0;
  for (const tr of rows) {
    const m = tr.querySelector('td.age').textContent.match(/([0-9.]+) s/);
    ages.push(m ? parseFloat(m[1]) : null);
    if (tr.dataset.stale === 'true') stale++;
  }
  const p = window.__pictures;
  return {t: Date.now() / 1000, rows: rows.length, ages: ages, stale: stale,
          conn: document.getElementById('conn').dataset.state,
          server_time: p.length ? p[p.length - 1][2] : null, pictures: p.length};
}"""


# ------------------------------------------------------------------ latency and memory over a flight
def owner_changes(seen: list[list[Any]], drone: str) -> list[tuple[float, str]]:
    """The page's owner of ``drone`` each time it changed (the first shown value included)."""
    out: list[tuple[float, str]] = []
    for t, d, owner in seen:
        if d == drone and (not out or out[-1][1] != (owner or "")):
            out.append((t, owner or ""))
    return out


def match_changes(records: list[tuple[float, str]], shown: list[tuple[float, str]]) -> list[float | None]:
    """For each (time, new owner) the drone recorded, in order, the delay (s) until the page next
    changed to that owner after the previous match (None: never shown)."""
    delays: list[float | None] = []
    j = 0
    for t, to in records:
        k = next((i for i in range(j, len(shown)) if shown[i][1] == to), None)
        if k is None:
            delays.append(None)
            continue
        delays.append(shown[k][0] - t)
        j = k + 1
    return delays


def _flight(browser: Browser, base: Path, crossings: int, interval: float, status: ProgressLine) -> dict[str, Any]:
    from playwright.sync_api import Error as PlaywrightError

    from zdrone.bench.soak import CROSSING_SIM_S
    from zdrone.core.records import AuthorityMoved, only
    from zdrone.net.eventlog import read_records
    from zdrone.sil.launcher import Demo, DemoOptions
    from zdrone.sil.ports import free_port

    out = base / "flight"
    out.mkdir(parents=True, exist_ok=True)
    port = free_port()
    timeout = 120.0 + 2.0 * (crossings + 2) * CROSSING_SIM_S / SPEEDUP
    demo = Demo(DemoOptions(out=out, speedup=SPEEDUP, quiet=True, live=False, command_rate=20.0, report=False,
                            mission=f"shuttle:{crossings}", timeout=timeout, view=port), out.resolve())

    t_start = time.monotonic()
    flight = BackgroundFlight(demo, "view-flight").start()
    page = None
    page_error: str | None = None
    rss: list[tuple[float, float]] = []
    ticks = 0
    try:
        while flight.is_alive():
            view = demo.children.get("view")
            if view is not None and view.proc.poll() is None and (out / "view.log").exists() \
                    and "zdrone view:" in (out / "view.log").read_text(errors="replace"):
                if page is None and page_error is None:
                    try:
                        page = browser.open(f"http://127.0.0.1:{port}", OWNER_OBSERVER)
                        t_page = time.time()
                    except PlaywrightError as exc:  # the flight goes on to its end; the figures say why not
                        page_error = f"the page did not open: {exc}"
                ticks += 1
                s = sample(view.proc.pid)
                if s is not None:
                    rss.append((time.monotonic(), s["rss_mb"]))
            st = demo.progress.get("status") or {}
            status.say(f"view: {crossings} crossings at speed-up {SPEEDUP:g}, {time.monotonic() - t_start:.0f} s, "
                       f"authority {st.get('owner')} epoch {st.get('epoch')}, server RSS "
                       f"{rss[-1][1] if rss else 0:.0f} MB")
            flight.join(interval)
    finally:
        seen = page.evaluate("window.__seen") if page is not None else []
        if page is not None:
            page.close()
    result = flight.result()
    if page is None:
        return {"error": page_error or f"the view never served; see {out / 'view.log'}"}
    moved = only(read_records(out / "drone.jsonl").records, AuthorityMoved)
    moved = [m for m in moved if m.kind != "paired"]  # the hand-overs (the first pairing is no hand-over)
    before = [m for m in moved if m.t < t_page]
    after = [m for m in moved if m.t >= t_page]
    delays = match_changes([(m.t, m.to) for m in after], owner_changes(seen, "d1"))
    rows = [{"t": round(m.t, 3), "to": m.to, "epoch": m.epoch, "kind": m.kind,
             "page_ms": None if d is None else round(1000.0 * d, 1)} for m, d in zip(after, delays)]
    shown = [d for d in delays if d is not None]
    lat = _stats(shown, 1000.0)
    growth_from = rss[0][0] + min(30.0, 0.2 * (rss[-1][0] - rss[0][0])) if rss else 0.0
    memory = {"interval_s": interval, "samples": len(rss), "ticks": ticks,
              "rss_start_mb": round(rss[0][1], 1) if rss else None,
              "rss_max_mb": round(max(v for _, v in rss), 1) if rss else None,
              "rss_end_mb": round(rss[-1][1], 1) if rss else None,
              "span_s": round(rss[-1][0] - rss[0][0], 1) if rss else 0.0,
              "growth_mb_per_h": round(_slope_per_h([p for p in rss if p[0] >= growth_from]), 2)}
    why_not = (["timed out"] if result.get("timed_out") else []) + (  # a shuttle: no delivery, home, no failsafe
        [f"failsafe: {result['failsafe']}"] if result.get("failsafe") else [])
    latency = {"crossings": crossings, "speedup": SPEEDUP, "changes": len(after), "before_page": len(before),
               "shown": len(shown), "missed": [r for r in rows if r["page_ms"] is None], "rows": rows,
               "ms": lat, "goal_p95_ms": GOAL_P95_MS,
               "within_goal": bool(shown) and len(shown) == len(after) and (lat["p95"] or 0.0) <= GOAL_P95_MS,
               "flight_ok": not why_not, "why_not_ok": why_not,
               "handovers": len(result.get("handovers", [])), "wall_s": round(time.monotonic() - t_start, 1)}
    return {"latency": latency, "memory": memory}


# ------------------------------------------------------------------ one page following the scale fleet
def _send_queue(port: int) -> int | None:
    """Bytes the server at ``port`` has not yet sent on its established sockets (sum of Send-Q)."""
    if shutil.which("ss") is None:
        return None
    try:
        text = subprocess.run(["ss", "-tnH", "state", "established", f"( sport = :{port} )"], capture_output=True,
                              text=True, timeout=5).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    total = 0
    for line in text.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[1].isdigit():
            total += int(parts[1])
    return total


def _fleet(browser: Browser, base: Path, k: int, window: float, from_take_off: bool,
           status: ProgressLine) -> dict[str, Any]:
    from playwright.sync_api import Error as PlaywrightError

    from zdrone.bench.scale import READY_TIMEOUT_S, _wait_line, hold_limit
    from zdrone.fleet.files import init_fleet, scale_nodes
    from zdrone.sil.ports import free_port
    from zdrone.sil.procs import stop_in_order

    d = base / f"fleet-{k}"
    d.mkdir(parents=True, exist_ok=True)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    port = free_port()
    init_fleet(d / "fleet", nodes_spec=scale_nodes(k, STATIONS))
    py = [sys.executable, "-m"]
    common = ["--fleet", str(d / "fleet"), "--out", str(d)]
    cmds = {"router": py + ["zdrone", "router", "-c", str(d / "fleet/router/router.json5"), "--listen", endpoint],
            "view": py + ["zdrone", "view", "--fleet", str(d / "fleet"), "--router", endpoint, "--port", str(port)],
            "drones": py + ["zdrone.bench.scale", "host-drones", "--k", str(k), "--speedup", "1",
                            "--duration", str(window + 60.0), "--hold", str(hold_limit(k)), "--router", endpoint,
                            *common],
            "stations": py + ["zdrone.bench.scale", "host-stations", "--stations", str(STATIONS), "--router", endpoint,
                              *common]}
    ready = {"router": "listening", "view": "zdrone view:"}
    logs = {n: open(d / f"{n}.log", "w") for n in cmds}
    procs: dict[str, subprocess.Popen] = {}
    samples: list[dict[str, Any]] = []
    send_q: list[int] = []
    page = None
    out: dict[str, Any] = {"k": k, "g": STATIONS, "window_s": window, "runs": str(d)}
    try:
        start_in_order(cmds, ready, d, logs, procs)
        page = browser.open(f"http://127.0.0.1:{port}", STREAM_PROBE)
        status.say(f"view: {k} drones x {STATIONS} GSs on the ground, pairing and sharing keys…")
        if _wait_line(d / "drones.log", "drones ready", READY_TIMEOUT_S, procs["drones"]) is None:
            raise RuntimeError(f"the drones host did not start; see {d / 'drones.log'}")
        if from_take_off:
            if _wait_line(d / "drones.log", "take-off", hold_limit(k) + 30, procs["drones"]) is None:
                raise RuntimeError(f"the drones did not take off; see {d / 'drones.log'}")
        else:
            live = "() => document.querySelectorAll('#rows tr[data-stale=false]').length"
            deadline = time.monotonic() + 60.0  # polled from here: the page's CSP forbids a predicate in it
            while page.evaluate(live) < k:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"the page never showed all {k} drones live; see {d}")
                time.sleep(0.2)
        out["from"] = "take-off" if from_take_off else "every drone shown live"
        view_pid = procs["view"].pid
        t0, cpu0, mem0 = time.monotonic(), cpu_seconds(view_pid), sample(view_pid)
        rss = [mem0["rss_mb"]] if mem0 else []
        n_pictures0 = page.evaluate("window.__pictures.length")
        while time.monotonic() - t0 < window:
            time.sleep(max(0.0, 1.0 - (time.monotonic() - t0) % 1.0))
            got = page.evaluate(READ_ROWS)
            samples.append(got)
            q = _send_queue(port)
            if q is not None:
                send_q.append(q)
            m = sample(view_pid)
            if m is not None:
                rss.append(m["rss_mb"])
            status.say(f"view: {k} drones, {time.monotonic() - t0:.0f}/{window:.0f} s, "
                       f"{got['rows']} rows, {got['stale']} stale")
        span = time.monotonic() - t0
        cpu1 = cpu_seconds(view_pid)
        pictures = page.evaluate("window.__pictures")[n_pictures0:]
        lags = [done - server for _, done, server, _ in pictures if server is not None]
        ages = []
        for s in samples:  # each drone's shown age, plus the time since that picture was the latest
            since = s["t"] - s["server_time"] if s["server_time"] is not None else 0.0
            ages += [a + since for a in s["ages"] if a is not None]
        out.update({
            "samples": len(samples), "expected_samples": int(window),
            "rows_shown": {"min": min((s["rows"] for s in samples), default=0),
                           "max": max((s["rows"] for s in samples), default=0)},
            "stale": {"samples_with_stale": sum(1 for s in samples if s["stale"]),
                      "max": max((s["stale"] for s in samples), default=0),
                      "per_sample": [s["stale"] for s in samples]},
            "disconnected_samples": sum(1 for s in samples if s["conn"] != "live"),
            "age_s": _stats(ages, digits=2), "lag_s": _stats(lags, digits=3),
            "lag_first_last_s": [round(lags[0], 3), round(lags[-1], 3)] if lags else None,
            "pictures": len(pictures), "pictures_per_s": round(len(pictures) / span, 1),
            "picture_kb": round(sum(p[3] for p in pictures) / max(1, len(pictures)) / 1024, 1),
            "send_q_bytes": {"max": max(send_q), "last": send_q[-1]} if send_q else None,
            "server_cpu_pct": round(100.0 * (cpu1 - cpu0) / span, 1) if cpu0 is not None and cpu1 is not None else None,
            "server_rss_mb": {"start": round(rss[0], 1), "max": round(max(rss), 1), "end": round(rss[-1], 1)}
            if rss else None})
        # the sampler runs on the same loaded machine: it may take a sample or two fewer than the window's
        out["kept_up"] = (out["samples"] >= SAMPLED_SHARE * out["expected_samples"] and out["rows_shown"]["min"] == k
                          and out["disconnected_samples"] == 0
                          and out["lag_s"]["p95"] is not None and out["lag_s"]["p95"] <= KEPT_UP_LAG_S
                          and (not send_q or send_q[-1] <= max(BACKLOG_SLACK_B, 1024 * out["picture_kb"])))
    except (RuntimeError, PlaywrightError) as exc:
        out["error"] = str(exc)
    finally:
        if page is not None:
            page.close()
        stop_in_order(procs, ("view", "stations", "drones", "router"))
        for f in logs.values():
            f.close()
    return out


#: The parts of the bench, each selectable alone (``--only``); all but ``corridor`` by default.
PARTS = ("flight", "fleet", "attack", "flood", "corridor")
DEFAULT_PARTS = ("flight", "fleet", "attack", "flood")
#: The parts that drive a real page (the browser is started for them only).
BROWSER_PARTS = ("flight", "fleet", "attack", "corridor")


def run(quick: bool = False, crossings: int | None = None, drones: int | None = None, progress: bool = True,
        out: Path | None = None, only: tuple[str, ...] = DEFAULT_PARTS, clients: int | None = None,
        forged_rate: float | None = None, flood_rate: float | None = None) -> dict[str, Any]:
    crossings = crossings or (QUICK_CROSSINGS if quick else FULL_CROSSINGS)
    drones = drones or (QUICK_DRONES if quick else FULL_DRONES)
    clients = clients or (QUICK_ATTACK_CLIENTS if quick else ATTACK_CLIENTS)
    forged_rate = forged_rate or (QUICK_ATTACK_RATE if quick else ATTACK_RATE)
    window = QUICK_WINDOW_S if quick else FULL_WINDOW_S
    interval = 2.0 if quick else 5.0
    base = out or Path(tempfile.mkdtemp(prefix="zdrone-bench-view-"))
    base.mkdir(parents=True, exist_ok=True)
    status = ProgressLine(progress)
    browser = Browser(base / "profile") if any(p in only for p in BROWSER_PARTS) else None
    t0 = time.monotonic()
    result: dict[str, Any] = {"parts": [p for p in PARTS if p in only]}
    try:
        if "flight" in only and browser is not None:
            result.update(_flight(browser, base, crossings, interval, status))
        if "fleet" in only and browser is not None:
            result["fleet"] = _fleet(browser, base, drones, window, not quick, status)
        if "attack" in only and browser is not None:
            result["attack"] = _attack(browser, base, clients, forged_rate,
                                       QUICK_ATTACK_WINDOW_S if quick else ATTACK_WINDOW_S, status, SPEEDUP)
        if "flood" in only:
            result["flood"] = run_flood(base, quick, flood_rate, status)
        if "corridor" in only and browser is not None:
            from zdrone.bench.viewcorridor import corridor_page

            result["corridor"] = corridor_page(browser, base, 20.0 if quick else 60.0, status)
    finally:
        if browser is not None:
            browser.close()
        status.close()
    result.update({"outside_requests": browser.outside if browser is not None else [],
                   "wall_s": round(time.monotonic() - t0, 1),
                   "runs": str(base), "browser": CHROMIUM})
    (base / "result.json").write_text(json.dumps(result, indent=2))
    return result


def failed(r: dict[str, Any]) -> bool:
    """A part asked for that did not give its figures (a target missed is a figure, not a failure)."""
    return ("flight" in r["parts"] and "latency" not in r) or ("fleet" in r["parts"] and "error" in r["fleet"]) or (
        "attack" in r["parts"] and ("error" in r["attack"] or "load" not in r["attack"])) or (
        "flood" in r["parts"] and "error" in r["flood"]) or ("corridor" in r["parts"] and "error" in r["corridor"])


def render(r: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    parts = r.get("parts", ["flight", "fleet"])
    if "flight" in parts:
        _render_flight(r)
    if "fleet" in parts:
        _render_fleet(r["fleet"])
    if "attack" in parts:
        render_attack(r["attack"])
    if "flood" in parts:
        render_flood(r["flood"])
    if "corridor" in parts:
        from zdrone.bench.viewcorridor import render_corridor

        render_corridor(r["corridor"])


def _render_flight(r: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    if "latency" in r:
        lat, mem = r["latency"], r["memory"]
        ms = lat["ms"]
        print_table(f"Drone record -> page DOM: {lat['shown']} of {lat['changes']} hand-overs shown "
                    f"({lat['crossings']} crossings at speed-up {lat['speedup']:g})",
                    ["p50 ms", "p95 ms", "max ms", "goal p95 ms", "within goal", "missed"],
                    [[ms["p50"], ms["p95"], ms["max"], lat["goal_p95_ms"], "yes" if lat["within_goal"] else "no",
                      len(lat["missed"])]],
                    caption=f"the drone's drone.jsonl record to the MutationObserver's stamp, both this host's wall "
                            f"clock; {lat['before_page']} before the page opened not counted")
        print_table(f"View server memory over the flight ({mem['span_s']:.0f} s, a sample every {mem['interval_s']:g} s)",
                    ["samples", "RSS start MB", "RSS max MB", "RSS end MB", "growth MB/h"],
                    [[mem["samples"], mem["rss_start_mb"], mem["rss_max_mb"], mem["rss_end_mb"], mem["growth_mb_per_h"]]])
    else:
        print(f"flight: {r.get('error')}")


def _render_fleet(f: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    if "error" in f:
        print(f"fleet: {f['error']}")
        return
    age, lag, q, mem = f["age_s"], f["lag_s"], f["send_q_bytes"] or {}, f["server_rss_mb"] or {}
    print_table(f"One page following {f['k']} drones x {f['g']} GSs ({f['window_s']:g} s from {f['from']}, "
                f"{f['samples']} samples)",
                ["rows shown", "samples with stale", "stale max", "age p50 s", "age p95 s", "age max s", "kept up"],
                [[f"{f['rows_shown']['min']}..{f['rows_shown']['max']}", f["stale"]["samples_with_stale"],
                  f["stale"]["max"], age["p50"], age["p95"], age["max"], "yes" if f["kept_up"] else "no"]],
                caption="age: each drone's newest report as the page shows it (the picture's age plus the time since "
                        "it arrived); stale: as the server's picture says (no GS's word fresher than 1 s); kept up: "
                        f"every drone shown in {SAMPLED_SHARE:.0%} of the window's samples at least, lag p95 <= "
                        f"{KEPT_UP_LAG_S:g} s, at most one picture unsent at the end")
    print_table("Its stream", ["lag p50 s", "lag p95 s", "lag max s", "pictures /s", "picture KB", "Send-Q max B",
                               "server CPU %", "RSS max MB"],
                [[lag["p50"], lag["p95"], lag["max"], f["pictures_per_s"], f["picture_kb"], q.get("max", "-"),
                  f["server_cpu_pct"], mem.get("max", "-")]],
                caption="lag: the server's snapshot -> the page has rendered it; Send-Q: stream bytes the server could not "
                        f"send yet (ss); the server's RSS from {mem.get('start')} to {mem.get('end')} MB")
