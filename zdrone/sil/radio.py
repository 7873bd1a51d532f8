"""TESTBED ONLY: a lossy, late radio between the drone and each GS, for software-in-the-loop flights.

Theory of operation
-------------------
``RadioModel`` is the same for every GS link unless overridden per GS; ``RadioChannel`` holds one
seeded random stream and one burst state per (GS, direction) and decides, for each frame at wall
time ``now``, whether it is lost and when it arrives:

* **independent loss**: each frame is lost with probability ``loss``;
* **bursty loss** (a two-state Gilbert-Elliott channel in continuous time): the link alternates
  between good periods (mean ``good_s``) and bad periods (mean ``bad_s``), both exponentially
  distributed; every frame in a bad period is lost;
* **delay and jitter**: a frame that survives arrives ``delay_s`` plus a uniform ``±jitter_s`` later
  (never before ``now``), so frames may also be reordered, as on a real radio.

It is pure (time comes in as ``now``, randomness from its own seeded generator): the drone node keeps
delayed frames in a queue and hands each on when its time comes. Frames lost here are counted per
(direction, GS, reason), never lost silently. A real deployment has real radios and no such model.
"""

from __future__ import annotations

import random
from collections import Counter
from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class RadioModel:
    """The impairments of one emulated radio link (both directions)."""

    loss: float = 0.0
    good_s: float = 0.0  # mean good period of the bursty channel (0: no bursts)
    bad_s: float = 0.0  # mean bad period (every frame lost)
    delay_s: float = 0.0
    jitter_s: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.loss <= 1.0:
            raise ValueError(f"loss {self.loss}: must be within 0..1")
        for name in ("good_s", "bad_s", "delay_s", "jitter_s"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} {getattr(self, name)}: must not be negative")
        if (self.good_s > 0) != (self.bad_s > 0):
            raise ValueError("bursts need both a mean good and a mean bad period")

    @property
    def perfect(self) -> bool:
        return self == RadioModel()


@dataclass(slots=True)
class _Path:
    rng: random.Random
    bad: bool = False
    switch_at: float | None = None  # when the burst state changes next


@dataclass
class RadioChannel:
    """Every emulated radio link of one drone (per GS, per direction)."""

    default: RadioModel = field(default_factory=RadioModel)
    per_gs: dict[str, RadioModel] = field(default_factory=dict)
    seed: int = 0
    lost: Counter = field(default_factory=Counter)
    _paths: dict[tuple[str, str], _Path] = field(default_factory=dict)

    def model(self, gs: str) -> RadioModel:
        return self.per_gs.get(gs, self.default)

    def _path(self, gs: str, direction: str) -> _Path:
        key = (gs, direction)
        if key not in self._paths:
            self._paths[key] = _Path(random.Random(f"{self.seed}/{gs}/{direction}"))
        return self._paths[key]

    def in_burst(self, gs: str, direction: str, now: float) -> bool:
        """Whether the bursty channel of this path is in a bad period at ``now``."""
        m, p = self.model(gs), self._path(gs, direction)
        if m.good_s <= 0:
            return False
        if p.switch_at is None:
            p.switch_at = now + p.rng.expovariate(1.0 / m.good_s)
        while now >= p.switch_at:
            p.bad = not p.bad
            p.switch_at += p.rng.expovariate(1.0 / (m.bad_s if p.bad else m.good_s))
        return p.bad

    def admit(self, gs: str, direction: str, now: float) -> float | None:
        """When a frame sent at ``now`` on this path arrives, or None if it is lost (counted)."""
        m = self.model(gs)
        if m.perfect:
            return now
        p = self._path(gs, direction)
        if self.in_burst(gs, direction, now):
            self.lost[f"{direction}:{gs}:burst"] += 1
            return None
        if m.loss > 0 and p.rng.random() < m.loss:
            self.lost[f"{direction}:{gs}:loss"] += 1
            return None
        late = m.delay_s + (p.rng.uniform(-m.jitter_s, m.jitter_s) if m.jitter_s > 0 else 0.0)
        return now + max(0.0, late)


def parse_models(loss: list[str], bursts: list[str], delay_ms: float, jitter_ms: float) -> tuple[RadioModel, dict[str, RadioModel]]:
    """Command-line values -> (default model, per-GS models). ``loss`` items: ``P`` or ``GS=P``;
    ``bursts`` items: ``GOOD_S:BAD_S`` or ``GS=GOOD_S:BAD_S``. ``ValueError`` with what is wrong."""
    default: dict[str, float] = {"delay_s": delay_ms / 1000.0, "jitter_s": jitter_ms / 1000.0}
    per: dict[str, dict[str, float]] = {}

    def target(item: str) -> tuple[dict[str, float], str]:
        if "=" in item:
            gs, value = item.split("=", 1)
            return per.setdefault(gs, {}), value
        return default, item

    for item in loss:
        d, value = target(item)
        d["loss"] = float(value)
    for item in bursts:
        d, value = target(item)
        good, _, bad = value.partition(":")
        d["good_s"], d["bad_s"] = float(good), float(bad)
    base = RadioModel(**default)
    return base, {gs: RadioModel(**{**default, **over}) for gs, over in per.items()}
