"""A GS's signed word that it restarted and holds none of its earlier link keys: its drones' owners
share keys with it again, and each drone takes the new key at once, on the owner's grant.

Theory of operation
-------------------
A GS keeps its link keys in memory only. When it restarts, every drone still holds the old key of
link (drone, GS) and lists the GS as linked, so no owner shares a key with it, and the drone hears
the GS only where its coverage holds the drone: a pairing from elsewhere is never proven and
expires. The GS therefore publishes, for ``NOTICE_FOR_S`` after it starts, a **keys-lost notice**:
"I, GS ``gs``, hold no link key made before ``since`` (my start's time of day); signed at ``wall``",
signed with its signing key in force, on its own revision key (only it may put there; the router
budgets that key, and every node hears it, ``zdrone.fleet.revisions``).

* **Whose word.** Only ``gs``'s: the signature is checked against its signing key in the fleet in
  force; a revoked GS's notice is refused. Any GS may carry it (it is ``gs``'s word, not the carrier's).
* **The owner** (``gs.linking``): a notice from a GS authorized for the drone moves that GS's key
  share back to ``NONE`` once per ``since`` (a re-published notice of the same start changes nothing
  more) and the owner asks that GS for a fresh key as for any share, even though the drone still
  lists it. The grant carries the newest notice heard (``KeyGrant.lost``).
* **The drone** (``judge``): it takes a granted key in place of the GS's live key (wiping the old
  one) only if the notice is that GS's, the GS is authorized for the drone, the notice was signed
  within ``FRESH_S`` of the drone's time of day (and not more than ``AHEAD_S`` ahead of it), and the
  drone's live key of that GS is older than ``since`` by ``SKEW_S`` at least (a key made after the
  restart is never replaced by the notice). Otherwise the grant is refused with the reason.
  Without a notice, a granted key for a link that has one stays a candidate the GS must prove, as
  before.

What it gives a hostile owner: nothing it does not hold already. An owner learns every key it grants;
the notice only lets it replace a key the GS itself made before its restart, and only while the
notice is fresh. A replayed notice does not reach past a key made after the restart.

Pure: no clock, no IO; times of day come in as arguments.
"""

from __future__ import annotations

from dataclasses import dataclass

import msgspec

from zdrone.core.fleet import Fleet
from zdrone.core.keys import SigningKey

DOMAIN = b"zdrone keys lost v1\n"
#: a put on a GS's revision key that is a keys-lost notice starts with these bytes
MAGIC = b"ZDKL1"
#: a notice signed longer ago than this (drone's time of day) is refused: stale
FRESH_S = 30.0
#: a notice dated further ahead of the receiver's clock than this is refused (clocks disagree)
AHEAD_S = 5.0
#: the drone's live key must be older than the notice's ``since`` by this much to be replaced
SKEW_S = 1.0
#: a restarted GS publishes its notice this long after its start (re-signed every stamp period)
NOTICE_FOR_S = 60.0


class KeysLostNotice(msgspec.Struct, frozen=True, array_like=True, forbid_unknown_fields=True):
    """GS ``gs`` holds no link key made before ``since`` (time of day, s); signed at ``wall``."""

    gs: str
    since: float
    wall: float
    signature: bytes = b""

    def signed_bytes(self) -> bytes:
        return DOMAIN + msgspec.msgpack.encode(msgspec.structs.replace(self, signature=b""))


_DECODER = msgspec.msgpack.Decoder(KeysLostNotice)


@dataclass(frozen=True, slots=True)
class NoticeRefused:
    """Why a notice does not let a grant replace a live key (``grant_refused:keys_lost_<reason>``)."""

    reason: str  # signature | other_gs | unauthorized | stale | ahead | since_ahead | key_newer


def make_notice(gs: str, since: float, wall: float, key: SigningKey) -> bytes:
    """GS ``gs``'s notice, signed with its signing key, as it goes on its revision key."""
    notice = KeysLostNotice(gs, round(since, 3), round(wall, 3))
    signed = msgspec.structs.replace(notice, signature=key.sign(notice.signed_bytes()))
    return MAGIC + msgspec.msgpack.encode(signed)


def is_notice(data: bytes | None) -> bool:
    return data is not None and data.startswith(MAGIC)


def check_notice(data: bytes, fleet: Fleet) -> KeysLostNotice | None:
    """The notice if it decodes and is signed by its GS's signing key in force in ``fleet`` (a GS of
    the fleet, not revoked); else None. Never raises."""
    if not is_notice(data):
        return None
    try:
        notice = _DECODER.decode(data[len(MAGIC):])
    except (msgspec.DecodeError, msgspec.ValidationError):
        return None
    return notice if fleet.gs_signed(notice.gs, notice.signed_bytes(), notice.signature) else None


def fresh(notice: KeysLostNotice, wall: float) -> NoticeRefused | None:
    """``stale`` or ``ahead`` at the time of day ``wall``, ``since_ahead`` if it speaks of a start after
    its own signature (a clock stepped back, or a thief's key: it would deafen owners to the GS's next
    start and open keys made after it); None if fresh."""
    if notice.since > notice.wall:
        return NoticeRefused("since_ahead")
    if notice.wall > wall + AHEAD_S:
        return NoticeRefused("ahead")
    if notice.wall < wall - FRESH_S:
        return NoticeRefused("stale")
    return None


def heard(data: bytes, fleet: Fleet, wall: float) -> KeysLostNotice | NoticeRefused:
    """A notice as anyone takes it at the time of day ``wall``: its GS's signature (``check_notice``),
    then ``fresh``; the notice, or why not."""
    notice = check_notice(data, fleet)
    if notice is None:
        return NoticeRefused("signature")
    return fresh(notice, wall) or notice


def judge(data: bytes, fleet: Fleet, drone: str, gs: str, wall: float, key_wall: float | None) -> KeysLostNotice | NoticeRefused:
    """The drone's judgement of the notice a grant for ``gs`` carries: the notice if the granted key
    may replace the live key of ``gs`` (made at the drone's time of day ``key_wall``; None: no live
    key), else why not."""
    notice = heard(data, fleet, wall)
    if isinstance(notice, NoticeRefused):
        return notice
    if notice.gs != gs:
        return NoticeRefused("other_gs")
    if not fleet.is_authorized(drone, gs):
        return NoticeRefused("unauthorized")
    if key_wall is not None and key_wall > notice.since - SKEW_S:
        return NoticeRefused("key_newer")
    return notice


__all__ = ["AHEAD_S", "FRESH_S", "KeysLostNotice", "MAGIC", "NOTICE_FOR_S", "NoticeRefused", "SKEW_S",
           "check_notice", "fresh", "heard", "is_notice", "judge", "make_notice"]
