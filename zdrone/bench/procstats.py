"""What a bench reads of the processes it started, from outside them: resident memory (``/proc``), and
the bytes and data segments of their established TCP sockets (``ss``).
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path


def _memory_mb(pid: int | str) -> dict[str, float] | None:
    """Resident memory of a live process now and at its peak (VmRSS, VmHWM), MB."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    kb = {k: int(v.split()[0]) for k, v in (line.split(":", 1) for line in text.splitlines() if ":" in line)
          if k in ("VmRSS", "VmHWM")}
    return {"rss": round(kb.get("VmRSS", 0) / 1024, 1), "peak": round(kb.get("VmHWM", 0) / 1024, 1)}


_SS_FIELDS = re.compile(r"\b(bytes_sent|bytes_received|data_segs_out|data_segs_in):(\d+)")


def _tcp_sockets(pids: set[int]) -> dict[tuple[str, str], dict[str, int]] | None:
    """Established TCP sockets of ``pids``: (local, peer) -> pid, bytes and data segments each way
    (``ss -tinp``; None without ``ss``)."""
    if shutil.which("ss") is None:
        return None
    try:
        text = subprocess.run(["ss", "-tinpH", "state", "established"], capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    socks: dict[tuple[str, str], dict[str, int]] = {}
    current: dict[str, int] | None = None
    for line in text.splitlines():
        if line and not line[0].isspace():  # the socket line; its TCP info follows, indented
            current = None
            parts = line.split()
            pid = re.search(r"pid=(\d+)", line)
            if len(parts) >= 4 and pid and int(pid.group(1)) in pids:
                current = socks.setdefault((parts[2], parts[3]), {"pid": int(pid.group(1))})
        elif current is not None:
            current.update({k: int(v) for k, v in _SS_FIELDS.findall(line)})
    return socks


def _port(addr: str) -> int:
    return int(addr.rsplit(":", 1)[1])


def _traffic(before: dict | None, after: dict | None, keys: list[tuple[str, str]]) -> dict[str, int]:
    """Bytes and data segments, both ways, that crossed ``keys`` between two ``_tcp_sockets`` snapshots."""
    total = {"bytes": 0, "segments": 0}
    for key in keys:
        a, b = (after or {}).get(key, {}), (before or {}).get(key, {})
        total["bytes"] += sum(a.get(f, 0) - b.get(f, 0) for f in ("bytes_sent", "bytes_received"))
        total["segments"] += sum(a.get(f, 0) - b.get(f, 0) for f in ("data_segs_out", "data_segs_in"))
    return total

