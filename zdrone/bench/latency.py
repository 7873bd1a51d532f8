"""One-way latency between the bench's processes (testbed): a message noted where it is sent and
where it arrives, matched afterwards by its bytes.

Every process of the machine reads the same clock (``time.monotonic``: CLOCK_MONOTONIC), so a
sender notes ``(drone, crc32 of the bytes, t)`` and the receiver notes the same for what it got; the
bench matches each arrival with the latest sending of the same bytes to the same drone no more than
``WINDOW_S`` before it. Nothing goes into the messages: both halves of ``bench overhead`` carry the
same bytes they would without the measurement. A sample of the messages only, chosen by their CRC
(the same choice on both sides, no coordination): one in ``SAMPLE_UP`` uplink messages and one in
``SAMPLE_DOWN`` vehicle frames (hundreds a second per drone at speed-up 4), so that the notes stay
small next to what is measured (the hosts' memory is measured too).

Which bytes: GS -> vehicle, the bytes the GS puts on the drone's uplink (zdrone: the sealed
envelope, noted as the GS's core hands it to its adapter, before the pacing; the drone notes the
envelope's CRC when the core forwards its frame to the vehicle, ``ToVehicle``); vehicle -> GS, the
MAVLink frame as the vehicle gives it to the drone's loop and as the GS gets it back (zdrone: the
GS's ``FrameUp``, the frame out of its envelope; bare: the frame out of the bundle in the GS's
Zenoh callback). A zdrone drone also sends a GS that becomes its owner (or heir) the newest frame of
each stream message at once (``DroneCore``'s catch-up: a standby GS was sent each at most once a
second); those are noted as sent again then, so that their delivery is timed like any other, and how
old they were is reported apart (``catch_up``): bare has no hand-over to send one at.

Vehicle -> GS is split likewise: **the drone** (sent -> put: its step, to the end of the put of its
bundles), **the wire** (put -> arrived in the GS's inbox: the drone's session, the routers, the GS's
session and its pump) and **the GS's host** (arrived -> got: the wait for the GS's loop, its opening).

GS -> vehicle is also split where the drone's host takes the message from Zenoh ("arrived": in the
Zenoh callback, before any queue): **the wire** (sent -> arrived: the GS's pacing, its session, the
routers, the drone's session) and **the host** (arrived -> got: the wait for the drone's turn in its
host's pass, then the drone's own handling: opening and checking the envelope, in zdrone). A host that
steps hundreds of drones in one loop, as the benches' does, makes the second as long as its pass; a
drone on its own companion computer waits for no other drone.

Pure but for ``dump``/``load``: ``LatencyLog`` is what a host keeps, ``match`` and ``summary`` what
the bench computes.
"""

from __future__ import annotations

import bisect
import json
import math
import zlib
from pathlib import Path
from typing import Any, Iterable

#: One uplink message in this many is noted (by its CRC): heartbeats and commands, a few a second per drone.
SAMPLE_UP = 8
#: One vehicle frame in this many is noted: the telemetry, tens to hundreds a second per drone.
SAMPLE_DOWN = 64
#: An arrival is matched to a sending of the same bytes at most this long before it (a MAVLink frame
#: repeats its bytes only after its 8-bit sequence number wraps: 256 frames, more than a minute apart).
WINDOW_S = 5.0
#: The streams noted: "up" GS -> vehicle, "down" vehicle -> GS.
DIRECTIONS = ("up", "down")
#: Where a message is noted: sent; put (GS -> vehicle: on its uplink's lane, after the GS's pass and
#: pacing; vehicle -> GS: published by the drone's step, sealed, in its bundle); arrived in the receiving host (GS -> vehicle: the drone's Zenoh callback; vehicle -> GS:
#: the GS's inbox, its bundle as it came); got.
SIDES = ("sent", "put", "arrived", "got")
_EVERY = {"up": SAMPLE_UP, "down": SAMPLE_DOWN}


def crc(data: bytes) -> int:
    return zlib.crc32(data)


class LatencyLog:
    """What one host notes: per direction, what it sent and what it got, from ``start()`` on (the
    take-off: the window every figure of the bench is taken over)."""

    def __init__(self) -> None:
        self.on = False
        self.t0 = 0.0
        self.notes: dict[str, dict[str, list[tuple[str, int, float]]]] = {
            d: {side: [] for side in SIDES} for d in DIRECTIONS}
        # every message (not only the sample), per second after ``start``: the rate each half carried
        self.counts: dict[str, dict[str, dict[int, int]]] = {d: {"sent": {}, "got": {}} for d in DIRECTIONS}
        # zdrone: how old each frame a new owner (or heir) is sent at once was (its catch-up: the newest
        # frame of each stream message, which a standby GS was sent at most once a second), in seconds
        self.catch_up: list[float] = []

    def start(self, now: float) -> None:
        self.on, self.t0 = True, now

    def note(self, direction: str, side: str, drone: str, data: bytes, now: float) -> None:
        """``side`` is one of ``SIDES``; noted only if on, and kept if the bytes are in the sample.
        Sent and got are also counted; an arrival is not (noted in Zenoh's callback thread: one append,
        atomic under the GIL, where a count's read-and-write would not be)."""
        if self.on:
            if side in ("sent", "got"):
                counts = self.counts[direction][side]
                s = int(now - self.t0)
                counts[s] = counts.get(s, 0) + 1
            c = zlib.crc32(data)
            if c % _EVERY[direction] == 0:
                self.notes[direction][side].append((drone, c, now))

    def note_many(self, direction: str, side: str, drone: str, frames: list[bytes], now: float) -> None:
        if self.on and frames:
            counts = self.counts[direction].get(side)  # sent and got are counted (the rates), not put or arrived
            if counts is not None:
                s = int(now - self.t0)
                counts[s] = counts.get(s, 0) + len(frames)
            every, notes = _EVERY[direction], self.notes[direction][side]
            for f in frames:
                c = zlib.crc32(f)
                if c % every == 0:
                    notes.append((drone, c, now))

    def note_catch_up(self, drone: str, frames: list[tuple[bytes, float]], now: float) -> None:
        """A new owner's catch-up (zdrone): each frame is sent again now (a delivery timed from this
        sending, as any other: its wire and hosts), and how old it was is kept apart."""
        if self.on and frames:
            notes = self.notes["down"]["sent"]  # noted, not counted: not frames out of the vehicle
            notes += [(drone, c, now) for c in (zlib.crc32(f) for f, _ in frames) if c % SAMPLE_DOWN == 0]
            self.catch_up += [now - t for _, t in frames]

    def dump(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps({**self.notes, "counts": self.counts, "catch_up": self.catch_up}))


def rates(paths: Iterable[Path], window_s: float) -> dict[str, dict[str, float]]:
    """Messages per second over the first ``window_s`` seconds after each host's ``start``, per
    direction and side, summed over the hosts' files."""
    total: dict[str, dict[str, int]] = {d: {"sent": 0, "got": 0} for d in DIRECTIONS}
    for p in paths:
        try:
            counts = json.loads(Path(p).read_text()).get("counts", {})
        except (OSError, ValueError):
            continue
        for d in DIRECTIONS:
            for side in ("sent", "got"):
                total[d][side] += sum(n for s, n in counts.get(d, {}).get(side, {}).items() if int(s) < window_s)
    span = max(1.0, float(int(window_s)))  # whole seconds counted
    return {d: {side: round(n / span, 1) for side, n in v.items()} for d, v in total.items()}


def load(paths: Iterable[Path]) -> dict[str, dict[str, list[tuple[str, int, float]]]]:
    """The notes of several hosts as one (a missing or unreadable file adds nothing)."""
    out: dict[str, dict[str, list[tuple[str, int, float]]]] = {d: {side: [] for side in SIDES} for d in DIRECTIONS}
    for p in paths:
        try:
            data = json.loads(Path(p).read_text())
        except (OSError, ValueError):
            continue
        for d in DIRECTIONS:
            for side in SIDES:
                out[d][side] += [tuple(x) for x in data.get(d, {}).get(side, [])]  # type: ignore[misc]
    return out


def catch_up(paths: Iterable[Path]) -> dict[str, Any]:
    """How old the frames of new owners' catch-ups were when sent (ms: n, p50, max), over the hosts' files."""
    ages: list[float] = []
    for p in paths:
        try:
            ages += json.loads(Path(p).read_text()).get("catch_up", [])
        except (OSError, ValueError):
            continue
    top = max(ages) if ages else None
    return {**_stats(ages), "max_ms": None if top is None else round(1000 * top, 2)}


def match(sent: list[tuple[str, int, float]], got: list[tuple[str, int, float]],
          window: float = WINDOW_S) -> list[float]:
    """The latency (seconds) of every arrival that has a sending of the same bytes to the same drone
    at most ``window`` before it (the latest such sending); the others are left out."""
    times: dict[tuple[str, int], list[float]] = {}
    for drone, c, t in sent:
        times.setdefault((drone, c), []).append(t)
    for ts in times.values():
        ts.sort()
    out = []
    for drone, c, t in got:
        ts = times.get((drone, c))
        if not ts:
            continue
        i = bisect.bisect_right(ts, t) - 1
        if i >= 0 and t - ts[i] <= window:
            out.append(t - ts[i])
    return out


def percentile(xs: list[float], q: float) -> float | None:
    """The ``q``-quantile (0..1) of ``xs``, nearest rank; None if empty."""
    if not xs:
        return None
    ys = sorted(xs)
    return ys[min(len(ys) - 1, max(0, math.ceil(q * len(ys) - 1e-9) - 1))]


def _stats(xs: list[float]) -> dict[str, Any]:
    p50, p99 = percentile(xs, 0.5), percentile(xs, 0.99)
    return {"n": len(xs), "p50_ms": None if p50 is None else round(1000 * p50, 2),
            "p99_ms": None if p99 is None else round(1000 * p99, 2)}


def summary(notes: dict[str, dict[str, list[tuple[str, int, float]]]]) -> dict[str, Any]:
    """Per direction: messages matched, p50 and p99 in milliseconds; GS -> vehicle also split into
    the wire (sent -> arrived) and the drone's host (arrived -> got), where arrivals were noted."""
    out: dict[str, Any] = {}
    for d, name in (("up", "gs_to_vehicle"), ("down", "vehicle_to_gs")):
        out[name] = _stats(match(notes[d]["sent"], notes[d]["got"]))
    up = notes["up"]
    if up.get("arrived"):
        out["gs_to_vehicle_wire"] = _stats(match(up["sent"], up["arrived"]))
        out["gs_to_vehicle_host"] = _stats(match(up["arrived"], up["got"]))
    if up.get("put"):  # of the wire, the part in the GS: its pass, sealing and pacing
        out["gs_to_vehicle_gs"] = _stats(match(up["sent"], up["put"]))
    down = notes["down"]
    if down.get("put") and down.get("arrived"):
        out["vehicle_to_gs_drone"] = _stats(match(down["sent"], down["put"]))
        out["vehicle_to_gs_wire"] = _stats(match(down["put"], down["arrived"]))
        out["vehicle_to_gs_host"] = _stats(match(down["arrived"], down["got"]))
    return out
