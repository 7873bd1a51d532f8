"""A node's revision traffic (``zdrone.fleet.revisions.RevisionChannel``) on an in-memory runtime,
with explicit ``now``: a drone declares no queryable and asks at start, on coming back in reach and
every ``ASK_PERIOD_S`` only, its queries ``ASK_GAP_S`` apart; a GS answers on its own key, pushes the
revision it holds every ``PUSH_PERIOD_S`` and a new one at once, its puts ``PUSH_GAP_S`` apart; the
revision in force heard again costs no signature check; only a GS publishes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from zdrone.cli import main
from zdrone.core.errors import ConfigError
from zdrone.core.revision import RevisionAccepted, RevisionRefusal, RevisionRefused
from zdrone.fleet import keyexprs
from zdrone.fleet import revisions
from zdrone.fleet.bundle import export_bundle
from zdrone.fleet.files import REVISION_FILE
from zdrone.net.revisions import publish
from zdrone.fleet.revisions import (ASK_GAP_S, ASK_PERIOD_S, MAX_REVISION_BYTES, PUSH_GAP_S, PUSH_PERIOD_S,
                                    REACH_LOOK_S, RevisionChannel)


class _Events:
    def __init__(self) -> None:
        self.records: list[Any] = []

    def write_record(self, record: Any) -> None:
        self.records.append(record)


class _Query:
    def __init__(self, replies: list[tuple[str, bytes]]) -> None:
        self.replies, self.dropped = replies, False

    def reply(self, keyexpr: str, data: bytes) -> None:
        self.replies.append((keyexpr, data))

    def drop(self) -> None:
        self.dropped = True


class _Queryable:
    def __init__(self, keyexpr: str) -> None:
        self.keyexpr = keyexpr
        self.waiting: list[_Query] = []

    def try_recv(self) -> _Query | None:
        return self.waiting.pop(0) if self.waiting else None


class _Runtime:
    """What a ``RevisionChannel`` uses of ``NodeRuntime``, recorded; ``paths`` connected paths."""

    def __init__(self, name: str, paths: int = 1) -> None:
        self.name, self.paths, self.now = name, paths, 0.0
        self.events = _Events()
        self.subs: list[tuple[str, str, int]] = []
        self.queryables: list[_Queryable] = []
        self.puts: list[tuple[float, str, bytes]] = []
        self.asks: list[tuple[float, str, int]] = []

    def subscribe(self, keyexpr: str, kind: str, peer_of: Any, limit: int) -> None:
        assert peer_of(keyexprs.revision("A")) == "A"  # one inbox queue per sender
        self.subs.append((keyexpr, kind, limit))

    def queryable(self, keyexpr: str) -> _Queryable:
        q = _Queryable(keyexpr)
        self.queryables.append(q)
        return q

    def put(self, keyexpr: str, payload: bytes) -> None:
        self.puts.append((self.now, keyexpr, payload))

    def ask(self, keyexpr: str, payload: bytes, timeout: float, kind: str, peer: str, limit: int) -> None:
        self.asks.append((self.now, keyexpr, limit))

    def path_status(self) -> dict[str, dict[str, Any]]:
        return {f"tcp/127.0.0.1:{7447 + i}": {"open": True, "connected": i < self.paths} for i in range(3)}


def _run(ch: RevisionChannel, rt: _Runtime, start: float, end: float, step: float = 0.05) -> None:
    t = start
    while t < end - 1e-9:
        rt.now = t
        ch.serve(t)
        t = round(t + step, 6)


@pytest.fixture()
def fleet_dir(tmp_path) -> Path:
    d = tmp_path / "fleet"
    assert main(["fleet", "init", "--dir", str(d)]) == 0
    return d


def _revision(fleet_dir: Path, node: str) -> bytes:
    assert main(["fleet", "revoke", node, "--dir", str(fleet_dir)]) == 0
    return (fleet_dir / REVISION_FILE).read_bytes()


def test_a_drone_answers_nothing_and_asks_at_start_on_coming_back_in_reach_and_every_30_s(fleet_dir, tmp_path):
    export_bundle(fleet_dir, "d1", tmp_path / "d1")
    rt, radio = _Runtime("d1"), [True]
    ch = RevisionChannel(rt, tmp_path / "d1", publisher=False, in_reach=lambda: radio[0])
    assert rt.queryables == [] and rt.subs == [(keyexprs.revision_all(), revisions.PUBLISHED, MAX_REVISION_BYTES)]
    _run(ch, rt, 100.0, 110.0)
    assert rt.asks == [(100.0, keyexprs.revision_all(), MAX_REVISION_BYTES)]  # at start, with the revision's size limit
    radio[0] = False  # out of every GS's radio: no ask
    _run(ch, rt, 110.0, 125.0)
    radio[0] = True
    _run(ch, rt, 125.0, 127.0)
    assert len(rt.asks) == 2 and 125.0 <= rt.asks[1][0] <= 125.0 + REACH_LOOK_S  # back in reach: asks
    _run(ch, rt, 127.0, 125.0 + REACH_LOOK_S + ASK_PERIOD_S + 1)
    assert [round(t - rt.asks[1][0], 2) for t, *_ in rt.asks[1:]] == [0.0, ASK_PERIOD_S]  # then every 30 s only
    assert rt.puts == []


def test_a_path_that_reconnects_right_after_an_ask_is_asked_on_after_the_gap(fleet_dir, tmp_path):
    export_bundle(fleet_dir, "d1", tmp_path / "d1")
    rt = _Runtime("d1", paths=0)
    ch = RevisionChannel(rt, tmp_path / "d1", publisher=False)
    _run(ch, rt, 0.0, 3.0)
    assert rt.asks == []  # no router: nobody to ask
    rt.paths = 1
    _run(ch, rt, 3.0, 4.5)
    rt.paths = 2  # a second site's path opens
    _run(ch, rt, 4.5, 10.0)
    first, second = rt.asks[0][0], rt.asks[1][0]
    assert len(rt.asks) == 2 and 3.0 <= first <= 3.0 + REACH_LOOK_S and second - first >= ASK_GAP_S  # the router's budget


def test_a_gs_answers_on_its_own_key_and_pushes_every_10_s_and_a_new_revision_at_once(fleet_dir, tmp_path):
    export_bundle(fleet_dir, "A", tmp_path / "A")
    rt = _Runtime("A")
    ch = RevisionChannel(rt, tmp_path / "A", publisher=True, write_applied=True)
    (q,) = rt.queryables
    assert q.keyexpr == keyexprs.revision("A")
    _run(ch, rt, 0.0, 5.0)
    assert rt.puts == []  # nothing to push before the first revision
    first = _revision(fleet_dir, "X")
    assert isinstance(ch.on_inbox(revisions.PUBLISHED, first), RevisionAccepted)
    _run(ch, rt, 5.0, 35.3)
    assert [(t, k, d) for t, k, d in rt.puts] == [(5.0, keyexprs.revision("A"), first), (15.0, keyexprs.revision("A"), first),
                                                  (25.0, keyexprs.revision("A"), first), (35.0, keyexprs.revision("A"), first)]
    second = _revision(fleet_dir, "B")
    assert isinstance(ch.on_inbox(revisions.REPLY, (second, None)), RevisionAccepted)
    _run(ch, rt, 35.3, 47.0)
    times = [t for t, *_ in rt.puts]
    assert times[4:] == [35.0 + PUSH_GAP_S, 35.0 + PUSH_GAP_S + PUSH_PERIOD_S]  # at once, PUSH_GAP_S after the last
    assert rt.puts[4][2] == second
    replies: list[tuple[str, bytes]] = []
    q.waiting = [_Query(replies) for _ in range(3)]
    ch.serve(47.0)
    assert replies == [(keyexprs.revision("A"), second)] * 3 and ch.keeper.counters["answered"] == 3
    assert [type(r).__name__ for r in rt.events.records] == ["RevisionApplied", "RevisionApplied"]


def test_the_revision_in_force_heard_again_costs_no_signature_check(fleet_dir, tmp_path, monkeypatch):
    export_bundle(fleet_dir, "d1", tmp_path / "d1")
    ch = RevisionChannel(_Runtime("d1"), tmp_path / "d1", publisher=False)
    data = _revision(fleet_dir, "B")
    checks = []
    real = revisions.check_revision
    monkeypatch.setattr(revisions, "check_revision", lambda *a: checks.append(1) or real(*a))
    assert isinstance(ch.on_inbox(revisions.PUBLISHED, data), RevisionAccepted)
    for _ in range(3):  # three GSs' pushes
        got = ch.on_inbox(revisions.PUBLISHED, data)
        assert got == RevisionRefused(RevisionRefusal.REPLAYED, 1)  # renews the drone's lease
    assert len(checks) == 1 and ch.keeper.counters["refused:replayed"] == 3
    assert isinstance(ch.on_inbox(revisions.REPLY, (None, b"oversize")), RevisionRefused)
    assert ch.keeper.counters["reply_error"] == 1


def test_only_a_ground_station_publishes_a_revision(fleet_dir):
    data = _revision(fleet_dir, "B")
    with pytest.raises(ConfigError, match="as a ground station"):
        publish(fleet_dir, "d1", "tcp/127.0.0.1:9", data)


def _push(fleet_dir: Path, gs: str, drones: tuple[str, ...] = ("d1",)) -> bytes:
    from zdrone.core.revision import make_push
    from zdrone.fleet.files import load_secret

    return make_push(gs, 0, 1_800_000_000.0, load_secret(fleet_dir, gs).signing, None, drones)


def test_a_stamp_is_handed_on_only_from_a_publication_never_from_a_querys_reply(fleet_dir, tmp_path):
    """A query's replies all come labelled ``fleet`` (``NodeRuntime.ask``), whoever answered: a stamp in
    one would be judged as published on the key of a GS named ``fleet``. So a reply hands on none."""
    from zdrone.core.revision import split_push

    export_bundle(fleet_dir, "d1", tmp_path / "d1")
    ch = RevisionChannel(_Runtime("d1"), tmp_path / "d1", publisher=False)
    push = _push(fleet_dir, "B")
    ch.on_inbox(revisions.REPLY, (push, None))
    assert ch.take_stamp() is None
    ch.on_inbox(revisions.PUBLISHED, push)
    assert ch.take_stamp() == split_push(push)[0] and ch.take_stamp() is None  # once


@pytest.mark.parametrize("drones", [["d1"], None])
def test_a_gss_stamp_names_the_drones_it_vouches_for(fleet_dir, tmp_path, drones):
    from zdrone.core.revision import check_stamp, split_push
    from zdrone.fleet.files import load_fleet, load_secret

    export_bundle(fleet_dir, "A", tmp_path / "A")
    rt = _Runtime("A")
    key = load_secret(fleet_dir, "A").signing
    ch = RevisionChannel(rt, tmp_path / "A", publisher=True, signing=lambda: key, wall=lambda: 1_800_000_000.0,
                         drones=(lambda: drones) if drones is not None else None)
    _run(ch, rt, 0.0, 0.1)
    (_, keyexpr, data), = rt.puts
    got = check_stamp(split_push(data)[0], load_fleet(fleet_dir))
    assert keyexpr == keyexprs.revision("A") and got is not None and got.drones == tuple(drones or ())


def test_a_restarted_gs_puts_its_keys_lost_notice_between_its_stamps_which_still_go_every_5_s(fleet_dir, tmp_path):
    """The notice (``zdrone.core.keyslost``) on the GS's own key: five a put gap apart, then every 2.5 s,
    for as long as the GS gives one; a stamp or revision due goes first, so the lease's stamps keep
    their period; a node hears it as a notice (``take_notice``), never as a revision."""
    from zdrone.core import keyslost
    from zdrone.core.revision import STAMP_MAGIC
    from zdrone.fleet.files import load_fleet, load_secret
    from zdrone.fleet.revisions import NOTICE_PERIOD_S, STAMP_PERIOD_S

    export_bundle(fleet_dir, "B", tmp_path / "B")
    rt = _Runtime("B")
    key = load_secret(fleet_dir, "B").signing
    t0 = 1_800_000_000.0
    ch = RevisionChannel(rt, tmp_path / "B", publisher=True, signing=lambda: key, wall=lambda: t0 + rt.now,
                         notice=lambda: keyslost.make_notice("B", t0, t0 + rt.now, key) if rt.now < 30.0 else None)
    _run(ch, rt, 0.0, 40.0)
    notices = [t for t, k, d in rt.puts if keyslost.is_notice(d)]
    stamps = [t for t, k, d in rt.puts if d.startswith(STAMP_MAGIC)]
    assert all(b - a >= PUSH_GAP_S - 1e-6 for a, b in zip(sorted(notices + stamps), sorted(notices + stamps)[1:]))
    assert notices[0] <= 1.1 and len([t for t in notices if t < 6.0]) >= 4 and max(notices) < 30.0
    assert all(b - a <= NOTICE_PERIOD_S + PUSH_GAP_S + 0.1 for a, b in zip(notices, notices[1:]))
    assert all(b - a <= STAMP_PERIOD_S + PUSH_GAP_S + 0.1 for a, b in zip(stamps, stamps[1:])) and stamps[-1] > 35.0
    first = next(d for _, _, d in rt.puts if keyslost.is_notice(d))
    assert keyslost.check_notice(first, load_fleet(fleet_dir)) is not None
    heard = RevisionChannel(_Runtime("A"), tmp_path / "B", publisher=False)
    got = heard.on_inbox(revisions.PUBLISHED, first)
    assert isinstance(got, RevisionRefused) and got.reason is RevisionRefusal.REPLAYED
    assert heard.take_notice() is not None and heard.take_notice() is None and heard.keeper.number == 0
