"""A node's fleet revisions over Zenoh: hear them, check them, keep the latest, hand it on.

Theory of operation
-------------------
Every node (drone, GS) holds a ``RevisionKeeper``: the base fleet (``fleet.json5`` of its bundle),
the revision in force and its bytes. Revisions reach it three ways, all on ``kx.revision()``:

* a **publication** (``zdrone fleet publish``, or a node relaying one it just applied);
* the **reply to its query**: a node asks at start, whenever one of its router paths (re)opens (it
  reconnected, or came back in reach) and every ``ASK_PERIOD_S``; every node answers with the
  revision it holds, so one honest node in reach is enough (replies are not consolidated: a stale
  reply from a revoked node is refused as ``stale``/``replayed`` and the newest wins);
* the node's own durable copy at start (``load_fleet``: beside ``fleet.json5`` or in
  ``$ZDRONE_STATE_DIR``).

``offer(data)`` checks the bytes (``zdrone.core.revision.check_revision``: fleet key, signature,
number above the one in force, no revocation undone); a refusal is counted by reason and never
raised; an acceptance is written durably (``revision.json`` in the state directory if the node runs
under ``zdrone service``, else in its bundle folder) before the node applies the new effective fleet.
A revision heard again (``replayed``) renews the drone's revision lease (``DroneCore.on_revision_sync``).
"""

from __future__ import annotations

import logging
import os
from collections import Counter
from pathlib import Path
from typing import Any

from ..core import records as rec
from ..core.fleet import Fleet
from ..core.revision import (Revision, RevisionAccepted, RevisionRefusal, RevisionRefused, RevisionResult,
                             check_revision, encode_revision)
from .files import REVISION_FILE, STATE_DIR_ENV, fleet_path, load_base_fleet, load_revision, write_durably

log = logging.getLogger(__name__)

#: A node asks for the latest revision this often (and at every path (re)open).
ASK_PERIOD_S = 2.0
#: How long a revision query waits for its replies.
ASK_TIMEOUT_S = 1.0
#: The largest revision a node takes (a fleet of 150 drones x 26 GSs, every list changed, is ~60 KB).
MAX_REVISION_BYTES = 256 * 1024


class RevisionKeeper:
    """The revision in force at one node, and what was refused (``counters``)."""

    def __init__(self, fleet_dir: str | Path, name: str = "") -> None:
        self.fleet_dir, self.name = Path(fleet_dir), name
        self.base: Fleet = load_base_fleet(fleet_dir)
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
    subscription and the queryable on ``kx.revision()``, its periodic query, the keeper. The node's
    loop hands it the inbox items of ``KINDS`` (``on_inbox``) and calls ``serve(now)`` every turn."""

    def __init__(self, rt: Any, fleet_dir: str | Path, write_applied: bool = False) -> None:
        from .keyexprs import revision

        self.rt, self.key = rt, revision()
        self.keeper = RevisionKeeper(fleet_dir, rt.name)
        self.write_applied = write_applied  # the drone's core writes its own record
        rt.subscribe(self.key, PUBLISHED, lambda _k: "fleet", limit=MAX_REVISION_BYTES)
        self.queries = rt.queryable(self.key)
        self._next_ask = 0.0

    def on_inbox(self, kind: str, data: Any) -> RevisionResult:
        """A publication's bytes, or a reply's ``(ok, err)``: checked and kept (``RevisionKeeper.offer``)."""
        if kind == REPLY:
            ok, _err = data
            if ok is None:  # a node with no revision answers nothing; an error or oversize is counted
                self.keeper.counters["reply_error"] += 1
                return RevisionRefused(RevisionRefusal.MALFORMED)
            data = ok
        got = self.keeper.offer(data)
        if isinstance(got, RevisionRefused):
            key = f"refused:{got.reason.value}"
            if got.reason is not RevisionRefusal.REPLAYED and self.keeper.counters[key] <= LOGGED_PER_REASON:
                self.rt.events.write_record(rec.RevisionRefused(reason=got.reason.value, number=got.number))
        elif self.write_applied:
            c = got.revision.changes
            self.rt.events.write_record(rec.RevisionApplied(number=got.revision.number, revoked=tuple(c.revoked),
                                                            rotated=tuple(c.keys), pairing_pq=c.pairing_pq))
        return got

    def serve(self, now: float) -> None:
        """Answer the revision queries that wait (with the revision in force, if any), and ask for
        the latest every ``ASK_PERIOD_S``."""
        for _ in range(16):
            q = self.queries.try_recv()
            if q is None:
                break
            try:
                if self.keeper.data is not None:
                    q.reply(self.key, self.keeper.data)
            except Exception as exc:  # a reply that cannot go out (session closing): counted
                self.keeper.counters["reply_failed"] += 1
                log.info("revision reply failed: %s", exc)
            finally:
                q.drop()
        if now >= self._next_ask:
            self._next_ask = now + ASK_PERIOD_S
            self.rt.ask(self.key, b"", ASK_TIMEOUT_S, REPLY, "fleet")

    def ask_now(self) -> None:
        """Ask at the next turn (a path reopened, the node came back in reach)."""
        self._next_ask = 0.0


def publish(fleet_dir: str | Path, node: str, router: str, data: bytes) -> None:
    """Put revision ``data`` on the revision key through ``router`` as ``node`` (its bundle's
    credentials), and close."""
    from ..net.session import open_client
    from .files import load_fleet, load_secret
    from .keyexprs import revision
    from .tls import node_files

    fleet = load_fleet(fleet_dir)
    secret = load_secret(fleet_dir, node, fleet)
    tls = node_files(fleet_dir, node).check() if router.startswith("tls/") else None
    session = open_client(router, node, secret.router_password, tls, None)
    try:
        session.put(revision(), data)
    finally:
        session.close()


__all__ = ["ASK_PERIOD_S", "ASK_TIMEOUT_S", "KINDS", "MAX_REVISION_BYTES", "RevisionAccepted", "RevisionChannel",
           "RevisionKeeper", "publish"]
