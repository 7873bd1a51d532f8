"""The price of security per drone as the fleet grows: ``zdrone bench overhead --plot FILE`` draws, for each
process class (drones host, GSs host, routers), the CPU it spends per drone (ms of CPU per second per
drone) against the fleet's size K, zdrone beside bare Zenoh. Flat lines mean the cost per drone does
not grow with the fleet."""

from __future__ import annotations

from pathlib import Path
from typing import Any

CLASSES = ("drones host", "GSs host", "routers")


def series(result: dict[str, Any]) -> dict[str, dict[str, list[tuple[int, float]]]]:
    """Per class and half ("zdrone", "bare"): (K, CPU ms/s per drone) for every row that has it."""
    out: dict[str, dict[str, list[tuple[int, float]]]] = {c: {"zdrone": [], "bare": []} for c in CLASSES}
    for row in sorted(result.get("rows", []), key=lambda r: r["k"]):
        for cls, figures in row.get("compare", {}).get("classes", {}).items():
            cpu = figures.get("cpu_ms_per_s_per_drone", {})
            for half in ("zdrone", "bare"):
                if cls in out and cpu.get(half) is not None:
                    out[cls][half].append((row["k"], float(cpu[half])))
    return out


def plot(result: dict[str, Any], path: Path) -> Path:
    """Write the plot (PNG) to ``path``; matplotlib without a display."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = series(result)
    fig, ax = plt.subplots(figsize=(6.0, 3.6), dpi=110)
    colours = {"drones host": "tab:blue", "GSs host": "tab:orange", "routers": "tab:green"}
    for cls, halves in data.items():
        for half, style in (("zdrone", "-o"), ("bare", "--s")):
            points = halves[half]
            if points:
                ax.plot([k for k, _ in points], [v for _, v in points], style, color=colours[cls],
                        label=f"{cls}, {half}", markersize=4)
    layout = (result.get("rows") or [{}])[0].get("layout", "")
    ax.set_xlabel("drones (K), 3 GSs" + (f", {layout}" if layout else ""))
    ax.set_ylabel("CPU ms per s per drone")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("zdrone bench overhead: CPU per drone", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
