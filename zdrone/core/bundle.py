"""Envelope bundles: the sealed envelopes a drone sends one GS in one pass, in one publication.

Theory of operation
-------------------
A drone says most of what it says at the same instants: its autopilot streams a dozen telemetry
messages due on the same second, and a status, a catch-up or a reject come in the same pass as the
frames around them. Published one envelope each, a fleet of 300 drones made some 13 000 Zenoh
messages a second, and every router on the way, the drones' host and the GSs' host paid for each
one (issue 30). The drone's adapter therefore gathers the envelopes of one pass per GS and publishes
them as one **bundle** on the GS's ``down`` key; the GS opens every envelope in it on its own.

A bundle is a byte string of items, each a 2-byte big-endian length (1..``MAX_ITEM``) followed by
that many bytes; at least one item, nothing after the last. The bundle adds no security of its own
and needs none: every item is a sealed envelope that authenticates itself (AEAD, replay window), so
whoever splits, reorders, drops or merges bundles on the way can do no more than with envelopes
sent one by one. A receiver refuses a bundle longer than ``MAX_BUNDLE`` by its length before
copying it (the runtime's per-kind limit), and one that does not parse as a whole (``unpack`` gives
None: counted, never raised). ``BundleWriter`` is the sender's side: items in order, a bundle closed
when the next item would take it over ``MAX_BUNDLE``.

Pure: no I/O; the adapter decides when a pass ends (``BundleWriter.take``).
"""

from __future__ import annotations

#: An item's length fits in two bytes; a sealed envelope is far below this.
MAX_ITEM = 0xFFFF
#: A bundle's bytes at most, on the wire and as a receiver accepts it: a dozen telemetry frames
#: (about 70 bytes sealed each) and a status fit many times over, and a single publication stays
#: well inside one Zenoh batch and a slow radio's burst.
MAX_BUNDLE = 4096
_LEN = 2


def pack(items: list[bytes]) -> bytes:
    """One bundle of ``items`` (each 1..``MAX_ITEM`` bytes). Programming errors raise."""
    if not items:
        raise ValueError("an empty bundle")
    out = bytearray()
    for item in items:
        if not 0 < len(item) <= MAX_ITEM:
            raise ValueError(f"bundle item of {len(item)} bytes")
        out += len(item).to_bytes(_LEN, "big")
        out += item
    return bytes(out)


def unpack(data: bytes) -> list[bytes] | None:
    """The items of a bundle, or None if ``data`` is not one bundle exactly (empty, an item of
    length 0, a length past the end, bytes after the last item). Never raises on bytes."""
    items: list[bytes] = []
    i, end = 0, len(data)
    if end == 0:
        return None
    while i < end:
        if i + _LEN > end:
            return None
        n = int.from_bytes(data[i:i + _LEN], "big")
        i += _LEN
        if n == 0 or i + n > end:
            return None
        items.append(data[i:i + n])
        i += n
    return items


class BundleWriter:
    """The envelopes waiting per destination for the end of the pass, in order."""

    __slots__ = ("limit", "_items", "_size", "_ready")

    def __init__(self, limit: int = MAX_BUNDLE) -> None:
        if limit < _LEN + 1:
            raise ValueError("bundle limit too small")
        self.limit = limit
        self._items: dict[str, list[bytes]] = {}
        self._size: dict[str, int] = {}
        self._ready: list[tuple[str, bytes]] = []  # bundles closed early (full), in order

    def add(self, dest: str, item: bytes) -> None:
        """Queue ``item`` for ``dest``; the bundle waiting for ``dest`` is closed first if ``item``
        would take it over the limit. An item too large for any bundle is a programming error."""
        need = _LEN + len(item)
        if need > self.limit:
            raise ValueError(f"an item of {len(item)} bytes exceeds the bundle limit {self.limit}")
        if self._size.get(dest, 0) + need > self.limit:
            self._ready.append((dest, pack(self._items.pop(dest))))
            del self._size[dest]
        self._items.setdefault(dest, []).append(item)
        self._size[dest] = self._size.get(dest, 0) + need

    def pending(self) -> bool:
        return bool(self._items or self._ready)

    def take(self) -> list[tuple[str, bytes]]:
        """Every bundle to send now, ``(dest, bundle)``, each destination's in order; empties the writer."""
        out = self._ready + [(dest, pack(items)) for dest, items in self._items.items()]
        self._ready, self._items, self._size = [], {}, {}
        return out
