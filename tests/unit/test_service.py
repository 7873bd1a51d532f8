"""``zdrone service``: a hardened systemd unit per node kind that ``systemd-analyze verify`` accepts
and ``systemd-analyze security --offline=yes`` rates at an exposure <= 2.0."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.procs import ZDRONE
from zdrone.cli import main
from zdrone.fleet.bundle import export_bundle
from zdrone.fleet.files import init_fleet

ANALYZE = shutil.which("systemd-analyze")
CASES = {  # unit name: (fleet, node, options)
    "zdrone-router": ("tls", "router", []),
    "zdrone-site-2": ("sites", "site-2", []),
    "zdrone-d1-serial": ("tls", "d1", ["--vehicle", "/dev/ttyACM0,921600", "--router", "tls/10.0.0.1:7447"]),
    "zdrone-d1-udp": ("plain", "d1", ["--vehicle", "udpin:0.0.0.0:14540"]),
    "zdrone-A": ("plain", "A", []),
    "zdrone-B-site": ("sites", "B", ["--router", "tls/127.0.0.1:7448"]),
}


@pytest.fixture(scope="module")
def bundles(tmp_path_factory) -> dict[tuple[str, str], Path]:
    base = tmp_path_factory.mktemp("svc")
    fleets = {"plain": {}, "tls": {"tls": True}, "sites": {"sites": ["tls/127.0.0.1:7447", "tls/127.0.0.1:7448"]}}
    out = {}
    for kind, kw in fleets.items():
        init_fleet(base / kind, **kw)
    for fleet, node, _ in CASES.values():
        if (fleet, node) not in out:
            out[(fleet, node)] = export_bundle(base / fleet, node, base / f"{fleet}-{node}") and base / f"{fleet}-{node}"
    return out


def _unit(bundles, name: str, capsys, tmp_path: Path) -> Path:
    fleet, node, opts = CASES[name]
    assert main(["service", node, "--bundle", str(bundles[(fleet, node)]), "--exec", ZDRONE, *opts]) == 0
    path = tmp_path / f"{name}.service"
    path.write_text(capsys.readouterr().out)
    return path


@pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze is not installed")
@pytest.mark.parametrize("name", list(CASES))
def test_every_node_kinds_unit_verifies_and_rates_at_most_2(bundles, name, capsys, tmp_path):
    unit = _unit(bundles, name, capsys, tmp_path)
    v = subprocess.run([ANALYZE, "verify", str(unit)], capture_output=True, text=True, timeout=60)
    assert v.returncode == 0 and not v.stderr.strip(), v.stderr
    s = subprocess.run([ANALYZE, "security", "--offline=yes", str(unit)], capture_output=True, text=True, timeout=60)
    score = re.search(r"Overall exposure level for \S+: ([\d.]+)", s.stdout)
    assert score, s.stdout[-500:] + s.stderr
    assert float(score.group(1)) <= 2.0, s.stdout


def test_the_unit_restarts_on_failure_keeps_state_and_logs_in_systemds_directories(bundles, capsys, tmp_path):
    text = _unit(bundles, "zdrone-d1-serial", capsys, tmp_path).read_text()
    for line in ("Restart=on-failure", "StateDirectory=zdrone-d1", "LogsDirectory=zdrone-d1",
                 "Environment=ZDRONE_STATE_DIR=%S/zdrone-d1", "DeviceAllow=/dev/ttyACM0 rw", "DevicePolicy=closed",
                 "SupplementaryGroups=dialout", "User=zdrone", "ProtectSystem=strict", "NoNewPrivileges=yes",
                 "IPAddressAllow=localhost 10.0.0.1", "StandardError=journal"):
        assert line in text.splitlines(), line
    exec_start = next(line for line in text.splitlines() if line.startswith("ExecStart="))
    assert f"--fleet {bundles[('tls', 'd1')].resolve()}" in exec_start
    assert "--events %L/zdrone-d1/events.jsonl" in exec_start and "--vehicle /dev/ttyACM0,921600" in exec_start
    gs = _unit(bundles, "zdrone-A", capsys, tmp_path).read_text()
    assert "PrivateDevices=yes" in gs.splitlines() and "DeviceAllow" not in gs


def test_a_unit_for_the_wrong_bundle_or_a_vehicle_for_a_gs_is_refused(bundles, capsys):
    assert main(["service", "B", "--bundle", str(bundles[("plain", "A")]), "--exec", ZDRONE]) == 2
    assert "the bundle of A, not of B" in capsys.readouterr().err
    assert main(["service", "A", "--bundle", str(bundles[("plain", "A")]), "--vehicle", "/dev/ttyACM0"]) == 2
    assert "only a drone has a vehicle" in capsys.readouterr().err
