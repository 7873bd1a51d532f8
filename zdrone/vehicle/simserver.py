"""``zdrone sim``: the simulator on a MAVLink socket, in real time or faster (``--speedup``)."""

from __future__ import annotations

import logging
import signal
import time
from dataclasses import dataclass

from ..core.geometry import GeoPoint
from .sim import SimAutopilot
from .transport import MavTransport

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class SimOptions:
    mavlink: str = "udpin:127.0.0.1:14580"
    home: GeoPoint = GeoPoint(47.397742, 8.545594, 0.0)
    speedup: float = 1.0
    seed: int = 0
    sysid: int = 1
    gps_noise: float = 0.0
    duration: float | None = None  # wall seconds, None = until stopped


class SimServer:
    """Runs a ``SimAutopilot`` against a socket. ``run()`` blocks until ``stop()`` or SIGTERM."""

    def __init__(self, opts: SimOptions) -> None:
        self.opts = opts
        self.transport = MavTransport(opts.mavlink)
        self.sim = SimAutopilot(opts.home, sysid=opts.sysid, seed=opts.seed)
        self.sim.params["SIM_GPS_NOISE"].value = opts.gps_noise
        self._running = True

    def stop(self, *_: object) -> None:
        self._running = False

    def run(self) -> None:
        t0 = time.monotonic()
        tick = 0.02
        log.info("sim on %s (sysid %d, speed-up %g)", self.transport.endpoint, self.opts.sysid, self.opts.speedup)
        try:
            while self._running:
                wall = time.monotonic() - t0
                if self.opts.duration is not None and wall >= self.opts.duration:
                    break
                for frame, _peer in self.transport.poll(tick):
                    self.sim.receive(frame, self.sim.t)
                self.sim.step((time.monotonic() - t0) * self.opts.speedup)
                out = self.sim.drain()
                if self.transport.has_peer():
                    for f in out:
                        self.transport.send(f)
        finally:
            self.transport.close()
            log.info("sim stopped; counters %s, stream bytes skipped %d", dict(self.sim.counters), self.transport.skipped_bytes)


def run_sim(opts: SimOptions) -> int:
    server = SimServer(opts)
    signal.signal(signal.SIGTERM, server.stop)
    signal.signal(signal.SIGINT, server.stop)
    print(f"zdrone sim: PX4-type quadrotor sysid {opts.sysid} on {server.transport.endpoint}"
          f" (home {opts.home.lat:.6f},{opts.home.lon:.6f}, speed-up {opts.speedup:g})", flush=True)
    server.run()
    return 0
