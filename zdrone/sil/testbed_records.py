"""The testbed's typed event records: the attacker's (``zdrone sil rogue``) and the emulated radio's
(radio links brought up and down, links a scenario cut). Not the product's: importing this module
registers them as the ``testbed`` vocabulary of ``zdrone.core.records``, so that the testbed's
readers decode them; the nodes never write them."""

from __future__ import annotations

import msgspec

from zdrone.core.records import Closed, Position, Record, Suppressed, register_vocabulary

__all__ = ["TESTBED_RECORDS"]


# ----------------------------------------------------------------------------- the attacker
class RogueReady(Record, frozen=True, tag="ready"):
    """The attacker is set up (``wait_go``: it waits for its signal to start)."""

    wait_go: bool


class RogueGo(Record, frozen=True, tag="go"):
    """The attacker got its signal to start."""


class RogueNoGo(Record, frozen=True, tag="no_go"):
    """The attacker never got its signal (``stopped``: it was told to stop first)."""

    stopped: bool


class RouterAcceptedWrongPassword(Record, frozen=True, tag="router_accepted_wrong_password"):
    """The router let the attacker in with a wrong password (a finding)."""


class RouterRefused(Record, frozen=True, tag="router_refused"):
    """The router refused the attacker's wrong password for ``user``."""

    user: str


class PairAttempt(Record, frozen=True, tag="pair_attempt"):
    """The attacker's pairing try: ``answered`` replies that were not errors."""

    answered: int


class UnauthorizedAttempt(Record, frozen=True, tag="unauthorized_attempt"):
    """An unauthorized GS's try: what it got back."""

    pair_answered: int
    pair_refused: int
    linkkey_replies: int


class ForgedReply(Record, frozen=True, tag="forged_reply"):
    """The attacker answered ``asker``'s key query for ``drone`` with forged replies."""

    drone: str
    asker: str
    replies: int


class NothingCaptured(Record, frozen=True, tag="nothing_captured"):
    """The attacker captured nothing to replay."""


class Captured(Record, frozen=True, tag="captured"):
    """The attacker captured ``what`` (``bytes_`` long) to replay."""

    what: str
    bytes_: int = msgspec.field(name="bytes")


class FloodStart(Record, frozen=True, tag="flood_start"):
    """The attacker starts flooding at ``target_rate`` per second."""

    target_rate: float


class RoguePairFailed(Record, frozen=True, tag="pair_failed"):
    """The attacker's pairing failed; ``refusals``: the drone's answers."""

    refusals: tuple[str, ...]


class PairedAs(Record, frozen=True, tag="paired_as"):
    """The attacker paired, claiming to be GS ``gs``."""

    gs: str


class TlsAttempt(Record, frozen=True, tag="tls_attempt"):
    """The no-cert attacker tried the TLS router with ``attempt`` (no_certificate, other_ca): ``result``."""

    attempt: str
    result: str


class WordCaptured(Record, frozen=True, tag="word_captured"):
    """The attacker read one of the drone's signed words on its authority (``AuthorityAttestation``) on
    its way to the viewer: the first it saw of this ``owner`` and ``epoch`` (the drone's ``at`` and ``seq``)."""

    owner: str | None
    epoch: int
    state: str
    at: float
    seq: int


class StampPut(Record, frozen=True, tag="stamp_put"):
    """The attacker put a revision stamp signed by ``gs`` (its own key) naming revision ``number``,
    dated ``wall`` (time of day), vouching for ``drones``, on ``gs``'s own revision key."""

    gs: str
    number: int
    wall: float
    drones: tuple[str, ...]


# ----------------------------------------------------------------------------- the emulated radio
class RadioLinkChanged(Record, frozen=True, tag="radio_link"):
    """The testbed brought site ``site``'s radio link up or down, from the vehicle's true ``position``."""

    site: str
    up: bool
    position: Position | None


class LinkFault(Record, frozen=True, tag="link_fault"):
    """A scenario cut (or mended) a testbed link (``backhaul-site-1-site-2``, or a site's radio)."""

    link: str
    up: bool


#: the testbed's records (the attacker's ``attack_done`` has fields of its own per attack: untyped)
TESTBED_RECORDS: tuple[type[Record], ...] = (
    Closed, Suppressed, RogueReady, RogueGo, RogueNoGo, RouterAcceptedWrongPassword, RouterRefused, PairAttempt,
    UnauthorizedAttempt, ForgedReply, NothingCaptured, Captured, FloodStart, RoguePairFailed, PairedAs,
    TlsAttempt, RadioLinkChanged, LinkFault, WordCaptured, StampPut,
)
register_vocabulary("testbed", TESTBED_RECORDS)
