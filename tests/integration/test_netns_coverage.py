"""Real coverage: the drone and its vehicle live in their own network namespace and reach the router
through a veth pair. The test takes the link down (the drone flies out of radio range) and up again.

Skipped, with the reason, where network namespaces cannot be made (not root, no iproute2).
Only addresses inside the namespace pair this test creates are used.
"""

from __future__ import annotations

import os
import random
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from tests.procs import ZDRONE, free_port, spawn
from tests.waiting import wait_until
from zdrone.fleet.files import init_fleet
from zdrone.net.eventlog import read_events


def _ip(*args: str, ns: str | None = None) -> None:
    cmd = (["ip", "netns", "exec", ns, "ip"] if ns else ["ip"]) + list(args)
    subprocess.run(cmd, check=True, capture_output=True, timeout=10)


@pytest.fixture()
def netns():
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("network namespaces need root and iproute2")
    tag = f"{os.getpid() % 10000}{random.randint(0, 99)}"
    ns, host_if, ns_if = f"zd{tag}", f"zdh{tag}", f"zdn{tag}"
    octet = random.randint(1, 250)
    host_ip, ns_ip = f"10.231.{octet}.1", f"10.231.{octet}.2"
    try:
        _ip("netns", "add", ns)
    except (subprocess.CalledProcessError, OSError) as exc:
        pytest.skip(f"cannot create a network namespace here: {exc}")
    try:
        _ip("link", "add", host_if, "type", "veth", "peer", "name", ns_if)
        _ip("link", "set", ns_if, "netns", ns)
        _ip("addr", "add", f"{host_ip}/30", "dev", host_if)
        _ip("link", "set", host_if, "up")
        _ip("addr", "add", f"{ns_ip}/30", "dev", ns_if, ns=ns)
        _ip("link", "set", ns_if, "up", ns=ns)
        _ip("link", "set", "lo", "up", ns=ns)
        yield {"ns": ns, "host_if": host_if, "host_ip": host_ip}
    finally:
        subprocess.run(["ip", "link", "del", host_if], capture_output=True)
        subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def _wait(pred, timeout: float, what: str) -> None:
    if not wait_until(pred, timeout, step=0.1):
        raise AssertionError(f"timed out waiting for {what}")


def _events(path: Path, type_: str) -> list[dict]:
    return [e for e in read_events(path) if e["type"] == type_] if path.exists() else []


@pytest.mark.slow
def test_link_down_up_through_a_real_veth(netns, tmp_path):
    init_fleet(tmp_path / "fleet")
    rport, sport = free_port(), free_port()
    router_host = f"tcp/{netns['host_ip']}:{rport}"
    in_ns = ["ip", "netns", "exec", netns["ns"]]
    common = ["--fleet", str(tmp_path / "fleet")]
    drone_log, a_log = tmp_path / "drone.jsonl", tmp_path / "A.jsonl"
    with spawn(ZDRONE, "router", "-c", str(tmp_path / "fleet/router/router.json5"), "--listen", f"tcp/127.0.0.1:{rport}",
               "--listen", router_host) as router:
        router.wait_line("listening", 20)
        with spawn(*in_ns, ZDRONE, "sim", "--mavlink", f"udpin:127.0.0.1:{sport}", "--speedup", "2") as sim, \
             spawn(*in_ns, ZDRONE, "drone", *common, "--router", router_host, "--vehicle", f"udpout:127.0.0.1:{sport}",
                   "--events", str(drone_log)) as drone:
            sim.wait_line("zdrone sim:", 20)
            drone.wait_line("ready", 40)
            with spawn(ZDRONE, "gs", "--id", "A", *common, "--router", f"tcp/127.0.0.1:{rport}", "--pair",
                       "--mission", "reference", "--events", str(a_log)) as gs_a:
                gs_a.wait_line("paired", 30)
                _wait(lambda: any(e["drones"]["d1"]["position"] and e["drones"]["d1"]["position"][2] > 10
                                  for e in _events(a_log, "status")), 60, "take-off seen by A")
                # out of range: the veth goes down
                _ip("link", "set", netns["host_if"], "down")
                t_down = time.time()
                _wait(lambda: _events(drone_log, "failsafe"), 15, "the drone's failsafe")
                fs = _events(drone_log, "failsafe")[0]
                assert fs["action"] == "LAND" and fs["detect_to_command_ms"] >= 0
                # the 3 s TBM threshold counts from the last heartbeat (2 Hz), which may precede the outage by 0.5 s:
                # never before it (how long after: the machine's pace)
                assert fs["t"] - t_down >= 2.3
                # back in range: telemetry reaches A again over the same Zenoh session
                opened_before = _events(a_log, "status")[-1]["drones"]["d1"]["link"]["opened"]
                _ip("link", "set", netns["host_if"], "up")
                _wait(lambda: _events(a_log, "status")[-1]["drones"]["d1"]["link"]["opened"] > opened_before + 5, 20,
                      "telemetry at A after the link came back")
                _wait(lambda: any(s["landed_state"] == 1 and not s["armed"] for s in _events(drone_log, "status")), 60,
                      "the vehicle landed")
                final = _events(drone_log, "status")[-1]
                assert final["state"] == "failsafe" and final["owner"] == "A"
