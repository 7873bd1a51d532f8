"""Every well-formed frame passes, end to end (real router, simulator, drone node and ground station as
processes): a GCS application behind GS A's gateway sees PX4's EVENT (410) and a message id no
dialect defines, both sent by the vehicle; against the ArduPilot personality, which streams nothing
until asked, the drone node's vehicle link asks, so the drone knows its position and the application
gets the telemetry."""

from __future__ import annotations

import contextlib
import selectors
import socket
import threading
import time
from pathlib import Path
from typing import Iterator

import pytest
from pymavlink.dialects.v20 import all as every_dialect
from pymavlink.dialects.v20 import common as mav

from tests.integration.test_gcs_gateway import RawApp
from tests.procs import ZDRONE, free_port, spawn
from zdrone.core.mavlink import crc_ok, crc_seed, encode_raw, read_header
from zdrone.fleet.files import init_fleet
from zdrone.net.eventlog import read_events

#: a message id no pymavlink dialect defines, and the checksum seed its (imaginary) definition has
NOWHERE_ID = next(i for i in range(4242, 5000) if i not in every_dialect.mavlink_map)
NOWHERE_SEED = 0x42
NOWHERE_PAYLOAD = b"zdrone-every-frame"


class VehicleSide:
    """A UDP relay between the drone node and the simulator that also sends the drone node, every
    0.2 s, a frame of ``NOWHERE_ID`` from the vehicle (sysid 1, compid 1), as a vehicle of a dialect
    nobody here knows would."""

    def __init__(self, sim_port: int) -> None:
        self.sim = ("127.0.0.1", sim_port)
        self.drone_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.drone_side.bind(("127.0.0.1", 0))
        self.sim_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sim_side.bind(("127.0.0.1", 0))
        self.port = self.drone_side.getsockname()[1]
        self.drone: tuple[str, int] | None = None
        self.injected = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self.drone_side, selectors.EVENT_READ, "drone")
        sel.register(self.sim_side, selectors.EVENT_READ, "sim")
        next_inject = 0.0
        while not self._stop.is_set():
            for key, _ in sel.select(0.05):
                data, addr = key.fileobj.recvfrom(65535)  # type: ignore[union-attr]
                if key.data == "drone":
                    self.drone = addr
                    self.sim_side.sendto(data, self.sim)
                elif self.drone is not None:
                    self.drone_side.sendto(data, self.drone)
            if self.drone is not None and time.monotonic() >= next_inject:
                next_inject = time.monotonic() + 0.2
                frame = encode_raw(NOWHERE_ID, NOWHERE_SEED, NOWHERE_PAYLOAD, 1, 1, seq=self.injected)
                self.drone_side.sendto(frame, self.drone)
                self.injected += 1
        sel.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.drone_side.close()
        self.sim_side.close()


@contextlib.contextmanager
def stack(tmp: Path, autopilot: str) -> Iterator[dict[str, int]]:
    """Router, simulator (through ``VehicleSide`` for PX4), drone node, GS A paired with a TCP gateway."""
    init_fleet(tmp / "fleet")
    rport, ta = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    router = f"tcp/127.0.0.1:{rport}"
    common = ["--fleet", str(tmp / "fleet"), "--router", router]
    with contextlib.ExitStack() as es:
        r = es.enter_context(spawn(ZDRONE, "router", "-c", str(tmp / "fleet/router/router.json5"), "--listen", router))
        r.wait_line("listening", 20)
        if autopilot == "px4":
            sport = free_port()
            sim = es.enter_context(spawn(ZDRONE, "sim", "--mavlink", f"udpin:127.0.0.1:{sport}", "--speedup", "2"))
            relay = VehicleSide(sport)
            es.callback(relay.close)
            vehicle = f"udpout:127.0.0.1:{relay.port}"
        else:
            tport = free_port(socket.SOCK_STREAM)
            sim = es.enter_context(spawn(ZDRONE, "sim", "--autopilot", "ardupilot", "--mavlink",
                                         f"tcpin:127.0.0.1:{tport}", "--speedup", "2"))
            vehicle = f"tcp:127.0.0.1:{tport}"
        sim.wait_line("zdrone sim:", 20)
        # The relay injects frames as the vehicle: unsigned, so a signed link would rightly drop them
        # (tests/unit/test_fc_signing.py); here the link is unsigned, and every frame must pass. An
        # unsigned link's positions grant nothing unless opted in: A's first pairing needs coverage.
        drone = es.enter_context(spawn(ZDRONE, "drone", "--id", "d1", *common, "--vehicle", vehicle,
                                       "--fc-signing", "off", "--trust-unsigned-position",
                                       "--events", str(tmp / "drone.jsonl")))
        drone.wait_line("ready", 40)
        a = es.enter_context(spawn(ZDRONE, "gs", "--id", "A", *common, "--pair", "--gcs", f"tcpin:127.0.0.1:{ta}",
                                   "--events", str(tmp / "A.jsonl")))
        a.wait_line("paired", 30)
        yield {"a_tcp": ta}


def _collect(app: RawApp, pred, timeout: float) -> list[bytes]:
    """Frames the application receives until ``pred(frames so far)`` holds; all of them."""
    got: list[bytes] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not pred(got):
        got += app._frames(0.3)
    return got


def _of(frames: list[bytes], msgid: int) -> list[bytes]:
    return [f for f in frames if read_header(f).msgid == msgid]


@pytest.mark.slow
def test_a_gateway_application_sees_px4_events_and_ids_of_no_dialect(tmp_path):
    with stack(tmp_path, "px4") as ports:
        app = RawApp(ports["a_tcp"], 250)
        try:
            frames = _collect(app, lambda fs: bool(_of(fs, NOWHERE_ID)), 15)
            unknown = _of(frames, NOWHERE_ID)
            assert unknown, "the id of no dialect did not reach the application"
            f = unknown[0]
            assert read_header(f).sysid == 1 and f[10:10 + f[1]] == NOWHERE_PAYLOAD and crc_seed(f) == NOWHERE_SEED
            # arming makes PX4 say "Armed by external command" as STATUSTEXT and as EVENT (410)
            app.send(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
            frames = _collect(app, lambda fs: bool(_of(fs, 410)), 15)
            events = _of(frames, 410)
            assert events, "no EVENT reached the application"
            assert all(crc_ok(e) and read_header(e).sysid == 1 for e in events)  # intact, checksum seed 160
            app.send(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0, 0, 0, 0))
        finally:
            app.close()
    # nothing the vehicle sent was refused as bad MAVLink on the way
    final = [e for e in read_events(tmp_path / "A.jsonl") if e["type"] in ("status", "stop")]
    assert final and "bad_inner_mavlink" not in str(final[-1])


@pytest.mark.slow
def test_the_drone_asks_ardupilot_for_its_streams_and_the_application_gets_them(tmp_path):
    with stack(tmp_path, "ardupilot") as ports:
        app = RawApp(ports["a_tcp"], 250)
        try:
            wanted = (mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
                      mav.MAVLINK_MSG_ID_MISSION_CURRENT, mav.MAVLINK_MSG_ID_SYS_STATUS)
            frames = _collect(app, lambda fs: all(_of(fs, i) for i in wanted), 20)
            assert all(_of(frames, i) for i in wanted), {read_header(f).msgid for f in frames}
        finally:
            app.close()
    status = [e for e in read_events(tmp_path / "drone.jsonl") if e["type"] == "status"]
    assert any(s["position"] is not None for s in status), "the drone node never learnt its position"
    assert status[-1]["mode"] == "STABILIZE" and status[-1]["landed_state"] == mav.MAV_LANDED_STATE_ON_GROUND
