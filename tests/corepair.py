"""In-memory pairs for unit tests (like h11's ConnectionPair): both ends of a link, no sockets."""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mav

from zdrone.core.envelope import SecureLink
from zdrone.core.keys import LinkKey
from zdrone.core.mavlink import FrameCodec

SECRET = bytes(range(32))


@dataclass
class LinkPair:
    gs: SecureLink
    drone: SecureLink
    gs_codec: FrameCodec
    vehicle_codec: FrameCodec

    def heartbeat(self) -> bytes:
        return self.gs_codec.encode(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))

    def command(self) -> bytes:
        return self.gs_codec.encode(mav.MAVLink_command_long_message(1, 1, 21, 0, 0, 0, 0, 0, 0, 0, 0))

    def telemetry(self) -> bytes:
        return self.vehicle_codec.encode(mav.MAVLink_global_position_int_message(1, 2, 3, 4, 5, 6, 7, 8, 9))


def make_pair(secret: bytes = SECRET, gs: str = "A", gs_sysid: int = 4, now: float = 0.0, **kw) -> LinkPair:
    key = LinkKey.from_secret("d1", gs, secret)
    up, down = f"zdrone/d1/up/{gs}", f"zdrone/d1/down/{gs}"
    g = SecureLink(key=key, role="gs", tx_keyexpr=up, rx_keyexpr=down, peer_sysid=1, now=now, **kw)
    d = SecureLink(key=key, role="drone", tx_keyexpr=down, rx_keyexpr=up, peer_sysid=gs_sysid, now=now, **kw)
    return LinkPair(g, d, FrameCodec(gs_sysid, 190), FrameCodec(1, 1))
