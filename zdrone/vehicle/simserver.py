"""``zdrone sim``: the simulator on a MAVLink socket, in real time or faster (``--speedup``).

Theory of operation: ``SimServer`` owns the clock and the socket of one ``SimAutopilot``. Each turn
it polls the socket for up to 20 ms, hands the frames to the simulator at the current simulated
time (wall time since boot × speed-up), steps it and sends what it drained to every peer. The
personality's endpoints are the defaults: PX4's onboard link listens on UDP 14580 and sends to
14540 from boot; ArduPilot SITL listens on TCP 5760 and does not boot (its clock does not start)
until a client has connected there.

A second endpoint (``telem2``) stands for the autopilot's TELEM2 port (a telemetry radio): link 1,
the main endpoint being link 0. Both get every frame the autopilot sends, each signed or not as the
autopilot's MAVLink signing says for that link (``sim.signing``); frames are handed to the
autopilot with the link they came on. ``storage`` is the autopilot's persistent storage (its
signing key and timestamp survive a restart of ``zdrone sim`` with the same directory).
"""

from __future__ import annotations

import json
import logging
import signal
import socket
import time
from dataclasses import dataclass

from zdrone.core.geometry import GeoPoint
from zdrone.vehicle.personality import PX4, Personality
from zdrone.vehicle.sim import SimAutopilot
from zdrone.vehicle.sim.signing import RULES as SIGNING_RULES, SigningStorage, SimSigning
from zdrone.vehicle.transport import MavTransport

log = logging.getLogger(__name__)

#: TESTBED ONLY: how often the true position goes to ``--truth`` (wall seconds).
TRUTH_PERIOD_S = 0.05


@dataclass(frozen=True, slots=True)
class SimOptions:
    mavlink: str | None = None  # None: the personality's endpoint (PX4 udpin:127.0.0.1:14580 -> 14540)
    home: GeoPoint = GeoPoint(47.397742, 8.545594, 0.0)
    speedup: float = 1.0
    seed: int = 0
    sysid: int = 1
    gps_noise: float = 0.0
    duration: float | None = None  # wall seconds, None = until stopped
    personality: Personality = PX4
    ready_after: float | None = None  # simulated seconds; None: the personality's short default
    truth: tuple[str, int] | None = None  # TESTBED ONLY: send the true position here (UDP JSON, 20 Hz wall)
    telem2: str | None = None  # a second MAVLink endpoint (link 1), e.g. udpin:127.0.0.1:14590
    storage: str | None = None  # directory of the autopilot's persistent storage (signing key); None: none
    signing: bool = True  # False: an autopilot without MAVLink signing (PX4 before 1.17)


class SimServer:
    """Runs a ``SimAutopilot`` against a socket. ``run()`` blocks until ``stop()`` or SIGTERM."""

    def __init__(self, opts: SimOptions) -> None:
        self.opts = opts
        pers = opts.personality
        conn = opts.mavlink or pers.endpoint
        peers = (pers.send_to,) if opts.mavlink is None and pers.send_to is not None else ()
        self.transport = MavTransport(conn, peers)
        #: link number -> transport (0: the main endpoint, 1: TELEM2)
        self.links: list[MavTransport] = [self.transport]
        if opts.telem2 is not None:
            try:
                self.links.append(MavTransport(opts.telem2))
            except Exception:
                self.transport.close()
                raise
        self.peers = peers
        self.ready_after = pers.default_ready_after if opts.ready_after is None else opts.ready_after
        rules = SIGNING_RULES.get(pers.name) if opts.signing else None
        storage = SigningStorage(opts.storage, rules) if opts.storage is not None and rules is not None else None
        self.sim = SimAutopilot(opts.home, sysid=opts.sysid, seed=opts.seed, personality=pers,
                                ready_after=self.ready_after, signing=SimSigning(rules, storage, wall=time.time))
        self.sim.params["SIM_GPS_NOISE"].value = opts.gps_noise
        self._running = True
        self._truth = socket.socket(socket.AF_INET, socket.SOCK_DGRAM) if opts.truth else None
        self._next_truth = 0.0

    def _send_truth(self, now: float) -> None:
        """TESTBED ONLY: the vehicle's true position, for the testbed's radio links (``--truth``)."""
        if self._truth is None or now < self._next_truth or self.opts.truth is None:
            return
        self._next_truth = now + TRUTH_PERIOD_S
        p = self.sim.position
        try:
            self._truth.sendto(json.dumps({"lat": p.lat, "lon": p.lon, "alt": p.alt, "t": self.sim.t}).encode(),
                               self.opts.truth)
        except OSError:
            pass  # nobody listening (yet): the next one goes out in 50 ms

    def stop(self, *_: object) -> None:
        self._running = False

    def run(self) -> None:
        t0 = start = time.monotonic()
        tick = 0.02
        booted = not self.opts.personality.boots_on_first_client
        log.info("sim (%s) on %s%s (sysid %d, speed-up %g, ready after %g s)", self.opts.personality.name,
                 self.transport.endpoint, "".join(f", sending to {h}:{p}" for h, p in self.peers), self.opts.sysid,
                 self.opts.speedup, self.ready_after)
        if not booted:
            log.info("waiting for a client before boot")
        try:
            while self._running:
                if self.opts.duration is not None and time.monotonic() - start >= self.opts.duration:
                    break
                received = [(0, f) for f, _peer in self.transport.poll(tick)]
                for link, extra in enumerate(self.links[1:], start=1):
                    received += [(link, f) for f, _peer in extra.poll(0.0)]
                if not booted:
                    if not self.transport.has_peer():
                        continue
                    booted, t0 = True, time.monotonic()  # the autopilot boots now: its clock starts at 0
                    log.info("client connected: booting")
                for link, frame in received:
                    self.sim.receive(frame, self.sim.t, link)
                self.sim.step((time.monotonic() - t0) * self.opts.speedup)
                out = self.sim.drain()
                self._send_truth(time.monotonic())
                for link, transport in enumerate(self.links):
                    if transport.has_peer():
                        for f in out:
                            transport.send(self.sim.signing.outgoing(f, link))
        finally:
            for transport in self.links:
                transport.close()
            if self._truth is not None:
                self._truth.close()
            log.info("sim stopped; counters %s, stream bytes skipped %d", dict(self.sim.counters), self.transport.skipped_bytes)


def run_sim(opts: SimOptions) -> int:
    server = SimServer(opts)
    signal.signal(signal.SIGTERM, server.stop)
    signal.signal(signal.SIGINT, server.stop)
    pers = opts.personality
    also = "".join(f" -> udp {h}:{p}" for h, p in server.peers)
    print(f"zdrone sim: {pers.label} quadrotor sysid {opts.sysid} on {server.transport.endpoint}{also}"
          f" (home {opts.home.lat:.6f},{opts.home.lon:.6f}, speed-up {opts.speedup:g},"
          f" ready {server.ready_after:g} s after boot)"
          + (f", TELEM2 on {server.links[1].endpoint}" if len(server.links) > 1 else "")
          + ("" if opts.signing else ", no MAVLink signing"), flush=True)
    server.run()
    return 0
