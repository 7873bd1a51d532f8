"""The event log is bounded whatever the peers send: rate per (type, reason) with exact counts of
what it left out, rotation by size, and readers (``read_records``, ``LogTail``) across rotated files."""

from __future__ import annotations

import pytest

from zdrone.core.records import Reject, Suppressed, only
from zdrone.net.eventlog import (MAX_REASONS_PER_TYPE, OTHER_REASON, EventLog, EventRate, LogLimits, LogTail,
                                 log_files, read_events, read_records, rotated)

MB = 1024 * 1024


class Clock:
    def __init__(self, t: float = 1_700_000_000.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def _status(log: EventLog, **extra) -> None:
    """A status line of the drone's size (1.5 kB; its fields are not what this tests: ``closed`` is
    written on the node's clock as ``status`` is, and like it is never limited)."""
    log.write("status", blob="x" * 1500, **extra)


def test_a_flood_of_authentic_control_messages_grows_the_log_by_at_most_1_mb_a_minute(tmp_path):
    """4000 control messages a second from a linked GS for a minute, each making a ``reject`` and a
    ``handover_requested`` line (as the drone wrote them: 25 MB a minute unbounded), beside the
    node's own 2 Hz status."""
    clock = Clock()
    path = tmp_path / "drone.jsonl"
    log = EventLog(path, "d1", clock=clock, limits=LogLimits(max_bytes=None), strict=False)
    detail = "handover request from B refused: B is not the authority's chosen recipient (epoch 7)"
    sent = 0
    for tick in range(60 * 4000):
        clock.t += 1 / 4000
        log.write("reject", detail=detail, position=[47.39, 8.54, 30.0])
        log.write("handover_requested", detail=detail, position=[47.39, 8.54, 30.0])
        sent += 2
        if tick % 2000 == 0:
            _status(log)
    log.close()
    size = path.stat().st_size
    assert size <= 1 * MB, f"{size / MB:.2f} MB in a minute"
    assert log.bytes_written == size
    recs = read_records(path).records
    rejects = only(recs, Reject)
    summaries = only(recs, Suppressed)
    left_out = {(s.of, s.reason): 0 for s in summaries}
    for s in summaries:
        left_out[(s.of, s.reason)] += s.count
    # exact: every event is either in the log or counted, in the counters and in the summary lines
    assert len(rejects) + log.suppressed[("reject", None)] == sent // 2
    assert left_out == dict(log.suppressed)
    assert 50 + 5 * 60 - 2 <= len(rejects) <= 50 + 5 * 60 + 2  # the burst, then 5 a second
    assert all(s.last >= s.first for s in summaries)


def test_forged_input_with_ever_new_reasons_makes_no_new_buckets_without_end(tmp_path):
    clock = Clock()
    log = EventLog(tmp_path / "gs.jsonl", "A", clock=clock, limits=LogLimits(max_bytes=None))
    for i in range(100_000):
        clock.t += 1 / 4000
        log.write("linkkey_refused", drone="d1", asker="B", reason=f"junk-{i}", detail="bad length")
    log.close()
    assert (tmp_path / "gs.jsonl").stat().st_size <= 1 * MB / 60 * 25 + 64 * 1024
    assert len({r for (_, r) in log.suppressed}) <= MAX_REASONS_PER_TYPE + 1
    assert log.suppressed[("linkkey_refused", OTHER_REASON)] > 90_000


def test_the_nodes_own_clockwork_and_ordinary_events_are_never_left_out(tmp_path):
    clock = Clock()
    log = EventLog(tmp_path / "x.jsonl", "d1", clock=clock, strict=False)
    for _ in range(2000):
        clock.t += 0.0005
        _status(log)
    for i in range(40):  # a flight's worth of events of one type, a few a second
        clock.t += 0.3
        log.write("link_state", gs="A", state="ok")
    log.close()
    assert not log.suppressed
    assert len(read_events(tmp_path / "x.jsonl")) == 2040


def test_the_log_rotates_by_size_keeping_a_few_files_and_the_readers_read_across_them(tmp_path):
    clock = Clock()
    path = tmp_path / "drone.jsonl"
    log = EventLog(path, "d1", clock=clock, limits=LogLimits(max_bytes=20_000, keep=3, rate=None), strict=False)
    tail = LogTail(path)
    tailed = []
    for i in range(3000):
        clock.t += 0.01
        log.write("status", i=i)
        if i % 97 == 0:
            tailed += tail.read()  # a watcher polling as the log grows and rotates
    log.close()
    tailed += tail.read()
    files = log_files(path)
    assert files == [rotated(path, 3), rotated(path, 2), rotated(path, 1), path] and not rotated(path, 4).exists()
    assert all(f.stat().st_size <= 20_000 for f in files)
    assert log.rotations > 3
    kept = [e["i"] for e in read_events(path)]
    assert kept == list(range(kept[0], 3000)) and kept[0] > 0  # the newest, in order, the oldest dropped
    assert [e.t for e in read_records(path).records] == sorted(e.t for e in read_records(path).records)
    assert [e.fields["i"] for e in tailed] == list(range(3000))  # the tail missed nothing, read nothing twice
    assert tail.undecodable == 0


def test_the_tail_skips_a_half_written_line_until_it_is_finished(tmp_path):
    path = tmp_path / "a.jsonl"
    tail = LogTail(path)
    assert tail.read() == []
    with open(path, "w") as fh:
        fh.write('{"t": 1.0, "node": "A", "type": "closed"}\n{"t": 2.0, "node": "A", "ty')
        fh.flush()
        assert [e.t for e in tail.read()] == [1.0]
        fh.write('pe": "closed"}\n')
    assert [e.t for e in tail.read()] == [2.0]


@pytest.mark.parametrize("rate", [EventRate(burst=3, per_s=1, summary_every=5)])
def test_a_summary_says_how_many_similar_events_were_left_out_and_when(tmp_path, rate):
    clock = Clock(100.0)
    path = tmp_path / "d.jsonl"
    log = EventLog(path, "d1", clock=clock, limits=LogLimits(rate=rate), strict=False)
    for _ in range(10):  # 3 written, 7 left out, all at t=100
        log.write("reject", detail="x", position=None)
    clock.t = 106.0
    _status(log)  # any write after summary_every brings the summary out
    log.close()
    recs = read_records(path).records
    s = only(recs, Suppressed)
    assert [(x.of, x.reason, x.count, x.first, x.last) for x in s] == [("reject", None, 7, 100.0, 100.0)]
    assert len(only(recs, Reject)) == 3
