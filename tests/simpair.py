"""In-memory GCS <-> simulator pair for unit tests: no sockets, explicit simulated time."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import all as every_dialect
from pymavlink.dialects.v20 import common as mav

from zdrone.core.geometry import GeoPoint, offset
from zdrone.core.mavlink import FrameCodec, read_header
from zdrone.core.reference import HOME
from zdrone.vehicle.personality import PX4, Personality
from zdrone.vehicle.sim import SimAutopilot


@dataclass(frozen=True)
class RawFrame:
    """A frame of an id no pymavlink dialect defines (PX4's EVENT, ...): header and payload only."""

    msgid: int
    payload: bytes

    def get_type(self) -> str:
        return f"UNKNOWN_{self.msgid}"


class SimPair:
    def __init__(self, seed: int = 0, personality: Personality = PX4, ready_after: float = 0.0) -> None:
        self.sim = SimAutopilot(HOME, sysid=1, seed=seed, personality=personality, ready_after=ready_after)
        self.gcs = FrameCodec(255, 190)
        self._any = every_dialect.MAVLink(None)  # decodes common, development and ardupilotmega ids
        self._any.robust_parsing = True
        self.now = 0.0
        self.inbox: list[Any] = []

    def send(self, msg: Any) -> None:
        self.sim.receive(self.gcs.encode(msg), self.now)
        self._collect()

    def _collect(self) -> None:
        for f in self.sim.drain():
            hdr = read_header(f)
            if hdr.msgid in every_dialect.mavlink_map:
                msgs = self._any.parse_buffer(f)
                assert msgs and msgs[0].get_type() != "BAD_DATA", f.hex()
                self.inbox.append(msgs[0])
            else:
                self.inbox.append(RawFrame(hdr.msgid, f[10:10 + f[1]]))

    def texts(self) -> list[str]:
        """STATUSTEXTs received so far (taken from the inbox), in order."""
        return [m.text for m in self.take("STATUSTEXT")]

    def run(self, seconds: float, dt: float = 0.1) -> None:
        end = self.now + seconds
        while self.now < end:
            self.now = round(self.now + dt, 6)
            self.sim.step(self.now)
            self._collect()

    def run_until(self, pred, timeout: float, dt: float = 0.1) -> bool:
        end = self.now + timeout
        while self.now < end:
            if pred():
                return True
            self.run(dt, dt)
        return pred()

    def take(self, name: str) -> list[Any]:
        got = [m for m in self.inbox if m.get_type() == name]
        self.inbox = [m for m in self.inbox if m.get_type() != name]
        return got

    def command(self, cmd: int, *params: float) -> int:
        p = list(params) + [0.0] * (7 - len(params))
        self.send(mav.MAVLink_command_long_message(1, 1, cmd, 0, *p))
        acks = [a for a in self.take("COMMAND_ACK") if a.command == cmd]
        assert acks, f"no ack for {cmd}"
        return acks[-1].result

    def upload(self, items: list[Any]) -> int:
        """Upload MISSION_ITEM_INT messages the way a GCS does; return the MISSION_ACK type."""
        self.take("MISSION_ACK")
        self.send(mav.MAVLink_mission_count_message(1, 1, len(items), 0))
        for _ in range(len(items) + 1):
            acks = self.take("MISSION_ACK")
            if acks:
                return acks[-1].type
            reqs = self.take("MISSION_REQUEST_INT")
            assert reqs, "vehicle asked for nothing"
            self.send(items[reqs[-1].seq])
        acks = self.take("MISSION_ACK")
        assert acks
        return acks[-1].type


def waypoint(seq: int, north: float, east: float, alt: float, cmd: int = mav.MAV_CMD_NAV_WAYPOINT,
             frame: int = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, params=(0.0, 0.0, 0.0, float("nan"))) -> Any:
    p: GeoPoint = offset(HOME, north, east)
    return mav.MAVLink_mission_item_int_message(1, 1, seq, frame, cmd, 0, 1, *params,
                                                int(p.lat * 1e7), int(p.lon * 1e7), alt)
