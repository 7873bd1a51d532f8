"""``zdrone bench view``'s flood part (``--only flood``): the real ``zdrone view`` (the fleet's viewer on
a router of its own, no flight), exposed with a token, under a stranger's half-open connections from one
address (``FLOOD_SOURCE``, 127.0.0.2; the operator is 127.0.0.1), the flood a process of its own
(``python -m zdrone.bench.viewload halfopen``), each of its connections reopened as soon as the server
cuts it (at most ``--flood-rate`` connects a second in all). Two modes, each on a view of its own:

- ``heads``: plain HTTP, ``HEADS`` connections each with half a request head and no token;
- ``handshakes``: TLS, ``HANDSHAKES`` connections, every other one with half a ClientHello, the others
  sending nothing.

Per mode a control run (no flood), then a window under the flood: the operator (this process, with the
token) loads the page and opens its stream in turn, each on a new connection (the token in the address
once, then its cookie, as the page does; a stream counts once its first picture came), as many times as
the window allows; the view's RSS (start, max, end), open files and CPU; the flood's connects and cuts a
second. Targets: every page and stream served, RSS under ``TARGET_RSS_MB``. Found: 256 half heads
locked the operator out (page 0/60, stream 0/60); 1 500 half-open handshakes grew the view 66 -> 519 MB.
"""

from __future__ import annotations

import http.client
import os
import socket
import ssl
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

from zdrone.bench.revoke import percentile
from zdrone.bench.table import ProgressLine

#: The name the operator's browser reaches the view by (its Host header; ``--name``).
VIEW_NAME = "view.test"
#: The flood's source: another host, as the server sees it.
FLOOD_SOURCE = "127.0.0.2"
#: Each mode: TLS or not, what each connection sends (``viewload halfopen --send``), how many.
HEADS = 300
HANDSHAKES = 1500
MODES: dict[str, tuple[bool, str, int]] = {"heads": (False, "head", HEADS), "handshakes": (True, "mixed", HANDSHAKES)}
#: The flood's connects a second at most (the attack found: about 50); 0: as fast as it can.
FLOOD_RATE = 2000.0
#: The operator's page loads and stream opens in the control run.
CONTROL_N = 20
#: Seconds under the flood.
FLOOD_WINDOW_S = 30.0
QUICK_FLOOD_WINDOW_S = 8.0
#: Seconds between the operator's requests in the window (a page load or a stream opened: 5 a second).
OPERATOR_PACE_S = 0.2
#: Seconds the operator gives one request (its connect, TLS handshake and answer).
REQUEST_TIMEOUT_S = 10.0
TARGET_RSS_MB = 150.0


def view_secrets(d: Path, tls: bool) -> tuple[str, list[str], "ssl.SSLContext | None"]:
    """A fresh token in ``d``'s token file (0600) and, with ``tls``, a certificate: the token, the view's
    extra arguments (``--tls-cert``, ``--tls-key``) and the operator's TLS context that trusts it."""
    token = os.urandom(24).hex()
    (d / "token").write_text(token + "\n")
    (d / "token").chmod(0o600)
    if not tls:
        return token, [], None
    cert, key, ca = tls_files(d)
    return token, ["--tls-cert", cert, "--tls-key", key], ssl.create_default_context(cafile=ca)


def tls_files(d: Path, hosts: tuple[str, ...] = ("127.0.0.1", VIEW_NAME)) -> tuple[str, str, str]:
    """A CA, and a server certificate from it for ``hosts``: (cert, key, ca) PEM files in ``d``."""
    from cryptography.hazmat.primitives import serialization

    from zdrone.fleet.tls import issue, make_ca

    ca, ca_key = make_ca()
    cert, key = issue(ca, ca_key, "view", hosts)
    (d / "ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    (d / "cert.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (d / "key.pem").write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                                  serialization.NoEncryption()))
    (d / "key.pem").chmod(0o600)
    return str(d / "cert.pem"), str(d / "key.pem"), str(d / "ca.pem")


def _request(port: int, ctx: ssl.SSLContext | None, path: str, headers: dict[str, str]) -> tuple[Any, Any]:
    cls: Any = http.client.HTTPSConnection if ctx is not None else http.client.HTTPConnection
    kw = {"context": ctx} if ctx is not None else {}
    conn = cls("127.0.0.1", port, timeout=REQUEST_TIMEOUT_S, **kw)
    conn.request("GET", path, headers={"Host": f"{VIEW_NAME}:{port}", **headers})
    return conn, conn.getresponse()


def operator(port: int, token: str, ctx: ssl.SSLContext | None, n: int | None = None, until: float | None = None,
             after: Callable[[], None] = lambda: None, pace: float = 0.0) -> dict[str, Any]:
    """The operator's page loaded (``?token=``, as from the link given) and its stream opened (with the
    cookie the page got, until its first picture) in turn, each on a connection of its own: ``n`` of
    each, or as many as fit before ``until`` (monotonic), one every ``pace`` seconds at most; ``after()``
    after each request. How many were served of how many, the time each took (p50, max), the first errors."""
    from zdrone.view.server import COOKIE

    out: dict[str, Any] = {"pages": 0, "page_tries": 0, "streams": 0, "stream_tries": 0, "errors": []}
    took: list[float] = []
    i, start = 0, time.monotonic()
    while (n is not None and i < 2 * n) or (n is None and until is not None and time.monotonic() < until):
        page = i % 2 == 0
        wait = start + i * pace - time.monotonic()
        if wait > 0:
            time.sleep(wait)  # the operator's pace (a bench's own clock, not a test's wait)
        i += 1
        t0 = time.monotonic()
        conn = None
        out["page_tries" if page else "stream_tries"] += 1
        try:
            if page:
                conn, r = _request(port, ctx, f"/?token={token}", {})
                body = r.read()
                if r.status == 200 and b"view.js" in body:
                    out["pages"] += 1
                else:
                    out["errors"].append(f"page {r.status}")
            else:
                conn, r = _request(port, ctx, "/api/stream", {"Cookie": f"{COOKIE}={token}", "Accept": "text/event-stream"})
                got = b""
                while r.status == 200 and b"event: picture" not in got and len(got) < 1 << 20:
                    chunk = r.read1(65536)
                    if not chunk:
                        break
                    got += chunk
                if r.status == 200 and b"event: init" in got and b"event: picture" in got:
                    out["streams"] += 1
                else:
                    out["errors"].append(f"stream {r.status} {got[:60]!r}")
        except (OSError, http.client.HTTPException) as exc:
            out["errors"].append(f"{'page' if page else 'stream'}: {type(exc).__name__}: {exc}")
        finally:
            if conn is not None:
                conn.close()
        took.append(time.monotonic() - t0)
        after()
    ordered = sorted(took)
    out["p50_s"] = round(percentile(ordered, 50), 3) if ordered else None
    out["max_s"] = round(ordered[-1], 3) if ordered else None
    out["errors"] = out["errors"][:5]
    return out


def served(op: dict[str, Any]) -> bool:
    """Every page and stream the operator asked for was served (and it asked)."""
    return op["page_tries"] > 0 and op["pages"] == op["page_tries"] and op["streams"] == op["stream_tries"]


def _mode(base: Path, fleet: Path, router: str, mode: str, window: float, rate: float,
          status: ProgressLine) -> dict[str, Any]:
    from zdrone.bench.scale import _wait_line
    from zdrone.bench.soak import sample
    from zdrone.bench.stallwatch import cpu_seconds
    from zdrone.bench.viewload import last_stats
    from zdrone.sil.ports import free_port
    from zdrone.sil.procs import spawn, stop_in_order

    tls, send, n = MODES[mode]
    d = base / mode
    d.mkdir(parents=True, exist_ok=True)
    token, extra, ctx = view_secrets(d, tls)
    port = free_port(socket.SOCK_STREAM)
    out: dict[str, Any] = {"mode": mode, "tls": tls, "send": send, "connections": n, "rate": rate, "source": FLOOD_SOURCE,
                           "window_s": window, "runs": str(d)}
    cmds = {"view": [sys.executable, "-m", "zdrone", "view", "--fleet", str(fleet), "--router", router, "--port",
                     str(port), "--listen", "127.0.0.1", "--name", VIEW_NAME, "--token-file", str(d / "token"), *extra],
            "flood": [sys.executable, "-m", "zdrone.bench.viewload", "halfopen", "--port", str(port), "--n", str(n),
                      "--source", FLOOD_SOURCE, "--send", send, "--rate", f"{rate:g}", "--host-header",
                      f"{VIEW_NAME}:{port}", "--stats", str(d / "flood.jsonl"), "--duration", str(window + 120.0)]}
    logs = {name: open(d / f"{name}.log", "w") for name in cmds}
    procs: dict[str, subprocess.Popen] = {}
    try:
        status.say(f"view flood: {mode}: the view starting")
        procs["view"] = spawn(cmds["view"], stdout=logs["view"], stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        if _wait_line(d / "view.log", "zdrone view:", 30, procs["view"]) is None:
            raise RuntimeError(f"the view did not start; see {d / 'view.log'}")
        pid = procs["view"].pid
        out["control"] = operator(port, token, ctx, n=CONTROL_N)
        status.say(f"view flood: {mode}: {n} connections from {FLOOD_SOURCE} arriving")
        procs["flood"] = spawn(cmds["flood"], stdout=logs["flood"], stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        if _wait_line(d / "flood.log", "viewload halfopen: ready", 30, procs["flood"]) is None:
            raise RuntimeError(f"the flood did not open its {n} connections; see {d / 'flood.log'}")
        first = sample(pid)
        rss = [first["rss_mb"]] if first else []
        fds = [first["fds"]] if first else []
        t0, cpu0, wall0 = time.monotonic(), cpu_seconds(pid), time.time()
        last_say = [0.0]

        def look() -> None:
            m = sample(pid)
            if m is not None:
                rss.append(m["rss_mb"])
                fds.append(m["fds"])
            now = time.monotonic()
            if now - last_say[0] >= 1.0:
                last_say[0] = now
                status.say(f"view flood: {mode} {now - t0:.0f}/{window:g} s, view RSS {rss[-1] if rss else 0:.0f} MB, "
                           f"{fds[-1] if fds else 0} files")

        out["flood"] = operator(port, token, ctx, until=t0 + window, after=look, pace=OPERATOR_PACE_S)
        span, cpu1, wall1 = time.monotonic() - t0, cpu_seconds(pid), time.time()
        look()
        if procs["flood"].poll() is not None or procs["view"].poll() is not None:
            raise RuntimeError(f"the flood or the view ended during the window; see {d}")
        out["view"] = {"rss_start_mb": round(rss[0], 1) if rss else None, "rss_max_mb": round(max(rss), 1) if rss else None,
                       "rss_end_mb": round(rss[-1], 1) if rss else None, "fds_max": max(fds) if fds else None,
                       "cpu_pct": round(100.0 * (cpu1 - cpu0) / span, 1) if cpu0 is not None and cpu1 is not None else None}
        out["attacker"] = flood_rates(d / "flood.jsonl", wall0, wall1)
        out["met"] = {"operator": served(out["flood"]),
                      "rss": out["view"]["rss_max_mb"] is not None and out["view"]["rss_max_mb"] < TARGET_RSS_MB}
    except RuntimeError as exc:
        out["error"] = str(exc)
    finally:
        stop_in_order(procs, ("flood", "view"), grace=10.0)
        for f in logs.values():
            f.close()
    return out


def flood_rates(path: Path, t0: float, t1: float) -> dict[str, Any] | None:
    """The flood's connects and cuts a second over its counters' lines stamped in [``t0``, ``t1``] (wall
    clock; None: fewer than two), and its counters at the last of them."""
    from zdrone.bench.viewload import stats_lines

    inside = [r for r in stats_lines(path) if t0 <= r["t"] <= t1]
    if len(inside) < 2:
        return None
    a, b = inside[0], inside[-1]
    dt = max(1e-6, b["t"] - a["t"])
    return {"connects_per_s": round((b["attempts"] - a["attempts"]) / dt, 1),
            "cut_per_s": round((b["cut"] - a["cut"]) / dt, 1), "held_max": b["held_max"],
            "connect_failed": b["connect_failed"], "span_s": round(dt, 1)}


def run_flood(base: Path, quick: bool, rate: float | None, status: ProgressLine) -> dict[str, Any]:
    """Each mode on a view of its own, over one fleet and its router."""
    from zdrone.bench.scale import _wait_line
    from zdrone.fleet.files import init_fleet
    from zdrone.sil.ports import free_port
    from zdrone.sil.procs import spawn, stop_in_order

    d = base / "flood"
    d.mkdir(parents=True, exist_ok=True)
    rate = FLOOD_RATE if rate is None else rate
    window = QUICK_FLOOD_WINDOW_S if quick else FLOOD_WINDOW_S
    init_fleet(d / "fleet")
    router = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    out: dict[str, Any] = {"rate": rate, "window_s": window, "source": FLOOD_SOURCE, "target_rss_mb": TARGET_RSS_MB,
                           "modes": {}}
    log = open(d / "router.log", "w")
    procs = {"router": spawn([sys.executable, "-m", "zdrone", "router", "-c", str(d / "fleet/router/router.json5"),
                              "--listen", router], stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)}
    try:
        if _wait_line(d / "router.log", "listening", 30, procs["router"]) is None:
            out["error"] = f"the router did not start; see {d / 'router.log'}"
            return out
        for mode in MODES:
            out["modes"][mode] = _mode(d, d / "fleet", router, mode, window, rate, status)
    finally:
        stop_in_order(procs, ("router",), grace=10.0)
        log.close()
    errors = [f"{m}: {r['error']}" for m, r in out["modes"].items() if "error" in r]
    if errors:
        out["error"] = "; ".join(errors)
    return out


def _yes(v: bool | None) -> str:
    return "-" if v is None else "yes" if v else "NO"


def flood_rows(f: dict[str, Any]) -> list[list[Any]]:
    """A control row and a flood row per mode."""
    rows: list[list[Any]] = []
    for mode, r in f.get("modes", {}).items():
        if "control" in r:
            c = r["control"]
            rows.append([f"{mode}: none", "-", f"{c['pages']}/{c['page_tries']}", f"{c['streams']}/{c['stream_tries']}",
                         c["max_s"], "", "", "", "", ""])
        if "flood" in r and "view" in r:
            o, v, a, met = r["flood"], r["view"], r.get("attacker") or {}, r["met"]
            cps = a.get("connects_per_s")
            rows.append([f"{mode}: {r['connections']}", None if cps is None else round(cps), f"{o['pages']}/{o['page_tries']}",
                         f"{o['streams']}/{o['stream_tries']}", o["max_s"], v["rss_max_mb"], v["rss_end_mb"],
                         v["fds_max"], v["cpu_pct"], f"{_yes(met['operator'])} {_yes(met['rss'])}"])
    return rows


def render_flood(f: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    if not f.get("modes"):
        print(f"flood: {f.get('error')}")
        return
    start = [str(r["view"]["rss_start_mb"]) for r in f["modes"].values() if "view" in r]
    print_table(f"The view under half-open connections from one address ({f['source']}; {f['window_s']:g} s "
                f"windows, at most {f['rate']:g} connects/s)",
                ["flood", "connects /s", "page ok", "stream ok", "slowest s", "RSS max MB", "RSS end MB",
                 "files max", "CPU %", "met"],
                flood_rows(f),
                caption="heads: plain HTTP, half a request head each, no token; handshakes: TLS, half a ClientHello "
                        "on every other connection, nothing on the others; each reopened as soon as cut (none: the "
                        "control run before it). page / stream ok: the operator's (127.0.0.1) requests served, each "
                        "on a new connection, a stream once its first picture came; slowest: the operator's slowest "
                        f"request. RSS, files, CPU: the view's (RSS at the flood's start {' / '.join(start)} MB). "
                        f"met: every request served, RSS < {f['target_rss_mb']:g} MB"
                        + (f"; error: {f['error']}" if f.get("error") else ""))
