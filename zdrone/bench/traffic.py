"""``zdrone bench traffic [--autopilot px4|ardupilot]``: the paper's Table 1, measured on our own flights.

Three complete stacks (router, simulator, drone, GS A, GS B) fly the reference mission at the same
time, in real time, against the same autopilot personality of the simulator, differing only in the
security layer:

* ``plain``: MAVLink over Zenoh with no security layer (the same nodes, envelope disabled);
* ``zdrone``: our envelope (ChaCha20-Poly1305, 24 bytes), liveness from the MAVLink HEARTBEAT;
* ``paper``: the paper's layer: Fernet per frame plus a separate security heartbeat at 2 Hz.

All three send the GCS HEARTBEAT at 2 Hz (the drone's authority needs the liveness either way).
Packets and bytes are counted at the Zenoh layer by a tap in each router process (every sample on
``zdrone/**``; bytes are sample payload bytes, without Zenoh/TCP framing), per direction:
``up`` = GS -> drone, ``down`` = drone -> GS. A drone's publication is a bundle (``zdrone.core.bundle``)
holding, per GS, one envelope with the pass's messages (a batch, ``SecureLink.seal_batch``; the
paper's Fernet layer seals each frame on its own). What the envelopes carried is counted by their
receivers, per kind (``zdrone.core.linktraffic``: MAVLink frames, authority statuses and the
attestations and audit heads inside them, the other control messages, the cipher's and the batch's
own bytes; each node's last status record): the table lists the link's own messages per minute by
kind, and the bytes added are given per packet and per message. The tap also counts the fleet's
revision pushes (``zdrone-fleet/**``, every node hears them: the radio carries them too), listed
apart from the link's totals.

The downlink is the autopilot's own stream: PX4 streams its default set unasked (the paper's figures
were taken with PX4's real stream); ArduPilot streams nothing until asked, so its downlink is what
the drone node's vehicle link asks for (``zdrone.vehicle.tracker.DEFAULT_STREAMS``) plus HEARTBEAT,
STATUSTEXT and the protocol replies.
"""

from __future__ import annotations

import json
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from zdrone.sil.launcher import Demo, DemoOptions

VARIANTS = {"plain": ("plain", False), "zdrone": ("zdrone", False), "paper": ("fernet", True)}
PAPER = {"without": {"packets_per_min": 161, "mean_packet_bytes": 433.2},
         "with": {"packets_per_min": 196, "mean_packet_bytes": 435.3}}


#: The link's own messages (all but the MAVLink frames), in the order the kinds table lists them
OWN_KINDS = ("envelope", "batch", "status", "attestation", "audit_head", "key_grant", "key_grant_ack",
             "handover_request", "handover_release", "operator_request", "reject", "failsafe", "sm_heartbeat",
             "audit_offer")


#: Kinds that are part of a message or of its envelope, not messages of their own
NOT_MESSAGES = ("envelope", "batch", "attestation", "audit_head")


def _per_min(x: float, window: float) -> float:
    return round(x / window * 60, 1)


def _rates(tap: dict[str, Any], heard: dict[str, dict[str, list[int]]] | None = None) -> dict[str, Any]:
    """Rates from a router's tap and what the receivers opened, per direction (``heard``: ``up`` = the
    drone's, ``down`` = the GSs' together, kind -> [messages, bytes]; without it, the tap's envelopes
    stand for the messages)."""
    window = max(1e-6, (tap.get("last") or 0) - (tap.get("first") or 0))
    out: dict[str, Any] = {"window_s": round(window, 2)}
    tot_n = tot_b = tot_f = 0
    for direction in ("up", "down"):
        keys = [v for k, v in tap["keys"].items() if k.startswith("zdrone/") and f"/{direction}/" in k]
        n, b = sum(v[0] for v in keys), sum(v[1] for v in keys)
        envelopes = sum(v[2] if len(v) > 2 else v[0] for v in keys)
        kinds = (heard or {}).get(direction)
        f = sum(c[0] for k, c in kinds.items() if k not in NOT_MESSAGES) if kinds else envelopes
        out[direction] = {"packets_per_min": _per_min(n, window), "bytes_per_min": _per_min(b, window),
                          "mean_packet_bytes": round(b / n, 1) if n else 0.0,
                          "packets": n, "bytes": b, "envelopes": envelopes, "frames": f}
        if kinds:  # by kind; the rest of the tap's bytes: the bundles' framing and envelopes that did not open
            out[direction]["kinds"] = {k: {"per_min": _per_min(c[0], window), "bytes_per_min": _per_min(c[1], window),
                                           "messages": c[0], "bytes": c[1]} for k, c in sorted(kinds.items())}
            rest = b - sum(c[1] for c in kinds.values())
            out[direction]["kinds"]["bundle_and_unopened"] = {"per_min": None, "bytes_per_min": _per_min(rest, window),
                                                              "messages": None, "bytes": rest}
        tot_n, tot_b, tot_f = tot_n + n, tot_b + b, tot_f + f
    out["packets_per_min"] = _per_min(tot_n, window)
    out["bytes_per_min"] = _per_min(tot_b, window)
    out["mean_packet_bytes"] = round(tot_b / tot_n, 1) if tot_n else 0.0
    out["frames_per_min"] = _per_min(tot_f, window)  # the messages the envelopes carried (frames and controls)
    out["mean_frame_bytes"] = round(tot_b / tot_f, 1) if tot_f else 0.0
    rev = [v for k, v in tap["keys"].items() if k.startswith("zdrone-fleet/")]
    out["revision_push"] = {"per_min": _per_min(sum(v[0] for v in rev), window),
                            "bytes_per_min": _per_min(sum(v[1] for v in rev), window)}
    return out


def _heard(run_dir: Path) -> dict[str, dict[str, list[int]]] | None:
    """What the receivers opened, by kind: the drone's (``up``) and the GSs' (``down``) last status
    record with a ``traffic`` field; None if a node wrote none (an older node)."""
    out: dict[str, dict[str, list[int]]] = {"up": {}, "down": {}}
    found = False
    for log in sorted(run_dir.glob("*.jsonl")):
        if log.name.endswith(".audit.jsonl"):
            continue
        last = None
        for line in log.read_text().splitlines():
            if '"traffic"' in line:
                try:
                    rec = json.loads(line)
                except ValueError:
                    continue
                if isinstance(rec.get("traffic"), dict):
                    last = rec["traffic"]
        if last is None:
            continue
        found = True
        into = out["up" if log.name == "drone.jsonl" else "down"]
        for kind, (n, b) in last.items():
            c = into.setdefault(kind, [0, 0])
            c[0] += n
            c[1] += b
    return out if found else None


AUTOPILOTS = ("px4", "ardupilot")


def run(quick: bool = False, out: Path | None = None, progress: bool = True, autopilot: str = "px4") -> dict[str, Any]:
    if autopilot not in AUTOPILOTS:
        raise ValueError(f"autopilot {autopilot!r}: expected one of {', '.join(AUTOPILOTS)}")
    base = out or Path(tempfile.mkdtemp(prefix=f"zdrone-bench-traffic-{autopilot}-"))
    demos: dict[str, Demo] = {}
    results: dict[str, Any] = {}
    errors: dict[str, str] = {}

    def fly(name: str) -> None:
        cipher, paper_hb = VARIANTS[name]
        d = base / name
        d.mkdir(parents=True, exist_ok=True)
        opts = DemoOptions(out=d, speedup=1.0, live=False, quiet=True, tap=True, cipher=cipher, paper_heartbeat=paper_hb,
                           command_rate=0.0, report=False, max_wall=15.0 if quick else None, autopilot=autopilot)
        demo = demos[name] = Demo(opts, d.resolve())
        try:
            results[name] = demo.run()
        except Exception as exc:  # reported in the table, never silently
            errors[name] = str(exc)
            demo.shutdown()

    threads = [threading.Thread(target=fly, args=(n,), daemon=True) for n in VARIANTS]
    for t in threads:
        t.start()
    _show_progress(demos, threads, expected=20.0 if quick else 170.0, enabled=progress)
    for t in threads:
        t.join()
    rows = []
    for name in VARIANTS:
        tap_file = base / name / "tap.json"
        if name in errors or not tap_file.exists():
            rows.append({"variant": name, "error": errors.get(name, "no tap data")})
            continue
        r = _rates(json.loads(tap_file.read_text()), _heard(base / name))
        s = results.get(name, {})
        rows.append({"variant": name, **r, "flight_ok": bool(s.get("ok")) if not quick else None,
                     "handovers": len(s.get("handovers", []))})
    plain = next((r for r in rows if r["variant"] == "plain" and "error" not in r), None)
    for r in rows:
        if plain and "error" not in r:
            r["change_vs_plain"] = {
                "packets_pct": round((r["packets_per_min"] / plain["packets_per_min"] - 1) * 100, 2),
                "bytes_pct": round((r["bytes_per_min"] / plain["bytes_per_min"] - 1) * 100, 2),
                "mean_packet_bytes_added": round(r["mean_packet_bytes"] - plain["mean_packet_bytes"], 1),
                "mean_bytes_added": round(r["mean_frame_bytes"] - plain["mean_frame_bytes"], 1)}
    return {"autopilot": autopilot, "rows": rows, "paper_table1": PAPER, "quick": quick,
            "measured_at": "router tap, Zenoh sample payload bytes",
            "targets": {"packets_pct_max": 5.0, "bytes_pct_max": 25.0}, "runs": str(base)}


def _show_progress(demos: dict[str, Demo], threads: list[threading.Thread], expected: float, enabled: bool) -> None:
    if not enabled:
        return
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[stage]}"), TimeElapsedColumn(),
                  transient=True) as prog:
        tasks = {n: prog.add_task(f"flight {n:6}", total=expected, stage="starting") for n in VARIANTS}
        t0 = time.monotonic()
        while any(t.is_alive() for t in threads):
            for n, task in tasks.items():
                d = demos.get(n)
                st = d.progress.get("status", {}) if d else {}
                stage = f"authority {st.get('owner')} epoch {st.get('epoch')}" if st else "starting"
                prog.update(task, completed=min(expected, time.monotonic() - t0), stage=stage)
            time.sleep(0.5)


def _kinds(row: dict[str, Any]) -> dict[str, dict[str, float]]:
    """A row's kinds, both directions added (the JSON keeps them apart)."""
    out: dict[str, dict[str, float]] = {}
    for direction in ("up", "down"):
        for kind, c in row.get(direction, {}).get("kinds", {}).items():
            k = out.setdefault(kind, {"per_min": None, "bytes_per_min": 0.0})
            if c["per_min"] is not None:
                k["per_min"] = round((k["per_min"] or 0.0) + c["per_min"], 1)
            k["bytes_per_min"] = round(k["bytes_per_min"] + c["bytes_per_min"], 1)
    return out


def render(result: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    rows = []
    ok = [r for r in result["rows"] if "error" not in r]
    for r in result["rows"]:
        if "error" in r:
            rows.append([r["variant"], "error", r["error"], "", "", "", "", "", "", ""])
            continue
        ch = r.get("change_vs_plain", {})
        rows.append([r["variant"], r["packets_per_min"], f"{r['bytes_per_min'] / 1000:,.1f} kB", r["mean_packet_bytes"],
                     r["up"]["packets_per_min"], r["down"]["packets_per_min"], f"{ch.get('packets_pct', 0):+.2f} %",
                     f"{ch.get('bytes_pct', 0):+.2f} %", f"{ch.get('mean_packet_bytes_added', 0):+.1f}",
                     f"{ch.get('mean_bytes_added', 0):+.1f}"])
    p = result["paper_table1"]
    rows.append(["paper, without", p["without"]["packets_per_min"], "", p["without"]["mean_packet_bytes"], "", "", "", "", "",
                 ""])
    rows.append(["paper, with", p["with"]["packets_per_min"], "", p["with"]["mean_packet_bytes"], "", "", "+21.74 %", "", "+2.1",
                 ""])
    autopilot = result.get("autopilot", "px4")
    t = result.get("targets", {})
    print_table(f"Table 1 — traffic through the router (per minute of flight), {autopilot} personality",
                ["variant", "packets/min", "bytes/min", "mean packet B", "up pkt/min", "down pkt/min", "packets vs plain",
                 "bytes/min vs plain", "B added /packet", "B added /message"],
                rows, caption=f"target for zdrone: ≤ +{t.get('packets_pct_max', 5.0):g} % packets, "
                              f"≤ +{t.get('bytes_pct_max', 25.0):g} % bytes per minute vs plain; the paper's rows were "
                              "measured with PX4's stream")
    kinds = {r["variant"]: _kinds(r) for r in ok}
    if not any(kinds.values()):
        return
    names = ["mavlink", *[k for k in OWN_KINDS if any(k in v for v in kinds.values())],
             *sorted({k for v in kinds.values() for k in v} - {"mavlink", "bundle_and_unopened", *OWN_KINDS}),
             "bundle_and_unopened"]
    krows = []
    for kind in names:
        row: list[Any] = [kind]
        for r in ok:
            c = kinds[r["variant"]].get(kind)
            row += ["" if c is None or c["per_min"] is None else c["per_min"],
                    "" if c is None else f"{c['bytes_per_min']:,.0f}"]
        krows.append(row)
    krows.append(["revision_push (fleet key)", *[x for r in ok for x in (r["revision_push"]["per_min"],
                                                                         f"{r['revision_push']['bytes_per_min']:,.0f}")]])
    print_table("What the link carried, by kind (per minute; messages opened by their receivers, both directions)",
                ["kind", *[f"{r['variant']} {col}" for r in ok for col in ("msgs/min", "B/min")]], krows,
                caption="envelope: the cipher's bytes per envelope; batch: a batch's framing; status: the authority "
                        "status without the attestation and audit head it carries; bundle_and_unopened: the tap's bytes "
                        "not in an opened envelope (bundle framing, envelopes before a key); revision pushes are on the "
                        "fleet's key, outside the link's totals")
    plain = next((r for r in ok if r["variant"] == "plain"), None)
    mav_only = kinds.get("plain", {}).get("mavlink", {}).get("bytes_per_min") if plain else None
    if mav_only:
        lines = []
        for r in ok:
            if r["variant"] == "plain":
                continue
            lines.append(f"{r['variant']} {r['bytes_per_min'] / 1000:,.1f} kB/min: "
                         f"{100.0 * (r['bytes_per_min'] / plain['bytes_per_min'] - 1):+.1f} % against plain "
                         f"(the envelope alone: plain already carries the statuses, attestations and audit heads), "
                         f"{100.0 * (r['bytes_per_min'] / mav_only - 1):+.1f} % against plain MAVLink alone "
                         f"({mav_only / 1000:,.1f} kB/min)")
        print_table("Bytes a minute against plain, and against plain MAVLink alone", ["variant"], [[x] for x in lines])
