"""Which UDP peer is the autopilot: the vehicle link takes frames from that endpoint only (sans-IO).

Over TCP or a serial line the autopilot is the other end of the wire. Over UDP anyone on the
companion host (or the network) can write datagrams into the companion's vehicle socket, and
pymavlink takes them all: a local process could play the autopilot (a HEARTBEAT of its own, forged
positions, a fake answer to the failsafe) and, on a listening socket, even become the address the
companion sends to (issue 29). ``AutopilotEndpoint`` decides, per datagram, whether it comes from
the autopilot:

* **fixed** (``udpout:HOST:PORT``): the autopilot is the address the companion sends to; a datagram
  from any other address is dropped (``foreign_endpoint``).
* **learned** (``udpin:HOST:PORT``, the companion listening, as on PX4's onboard link): the first
  address that proves to be the autopilot becomes its endpoint: a datagram holding a HEARTBEAT of an
  autopilot with the drone's fleet sysid and the autopilot's component (``heartbeat``), or a frame
  signed with the link's key (``signed``: only the autopilot holds it). Until then every datagram is
  dropped (``before_autopilot``); afterwards any other address's (``foreign_endpoint``). "Signed"
  means signed on the autopilot's own stream (its ids, not a stream the companion emits) with a fresh
  timestamp (``FcSigning.proves``): the companion's own signed frames sent straight back (a
  reflection), or a copy of an autopilot frame the link already took, prove nothing. An endpoint
  found by its HEARTBEAT alone gives way once, to an address that proves itself by signature
  (``moved_to_signed``): someone who raced the real autopilot with its ids is overruled by the one
  holding the key. The companion sends only to the endpoint (``destinations``), and while it is
  known by HEARTBEAT alone, to the other addresses that claimed to be the autopilot as well (so
  the real one receives signed traffic and signs back: an autopilot signs once signed traffic reaches
  it; nothing secret goes to them: the link never re-sends a stored key over a learned endpoint, and
  nothing they can send back from it proves anything).

Every drop is counted by reason; ``status`` gives the endpoint, how it was found and the counters.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable
from typing import Any

from zdrone.core.mavlink import MAGIC_V2

log = logging.getLogger(__name__)

MSG_HEARTBEAT = 0
MAV_AUTOPILOT_INVALID = 8
AUTOPILOT_COMPID = 1
#: Addresses that claimed to be the autopilot remembered at most (the rest are only counted).
MAX_CLAIMANTS = 4

Address = tuple[Any, ...]


def autopilot_heartbeat(frame: bytes, sysid: int) -> bool:
    """The frame is a MAVLink 2 HEARTBEAT of an autopilot (not MAV_AUTOPILOT_INVALID) from ``sysid`` and
    the autopilot's component. Its checksum was checked by the framing (``split_frames``)."""
    if len(frame) < 12 or frame[0] != MAGIC_V2:
        return False
    msgid = frame[7] | (frame[8] << 8) | (frame[9] << 16)
    if msgid != MSG_HEARTBEAT or frame[5] != sysid or frame[6] != AUTOPILOT_COMPID:
        return False
    payload = frame[10:10 + frame[1]]
    autopilot = payload[5] if len(payload) > 5 else 0  # custom_mode (4), type (1), autopilot (1): zeros truncated
    return autopilot != MAV_AUTOPILOT_INVALID


class AutopilotEndpoint:
    """The autopilot's UDP endpoint: fixed, or learned from the first datagram that proves it."""

    def __init__(self, sysid: int, fixed: Address | None = None,
                 signed_by_us: Callable[[bytes], bool] = lambda frame: False) -> None:
        self.sysid = sysid
        self.address: Address | None = fixed
        self.how: str | None = "fixed" if fixed is not None else None
        self.signed_by_us = signed_by_us
        self.claimants: list[Address] = []  # other addresses that sent the autopilot's HEARTBEAT
        self.counters: Counter[str] = Counter()

    @property
    def learned(self) -> bool:
        return self.how != "fixed"

    def admit(self, address: Address, frames: list[bytes]) -> str | None:
        """None to take the datagram from ``address`` (its ``frames``), else the reason it is dropped."""
        if address == self.address:
            if self.how == "heartbeat" and any(self.signed_by_us(f) for f in frames):
                self.how = "signed"  # the endpoint found by HEARTBEAT signs with our key: proven
                log.info("vehicle link: the autopilot's endpoint %s signs with the link's key", _show(address))
            self.counters["taken"] += 1
            return None
        if self.how == "fixed" or self.how == "signed":
            return self._drop("foreign_endpoint", address)
        if any(self.signed_by_us(f) for f in frames):
            was = self.address
            self.address, self.how = address, "signed"
            if address in self.claimants:
                self.claimants.remove(address)
            if was is not None:
                self.counters["moved_to_signed"] += 1
                log.warning("vehicle link: %s signs with the link's key: it is the autopilot, not %s (which sent its "
                            "HEARTBEAT first)", _show(address), _show(was))
            else:
                log.info("vehicle link: the autopilot is at %s (signed)", _show(address))
            self.counters["taken"] += 1
            return None
        claims = any(autopilot_heartbeat(f, self.sysid) for f in frames)
        if self.address is None and claims:
            self.address, self.how = address, "heartbeat"
            log.info("vehicle link: the autopilot is at %s (its HEARTBEAT)", _show(address))
            self.counters["taken"] += 1
            return None
        if claims and address not in self.claimants and len(self.claimants) < MAX_CLAIMANTS:
            self.claimants.append(address)
            log.warning("vehicle link: %s also sends the autopilot's HEARTBEAT (%d/1); the autopilot is at %s",
                        _show(address), self.sysid, _show(self.address))
        return self._drop("before_autopilot" if self.address is None else "foreign_endpoint", address)

    def destinations(self) -> list[Address]:
        """Where the companion's frames go: the endpoint, and while it is known by HEARTBEAT alone the
        other claimants too (only the autopilot can answer them signed: the link sends them there only
        while it holds a key)."""
        if self.address is None:
            return []
        return [self.address] + (self.claimants if self.how == "heartbeat" else [])

    def _drop(self, reason: str, address: Address) -> str:
        self.counters[f"dropped:{reason}"] += 1
        n = self.counters[f"dropped:{reason}"]
        if n <= 3 or n & (n - 1) == 0:  # the first few, then at powers of two
            log.warning("vehicle link: datagram from %s dropped (%s, %d so far)", _show(address), reason, n)
        return reason

    def status(self) -> dict[str, Any]:
        return {"address": _show(self.address) if self.address else None, "how": self.how,
                "claimants": [_show(a) for a in self.claimants], "counters": dict(self.counters)}


def _show(address: Address | None) -> str:
    return "none" if address is None else ":".join(str(p) for p in address[:2])
