"""``zdrone report``: one self-contained HTML page (PNG plots inlined) from a flight's event log.

Input: a run folder (as ``zdrone demo`` writes it) or its ``drone.jsonl``. The fleet (coverage
circles) is read from ``fleet/fleet.json5`` next to the log when present, else the reference fleet.
Output: ``report.html`` and ``track.png`` (the ground track alone, for a README) in the run folder.
The page shows each node's authority record (``zdrone.core.audit``): verified, or its first bad entry.

``verify_audit`` is ``zdrone audit verify``: every ``*.audit.jsonl`` of a run folder (or the files
given) checked offline against the fleet's public signing keys over time, and against every
countersignature chained in any of them; for a run folder, a record missing is named too.
"""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path
from typing import Any, Mapping

import msgspec

from zdrone.core.audit import AuditWitness, ChainReport, CheckedChain, PublicKeys, Verified, check_chain, decode_line
from zdrone.core.fleet import ConfigError, Fleet, parse_fleet
from zdrone.core.geometry import GeoPoint, ne_of
from zdrone.core.records import (AnyRecord, Closed, Drop, DroneState, DroneStatus, DroneStop, Failsafe, HandoverComplete,
                           LinkStateChanged, Start, Subscribe, Unsubscribe, fields_of, only, record_type)
from zdrone.core.reference import COVERAGE_RADIUS_M, GS_A, GS_B, HOME
from zdrone.net.eventlog import read_records

COLOURS = {"A": "#1f77b4", "B": "#ff7f0e", None: "#999999"}
#: records left out of the events table (the status is in the plots)
HIDDEN = (DroneState, Subscribe, Unsubscribe, LinkStateChanged, Drop, Start, Closed)


def _resolve(log: str | Path) -> tuple[Path, Path]:
    p = Path(log)
    if p.is_dir():
        p = p / "drone.jsonl"
    if not p.is_file():
        raise ConfigError(f"{p}: no such event log (give a run folder or its drone.jsonl)")
    return p, p.parent


def _coverage(run: Path) -> dict[str, tuple[GeoPoint, float]]:
    f = run / "fleet" / "fleet.json5"
    if f.is_file():
        try:
            fleet = parse_fleet(f.read_text(), str(f))
            return {n: (GeoPoint(v.coverage.lat, v.coverage.lon), v.coverage.radius_m)
                    for n, v in fleet.nodes.items() if v.role == "gs" and v.coverage and n in ("A", "B")}
        except ConfigError:
            pass
    return {"A": (GS_A, COVERAGE_RADIUS_M), "B": (GS_B, COVERAGE_RADIUS_M)}


def audit_files(targets: list[str | Path]) -> list[Path]:
    """The authority records named: files as given, a folder's ``*.audit.jsonl``."""
    files: list[Path] = []
    for t in targets:
        p = Path(t)
        if p.is_dir():
            files += sorted(p.glob("*.audit.jsonl"))
        elif p.is_file():
            files.append(p)
        else:
            raise ConfigError(f"{p}: no such file or folder")
    if not files:
        raise ConfigError(f"{', '.join(map(str, targets))}: no authority record (*.audit.jsonl)")
    return files


def run_fleet_dir(targets: list[str | Path], fleet_dir: str | Path | None) -> Path:
    """The fleet folder to verify against: ``--fleet``, else ``fleet/`` of the run folder given."""
    if fleet_dir is None:
        found = [Path(t) / "fleet" for t in targets if (Path(t) / "fleet" / "fleet.json5").is_file()]
        if not found:
            raise ConfigError("no fleet to check the signatures against: give --fleet DIR (its public fleet.json5)")
        fleet_dir = found[0]
    return Path(fleet_dir)


def run_fleet(targets: list[str | Path], fleet_dir: str | Path | None) -> Fleet:
    """The fleet to verify against: ``--fleet``, else ``fleet/`` of the run folder given."""
    from zdrone.fleet.files import load_fleet

    return load_fleet(run_fleet_dir(targets, fleet_dir))


#: What every free witness line holds (its tag).
_WITNESS_TAG = b'"audit":"witness"'


def _record_owner(lines: list[bytes]) -> str | None:
    """The node whose record these lines are: the one its first entry or checkpoint names."""
    for raw in lines:
        try:
            line = decode_line(raw)
        except (msgspec.DecodeError, msgspec.ValidationError):
            continue  # check_chain names it, with its line number
        if not isinstance(line, AuditWitness):
            return line.node
    return None


def _log_node(log: Path) -> str | None:
    """The node an event log is of: the one its first line names (None if it names none)."""
    try:
        with open(log, "rb") as fh:
            first = fh.readline(1 << 16)
        node = json.loads(first).get("node")
    except (OSError, ValueError, AttributeError):
        return None
    return node if isinstance(node, str) else None


def _empty_record_owner(f: Path) -> str:
    """The node of a record with no line of its own: the one its event log beside it names
    (``drone.audit.jsonl`` -> ``drone.jsonl``), else the file's name."""
    stem = f.name[:-len(".audit.jsonl")] if f.name.endswith(".audit.jsonl") else f.stem
    return _log_node(f.with_name(f"{stem}.jsonl")) or stem


def run_expected(targets: list[str | Path], fleet: Fleet) -> dict[str, str] | None:
    """The records the folders given must hold together (node -> why), None if no target is a
    folder (files only: those are checked): every drone of the fleet not revoked that has a signing
    key, and every drone or GS whose event log is in a folder. The same whether the fleet is the
    folder's own ``fleet/`` or ``--fleet``."""
    runs = [Path(t) for t in targets if Path(t).is_dir()]
    if not runs:
        return None

    def keeps(n: str | None) -> bool:
        v = fleet.nodes.get(n or "")
        return v is not None and v.role in ("drone", "gs") and v.signing_public_bytes is not None

    out = {d: f"the fleet names drone {d}" for d in fleet.drones() if not fleet.is_revoked(d) and keeps(d)}
    for run in runs:
        for log in sorted(run.glob("*.jsonl")):
            if not log.name.endswith(".audit.jsonl") and keeps(node := _log_node(log)):
                out.setdefault(str(node), f"its event log {log.name} is in the run")
    return out


def verify_audit(files: list[Path], fleet: Fleet, key_history: Mapping[str, PublicKeys] | None = None,
                 expect: dict[str, str] | None = None, where: Path | None = None) -> list[tuple[Path, ChainReport]]:
    """Each file's record verified (its node: the one its entries name) against its keys over time
    (``key_history``: ``zdrone.fleet.revisions.signing_key_epochs``; else the fleet's keys in force),
    then against every countersignature chained in any of the records (a node's decisions after
    the last entry countersigned counted). With ``expect`` (node -> why: ``run_expected``) the records
    are meant to be the whole run: a node expected, or countersigned by a record given, whose record
    is not among them is reported ``record_missing`` (its path: ``where``)."""
    contents: dict[Path, list[bytes]] = {f: [ln for ln in f.read_bytes().splitlines() if ln.strip()] for f in files}
    keys: dict[str, PublicKeys] = {n: fleet.nodes[n].signing_public_bytes for n in fleet.nodes}
    keys.update(key_history or {})
    drones = set(fleet.drones())
    owners = {f: _record_owner(lines) for f, lines in contents.items()}
    seen: Verified = set()  # a drone's checkpoint checked once: in its record (first), then in its witnesses'
    chains: dict[Path, tuple[str, CheckedChain]] = {}
    for f in sorted(contents, key=lambda f: owners[f] not in drones):
        node, lines = owners[f], contents[f]
        free = sum(1 for raw in lines if _WITNESS_TAG in raw) if node is None else 0
        if node is None and free == len(lines):  # no line of its own: empty, or free witness lines (an older format)
            chains[f] = _empty_record_owner(f), CheckedChain(_empty_record_owner(f), [], 0, -1, [], free)
        else:  # (no owner: no line decodes; check_chain names the first)
            node = node or _empty_record_owner(f)
            chains[f] = node, check_chain(node, lines, keys.get(node), keys, seen)
    checked = [(f, *chains[f]) for f in contents]
    countersigned = [w for _, _, c in checked for w in c.countersigned]
    out: list[tuple[Path, ChainReport]] = []
    for f, node, c in checked:  # every node's decisions are countersigned: a drone's by its GSs, a GS's by its drones
        witnessed = node in fleet.nodes and fleet.nodes[node].role in ("drone", "gs")
        out.append((f, c.report(countersigned, witnessed=witnessed)))
    if expect is not None:
        present = {node for _, node, _ in checked}
        seen: dict[str, list[AuditWitness]] = {}
        for w in countersigned:
            seen.setdefault(w.node, []).append(w)
        for node in sorted((set(seen) | set(expect)) - present):
            ws = seen.get(node, [])
            top = max((w.seq for w in ws), default=-1)
            why = (f"{', '.join(sorted({w.witness for w in ws}))} countersigned its entries up to {top}" if ws
                   else expect[node])
            out.append((where or Path("."), ChainReport(node, 0, 0, -1, top, len(ws), f"record missing: {why}",
                                                        "record_missing", 0)))
    return out


def _audit_section(run: Path) -> str:
    """The flight report's view of the run's authority records."""
    files = sorted(run.glob("*.audit.jsonl"))
    if not files:
        return "<h2>Authority record</h2><p>none in this run</p>"
    from zdrone.fleet.revisions import signing_key_epochs

    try:
        fleet = run_fleet([run], None)
        results = verify_audit(files, fleet, signing_key_epochs(run_fleet_dir([run], None)),
                               expect=run_expected([run], fleet), where=run)
    except ConfigError as exc:
        return f"<h2>Authority record</h2><p>not verified: {html.escape(str(exc))}</p>"
    rows = "".join(f"<tr><td>{html.escape(f.name)}</td><td>{'verified' if r.ok else '<b>BAD</b>'}</td>"
                   f"<td>{html.escape(r.summary())}</td></tr>" for f, r in results)
    return f"<h2>Authority record</h2><table><tr><th>file</th><th>chain</th><th>detail</th></tr>{rows}</table>"


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    return buf.getvalue()


def _track_figure(status: list[DroneStatus], events: list[AnyRecord], cov: dict[str, tuple[GeoPoint, float]]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    fig, ax = plt.subplots(figsize=(8, 5.2))
    for name, (centre, r) in cov.items():
        n, e = ne_of(HOME, centre)
        ax.add_patch(Circle((e, n), r, color=COLOURS.get(name, "#777"), alpha=0.12))
        ax.add_patch(Circle((e, n), r, fill=False, ec=COLOURS.get(name, "#777"), lw=1.2))
        ax.annotate(f"GS {name}", (e, n), ha="center", va="center", fontsize=10, color=COLOURS.get(name, "#777"))
    if len(cov) >= 2:  # shade the overlap (hand-over region)
        import numpy as np

        (c1, r1), (c2, r2) = list(cov.values())[:2]
        n1, e1 = ne_of(HOME, c1)
        n2, e2 = ne_of(HOME, c2)
        xs = np.linspace(min(e1 - r1, e2 - r2), max(e1 + r1, e2 + r2), 300)
        ys = np.linspace(min(n1 - r1, n2 - r2), max(n1 + r1, n2 + r2), 300)
        X, Y = np.meshgrid(xs, ys)
        inside = ((X - e1) ** 2 + (Y - n1) ** 2 <= r1 ** 2) & ((X - e2) ** 2 + (Y - n2) ** 2 <= r2 ** 2)
        ax.contourf(X, Y, inside.astype(float), levels=[0.5, 1.5], colors=["#2ca02c"], alpha=0.12)
        ax.plot([], [], color="#2ca02c", alpha=0.4, lw=6, label="hand-over region")
    pts = [(s.t, s.position, s.owner) for s in status if s.position]
    for (t1, p1, o1), (_, p2, _) in zip(pts, pts[1:]):
        n1, e1 = ne_of(HOME, GeoPoint(p1[0], p1[1]))
        n2, e2 = ne_of(HOME, GeoPoint(p2[0], p2[1]))
        ax.plot([e1, e2], [n1, n2], color=COLOURS.get(o1, "#999"), lw=2.5)
    for owner in ("A", "B"):
        ax.plot([], [], color=COLOURS[owner], lw=2.5, label=f"authority {owner}")
    for ev in events:
        if isinstance(ev, HandoverComplete) and ev.position:
            n, e = ne_of(HOME, GeoPoint(ev.position[0], ev.position[1]))
            ax.plot(e, n + (6 if ev.to == "B" else -6), marker="*", ms=15, color="#d62728" if ev.kind == "emergency" else "black")
            ax.annotate(f"{ev.from_}→{ev.to}", (e, n), textcoords="offset points",
                        xytext=(0, 12 if ev.to == "B" else -18), ha="center", fontsize=9)
        if isinstance(ev, Failsafe) and ev.position:
            n, e = ne_of(HOME, GeoPoint(ev.position[0], ev.position[1]))
            ax.plot(e, n, marker="X", ms=14, color="red")
            ax.annotate(f"failsafe {ev.action}", (e, n), textcoords="offset points", xytext=(0, 12), ha="center",
                        color="red", fontsize=9)
    ax.plot([], [], marker="*", ls="", color="black", ms=12, label="hand-over")
    ax.set_aspect("equal")
    ax.set_xlabel("east of take-off (m)")
    ax.set_ylabel("north (m)")
    ax.set_title("Ground track, coloured by the GS holding authority")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def _tbm_figure(status: list[DroneStatus], t0: float) -> Any:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3))
    links = sorted({gs for s in status for gs in s.links})
    for gs in links:
        xs = [s.t - t0 for s in status if gs in s.links]
        ys = [min(s.links[gs].since_last, 6.0) for s in status if gs in s.links]
        ax.plot(xs, ys, label=f"link {gs}", color=COLOURS.get(gs, "#777"))
    ax.axhline(1.0, ls="--", color="#bcbd22", label="DEGRADED (1 s)")
    ax.axhline(3.0, ls="--", color="#d62728", label="LOST (3 s)")
    ax.set_ylabel("time since last authentic\nframe (s, clipped at 6)")
    ax.set_xlabel("time (s)")
    ax.set_ylim(0, 6.2)
    ax.set_title("Time between messages per link")
    ax.legend(fontsize=8, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.28), frameon=False)
    ax.grid(alpha=0.3)
    return fig


def _alt_figure(status: list[DroneStatus], events: list[AnyRecord], t0: float) -> Any:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 2.6))
    xs = [s.t - t0 for s in status if s.position]
    ys = [s.position[2] for s in status if s.position]
    ax.plot(xs, ys, color="#333")
    for ev in events:
        if isinstance(ev, (HandoverComplete, Failsafe)):
            ax.axvline(ev.t - t0, color="red" if isinstance(ev, Failsafe) else "#555", ls=":")
    ax.set_ylabel("altitude (m)")
    ax.set_xlabel("time (s)")
    ax.set_title("Altitude (dotted: hand-overs, red: failsafe)")
    ax.grid(alpha=0.3)
    return fig


def _detail(ev: AnyRecord) -> str:
    return ", ".join(f"{k}={v}" for k, v in fields_of(ev).items())


def write_report(log: str | Path) -> Path:
    """Write ``report.html`` and ``track.png`` next to the log; return the HTML path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path, run = _resolve(log)
    events = read_records(path).records
    status = only(events, DroneStatus)
    if not status:
        raise ConfigError(f"{path}: no status events: not a drone event log")
    t0 = events[0].t
    cov = _coverage(run)
    figs = {"track": _track_figure(status, events, cov), "tbm": _tbm_figure(status, t0), "alt": _alt_figure(status, events, t0)}
    pngs = {k: _png(f) for k, f in figs.items()}
    for f in figs.values():
        plt.close(f)
    (run / "track.png").write_bytes(pngs["track"])
    stops = only(events, DroneStop)
    final: DroneState = stops[-1] if stops else status[-1]
    drops: dict[str, int] = {}
    for gs, ln in final.links.items():
        for reason, n in ln.dropped.items():
            drops[f"security: {reason} (link {gs})"] = n
    for reason, n in final.ha_drops.items():
        drops[f"authority: {reason}"] = n
    for reason, n in final.rejects.items():
        drops[f"authority reject: {reason}"] = n
    for k, n in final.out_of_coverage.items():
        drops[f"testbed coverage: {k}"] = n
    for k, n in final.counters.items():
        drops[f"node: {k}"] = n
    summary_file = run / "summary.json"
    summary = json.loads(summary_file.read_text()) if summary_file.is_file() else {}
    rows = "".join(f"<tr><td>{e.t - t0:8.2f}</td><td>{html.escape(record_type(e))}</td><td>{html.escape(_detail(e))}</td></tr>"
                   for e in events if not isinstance(e, HIDDEN))
    drop_rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{n}</td></tr>" for k, n in sorted(drops.items())) or \
        "<tr><td colspan=2>none</td></tr>"
    img = {k: base64.b64encode(v).decode() for k, v in pngs.items()}
    head = ""
    if summary:
        head = (f"<p><b>{html.escape(summary.get('scenario', ''))}</b>: {'OK' if summary.get('ok') else 'FAILED'} in "
                f"{summary.get('wall_time_s')} s (speed-up {summary.get('speedup')}); hand-overs "
                f"{', '.join(h['from'] + '→' + h['to'] for h in summary.get('handovers', [])) or 'none'}; authority gap "
                f"{summary.get('authority_gap_ms')} ms; commands lost {summary.get('commands', {}).get('lost')}.</p>")
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>zdrone flight report</title>
<style>body{{font-family:sans-serif;max-width:960px;margin:2em auto}}table{{border-collapse:collapse;font-size:13px}}
td,th{{border:1px solid #ccc;padding:2px 8px;text-align:left}}img{{max-width:100%}}</style></head><body>
<h1>zdrone flight report</h1><p>{html.escape(str(path))}</p>{head}
<img alt="ground track" src="data:image/png;base64,{img['track']}">
<img alt="time between messages" src="data:image/png;base64,{img['tbm']}">
<img alt="altitude" src="data:image/png;base64,{img['alt']}">
{_audit_section(run)}
<h2>Drops and refusals by reason</h2><table><tr><th>reason</th><th>count</th></tr>{drop_rows}</table>
<h2>Events</h2><table><tr><th>t (s)</th><th>event</th><th>detail</th></tr>{rows}</table></body></html>"""
    out = run / "report.html"
    out.write_text(page)
    return out


