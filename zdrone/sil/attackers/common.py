"""TESTBED ONLY: what every attacker shares: its context (``Ctx``: the fleet directory, the router,
its events file, its signals), the MAVLink frames they send, the lanes of an uplink, a reply counter.

Each attacker is its own process with real credentials taken from the demo's fleet directory (what
it is allowed to hold is stated per mode) and writes what it did to its events file, so that a
scenario can check both sides: what the attacker sent and what the nodes refused.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable

from pymavlink.dialects.v20 import common as mav

from zdrone.core.fleet import Fleet
from zdrone.core.mavlink import FrameCodec
from zdrone.fleet.files import load_fleet, load_secret
from zdrone.fleet import keyexprs
from zdrone.fleet.routerconfig import UPLINK_MAX_HZ
from zdrone.net.eventlog import EventLog
from zdrone.sil import testbed_records as trec

ROGUE_COMPID = 190
#: How long a ``--wait-go`` attacker waits for its signal before giving up.
GO_TIMEOUT = 600.0

#: The uplink attackers space their frames above the router's limit (UPLINK_MAX_HZ over an uplink's
#: lanes, which they take in turn, as a GS does), so that every frame reaches the drone and is
#: refused there, by the checks under test.
UPLINK_GAP_S = 1.5 / UPLINK_MAX_HZ
#: The lane each uplink's next frame goes on.
_next_lane: dict[tuple[str, str], int] = {}


def next_up(drone: str, gs: str) -> str:
    """The key of the next lane of uplink (drone, gs): an attacker uses them in turn, as a GS does."""
    lane = _next_lane.get((drone, gs), 0)
    _next_lane[(drone, gs)] = (lane + 1) % keyexprs.UP_LANES
    return keyexprs.up_lane(drone, gs, lane)


@dataclass
class Ctx:
    """What every attacker gets: the fleet directory, the router, its events file and its signals."""

    fleet_dir: str
    router: str
    drone: str
    events: EventLog
    duration: float
    rate: float
    gcs_port: int | None
    wait_go: bool
    replies: int = 1  # key-injection: forged replies of each kind per query
    recorded: int = 8  # stale-pairing: message 1s of A recorded in earlier flights
    fc_port: int | None = None  # fc-radio: the autopilot's TELEM2 UDP port
    vehicle_port: int | None = None  # fake-autopilot: the UDP port the companion listens on for its autopilot
    gcs_port_b: int | None = None  # local-app: GS B's gateway (B's operator asks for control there)
    gcs_keys: str | None = None  # local-app: A's application key file (its own operator's signed application)
    size: int = 40  # junk-flood: bytes per junk envelope
    after_go: float = 0.0  # wall seconds it waits after its signal before it attacks
    stop: threading.Event = field(default_factory=threading.Event)
    go: threading.Event = field(default_factory=threading.Event)
    _fleet: Fleet | None = None

    @property
    def fleet(self) -> Fleet:
        if self._fleet is None:
            self._fleet = load_fleet(self.fleet_dir)
        return self._fleet

    def password(self, node: str) -> str:
        """A stolen router password (the secret file also holds the private key: not used)."""
        return load_secret(self.fleet_dir, node).router_password

    def ready(self) -> None:
        print("rogue: ready", flush=True)
        self.events.write_record(trec.RogueReady(wait_go=self.wait_go))

    def wait_for_go(self) -> bool:
        """Block until SIGUSR2 (if ``--wait-go``) and ``after_go`` seconds more; False if told to stop first."""
        if not self.wait_go:
            return not self.stop.is_set()
        deadline = time.monotonic() + GO_TIMEOUT
        while not self.stop.is_set() and time.monotonic() < deadline:
            if self.go.wait(0.05):
                if self.stop.wait(self.after_go):
                    break
                self.events.write_record(trec.RogueGo())  # (after ``after_go``: when it attacks)
                return True
        self.events.write_record(trec.RogueNoGo(stopped=self.stop.is_set()))
        return False

    def attack_window(self) -> Callable[[], bool]:
        """A predicate: True while the attack should go on (``--duration`` from now, no SIGTERM)."""
        deadline = time.monotonic() + self.duration
        return lambda: not self.stop.is_set() and time.monotonic() < deadline


def land_frame(sysid: int) -> bytes:
    return FrameCodec(sysid, ROGUE_COMPID).encode(
        mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, float("nan"), float("nan"), float("nan"), float("nan")))


def dangerous_messages(target: int) -> list[tuple[str, Any]]:
    """Every message a GS without authority must never get to the vehicle (name, pymavlink message)."""
    nan = float("nan")
    return [
        ("SERIAL_CONTROL", mav.MAVLink_serial_control_message(10, 6, 0, 0, 8, list(b"reboot\n\0") + [0] * 62)),
        ("SETUP_SIGNING", mav.MAVLink_setup_signing_message(target, 1, list(os.urandom(32)), 1)),
        ("SET_GPS_GLOBAL_ORIGIN", mav.MAVLink_set_gps_global_origin_message(target, 473000000, 85000000, 500000, 0)),
        ("GPS_INPUT", mav.MAVLink_gps_input_message(0, 0, 0, 0, 0, 3, 473000000, 85000000, 500.0, 1.0, 1.0, 0, 0, 0,
                                                    0.1, 1.0, 1.0, 12, 0)),
        ("VISION_POSITION_ESTIMATE", mav.MAVLink_vision_position_estimate_message(0, 100.0, 100.0, -30.0, 0, 0, 0)),
        ("FILE_TRANSFER_PROTOCOL", mav.MAVLink_file_transfer_protocol_message(0, target, 1, [0] * 251)),
        ("PARAM_EXT_SET", mav.MAVLink_param_ext_set_message(target, 1, b"COM_DL_LOSS_T", b"1", mav.MAV_PARAM_EXT_TYPE_INT32)),
        ("SET_ACTUATOR_CONTROL_TARGET", mav.MAVLink_set_actuator_control_target_message(0, 0, target, 1, [1.0] * 8)),
        ("LOG_ERASE", mav.MAVLink_log_erase_message(target, 1)),
        ("COMMAND_LONG DO_REPOSITION", mav.MAVLink_command_long_message(target, 1, mav.MAV_CMD_DO_REPOSITION, 0, -1, 1, 0, nan,
                                                                        47.40, 8.56, 50.0)),
        ("SET_MODE", mav.MAVLink_set_mode_message(target, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4 << 16 | 6 << 24)),
        ("PARAM_SET", mav.MAVLink_param_set_message(target, 1, b"NAV_DLL_ACT", 0.0, mav.MAV_PARAM_TYPE_INT32)),
    ]


def gcs_heartbeat() -> Any:
    return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE, 3)


class Replies:
    """Counts query replies by outcome (``ok`` / the error text); filled on Zenoh's threads."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.counts: Counter[str] = Counter()
        self.ok_payloads: "queue.SimpleQueue[bytes]" = queue.SimpleQueue()

    def __call__(self, reply: Any) -> None:
        try:
            if reply.ok is not None:
                key = "ok"
                self.ok_payloads.put(reply.ok.payload.to_bytes())
            else:
                key = "err:" + (reply.err.payload.to_bytes().decode(errors="replace").split(":")[0][:40] if reply.err else "?")
        except Exception:  # never raise into Zenoh
            key = "unreadable"
        with self._lock:
            self.counts[key] += 1

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dict(self.counts)


def session_as(c: Ctx, node: str, own_site: bool = True) -> "zenoh.Session":
    """A session as fleet member ``node`` with its real credentials: its router password and, with a
    TLS router, its own certificate; with a router per site and ``own_site``, at ``node``'s own
    site's router."""
    from zdrone.core.errors import ConfigError
    from zdrone.fleet.files import load_sites
    from zdrone.fleet.tls import node_files
    from zdrone.net.session import open_client

    if not c.router.startswith("tls/"):
        return open_client(c.router, node, c.password(node))
    router = c.router
    if own_site:
        try:
            sites = load_sites(c.fleet_dir)
        except ConfigError:
            sites = {}
        router = next((s["endpoint"] for s in sites.values() if node in s["ground_stations"]), router)
    return open_client(router, node, c.password(node), node_files(c.fleet_dir, node).check())
