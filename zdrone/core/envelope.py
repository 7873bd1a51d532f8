"""The sealed envelope and the secure link: seal, open, replay protection, per-link stats.

Wire format of our envelope (24 bytes added to each plaintext: one frame, or a drone's batch of a
pass's frames to one GS, ``seal_batch``)::

    +-------+----------------------+---------------------------+----------+
    | epoch | counter (56 bit, BE) | ciphertext (= plaintext)  | tag (16) |
    +-------+----------------------+---------------------------+----------+
      1 B          7 B                      n B                   16 B

The AEAD nonce is four zero bytes followed by the 8 header bytes; it never repeats because every
(direction, epoch) has its own key and the counter only grows. The associated data binds a
version label, the key expression, sender, receiver and the header (hence the key epoch), so a
frame moved to another key expression, link or epoch fails to open.

Checks on open, in order; the first failure is returned as ``Dropped(reason)`` and counted, never
raised: envelope well-formed -> known key epoch -> AEAD opens -> not a replay -> inner MAVLink frame
parses and its sysid is the sender's fleet sysid (or the inner control message decodes) -> sender
authorized. A batch (drone -> GS only; ``wire.BATCH_PREFIX``) is authentic or not as a whole (one
AEAD, one counter, one replay check, one TBM observation); its items are then checked one by one as
above, a bad item dropped and counted on its own, the rest delivered in order (``Opened.batch``).
"""

from __future__ import annotations

import base64
import enum
import logging
import struct
from collections import Counter
from dataclasses import dataclass
from typing import Callable, Protocol

import msgspec
from cryptography.exceptions import InvalidTag
from cryptography.fernet import Fernet, InvalidToken
from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305

from zdrone.core import bundle, wire
from zdrone.core.errors import ProtocolError
from zdrone.core.keys import DOWN, UP, KeyChain, LinkKey
from zdrone.core.mavlink import FrameError, FrameHeader, read_header
from zdrone.core.replay import ReplayWindow
from zdrone.core.tbm import TbmSnapshot, TbmThresholds, TimeBetweenMessages

log = logging.getLogger(__name__)

HEADER = struct.Struct(">Q")  # epoch byte << 56 | counter
HEADER_LEN = 8
TAG_LEN = 16
COUNTER_LIMIT = (1 << 56) - 1
#: A sender moves to a new key epoch after this many frames (far below the 2**56 counter space).
DEFAULT_REKEY_AFTER = 1 << 32
AD_LABEL = b"zdrone/v1"
#: The AEAD nonce is these four zero bytes and the 8-byte header.
NONCE_PAD = b"\0\0\0\0"


class DropReason(enum.Enum):
    """Why an incoming envelope was dropped, in the order the checks run."""

    MALFORMED = "malformed"
    UNKNOWN_EPOCH = "unknown_epoch"
    AUTH_FAILED = "auth_failed"
    REPLAY = "replay"
    BAD_INNER = "bad_inner_mavlink"
    SYSID_MISMATCH = "sysid_mismatch"
    UNAUTHORIZED = "unauthorized_sender"


class Dropped(msgspec.Struct, frozen=True):
    """An envelope that failed a check. A value, never an exception."""

    reason: DropReason
    detail: str = ""


class Opened(msgspec.Struct, frozen=True):
    """An authentic, fresh envelope: either a MAVLink frame or a control message."""

    plaintext: bytes
    header: FrameHeader | None  # set for MAVLink frames
    control: wire.Control | None  # set for control messages
    epoch: int
    counter: int
    gap: float | None  # seconds since the previous authentic frame on this link (TBM)
    #: a batch's items, each opened and checked on its own, in order (``plaintext`` is then the batch's)
    batch: tuple["Opened", ...] = ()

    def items(self) -> tuple["Opened", ...]:
        """What the envelope carried, one message each: the batch's items, or itself."""
        return self.batch or (self,)


def associated_data(keyexpr: str, sender: str, receiver: str) -> bytes:
    """The AD prefix of a direction; the 8-byte header is appended per frame."""
    return b"\0".join((AD_LABEL, keyexpr.encode(), sender.encode(), receiver.encode(), b""))


class Cipher(Protocol):
    """A way of sealing frames. ``zdrone`` is ours; ``fernet`` reproduces the paper's numbers."""

    name: str

    def make(self, key: bytes) -> object: ...

    def seal(self, ctx: object, epoch: int, counter: int, ad: bytes, plaintext: bytes) -> bytes: ...

    def parse(self, data: bytes) -> tuple[int, int | None, bytes] | None: ...

    def open(self, ctx: object, data: bytes, ad: bytes) -> bytes | None: ...


class ChaChaCipher:
    """ChaCha20-Poly1305 with the 8-byte epoch/counter header: 24 bytes per frame."""

    name = "zdrone"
    overhead = HEADER_LEN + TAG_LEN

    def make(self, key: bytes) -> ChaCha20Poly1305:
        return ChaCha20Poly1305(key)

    def seal(self, ctx: ChaCha20Poly1305, epoch: int, counter: int, ad: bytes, plaintext: bytes) -> bytes:  # type: ignore[override]
        header = HEADER.pack(((epoch & 0xFF) << 56) | counter)
        return header + ctx.encrypt(NONCE_PAD + header, plaintext, ad + header)

    def parse(self, data: bytes) -> tuple[int, int | None, bytes] | None:
        if len(data) < HEADER_LEN + TAG_LEN + 1:
            return None
        (word,) = HEADER.unpack_from(data)
        return word >> 56, word & COUNTER_LIMIT, data

    def open(self, ctx: ChaCha20Poly1305, data: bytes, ad: bytes) -> bytes | None:  # type: ignore[override]
        header = data[:HEADER_LEN]
        try:
            return ctx.decrypt(NONCE_PAD + header, data[HEADER_LEN:], ad + header)
        except InvalidTag:
            return None


class FernetCipher:
    """The paper's security layer: one Fernet token per frame, no AD, no counter (side-by-side only).

    Adds 90..115 bytes to a 21..50-byte frame. Without a counter it has no replay protection
    beyond what the link's higher layers add; it exists to reproduce the paper's Table 1.
    """

    name = "fernet"

    def make(self, key: bytes) -> Fernet:
        return Fernet(base64.urlsafe_b64encode(key))

    def seal(self, ctx: Fernet, epoch: int, counter: int, ad: bytes, plaintext: bytes) -> bytes:  # type: ignore[override]
        return ctx.encrypt(plaintext)

    def parse(self, data: bytes) -> tuple[int, int | None, bytes] | None:
        return (0, None, data) if len(data) >= 57 else None

    def open(self, ctx: Fernet, data: bytes, ad: bytes) -> bytes | None:  # type: ignore[override]
        try:
            return ctx.decrypt(data)
        except (InvalidToken, ValueError, TypeError):
            return None


class PlainCipher:
    """No security layer at all: the frame as it is. The baseline of ``zdrone bench traffic`` only."""

    name = "plain"

    def make(self, key: bytes) -> None:
        return None

    def seal(self, ctx: None, epoch: int, counter: int, ad: bytes, plaintext: bytes) -> bytes:  # type: ignore[override]
        return plaintext

    def parse(self, data: bytes) -> tuple[int, int | None, bytes] | None:
        return (0, None, data) if data else None

    def open(self, ctx: None, data: bytes, ad: bytes) -> bytes | None:  # type: ignore[override]
        return data


CIPHERS: dict[str, Cipher] = {"zdrone": ChaChaCipher(), "fernet": FernetCipher(), "plain": PlainCipher()}
#: The only cipher a node uses unless the bench harness enabled the others in its own process.
PRODUCTION_CIPHER = "zdrone"
_bench_ciphers = False


class DowngradeRefused(ProtocolError, ValueError):
    """A cipher other than ours was asked for outside the bench harness (a programming error)."""


def enable_bench_ciphers() -> None:
    """Allow the measurement-only ciphers (plain, Fernet) in this process. Called only by the bench
    harness (``zdrone.bench``) and tests: no node command line can select them."""
    global _bench_ciphers
    _bench_ciphers = True


class _RxEpoch:
    __slots__ = ("epoch", "ctx", "window")

    def __init__(self, epoch: int, ctx: object, window: ReplayWindow) -> None:
        self.epoch, self.ctx, self.window = epoch, ctx, window


@dataclass(frozen=True, slots=True)
class LinkStats:
    """Counters of one link, as shown in stats and logs."""

    sent: int
    opened: int
    dropped: dict[str, int]
    tx_epoch: int
    rx_epoch: int
    tbm: TbmSnapshot


class SecureLink:
    """One end of a (drone, gs) link: seals what it sends, opens and checks what it receives.

    ``local``/``peer`` are fleet names; ``role`` is ``"drone"`` or ``"gs"`` (it picks which
    direction this end sends on). ``peer_sysid`` is the MAVLink sysid the peer's frames must carry;
    ``authorize(peer)`` is asked last on every frame. Pure: ``now`` is passed to ``open``.
    """

    def __init__(
        self,
        *,
        key: LinkKey,
        role: str,
        tx_keyexpr: str,
        rx_keyexpr: str,
        peer_sysid: int | None,
        now: float,
        authorize: Callable[[str], bool] | None = None,
        cipher: str = "zdrone",
        window: int = 1024,
        rekey_after: int = DEFAULT_REKEY_AFTER,
        thresholds: TbmThresholds = TbmThresholds(),
    ) -> None:
        if role not in ("drone", "gs"):
            raise ValueError(f"role must be 'drone' or 'gs', not {role!r}")
        if not 1 <= rekey_after <= COUNTER_LIMIT:
            raise ValueError("rekey_after out of range")
        self.key = key
        self.role = role
        self.local, self.peer = (key.drone, key.gs) if role == "drone" else (key.gs, key.drone)
        if cipher != PRODUCTION_CIPHER and not _bench_ciphers:
            raise DowngradeRefused(f"cipher {cipher!r} is for the bench harness only")
        self.cipher = CIPHERS[cipher]
        self._fast = cipher == PRODUCTION_CIPHER  # ChaCha20-Poly1305: ``seal`` and ``open`` take it inline

        self.peer_sysid = peer_sysid
        self.authorize = authorize
        self.rekey_after = rekey_after
        self.window_size = window
        tx_dir, rx_dir = (DOWN, UP) if role == "drone" else (UP, DOWN)
        self._tx_ad = associated_data(tx_keyexpr, self.local, self.peer)
        self._rx_ad = associated_data(rx_keyexpr, self.peer, self.local)
        self._tx_chain = KeyChain.start(key.direction(tx_dir))
        self._tx_ctx = self.cipher.make(self._tx_chain.aead_key())
        self._tx_counter = 0
        self._tx_epoch_bits = (self._tx_chain.epoch & 0xFF) << 56  # the header's epoch byte, in place
        self._rx_chain = KeyChain.start(key.direction(rx_dir))
        self._rx_current = _RxEpoch(0, self.cipher.make(self._rx_chain.aead_key()), ReplayWindow(window))
        self._rx_previous: _RxEpoch | None = None
        self._rx_next: _RxEpoch | None = None  # the peer's next epoch, derived once (see ``_rx_for``)
        self.tbm = TimeBetweenMessages(now, thresholds)
        self.made = now  # when this end made the link (the caller's clock): a keys-lost notice's ``since`` is compared
        self.sent = 0
        self.opened = 0
        self.missing = 0  # authentic frames the peer sent that never came (counters skipped, not filled later)
        self.drops: Counter[DropReason] = Counter()
        #: the key came from a hybrid (ML-KEM-768 + X25519) exchange, or was granted over such a link
        #: (``zdrone.nodes.drone_core``: under the fleet's ``pairing_pq`` only such links carry grants)
        self.hybrid = False

    # ------------------------------------------------------------------ sending
    def seal(self, plaintext: bytes) -> bytes:
        """Seal one MAVLink frame (or control plaintext) for the peer."""
        if not plaintext:
            raise ValueError("nothing to seal")
        if self._tx_counter >= self.rekey_after:
            self._tx_chain.advance()
            self._tx_ctx = self.cipher.make(self._tx_chain.aead_key())
            self._tx_counter = 0
            self._tx_epoch_bits = (self._tx_chain.epoch & 0xFF) << 56
            log.info("link %s->%s: tx rekey to epoch %d", self.local, self.peer, self._tx_chain.epoch)
        if self._fast:  # ChaChaCipher.seal, inline (the per-frame path: no call through the cipher table)
            header = HEADER.pack(self._tx_epoch_bits | self._tx_counter)
            out = header + self._tx_ctx.encrypt(NONCE_PAD + header, plaintext, self._tx_ad + header)  # type: ignore[attr-defined]
        else:
            out = self.cipher.seal(self._tx_ctx, self._tx_chain.epoch, self._tx_counter, self._tx_ad, plaintext)
        self._tx_counter += 1
        self.sent += 1
        return out

    def seal_control(self, msg: wire.Control) -> bytes:
        return self.seal(wire.encode_control(msg))

    def seal_batch(self, plaintexts: list[bytes]) -> bytes:
        """Seal a drone's plaintexts for the GS (a pass's frames and controls, in order) as one
        envelope: one header and tag for all (``wire.BATCH_PREFIX``); a single one is sealed as itself."""
        if self.role != "drone":
            raise ValueError("only a drone seals batches")
        if len(plaintexts) == 1:
            return self.seal(plaintexts[0])
        out = self.seal(wire.BATCH_PREFIX + bundle.pack(plaintexts))
        self.sent += len(plaintexts) - 1  # ``sent`` counts messages
        return out

    # ---------------------------------------------------------------- receiving
    def _drop(self, reason: DropReason, detail: str = "", count: bool = True) -> Dropped:
        if not count:
            return Dropped(reason, detail)
        self.drops[reason] += 1
        log.debug("link %s<-%s: dropped (%s) %s", self.local, self.peer, reason.value, detail)
        return Dropped(reason, detail)

    def _rx_for(self, epoch_byte: int) -> tuple[_RxEpoch | None, bool]:
        cur = self._rx_current
        if epoch_byte == cur.epoch & 0xFF:
            return cur, False
        prev = self._rx_previous
        if prev is not None and epoch_byte == prev.epoch & 0xFF:
            return prev, False
        if epoch_byte == (cur.epoch + 1) & 0xFF:
            return self._next_epoch(), True
        return None, False

    def _next_epoch(self) -> _RxEpoch:
        """The peer's next epoch: key derived and cipher set up once, kept until the peer moves to
        it, so a frame claiming that epoch (authentic or junk) costs one AEAD attempt and no key
        derivation. Its replay window is marked only by authentic frames."""
        nxt = self._rx_next
        if nxt is None:
            cur = self._rx_current
            nxt = self._rx_next = _RxEpoch(cur.epoch + 1, self.cipher.make(self._rx_chain.peek_next()),
                                           ReplayWindow(self.window_size))
        return nxt

    def count_drop(self, dropped: Dropped) -> None:
        """Count a drop that an ``open(..., count=False)`` returned (see ``LinkSlot``)."""
        self.drops[dropped.reason] += 1

    def open(self, data: bytes, now: float, count: bool = True) -> Opened | Dropped:
        """Open and check one received envelope. Never raises on bad input.

        With ``count=False`` a failure before authentication (malformed, unknown epoch, AEAD) is
        returned but not counted: the caller tries another key of the same peer first.
        """
        if self._fast:  # the production cipher: the same checks, its parse and open inline
            return self._open_fast(data, now, count)
        if type(data) is not bytes:
            if not isinstance(data, (bytearray, memoryview)):
                return self._drop(DropReason.MALFORMED, "not bytes", count)
            data = bytes(data)
        parsed = self.cipher.parse(data)
        if parsed is None:
            return self._drop(DropReason.MALFORMED, f"{len(data)} bytes", count)
        epoch_byte, counter, _ = parsed
        rx, is_next = self._rx_for(epoch_byte)
        if rx is None:
            return self._drop(DropReason.UNKNOWN_EPOCH, f"epoch byte {epoch_byte}", count)
        plaintext = self.cipher.open(rx.ctx, data, self._rx_ad)
        if plaintext is None:
            return self._drop(DropReason.AUTH_FAILED, "", count)
        if counter is not None:
            replayed = self._fresh(rx, counter)
            if replayed is not None:
                return replayed
        if is_next:
            self._follow(rx)
        return self._deliver(plaintext, rx.epoch, counter or 0, now)

    def _fresh(self, rx: _RxEpoch, counter: int) -> Dropped | None:
        """The replay check of an authentic envelope's counter, marked in its epoch's window (and the
        frames it skipped counted as missing); a replay is dropped."""
        window = rx.window
        if not window.is_fresh(counter):
            return self._drop(DropReason.REPLAY, f"counter {counter}")
        highest = window.highest
        window.mark(counter)
        if counter > highest + 1:  # the frames between never came (yet): lost on the way
            self.missing += counter - highest - 1
        elif counter < highest and self.missing:  # one of them, late
            self.missing -= 1
        return None

    def _follow(self, rx: _RxEpoch) -> None:
        """The first authentic frame of the peer's new epoch: follow it."""
        self._rx_chain.advance()
        self._rx_previous, self._rx_current, self._rx_next = self._rx_current, rx, None
        log.info("link %s<-%s: rx rekey to epoch %d", self.local, self.peer, rx.epoch)

    def _deliver(self, plaintext: bytes, epoch: int, counter: int, now: float) -> Opened | Dropped:
        """An authentic, fresh envelope's content checked and delivered: a drone's batch item by item,
        or one message; then the sender's authorization, the TBM observation and the count."""
        if plaintext[:1] == wire.BATCH_PREFIX and self.role == "gs":  # a drone's batch: its items one by one
            items = bundle.unpack(plaintext[1:])
            if items is None or len(items) < 2:
                return self._drop(DropReason.BAD_INNER, "batch")
            inner = [self._inner(item) for item in items]
            good = [i for i in inner if not isinstance(i, Dropped)]
            if not good:
                return inner[0]  # type: ignore[return-value]  # each counted by ``_inner``
        else:
            one = self._inner(plaintext)
            if isinstance(one, Dropped):
                return one
            good = [one]
        if self.authorize is not None and not self.authorize(self.peer):
            return self._drop(DropReason.UNAUTHORIZED, self.peer)
        gap = self.tbm.observe(now)
        self.opened += len(good)
        opened = [Opened(p, h, c, epoch, counter, gap) for p, h, c in good]  # type: ignore[misc]
        if len(opened) == 1 and plaintext[:1] != wire.BATCH_PREFIX:
            return opened[0]
        return Opened(plaintext, None, None, epoch, counter, gap, tuple(opened))

    def _open_fast(self, data: bytes, now: float, count: bool = True) -> Opened | Dropped:
        """``open`` for the production cipher: the same checks in the
        same order with the cipher's parse and open taken inline, and a single MAVLink frame (the
        common case) checked without building lists: what the per-frame cost is made of (``zdrone
        bench crypto``: at most twice a raw ChaCha20-Poly1305 encrypt and decrypt)."""
        if type(data) is not bytes:
            if not isinstance(data, (bytearray, memoryview)):
                return self._drop(DropReason.MALFORMED, "not bytes", count)
            data = bytes(data)
        if len(data) < HEADER_LEN + TAG_LEN + 1:
            return self._drop(DropReason.MALFORMED, f"{len(data)} bytes", count)
        header = data[:HEADER_LEN]
        (word,) = HEADER.unpack(header)
        epoch_byte, counter = word >> 56, word & COUNTER_LIMIT
        cur = self._rx_current
        if epoch_byte == cur.epoch & 0xFF:
            rx, is_next = cur, False
        else:
            rx, is_next = self._rx_for(epoch_byte)  # type: ignore[assignment]
            if rx is None:
                return self._drop(DropReason.UNKNOWN_EPOCH, f"epoch byte {epoch_byte}", count)
        try:
            plaintext = rx.ctx.decrypt(NONCE_PAD + header, data[HEADER_LEN:], self._rx_ad + header)  # type: ignore[attr-defined]
        except InvalidTag:
            return self._drop(DropReason.AUTH_FAILED, "", count)
        window = rx.window
        if counter == window.highest + 1:  # the next one, in order (the common case): fresh, nothing missed
            window.mark(counter)
        else:
            replayed = self._fresh(rx, counter)
            if replayed is not None:
                return replayed
        if is_next:
            self._follow(rx)
        first = plaintext[:1]
        if first == b"\xfd" or first == b"\xfe":  # one MAVLink frame: the common case
            try:
                hdr = read_header(plaintext)
            except FrameError as exc:
                return self._drop(DropReason.BAD_INNER, str(exc))
            if self.peer_sysid is not None and hdr.sysid != self.peer_sysid:
                return self._drop(DropReason.SYSID_MISMATCH, f"sysid {hdr.sysid} != {self.peer_sysid}")
            if self.authorize is not None and not self.authorize(self.peer):
                return self._drop(DropReason.UNAUTHORIZED, self.peer)
            gap = self.tbm.observe(now)
            self.opened += 1
            return Opened(plaintext, hdr, None, rx.epoch, counter, gap)
        return self._deliver(plaintext, rx.epoch, counter, now)  # a batch, or a control message

    def _inner(self, plaintext: bytes) -> tuple[bytes, FrameHeader | None, wire.Control | None] | Dropped:
        """One message of an authentic envelope checked: a MAVLink frame of the peer's sysid, or a
        control message that decodes (a failure counted)."""
        if plaintext[:1] in (b"\xfd", b"\xfe"):
            try:
                header = read_header(plaintext)
            except FrameError as exc:
                return self._drop(DropReason.BAD_INNER, str(exc))
            if self.peer_sysid is not None and header.sysid != self.peer_sysid:
                return self._drop(DropReason.SYSID_MISMATCH, f"sysid {header.sysid} != {self.peer_sysid}")
            return plaintext, header, None
        try:
            return plaintext, None, wire.decode_control(plaintext)
        except (msgspec.DecodeError, msgspec.ValidationError, ValueError) as exc:
            return self._drop(DropReason.BAD_INNER, f"control: {exc}")

    def stats(self, now: float) -> LinkStats:
        return LinkStats(
            self.sent,
            self.opened,
            {r.value: self.drops[r] for r in DropReason},
            self._tx_chain.epoch,
            self._rx_current.epoch,
            self.tbm.snapshot(now),
        )


