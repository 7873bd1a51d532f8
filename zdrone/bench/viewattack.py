"""``zdrone bench view``'s attack part (``--only attack``): a real page follows a shuttle flight with the
view while ``--clients`` raw clients of its stream and GS X's forged parts (``zdrone.bench.viewload``)
load the view; its figures over a control window and a window under the load, against the targets
(``TARGET_RSS_MB``, ``TARGET_CPU_PCT``, ``TARGET_GAP_S``), and their tables.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from zdrone.bench.background import BackgroundFlight
from zdrone.bench.revoke import percentile
from zdrone.bench.soak import sample
from zdrone.bench.stallwatch import cpu_seconds
from zdrone.bench.table import ProgressLine
from zdrone.bench.viewpage import STREAM_PROBE, Browser, _stats

#: The attack part's targets (the issue's): the view's RSS, its CPU (% of one core), the real page's picture gap.
TARGET_RSS_MB = 150.0
TARGET_CPU_PCT = 50.0
TARGET_GAP_S = 1.0
ATTACK_CLIENTS = 1000
ATTACK_RATE = 1000.0
QUICK_ATTACK_CLIENTS = 50
QUICK_ATTACK_RATE = 100.0
ATTACK_WINDOW_S = 30.0
QUICK_ATTACK_WINDOW_S = 10.0
#: Seconds the load has to arrive (every client tried once, the forger sending) before the window opens.
LOAD_RAMP_S = 30.0
#: Seconds after the load arrived before its window opens (the first wave of refusals settles).
LOAD_SETTLE_S = 3.0
#: What the page shows now: its stream's state, d1's row (live or stale, owner), pictures so far.
READ_D1 = """() => {
  const tr = document.querySelector('#rows tr[data-drone="d1"]');
  return {t: Date.now() / 1000, conn: document.getElementById('conn').dataset.state,
          d1: tr ? (tr.dataset.stale === 'true' ? 'stale' : 'live') : 'absent',
          owner: tr ? tr.getAttribute('data-owner') : null, pictures: window.__pictures.length};
}"""
#: The view's counters in the newest picture the page got.
READ_COUNTERS = """() => {
  if (!window.__lastPicture) return null;
  const p = JSON.parse(window.__lastPicture);
  return {opened: p.opened, drops: p.drops || {}, server_time: p.server_time};
}"""


def picture_gaps(stamps: list[float], t0: float, t1: float) -> dict[str, Any]:
    """The intervals between consecutive pictures the page got in [``t0``, ``t1``] (the one before
    ``t0`` included, so the first interval is whole); the max also counts the time from the last
    picture to ``t1`` (a stream gone silent shows), and the whole window when none came."""
    s = sorted(stamps)
    inside = [t for t in s if t0 <= t <= t1]
    before = [t for t in s if t < t0]
    seq = before[-1:] + inside
    gaps = [b - a for a, b in zip(seq, seq[1:])]
    tail = t1 - seq[-1] if seq else t1 - t0
    ordered = sorted(gaps)
    return {"pictures": len(inside), "max_s": round(max(gaps + [tail]), 3),
            "p95_s": round(percentile(ordered, 95), 3) if ordered else None,
            "p50_s": round(percentile(ordered, 50), 3) if ordered else None}


def counter_delta(first: dict[str, Any] | None, last: dict[str, Any] | None) -> dict[str, Any]:
    """The view's counters moved on between two pictures: parts opened, each drop reason, and X's parts
    that opened (each names d99, a drone outside the fleet: one ``unknown_drone`` each)."""
    if not first or not last:
        return {"opened": None, "x_opened": None, "drops": {}, "span_s": None}
    a, b = first.get("drops") or {}, last.get("drops") or {}
    drops = {k: b.get(k, 0) - a.get(k, 0) for k in sorted(set(a) | set(b)) if b.get(k, 0) - a.get(k, 0)}
    span = None
    if first.get("server_time") is not None and last.get("server_time") is not None:
        span = round(last["server_time"] - first["server_time"], 2)
    return {"opened": (last.get("opened") or 0) - (first.get("opened") or 0), "x_opened": drops.get("unknown_drone", 0),
            "drops": drops, "span_s": span}


def meets_targets(w: dict[str, Any]) -> dict[str, bool | None]:
    """Each target met by the figures of a window (None: no figure)."""
    def within(v: float | None, limit: float) -> bool | None:
        return None if v is None else v <= limit

    return {"rss": within(w.get("rss_max_mb"), TARGET_RSS_MB), "cpu": within(w.get("cpu_pct"), TARGET_CPU_PCT),
            "gap": within((w.get("gap") or {}).get("max_s"), TARGET_GAP_S),
            "page_live": w.get("samples", 0) > 0 and w.get("page_not_live", 1) == 0,
            "d1_live": w.get("samples", 0) > 0 and w.get("d1_not_live", 1) == 0}


def _load_at(path: Path | None) -> dict[str, Any] | None:
    from zdrone.bench.viewload import last_stats

    return None if path is None else last_stats(path)


def _window(page: Any, view_pid: int, window: float, name: str, status: ProgressLine,
            clients: Path | None = None, forger: Path | None = None) -> dict[str, Any]:
    """``window`` seconds of the view and the real page: the view's RSS and CPU, what the page showed
    each second, its pictures, the view's counters; the load's counters at both ends."""
    t0, cpu0, wall0 = time.monotonic(), cpu_seconds(view_pid), time.time()
    counters0, load0, forge0 = page.evaluate(READ_COUNTERS), _load_at(clients), _load_at(forger)
    rss: list[float] = []
    shown: list[dict[str, Any]] = []
    held: list[tuple[int, int]] = []
    while time.monotonic() - t0 < window:
        time.sleep(max(0.0, 1.0 - (time.monotonic() - t0) % 1.0))
        m = sample(view_pid)
        if m is not None:
            rss.append(m["rss_mb"])
        got = page.evaluate(READ_D1)
        shown.append(got)
        now = _load_at(clients)
        if now is not None:
            held.append((now["open"], now["streaming"]))
        status.say(f"view attack: {name} {time.monotonic() - t0:.0f}/{window:.0f} s, view RSS "
                   f"{rss[-1] if rss else 0:.0f} MB, page {got['conn']}, d1 {got['d1']}"
                   + (f", clients open {held[-1][0]} streaming {held[-1][1]}" if held else ""))
    span, cpu1, wall1 = time.monotonic() - t0, cpu_seconds(view_pid), time.time()
    counters1, load1, forge1 = page.evaluate(READ_COUNTERS), _load_at(clients), _load_at(forger)
    pics = page.evaluate("window.__pictures")  # [arrived, rendered, server's time, size] (STREAM_PROBE)
    stamps = [p[0] for p in pics]
    lags = [got - server for got, _, server, _ in pics if server is not None and wall0 <= got <= wall1]
    out: dict[str, Any] = {
        "window_s": round(span, 1), "samples": len(shown),
        "rss_max_mb": round(max(rss), 1) if rss else None, "rss_start_mb": round(rss[0], 1) if rss else None,
        "rss_end_mb": round(rss[-1], 1) if rss else None,
        "cpu_pct": round(100.0 * (cpu1 - cpu0) / span, 1) if cpu0 is not None and cpu1 is not None else None,
        "gap": picture_gaps(stamps, wall0, wall1), "lag_s": _stats(lags, digits=3),
        "page_not_live": sum(1 for s in shown if s["conn"] != "live"),
        "d1_not_live": sum(1 for s in shown if s["d1"] != "live"),
        "owners": sorted({s["owner"] or "" for s in shown}),
        "view": counter_delta(counters0, counters1)}
    out["pictures_per_s"] = round(out["gap"]["pictures"] / span, 1)
    if load0 is not None and load1 is not None:
        keys = ("attempts", "served", "streamed", "refused_503", "cut_before_answer", "connect_failed", "stream_ended",
                "other_status", "bytes")
        out["clients"] = {"n": load1["n"], "held_open": {"min": min(h[0] for h in held), "max": max(h[0] for h in held),
                                                         "end": load1["open"]} if held else None,
                          "streaming": {"min": min(h[1] for h in held), "max": max(h[1] for h in held),
                                        "end": load1["streaming"]} if held else None,
                          **{k: load1[k] - load0[k] for k in keys}}
        for k in ("attempts", "refused_503", "cut_before_answer"):
            out["clients"][f"{k}_per_s"] = round(out["clients"][k] / span, 1)
        out["clients"]["since_load_began"] = {k: load1[k] for k in keys}
    if forge0 is not None and forge1 is not None:
        sent = forge1["sent"] - forge0["sent"]
        dt = max(1e-6, forge1["t"] - forge0["t"])
        out["forger"] = {"sent": sent, "sent_per_s": round(sent / dt, 1)}
        x = out["view"]["x_opened"]
        if x is not None and out["view"]["span_s"]:
            out["forger"]["reached_per_s"] = round(x / out["view"]["span_s"], 1)
    out["targets_met"] = meets_targets(out)
    return out


def _attack(browser: Browser, base: Path, clients: int, rate: float, window: float,
            status: ProgressLine, speedup: float) -> dict[str, Any]:
    import math
    import socket

    from playwright.sync_api import Error as PlaywrightError

    from zdrone.bench.soak import CROSSING_SIM_S
    from zdrone.sil.launcher import Demo, DemoOptions
    from zdrone.sil.ports import free_port
    from zdrone.sil.procs import spawn, stop_in_order

    d = base / "attack"
    d.mkdir(parents=True, exist_ok=True)
    port = free_port(socket.SOCK_STREAM)
    # long enough for the page to come up, the control window, the load's arrival and its window
    crossings = math.ceil((2 * window + LOAD_RAMP_S + 90.0) / (CROSSING_SIM_S / speedup))
    timeout = 120.0 + 2.0 * (crossings + 2) * CROSSING_SIM_S / speedup
    demo = Demo(DemoOptions(out=d, speedup=speedup, quiet=True, live=False, command_rate=20.0, report=False,
                            mission=f"shuttle:{crossings}", timeout=timeout, view=port), d.resolve())
    out: dict[str, Any] = {"clients": clients, "forged_rate": rate, "window_s": window, "crossings": crossings,
                           "runs": str(d), "targets": {"rss_mb": TARGET_RSS_MB, "cpu_pct": TARGET_CPU_PCT,
                                                       "gap_s": TARGET_GAP_S}}
    flight = BackgroundFlight(demo, "view-attack-flight").start()
    page = None
    load: dict[str, Any] = {}
    logs: list[Any] = []
    files = {"clients": d / "clients.jsonl", "forger": d / "forger.jsonl"}
    t_start = time.monotonic()

    def flying() -> None:
        if not flight.is_alive():
            raise RuntimeError(f"the flight ended before the windows were done (crossings {crossings}); see {d}")

    try:
        while page is None:
            flying()
            view = demo.children.get("view")
            if view is not None and view.proc.poll() is None and (d / "view.log").exists() \
                    and "zdrone view:" in (d / "view.log").read_text(errors="replace"):
                page = browser.open(f"http://127.0.0.1:{port}", STREAM_PROBE)
            else:
                status.say(f"view attack: the flight starting, {time.monotonic() - t_start:.0f} s")
                time.sleep(0.2)
        view_pid = demo.children["view"].proc.pid
        deadline = time.monotonic() + 120.0
        while page.evaluate(READ_D1)["d1"] != "live":
            flying()
            if time.monotonic() > deadline:
                raise RuntimeError(f"the page never showed d1 live; see {d}")
            status.say(f"view attack: waiting for the page to show d1 live, {time.monotonic() - t_start:.0f} s")
            time.sleep(0.2)
        out["control"] = _window(page, view_pid, window, "control", status)
        flying()
        py = [sys.executable, "-m", "zdrone.bench.viewload"]
        cmds = {"clients": py + ["clients", "--port", str(port), "--n", str(clients), "--stats", str(files["clients"])],
                "forger": py + ["forge", "--fleet", str(d / "fleet"), "--router", demo.router, "--rate", f"{rate:g}",
                                "--stats", str(files["forger"])]}
        for name, cmd in cmds.items():
            log = open(d / f"{name}.log", "w")
            logs.append(log)
            load[name] = spawn(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        deadline = time.monotonic() + LOAD_RAMP_S
        while True:
            flying()
            c, f = _load_at(files["clients"]), _load_at(files["forger"])
            if c is not None and c["first_round"] >= clients and f is not None and f["sent"] > 0:
                break
            for name, p in load.items():
                if p.poll() is not None:
                    raise RuntimeError(f"the {name} ended ({p.returncode}); see {d / f'{name}.log'}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"the load did not arrive within {LOAD_RAMP_S:g} s: clients {c}, forger {f}")
            status.say(f"view attack: the load arriving: clients {c and c['first_round']}/{clients}, "
                       f"forger sent {f and f['sent']}")
            time.sleep(0.5)
        time.sleep(LOAD_SETTLE_S)
        out["load"] = _window(page, view_pid, window, "under attack", status, files["clients"], files["forger"])
        flying()
    except (RuntimeError, PlaywrightError) as exc:
        out["error"] = str(exc)
    finally:
        stop_in_order(load, ("clients", "forger"), grace=10.0)
        for f in logs:
            f.close()
        if page is not None:
            try:
                page.close()
            except PlaywrightError:
                pass
        status.say("view attack: the flight ending")
        flight.join()
    try:
        result = flight.result()
        out["flight_ok"] = not result.get("timed_out") and not result.get("failsafe")
    except Exception as exc:  # noqa: BLE001 - the figures say why
        out["flight_ok"] = False
        out.setdefault("error", f"the flight: {exc}")
    out["wall_s"] = round(time.monotonic() - t_start, 1)
    if "load" in out:
        out["within_targets"] = all(v is True for v in out["load"]["targets_met"].values())
    return out


def _yes(v: bool | None) -> str:
    return "-" if v is None else "yes" if v else "NO"


def attack_rows(a: dict[str, Any]) -> list[list[Any]]:
    """The attack part's main table: the control window, the window under attack, the targets."""
    rows = []
    for name, key in (("control (no load)", "control"), ("under attack", "load")):
        w = a.get(key)
        if w is None:
            continue
        g, met = w["gap"], w["targets_met"]
        rows.append([name, w["rss_max_mb"], w["cpu_pct"], g["max_s"], g["p95_s"], w["pictures_per_s"],
                     f"{w['samples'] - w['page_not_live']}/{w['samples']}", f"{w['samples'] - w['d1_not_live']}/{w['samples']}",
                     " ".join(f"{k}:{_yes(met[k])}" for k in ("rss", "cpu", "gap"))])
    rows.append(["target", f"<= {TARGET_RSS_MB:g}", f"<= {TARGET_CPU_PCT:g}", f"<= {TARGET_GAP_S:g}", "", "", "all", "all", ""])
    return rows


def render_attack(a: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    if "control" not in a:
        print(f"attack: {a.get('error')}")
        return
    print_table(f"The view under attack: {a['clients']} stream clients + {a['forged_rate']:g} forged parts/s from X "
                f"({a['window_s']:g} s windows, the same flight)",
                ["window", "view RSS max MB", "view CPU % of a core", "page gap max s", "page gap p95 s", "pictures /s",
                 "page live", "d1 live", "met"],
                attack_rows(a),
                caption="gap: between consecutive pictures at a real page (Chromium) opened before the load; page "
                        "live: samples (1/s) with the page's stream live; d1 live: samples showing d1 not stale"
                        + (f"; error: {a['error']}" if a.get("error") else ""))
    w = a.get("load")
    if w is None:
        return
    c, f, v = w.get("clients") or {}, w.get("forger") or {}, w["view"]
    held, streaming = c.get("held_open") or {}, c.get("streaming") or {}
    span = v.get("span_s") or w["window_s"]
    drops = sum(v["drops"].values())
    print_table("The load over its window",
                ["clients held open", "served (streaming)", "attempts /s", "refused 503 /s", "cut /s", "forged sent /s",
                 "X parts opened /s", "view drops /s"],
                [[f"{held.get('min')}..{held.get('max')}", f"{streaming.get('min')}..{streaming.get('max')}",
                  c.get("attempts_per_s"), c.get("refused_503_per_s"), c.get("cut_before_answer_per_s"),
                  f.get("sent_per_s"), f.get("reached_per_s"), round(drops / span, 1) if span else None]],
                caption="held open: the clients' connections open (min..max of the 1/s samples); served: of which a "
                        "200 stream; refused 503: over the stream cap; cut: connections the server closed unanswered "
                        "(over its connection cap); a refused or cut client tries again after about a second. X parts "
                        "opened: the view's unknown_drone count (each forged part names d99), what the router let "
                        "through; view drops: " + (", ".join(f"{k} {n}" for k, n in v["drops"].items()) or "none"))
