"""``zdrone bench overhead --plot``: the CPU per drone per class against K, from a saved result."""

import json
import subprocess
import sys

from zdrone.bench.overheadplot import series


def _result():
    def row(k, zd, bare):
        return {"k": k, "layout": "3 sites", "compare": {"classes": {
            "drones host": {"cpu_ms_per_s_per_drone": {"zdrone": zd, "bare": bare}},
            "GSs host": {"cpu_ms_per_s_per_drone": {"zdrone": zd / 2, "bare": None}}}}}
    return {"rows": [row(300, 6.0, 3.0), row(100, 7.0, 3.2)]}


def test_series_are_per_class_and_half_in_order_of_k():
    s = series(_result())
    assert s["drones host"] == {"zdrone": [(100, 7.0), (300, 6.0)], "bare": [(100, 3.2), (300, 3.0)]}
    assert s["GSs host"]["bare"] == [] and s["routers"] == {"zdrone": [], "bare": []}


def test_the_command_plots_a_saved_result_without_flying(tmp_path):
    saved, png = tmp_path / "overhead.json", tmp_path / "cpu.png"
    saved.write_text(json.dumps(_result()))
    r = subprocess.run([sys.executable, "-m", "zdrone", "bench", "overhead", "--from-json", str(saved), "--plot", str(png),
                        "--json"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    bad = subprocess.run([sys.executable, "-m", "zdrone", "bench", "overhead", "--from-json", str(tmp_path / "none")],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--from-json" in bad.stderr
