"""A node's fleet revisions over Zenoh: hear them, check them, keep the latest, hand it on.

Theory of operation
-------------------
Every node (drone, GS) holds a ``RevisionKeeper``: the base fleet (``fleet.json5`` of its bundle),
the revision in force and its bytes. Revisions travel on one key per sender,
``keyexprs.revision(<gs>)`` (``zdrone-fleet/revision/<gs>``): the router lets GS ``g`` put and answer on
its own key only and budgets each key on its own (``fleet/routerconfig.py``), so a flood with one
credential never starves the revisions of the others. A node hears them three ways:

* a **push**: every GS re-publishes the revision it holds every ``PUSH_PERIOD_S``, and at once when
  it takes a new one (``zdrone fleet publish`` puts one as its GS, on that GS's key). A push is one
  put that the router fans out: O(nodes) messages per period for the fleet, whatever its size;
* the **reply to its query** on ``keyexprs.revision_all()``: only GSs declare the queryable (a drone
  never answers, so a query costs one reply per GS, not one per node). A node asks at start,
  whenever it comes back in reach (one of its router paths (re)connected, or the testbed's coverage
  let it hear a GS again: looked at every ``REACH_LOOK_S``), and then every ``ASK_PERIOD_S``;
  replies are not consolidated: a stale reply from a revoked GS is refused (``stale``/``replayed``)
  and the newest wins;
* the node's own durable copy at start (``load_fleet``: beside ``fleet.json5`` or in
  ``$ZDRONE_STATE_DIR``).

So a drone out of reach for 30 s applies the revision once it is back within the round trip of
the query it sends then (at most ``REACH_LOOK_S`` after the path or the radio returned), and within
one push period (``PUSH_PERIOD_S``) at worst, if that query or its replies are lost.

A node's own traffic stays inside the router's budgets: a GS's puts are ``PUSH_GAP_S`` apart at
least (two of the router's intervals on its key), a node's queries ``ASK_GAP_S`` apart (a query due
sooner waits for it), so the router never drops an honest one.

``offer(data)`` checks the bytes (``zdrone.core.revision.check_revision``: fleet key, signature,
number above the one in force, no revocation undone); the bytes of the revision in force heard again
are ``replayed`` without checking the signature again (they were checked when taken); a refusal is
counted by reason and never raised; an acceptance is written durably (``revision.json`` in the
state directory if the node runs under ``zdrone service``, else in its bundle folder) before the
node applies the new effective fleet.

A GS's push starts with its signed **revision stamp** ("GS g holds revision N at time T and vouches
for drones D", ``zdrone.core.revision.make_push``; D: ``drones()``, those it is authorized for in the
revision it holds), pushed every ``STAMP_PERIOD_S`` (alone, or with the revision every
``PUSH_PERIOD_S``). A revision's bytes renew nothing (anyone may replay them); a drone's owner lease
is renewed only by a stamp naming the drone from a GS authorized for it other than the owner
(``zdrone.core.lease``). The channel hands its node the last stamp *published* on a GS's own key
(``take_stamp``); a query's reply comes labelled ``fleet``, not by its sender, so a stamp in one is
dropped. The node's core checks it.

A GS also puts its signed **keys-lost notice** on its own key for ``keyslost.NOTICE_FOR_S`` after it
starts, every ``NOTICE_PERIOD_S`` (``zdrone.core.keyslost``): the channel hands a notice heard to its
node (``take_notice``; a GS's core checks it, a drone ignores it) and keeps no revision from it.
"""

from __future__ import annotations

import logging
import os
from collections import Counter
from pathlib import Path
from typing import Any, Callable, Sequence

from zdrone.core import keyslost
from zdrone.core import records as rec
from zdrone.core.fleet import Fleet
from zdrone.core.revision import (Revision, RevisionAccepted, RevisionRefusal, RevisionRefused, RevisionResult,
                             check_revision, encode_revision, make_push, split_push)
from zdrone.core.keys import SigningKey
from zdrone.core.errors import ConfigError
from zdrone.fleet import keyexprs
from zdrone.fleet.files import (REVISION_FILE, STATE_DIR_ENV, fleet_path, load_base_fleet, load_revision, read_revisions,
                    write_durably)
from zdrone.fleet.routerconfig import REVISION_MAX_BYTES, REVISION_MAX_HZ, REVISION_QUERY_HZ

log = logging.getLogger(__name__)

#: A node asks for the latest revision this often (and at start, and when it comes back in reach).
ASK_PERIOD_S = 30.0
#: A node's revision queries are this far apart at least (the router takes ``REVISION_QUERY_HZ``).
ASK_GAP_S = 2.0 / REVISION_QUERY_HZ
#: How long a revision query waits for its replies.
ASK_TIMEOUT_S = 1.0
#: A GS re-publishes the revision it holds this often (and at once when it takes a new one).
PUSH_PERIOD_S = 10.0
#: A GS pushes its signed stamp this often (with the revision when that is due, else alone: ~100 B):
#: a drone's owner lease is renewed by the stamps of the other GSs (``Fleet.revision_lease``)
STAMP_PERIOD_S = 5.0
#: A GS puts its keys-lost notice this often while it publishes one (``zdrone.core.keyslost``), its first
#: ``NOTICE_BURST`` a put gap apart (a revision push or stamp that is due goes first)
NOTICE_PERIOD_S, NOTICE_BURST = 2.5, 5
#: A GS's revision puts are this far apart at least: two of the router's intervals on its key
#: (``REVISION_MAX_HZ``), so that a router that stalls and processes two back to back drops neither.
PUSH_GAP_S = 2.0 / REVISION_MAX_HZ
#: How often a node looks whether it came back in reach (a path reconnected, the radio returned).
REACH_LOOK_S = 1.0
#: Revision queries a GS answers per loop turn at most (the rest wait in the queryable's ring).
ANSWERS_PER_TURN = 16
#: The largest revision a node takes (the router's size limit on revision keys).
MAX_REVISION_BYTES = REVISION_MAX_BYTES


class RevisionKeeper:
    """The revision in force at one node, and what was refused (``counters``)."""

    def __init__(self, fleet_dir: str | Path, name: str = "", base: Fleet | None = None) -> None:
        """``base``: ``fleet.json5`` as the node's runtime already parsed it (else parsed here)."""
        self.fleet_dir, self.name = Path(fleet_dir), name
        self.base: Fleet = load_base_fleet(fleet_dir) if base is None else base
        self.current: Revision | None = load_revision(fleet_dir, self.base)
        self.data: bytes | None = encode_revision(self.current) if self.current is not None else None
        self.counters: Counter[str] = Counter()

    @property
    def number(self) -> int:
        return self.current.number if self.current is not None else 0

    def store_path(self) -> Path:
        state = os.environ.get(STATE_DIR_ENV)
        return (Path(state) if state else fleet_path(self.fleet_dir).parent) / REVISION_FILE

    def offer(self, data: bytes | None) -> RevisionResult:
        """Check ``data``; keep it (durably) if it is the next revision in force."""
        if data is None or len(data) > MAX_REVISION_BYTES:
            self.counters["refused:oversize"] += 1
            return RevisionRefused(RevisionRefusal.MALFORMED)
        if data == self.data:  # the revision in force again (a GS's push): its signature was checked when taken
            self.counters["refused:replayed"] += 1
            return RevisionRefused(RevisionRefusal.REPLAYED, self.number)
        got = check_revision(data, self.base, self.current)
        if isinstance(got, RevisionRefused):
            self.counters[f"refused:{got.reason.value}"] += 1
            return got
        try:  # kept before it is applied; a folder that cannot take it is counted, the revision applied all the same
            write_durably(self.store_path(), data, writer=f"{self.name}.{os.getpid()}")
            os.chmod(self.store_path(), 0o644)
        except OSError as exc:
            self.counters["store_failed"] += 1
            log.error("fleet revision %d not kept in %s: %s", got.revision.number, self.store_path(), exc)
        self.current, self.data = got.revision, data
        self.counters["applied"] += 1
        log.warning("fleet revision %d applied (revoked: %s)", got.revision.number,
                    ", ".join(got.revision.changes.revoked) or "none")
        return got

    def stats(self) -> dict[str, object]:
        return {"number": self.number, **dict(self.counters)}


#: the inbox kinds of revision traffic: a publication, a query's reply
PUBLISHED, REPLY = "revision", "revision_reply"
KINDS = (PUBLISHED, REPLY)
#: refusals of one reason written to the event log at most (all are counted)
LOGGED_PER_REASON = 5


class RevisionChannel:
    """A node's revision traffic on its runtime (``zdrone.net.runtime.NodeRuntime``): the
    subscription to every sender's key, its queries, the keeper; for a GS (``publisher``) also the
    queryable on its own key and its pushes. The node's loop hands it the inbox items of ``KINDS``
    (``on_inbox``) and calls ``serve(now)`` every turn. ``in_reach`` (the testbed's coverage: can the
    node hear any GS now?) joins the paths' connectivity in telling when the node came back in reach."""

    def __init__(self, rt: Any, fleet_dir: str | Path, publisher: bool, write_applied: bool = False,
                 in_reach: Callable[[], bool] | None = None, signing: Callable[[], SigningKey | None] | None = None,
                 wall: Callable[[], float] | None = None, drones: Callable[[], Sequence[str]] | None = None,
                 notice: Callable[[], bytes | None] | None = None) -> None:
        """``signing``: the GS's signing key in force (its pushes carry a stamp signed with it);
        ``wall``: the time of day (the stamp's); ``drones``: the drones its stamp names (those it is
        authorized for in the revision it holds; None: none); ``notice``: the GS's keys-lost notice to
        put now, if any (``zdrone.core.keyslost``: for a while after its start)."""
        self.rt = rt
        self.notice = notice
        self.heard_notice: bytes | None = None  # the last keys-lost notice heard (``take_notice``)
        self._next_notice = 0.0
        self.signing, self.wall, self.drones = signing, wall, drones
        self.stamp: bytes | None = None  # the stamp of the last push heard (``take_stamp``)
        self.keeper = RevisionKeeper(fleet_dir, rt.name, getattr(rt, "base_fleet", None))
        self.write_applied = write_applied  # the drone's core writes its own record
        self.in_reach = in_reach
        rt.subscribe(keyexprs.revision_all(), PUBLISHED, keyexprs.gs_of, limit=MAX_REVISION_BYTES)
        self.own = keyexprs.revision(rt.name) if publisher else None
        self.queries = rt.queryable(self.own) if self.own is not None else None
        self._next_ask, self._last_ask = 0.0, float("-inf")
        self._next_push, self._last_push = 0.0, float("-inf")
        self._next_stamp = 0.0
        self._next_look, self._reach = 0.0, 0

    def on_inbox(self, kind: str, data: Any) -> RevisionResult:
        """A publication's bytes, or a reply's ``(ok, err)``: checked and kept (``RevisionKeeper.offer``).
        A GS pushes a new one it took at once (within ``PUSH_GAP_S`` of its last push)."""
        if kind == REPLY:
            ok, _err = data
            if ok is None:  # an error or an oversize reply is counted
                self.keeper.counters["reply_error"] += 1
                return RevisionRefused(RevisionRefusal.MALFORMED)
            data = ok
        if kind == PUBLISHED and keyslost.is_notice(data):  # a GS's keys-lost notice: for its node's core
            self.heard_notice = data
            self.keeper.counters["keys_lost_notice"] += 1
            return RevisionRefused(RevisionRefusal.REPLAYED, self.keeper.number)  # the revision held is unchanged
        if data is not None:
            stamp, data = split_push(data)
            self.stamp = stamp if kind == PUBLISHED else None  # a reply is labelled "fleet": its stamp is no one's
            if data is None:  # a stamp alone (a GS that holds no revision)
                return RevisionRefused(RevisionRefusal.REPLAYED, self.keeper.number)
        got = self.keeper.offer(data)
        if isinstance(got, RevisionRefused):
            key = f"refused:{got.reason.value}"
            if got.reason is not RevisionRefusal.REPLAYED and self.keeper.counters[key] <= LOGGED_PER_REASON:
                self.rt.events.write_record(rec.RevisionRefused(reason=got.reason.value, number=got.number))
            return got
        self._next_push = 0.0
        if self.write_applied:
            c = got.revision.changes
            self.rt.events.write_record(rec.RevisionApplied(number=got.revision.number, revoked=tuple(c.revoked),
                                                            rotated=tuple(c.keys), pairing_pq=c.pairing_pq))
        return got

    def serve(self, now: float) -> None:
        """Answer the revision queries that wait (a GS), push the revision held when due (a GS), and
        ask for the latest when due: at start, on coming back in reach, every ``ASK_PERIOD_S``."""
        if self.queries is not None:
            self._answer()
        if now >= self._next_look:
            self._next_look = now + REACH_LOOK_S
            reach = self._reach_now()
            if reach > self._reach:  # a path (re)connected or the radio returned: ask now
                self._next_ask = min(self._next_ask, now)
            self._reach = reach
        if self._reach and now >= max(self._next_ask, self._last_ask + ASK_GAP_S):
            self._last_ask, self._next_ask = now, now + ASK_PERIOD_S
            self.keeper.counters["asked"] += 1
            self.rt.ask(keyexprs.revision_all(), b"", ASK_TIMEOUT_S, REPLY, "fleet", limit=MAX_REVISION_BYTES)
        if self.own is None or now < self._last_push + PUSH_GAP_S:
            return
        key = self.signing() if self.signing is not None else None
        stamping = key is not None and self.wall is not None
        full = self.keeper.data is not None and now >= self._next_push
        if not (full or (stamping and now >= self._next_stamp)):  # the stamp and revision go first
            if self.notice is not None and now >= self._next_notice:
                published = self.keeper.counters["keys_lost_published"]
                self._next_notice = now + (PUSH_GAP_S if published < NOTICE_BURST else NOTICE_PERIOD_S)
                notice = self.notice()
                if notice is not None:
                    self._last_push = now
                    self.keeper.counters["keys_lost_published"] += 1
                    self.rt.put(self.own, notice)
            return
        self._last_push, self._next_stamp = now, now + STAMP_PERIOD_S
        data = self.keeper.data if full else None
        if full:
            self._next_push = now + PUSH_PERIOD_S
            self.keeper.counters["pushed"] += 1
        if stamping:
            assert key is not None and self.wall is not None
            named = self.drones() if self.drones is not None else ()
            data = make_push(self.rt.name, self.keeper.number, self.wall(), key, data, named)
            self.keeper.counters["stamped"] += 1
        if data is not None:
            self.rt.put(self.own, data)

    def take_notice(self) -> bytes | None:
        """The keys-lost notice last handed to ``on_inbox`` (once)."""
        notice, self.heard_notice = self.heard_notice, None
        return notice

    def take_stamp(self) -> bytes | None:
        """The stamp of the push last handed to ``on_inbox`` (once)."""
        stamp, self.stamp = self.stamp, None
        return stamp

    def _answer(self) -> None:
        assert self.queries is not None and self.own is not None
        for _ in range(ANSWERS_PER_TURN):
            q = self.queries.try_recv()
            if q is None:
                break
            try:
                if self.keeper.data is not None:
                    q.reply(self.own, self.keeper.data)
                    self.keeper.counters["answered"] += 1
            except Exception as exc:  # a reply that cannot go out (session closing): counted
                self.keeper.counters["reply_failed"] += 1
                log.info("revision reply failed: %s", exc)
            finally:
                q.drop()

    def _reach_now(self) -> int:
        """The node's paths that reach a router now; 0 while the testbed's radio reaches no GS."""
        if self.in_reach is not None and not self.in_reach():
            return 0
        return sum(1 for p in self.rt.path_status().values() if p["connected"])


def signing_key_epochs(fleet_dir: str | Path) -> dict[str, tuple[tuple[int, bytes], ...]]:
    """Each node's Ed25519 signing keys over time, oldest first, each with the number of the revision
    that gave it (the base fleet's at 0): from the fleet machine's numbered revisions
    (``revisions/NNNN.json``, each checked against the pinned fleet key) and the latest kept beside
    ``fleet.json5``. What ``zdrone audit verify`` checks a node's checkpoints and countersignatures
    against, each under the key in force at its time (``zdrone.core.audit``). ``ConfigError`` (one
    line) for a revision file that is not a valid revision of this fleet."""
    d = fleet_path(fleet_dir).parent
    base = load_base_fleet(d)
    epochs: dict[str, list[tuple[int, bytes]]] = {
        n: [(0, k)] for n in base.nodes if (k := base.nodes[n].signing_public_bytes)}
    found = {got.revision.number: got for got in read_revisions([*sorted((d / "revisions").glob("*.json")),
                                                                 d / REVISION_FILE], base)}
    for number in sorted(found):
        for name, node in found[number].fleet.nodes.items():
            key = node.signing_public_bytes
            if key is not None and [k for _, k in epochs.setdefault(name, [])[-1:]] != [key]:
                epochs[name].append((number, key))
    return {n: tuple(e) for n, e in epochs.items()}


def signing_key_history(fleet_dir: str | Path) -> dict[str, tuple[bytes, ...]]:
    """Each node's Ed25519 signing keys over time, oldest first (``signing_key_epochs`` without the
    revision numbers)."""
    return {n: tuple(k for _, k in e) for n, e in signing_key_epochs(fleet_dir).items()}


__all__ = ["ASK_GAP_S", "ASK_PERIOD_S", "ASK_TIMEOUT_S", "KINDS", "MAX_REVISION_BYTES", "PUSH_GAP_S", "PUSH_PERIOD_S",
           "STAMP_PERIOD_S", "REACH_LOOK_S", "RevisionAccepted", "RevisionChannel", "RevisionKeeper",
           "signing_key_epochs", "signing_key_history"]
