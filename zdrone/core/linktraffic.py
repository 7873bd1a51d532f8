"""What one end of the secure links heard, by kind of message: what the radio carried, per kind.

The router counts publications and their bytes (``zdrone bench traffic``'s tap), but what is inside a
sealed envelope only its receiver can tell. Each node counts the envelopes it opened (``heard``):
per kind, the messages and their bytes, so that the kinds of one direction add up to the bytes of
its envelopes:

* ``mavlink``: MAVLink frames (the vehicle's stream and replies down, the GS's heartbeats and
  commands up);
* a control message by its tag (``key_grant``, ``handover_request``, ...); an authority status is
  split into ``status`` (the authority itself), ``attestation`` (the drone's signed word, carried
  inside it) and ``audit_head`` (its authority record's newest checkpoint, likewise);
* ``envelope``: the cipher's own bytes, one per envelope (24 for ours: header and tag; none plain);
* ``batch``: a drone's batch's framing (a prefix, then 2 bytes per message), one per batch.

What does not open (no key yet, a forgery, a replay) is not counted here: the router's bytes minus
these are the bundles' framing and whatever was dropped. Pure, no clock.
"""

from __future__ import annotations

import msgspec

from zdrone.core import wire
from zdrone.core.envelope import Opened

_enc = msgspec.msgpack.Encoder()


class LinkTraffic:
    """``kind -> [messages, bytes]`` of the envelopes a node opened (``heard``)."""

    __slots__ = ("kinds",)

    def __init__(self) -> None:
        self.kinds: dict[str, list[int]] = {}

    def add(self, kind: str, nbytes: int, n: int = 1) -> None:
        c = self.kinds.get(kind)
        if c is None:
            self.kinds[kind] = [n, nbytes]
        else:
            c[0] += n
            c[1] += nbytes

    def heard(self, data: bytes, opened: Opened) -> None:
        """Envelope ``data`` opened as ``opened``: its messages by kind, the batch's framing, the cipher's bytes."""
        items = opened.items()
        inner = 0
        for item in items:
            n = len(item.plaintext)
            inner += n
            msg = item.control
            if msg is None:
                self.add("mavlink", n)
            elif isinstance(msg, wire.AuthorityStatus):
                for part, kind in ((msg.attest, "attestation"), (msg.audit, "audit_head")):
                    if part is not None:
                        size = len(_enc.encode(part))
                        self.add(kind, size)
                        n -= size
                self.add("status", n)
            else:
                self.add(type(msg).__struct_config__.tag, n)  # type: ignore[attr-defined]
        if opened.batch:
            self.add("batch", len(opened.plaintext) - inner)
        self.add("envelope", len(data) - len(opened.plaintext))

    def report(self) -> dict[str, list[int]]:
        return {k: list(v) for k, v in sorted(self.kinds.items())}
