"""``zdrone bench scale --restart-gs G``: GS G's host process crashes in flight and a new one starts with
no key (``restart_gs``); from the drones' own events, when each took G's new key (``relinked``).
"""

from __future__ import annotations

import json
import signal
import subprocess
import time
from pathlib import Path
from typing import Any, Callable

#: ``--restart-gs``: the GS crashes this long after the take-off (every drone near home, A owning it)
RESTART_AFTER_S = 3.0


def restart_gs(d: Path, procs: dict[str, subprocess.Popen], part: str, start: Callable[[str, Any], subprocess.Popen],
               hosts_nice: int, wait_line: Callable[..., str | None], give_way: Callable[[int, int], str]) -> dict[str, Any]:
    """Kill GS host ``part`` (SIGKILL: a crash, no goodbye) ``RESTART_AFTER_S`` after the take-off and
    start a new one in its place with no key: when it was up, from the kill (``relinked``: the rest)."""
    time.sleep(RESTART_AFTER_S)
    procs[part].kill()
    procs[part].wait(10)
    killed = time.time()
    with open(d / f"{part}.restart.log", "w") as log:  # the child writes to its own copy of the file
        procs[part] = start(part, log)
    give_way(procs[part].pid, hosts_nice)
    out: dict[str, Any] = {"gs": part.split("-", 1)[1], "killed_after_takeoff_s": RESTART_AFTER_S, "killed_wall": killed}
    up = wait_line(d / f"{part}.restart.log", "stations ready", 60, procs[part])
    if up is None:
        return {**out, "error": "the new GS host did not start"}
    out["up_s"] = round(time.time() - killed, 2)
    procs[part].send_signal(signal.SIGUSR1)  # its deliveries count from now on
    return out


def relinked(d: Path, k: int, restart: dict[str, Any], stations: dict[str, Any]) -> dict[str, Any]:
    """When each drone took the restarted GS's new key (its event ``link_installed``, how
    ``grant:keys_lost``, or a new pairing), from the crash: how many, the median and the last; and when
    the GS had them all confirmed (the drone's first words under it, heard in the GS's radio only)."""
    gs, killed = restart["gs"], restart["killed_wall"]
    confirmed = (stations.get("linked_all") or {}).get(gs)
    took: list[float] = []
    for i in range(k):
        try:
            with open(d / f"d{i + 1}.jsonl") as f:
                for line in f:
                    if f'"gs":"{gs}"' in line and ('"link_installed"' in line or '"link_confirmed"' in line):
                        e = json.loads(line)
                        if e["t"] > killed:
                            took.append(e["t"] - killed)
                            break
        except (OSError, ValueError, KeyError):
            continue
    took.sort()
    return {"drones_relinked": len(took), "relinked_p50_s": round(took[(len(took) - 1) // 2], 2) if took else None,
            "relinked_s": round(took[-1], 2) if len(took) == k else None,
            "confirmed_s": round(confirmed - killed, 2) if confirmed else None}
