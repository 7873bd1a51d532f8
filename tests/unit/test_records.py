"""Typed event-log records: every record round-trips, real logs decode to typed records with
nothing lost, every writer's event has its record, and a misfit is caught as it is written."""

from __future__ import annotations

import ast
import logging
from pathlib import Path
from typing import Any

import msgspec
import msgspec.inspect as mi
import pytest
from hypothesis import given
from hypothesis import strategies as st

import gs
import zdrone
from zdrone.core import records as rec
from zdrone.sil import testbed_records as trec
from zdrone.core.tbm import LinkState
from zdrone.core.wire import AuthorityState
from zdrone.net.eventlog import STRICT_ENV, EventLog, EventShapeError, read_records

ROOT = Path(zdrone.__file__).parent
GS_ROOT = Path(gs.__file__).parent

# One line of each event type, copied from the logs of ``zdrone demo`` runs (the reference flight,
# failsafe-recover, companion-restart, gs-crash, gs-hang, link-loss and the attack scenarios).
DRONE_LOG = r'''
{"t": 1795338252.9752, "node": "d1", "type": "status", "owner": "A", "epoch": 3, "state": "linked", "pending_to": null, "position": [47.397742, 8.5459236, 30.0], "armed": true, "mode": "MISSION", "landed_state": 2, "autopilot": "px4", "vehicle_streams": {"autopilot": "px4", "connections": 1, "streams": {"GLOBAL_POSITION_INT": {"state": "seen", "via": "unasked", "interval_asks": 0, "stream_asks": 0, "lapses": 0, "refusal": null}, "EXTENDED_SYS_STATE": {"state": "seen", "via": "unasked", "interval_asks": 0, "stream_asks": 0, "lapses": 0, "refusal": null}, "SYS_STATUS": {"state": "seen", "via": "unasked", "interval_asks": 0, "stream_asks": 0, "lapses": 0, "refusal": null}, "MISSION_CURRENT": {"state": "seen", "via": "unasked", "interval_asks": 0, "stream_asks": 0, "lapses": 0, "refusal": null}, "HOME_POSITION": {"state": "seen", "via": "unasked", "interval_asks": 0, "stream_asks": 0, "lapses": 0, "refusal": null}}, "counters": {}}, "in_region": false, "subscribed": ["A"], "links": {"A": {"state": "ok", "since_last": 0.133, "opened": 110, "sent": 1467, "dropped": {}}, "B": {"state": "degraded", "since_last": 2.632, "opened": 123, "sent": 1726, "dropped": {}}}, "keys": {"A": {"live": true, "candidates": 0, "expired": 0, "dropped_unlinked": {}}, "B": {"live": true, "candidates": 0, "expired": 0, "dropped_unlinked": {}}}, "ha_drops": {}, "rejects": {}, "counters": {"pair_answered": 1, "pair_repeated": 12}, "forwarded_commands": {"A": 73, "B": 81}, "forwarded_epochs": {"1:A": 51, "2:B": 81, "3:A": 22}, "inbox_dropped": {}, "out_of_coverage": {"down:B": 10, "down:A": 12}, "radio_lost": {}}
{"t": 1795338605.4637, "node": "d1", "type": "start", "vehicle": "udpout:127.0.0.1:43754"}
{"t": 1795338606.148, "node": "d1", "type": "subscribe", "gs": "A"}
{"t": 1795338606.148, "node": "d1", "type": "pair_answered", "gs": "A"}
{"t": 1795338606.1541, "node": "d1", "type": "link_confirmed", "gs": "A", "how": "pair", "replaced": false}
{"t": 1795338606.1544, "node": "d1", "type": "paired", "gs": "A"}
{"t": 1795338606.1545, "node": "d1", "type": "authority", "from": null, "to": "A", "epoch": 1, "kind": "paired", "time": 1795338606.1545, "position": [47.397742, 8.545594, 0.0]}
{"t": 1795338606.1587, "node": "d1", "type": "link_state", "gs": "A", "state": "ok"}
{"t": 1795338606.1645, "node": "d1", "type": "link_installed", "gs": "B", "how": "grant"}
{"t": 1795338606.1646, "node": "d1", "type": "key_installed", "detail": "B", "position": [47.397742, 8.545594, 0.0]}
{"t": 1795338612.637, "node": "d1", "type": "region_entered", "detail": "A,B,X", "position": [47.397742, 8.5476149, 30.0]}
{"t": 1795338614.8905, "node": "d1", "type": "handover_start", "detail": "A -> B", "position": [47.397742, 8.5490506, 30.0]}
{"t": 1795338614.8907, "node": "d1", "type": "handover_complete", "from": "A", "to": "B", "epoch": 2, "kind": "handover", "time": 1795338614.8907, "position": [47.397742, 8.5490506, 30.0]}
{"t": 1795338616.8112, "node": "d1", "type": "region_left", "detail": "B", "position": [47.397742, 8.5502771, 30.0]}
{"t": 1795338616.8115, "node": "d1", "type": "unsubscribe", "gs": "A"}
{"t": 1795338641.9979, "node": "d1", "type": "stop", "owner": "A", "epoch": 3, "state": "linked", "pending_to": null, "position": [47.397742, 8.545594, 0.0], "armed": false, "mode": "MISSION", "landed_state": 1, "autopilot": "px4", "vehicle_streams": {"autopilot": "px4", "connections": 1, "streams": {"GLOBAL_POSITION_INT": {"state": "seen", "via": "unasked", "interval_asks": 0, "stream_asks": 0, "lapses": 0, "refusal": null}, "EXTENDED_SYS_STATE": {"state": "seen", "via": "unasked", "interval_asks": 0, "stream_asks": 0, "lapses": 0, "refusal": null}, "SYS_STATUS": {"state": "seen", "via": "unasked", "interval_asks": 0, "stream_asks": 0, "lapses": 0, "refusal": null}, "MISSION_CURRENT": {"state": "seen", "via": "unasked", "interval_asks": 0, "stream_asks": 0, "lapses": 0, "refusal": null}, "HOME_POSITION": {"state": "seen", "via": "unasked", "interval_asks": 0, "stream_asks": 0, "lapses": 0, "refusal": null}}, "counters": {}}, "in_region": false, "subscribed": ["A"], "links": {"A": {"state": "ok", "since_last": 0.418, "opened": 151, "sent": 1992, "dropped": {}}, "B": {"state": "lost", "since_last": 8.818, "opened": 123, "sent": 1732, "dropped": {}}}, "keys": {"A": {"live": true, "candidates": 0, "expired": 0, "dropped_unlinked": {}}, "B": {"live": true, "candidates": 0, "expired": 0, "dropped_unlinked": {}}}, "ha_drops": {}, "rejects": {}, "counters": {"pair_answered": 1}, "forwarded_commands": {"A": 102, "B": 81}, "forwarded_epochs": {"1:A": 51, "2:B": 81, "3:A": 51}, "inbox_dropped": {}, "out_of_coverage": {"down:B": 16, "down:A": 12}, "radio_lost": {}}
{"t": 1795338641.9996, "node": "d1", "type": "closed"}
{"t": 1795338738.3484, "node": "d1", "type": "failsafe", "action": "LAND", "reason": "authority link to A lost", "detect_to_command_ms": 1.2257340003998252, "position": [47.397742, 8.5466507, 30.0]}
{"t": 1795338738.3484, "node": "d1", "type": "failsafe_entered", "detail": "authority link to A lost", "position": [47.397742, 8.5466507, 30.0]}
{"t": 1795338738.3973, "node": "d1", "type": "pair_refused", "gs": "A", "reason": "failsafe: re-pair only on the ground"}
{"t": 1795338738.4011, "node": "d1", "type": "failsafe_recovered", "detail": "A took control after the failsafe", "position": [47.397742, 8.5466507, 30.0]}
{"t": 1795338793.7964, "node": "d1", "type": "authority_link_lost", "detail": "A: authority to B", "position": [47.397742, 8.549851, 30.0]}
{"t": 1795338870.3758, "node": "d1", "type": "restarted", "owner": "A", "epoch": 1, "state": "linked", "position": [47.397742, 8.5458512, 30.0]}
{"t": 1795338870.376, "node": "d1", "type": "restored", "detail": "authority A epoch 1; waiting 3.0 s for it to re-pair", "position": [47.397742, 8.5458512, 30.0]}
{"t": 1795338915.1586, "node": "d1", "type": "handover_timeout", "detail": "A -> B: authority stays with A", "position": [47.397742, 8.5500281, 30.0]}
'''
GS_LOG = r'''
{"t": 1795338147.5341, "node": "A", "type": "linkkey_bad_reply", "drone": "d1", "gs": "B", "reason": "bad_mac"}
{"t": 1795338377.4093, "node": "A", "type": "gcs_app", "sysid": 1, "compid": 190, "gs_compid": 100}
{"t": 1795338402.4363, "node": "A", "type": "status", "drones": {"d1": {"linked": true, "owner": "A", "epoch": 3, "state": "linked", "stage": "flying", "position": [47.397742, 8.5475592, 29.999], "commands_sent": {"1": 52, "3": 10}, "link": {"opened": 1252, "sent": 502, "dropped": {}}, "key_candidates": 0, "dropped_unlinked": {}}}, "counters": {}, "inbox_dropped": {}, "gateway": {"apps": 16, "max_apps": 16, "counters": {"app_table_full": 7310, "unrouted": 44, "for_other_gs": 21}, "endpoints": {"udpin:127.0.0.1:39324": {"rx_frames": 7694, "tx_frames": 1017, "skipped_bytes": 1603065}}}}
{"t": 1795338606.1278, "node": "A", "type": "start", "drones": ["d1"]}
{"t": 1795338606.1534, "node": "A", "type": "paired", "drone": "d1", "again": false}
{"t": 1795338606.1556, "node": "A", "type": "authority_status", "drone": "d1", "owner": "A", "epoch": 1, "state": "linked", "pending_to": null}
{"t": 1795338606.1627, "node": "B", "type": "linkkey_shared", "drone": "d1", "asker": "A"}
{"t": 1795338606.1637, "node": "A", "type": "linkkey_received", "drone": "d1", "gs": "B"}
{"t": 1795338606.1652, "node": "A", "type": "key_granted", "drone": "d1", "gs": "B"}
{"t": 1795338606.3855, "node": "A", "type": "autopilot", "drone": "d1", "autopilot": "px4", "mav_type": 2}
{"t": 1795338606.3863, "node": "A", "type": "mission_upload", "drone": "d1", "items": 7, "autopilot": "px4"}
{"t": 1795338606.4442, "node": "A", "type": "vehicle_text", "drone": "d1", "text": "Armed by external command", "severity": 6}
{"t": 1795338606.4508, "node": "A", "type": "mission_started", "drone": "d1", "result": 0}
{"t": 1795338612.6504, "node": "B", "type": "link_confirmed", "drone": "d1", "how": "linkkey:A", "replaced": false}
{"t": 1795338614.8895, "node": "A", "type": "handover_release", "drone": "d1", "to": "B", "epoch": 1, "position": [47.397742, 8.5490506]}
{"t": 1795338641.9973, "node": "A", "type": "stop", "drones": {"d1": {"linked": true, "owner": "A", "epoch": 3, "state": "linked", "stage": "flying", "position": [47.397742, 8.545594, 0.0], "commands_sent": {"1": 51, "3": 51}, "link": {"opened": 1980, "sent": 175, "dropped": {}}, "key_candidates": 0, "dropped_unlinked": {}}}, "counters": {}, "inbox_dropped": {}}
{"t": 1795338641.999, "node": "A", "type": "closed"}
{"t": 1795338738.3995, "node": "A", "type": "pair_refused", "drone": "d1", "reason": "failsafe: re-pair only on the ground"}
{"t": 1795338738.4003, "node": "A", "type": "failsafe_notice", "drone": "d1", "action": "LAND", "reason": "authority link to A lost"}
{"t": 1795338738.4004, "node": "A", "type": "control_requested", "drone": "d1", "state": "failsafe"}
{"t": 1795338795.9086, "node": "A", "type": "pair_not_needed", "drone": "d1"}
{"t": 1795338915.1598, "node": "A", "type": "handover_failed", "drone": "d1", "epoch": 1, "action": "RTL", "reason": "release timed out"}
'''
ROGUE_LOG = r'''
{"t": 1795338147.5335, "node": "rogue-key-injection", "type": "forged_reply", "drone": "d1", "asker": "A", "replies": 2}
{"t": 1795338223.2737, "node": "rogue-pair-replay", "type": "ready", "wait_go": true}
{"t": 1795338223.5024, "node": "rogue-pair-replay", "type": "captured", "what": "pairing message 1 of A", "bytes": 72}
{"t": 1795338225.4424, "node": "rogue-pair-replay", "type": "go"}
{"t": 1795338239.4517, "node": "rogue-pair-replay", "type": "attack_done", "replayed": 12, "replies": {"ok": 12}}
{"t": 1795338239.4536, "node": "rogue-pair-replay", "type": "closed"}
{"t": 1795338683.5956, "node": "rogue-unauthorized", "type": "unauthorized_attempt", "pair_answered": 0, "pair_refused": 0, "linkkey_replies": 0}
'''
# The testbed's radio log (``zdrone demo --sites``): a site's radio brought up and down from the
# vehicle's true position, the backhaul cut by a scenario.
RADIO_LOG = r'''
{"t": 1795340375.0189, "node": "radio", "type": "radio_link", "site": "site-1", "up": true, "position": [47.397742, 8.545594, 0.0]}
{"t": 1795340382.5018, "node": "radio", "type": "radio_link", "site": "site-2", "up": true, "position": [47.397742, 8.5475892, 30.0]}
{"t": 1795340383.1, "node": "radio", "type": "link_fault", "link": "backhaul-site-1-site-2", "up": false}
{"t": 1795340386.7048, "node": "radio", "type": "radio_link", "site": "site-1", "up": false, "position": [47.397742, 8.550269, 30.0]}
'''
#: event types without a record on purpose: the attacker's account has fields of its own per attack
UNTYPED_BY_DESIGN = {"attack_done"}


def _log(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text.lstrip("\n"))
    return path


# --------------------------------------------------------------------- values of a type, from msgspec
JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-2**53, 2**53) | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=6)


def _values(t: mi.Type) -> st.SearchStrategy[Any]:
    """Every value of a record field's type (as ``msgspec.inspect`` describes it)."""
    if isinstance(t, mi.StructType):
        return st.builds(t.cls, **{f.name: _values(f.type) for f in t.fields})
    if isinstance(t, mi.UnionType):
        return st.one_of([_values(x) for x in t.types])
    if isinstance(t, mi.TupleType):
        return st.tuples(*[_values(x) for x in t.item_types])
    if isinstance(t, mi.VarTupleType):
        return st.lists(_values(t.item_type), max_size=3).map(tuple)
    if isinstance(t, mi.DictType):
        return st.dictionaries(_values(t.key_type), _values(t.value_type), max_size=3)
    if isinstance(t, mi.EnumType):
        return st.sampled_from(list(t.cls))
    simple: dict[type, st.SearchStrategy[Any]] = {
        mi.NoneType: st.none(), mi.BoolType: st.booleans(), mi.IntType: st.integers(-2**53, 2**53),
        mi.FloatType: st.floats(allow_nan=False, allow_infinity=False), mi.StrType: st.text(max_size=12),
        mi.AnyType: JSON_VALUES,
    }
    return simple[type(t)]


def _sample(t: mi.Type) -> Any:
    """One fixed value of a field's type, containers not empty (nested records are exercised too)."""
    if isinstance(t, mi.StructType):
        return t.cls(**{f.name: _sample(f.type) for f in t.fields})
    if isinstance(t, mi.UnionType):
        return _sample(next(x for x in t.types if not isinstance(x, mi.NoneType)))
    if isinstance(t, mi.TupleType):
        return tuple(_sample(x) for x in t.item_types)
    if isinstance(t, mi.VarTupleType):
        return (_sample(t.item_type),)
    if isinstance(t, mi.DictType):
        return {_sample(t.key_type): _sample(t.value_type)}
    if isinstance(t, mi.EnumType):
        return list(t.cls)[-1]
    simple = {mi.BoolType: True, mi.IntType: 7, mi.FloatType: 1.5, mi.StrType: "x", mi.AnyType: {"k": [1, "v", None]}}
    return simple[type(t)]


def _names(cls: type[rec.Record]) -> tuple[set[str], set[str]]:
    """A record's field names as logged (without ``t`` and ``node``): all of them, the required ones."""
    fields = [f for f in mi.type_info(cls).fields if f.name not in ("t", "node")]
    return {f.encode_name for f in fields}, {f.encode_name for f in fields if f.required}


# ------------------------------------------------------------------------------------ round trips
@pytest.mark.parametrize("cls", rec.ALL_RECORDS, ids=lambda c: c.__name__)
def test_every_record_round_trips(cls):
    r = _sample(mi.type_info(cls))
    line = rec.encode_record(r)
    back = rec.decode_record(line)
    assert type(back) is cls and back == r  # the record of its own writer, not another's of the same tag
    assert rec.misfit(line) is None and rec.record_type(back) == msgspec.json.decode(line)["type"]


UNTYPED = st.builds(
    rec.UntypedRecord, t=st.floats(allow_nan=False, allow_infinity=False), node=st.text(max_size=8),
    type=st.text(max_size=12).filter(lambda s: not rec.records_for(s)),
    fields=st.dictionaries(st.text(max_size=6).filter(lambda k: k not in ("t", "node", "type")), JSON_VALUES, max_size=3))
ANY_RECORD = st.sampled_from(rec.ALL_RECORDS).flatmap(lambda cls: _values(mi.type_info(cls))) | UNTYPED


@given(ANY_RECORD)
def test_decoding_an_encoded_record_gives_it_back(r):
    back = rec.decode_record(rec.encode_record(r))
    assert type(back) is type(r) and back == r


def test_records_written_to_a_log_are_read_back(tmp_path):
    log = EventLog(tmp_path / "all.jsonl", "d1", strict=True)
    written = [log.write_record(_sample(mi.type_info(cls))) for cls in rec.ALL_RECORDS]
    stamped = log.write_record(rec.Paired(gs="A"))  # t and node unset: the log's clock and name
    log.close()
    got = read_records(tmp_path / "all.jsonl")
    assert got.records == [*written, stamped] and got.undecodable == 0
    assert stamped.node == "d1" and stamped.t > 1e9


# ----------------------------------------------------------------------------------- real logs
@pytest.mark.parametrize("name, text, vocabulary", [
    ("drone.jsonl", DRONE_LOG, rec.DRONE_RECORDS), ("A.jsonl", GS_LOG, rec.GS_RECORDS),
    ("rogue.jsonl", ROGUE_LOG, trec.TESTBED_RECORDS), ("radio.jsonl", RADIO_LOG, trec.TESTBED_RECORDS)],
    ids=["drone", "gs", "rogue", "radio"])
def test_real_logs_decode_to_typed_records_and_keep_every_field(tmp_path, name, text, vocabulary):
    lines = text.strip().splitlines()
    got = read_records(_log(tmp_path, name, text))
    assert got.undecodable == 0 and len(got.records) == len(lines)
    assert {r.type for r in got.untyped} <= UNTYPED_BY_DESIGN
    for line, r in zip(lines, got.records):
        if isinstance(r, rec.UntypedRecord):
            continue
        assert type(r) in vocabulary, (type(r).__name__, line)
        written, again = msgspec.json.decode(line), msgspec.json.decode(rec.encode_record(r))
        assert all(k in again and again[k] == v for k, v in written.items()), line  # nothing dropped or changed


def test_typed_fields_read_as_attributes(tmp_path):
    drone = read_records(_log(tmp_path, "drone.jsonl", DRONE_LOG)).records
    [hand] = rec.only(drone, rec.HandoverComplete)
    assert (hand.from_, hand.to, hand.epoch, hand.kind) == ("A", "B", 2, "handover") and len(hand.position or ()) == 3
    [status] = rec.only(drone, rec.DroneStatus)
    assert status.state is AuthorityState.LINKED and all(isinstance(ln.state, LinkState) for ln in status.links.values())
    assert rec.only(drone, rec.DroneState) == [status, *rec.only(drone, rec.DroneStop)]
    assert rec.only(drone, rec.AuthorityMoved) == rec.only(drone, rec.AuthorityChange) + [hand]
    gs_status = rec.only(read_records(_log(tmp_path, "A.jsonl", GS_LOG)).records, rec.GsStatus)
    assert [s.drones["d1"].linked for s in gs_status] == [True]


@pytest.mark.parametrize("text", [DRONE_LOG, GS_LOG, ROGUE_LOG, RADIO_LOG], ids=["drone", "gs", "rogue", "radio"])
def test_a_record_as_logged_is_its_line(text):
    """Every field of the line, as written; besides them only the defaults of fields it left out."""
    for line in text.strip().splitlines():
        r = rec.decode_record(line)
        written, logged = msgspec.json.decode(line), rec.logged(r)
        assert list(logged)[:3] == ["t", "node", "type"] and {k: logged[k] for k in written} == written, line
        defaults = set() if isinstance(r, rec.UntypedRecord) else {
            f.encode_name for f in msgspec.structs.fields(r) if not f.required}
        assert set(logged) - set(written) <= defaults, line


def test_the_launcher_reads_typed_records(tmp_path):
    """The watch loop and the summary of ``zdrone demo`` on typed records: summary.json is plain JSON
    with the logged values, and a scenario's predicate sees the records."""
    import json

    from zdrone.sil.launcher import Demo, DemoOptions, LiveView, Outcome, watch_state

    for name, text in (("drone.jsonl", DRONE_LOG), ("A.jsonl", GS_LOG), ("rogue.jsonl", ROGUE_LOG)):
        _log(tmp_path, name, text)
    demo = Demo(DemoOptions(out=tmp_path, live=False, quiet=True, report=False), tmp_path)
    demo._fire = lambda *args, **kw: None  # type: ignore[method-assign]  # no processes to start or signal
    state, live = watch_state(), LiveView("nominal", enabled=False, quiet=True)
    drone = read_records(tmp_path / "drone.jsonl").records
    for ev in drone:
        demo._on_event(ev, state, live)
    summary = demo._summarize(state, 1.0, {}, timed_out=False)
    assert json.loads((tmp_path / "summary.json").read_text()) == json.loads(json.dumps(summary))
    assert summary["handovers"] == [{"from": "A", "to": "B", "epoch": 2, "time": 1795338614.8907, "kind": "handover",
                                     "position": [47.397742, 8.5490506, 30.0]}]
    assert summary["failsafe"] == {"action": "LAND", "reason": "authority link to A lost",
                                   "detect_to_command_ms": 1.2257340003998252, "position": [47.397742, 8.5466507, 30.0]}
    assert summary["final_owner"] == "A" and summary["final_position"] == [47.397742, 8.545594, 0.0]
    assert summary["keys"]["A"] == {"live": True, "candidates": 0, "expired": 0, "dropped_unlinked": {}}
    assert summary["attacks"] == {"pair-replay": {"replayed": 12, "replies": {"ok": 12}}}
    assert summary["authority_link"]["worst_state"] == "ok" and summary["gs_counters"] == {"A": {}}
    assert demo.progress["status"]["owner"] == "A"  # the benches' displays: the status as logged
    assert "authority A -> B (epoch 2, handover)" in "\n".join(live.lines)
    o = Outcome(summary, drone, {"A": read_records(tmp_path / "A.jsonl").records, "B": [], "X": []},
                read_records(tmp_path / "rogue.jsonl").records)
    assert o.rogue_done("pair-replay")["replayed"] == 12 and o.rogue_done("no-key") == {}
    assert [c.gs for c in o.confirmed("A", "pair")] == ["A"] and len(o.rogue_events("pair-replay", trec.Captured)) == 1


def test_the_launcher_reads_the_radio_log(tmp_path):
    """Each radio/backhaul change, and for a site's radio lost: the paths still connected, how soon
    the drone noticed, and the copies the other paths delivered."""
    from zdrone.sil.summary import radio_summary

    radio_log = read_records(_log(tmp_path, "radio.jsonl", RADIO_LOG)).records
    ep1, ep2 = "tls/10.0.0.1:7447", "tls/10.0.0.2:7447"
    drone = [rec.PathState(t=1795340375.5, node="d1", router=ep1, connected=True),
             rec.PathState(t=1795340382.6, node="d1", router=ep2, connected=True),
             rec.PathState(t=1795340387.0, node="d1", router=ep1, connected=False)]
    drone.append(msgspec.structs.replace(rec.only(read_records(_log(tmp_path, "drone.jsonl", DRONE_LOG)).records,
                                                  rec.DroneStop)[0], inbox_dropped={"up:duplicate_path": 77}))
    radio = radio_summary(radio_log, drone, {ep1: "site-1", ep2: "site-2"})
    assert radio["changes"] == [
        {"t": 1795340375.0189, "site": "site-1", "link": None, "up": True},
        {"t": 1795340382.5018, "site": "site-2", "link": None, "up": True},
        {"t": 1795340383.1, "site": None, "link": "backhaul-site-1-site-2", "up": False},
        {"t": 1795340386.7048, "site": "site-1", "link": None, "up": False}]
    assert radio["site_losses"] == [{"site": "site-1", "other_paths_connected": ["site-2"], "noticed_ms": 295.2}]
    assert radio["path_duplicates"] == 77


def test_the_report_reads_typed_records(tmp_path):
    from zdrone.report import write_report

    _log(tmp_path, "drone.jsonl", DRONE_LOG)
    page = write_report(tmp_path).read_text()
    assert page.count("data:image/png;base64,") == 3 and (tmp_path / "track.png").stat().st_size > 1000
    assert "<td>handover_complete</td><td>from=A, to=B, epoch=2, kind=handover" in page
    assert "<td>status</td>" not in page and "<td>link_state</td>" not in page  # in the plots, not the table
    assert "<td>node: pair_answered</td>" in page  # the final status's counters


# ------------------------------------------------------------------------- the writers' events
def _const(node: ast.AST | None) -> str | None:
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else None


def _written_names(call: ast.Call) -> tuple[set[str], bool]:
    """The field names an ``events.write`` call writes, and whether it also writes some it does not
    name (``**fields``)."""
    names: set[str] = set()
    unnamed = False
    for kw in call.keywords:
        if kw.arg is not None:
            names.add(kw.arg)
        elif isinstance(kw.value, ast.Dict) and all(_const(k) for k in kw.value.keys):
            names |= {_const(k) for k in kw.value.keys}  # type: ignore[misc]
        else:
            unnamed = True
    return names, unnamed


def _is_event_write(call: ast.Call) -> bool:
    f = call.func
    return isinstance(f, ast.Attribute) and f.attr == "write" and bool(call.args) and (
        (isinstance(f.value, ast.Attribute) and f.value.attr == "events") or (isinstance(f.value, ast.Name) and f.value.id == "events"))


def _fits(type_: str, names: set[str], unnamed: bool, vocabulary: tuple[type[rec.Record], ...]) -> bool:
    for cls in rec.records_for(type_):
        known, required = _names(cls)
        if cls in vocabulary and names <= known and (unnamed or required <= names):
            return True
    return False


def _calls(path: Path) -> list[ast.Call]:
    return [n for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.Call)]


NODE_WRITERS = {
    ROOT / "nodes" / "drone.py": rec.DRONE_RECORDS, ROOT / "net" / "runtime.py": rec.DRONE_RECORDS + rec.GS_RECORDS,
    GS_ROOT / "station.py": rec.GS_RECORDS, GS_ROOT / "gateway.py": rec.GS_RECORDS, GS_ROOT / "core.py": rec.GS_RECORDS,
    GS_ROOT / "session.py": rec.GS_RECORDS,
    GS_ROOT / "opcontrol.py": rec.GS_RECORDS,
}


def _record_class(node: ast.AST) -> str | None:
    """``rec.X`` -> ``X``."""
    return node.attr if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "rec" else None


def test_the_nodes_write_typed_records_only():
    """Issue 19: the drone node, the GS and their runtime write typed records (``write_record``, or
    ``write_as`` a named record class for a status they assemble), never a type string and fields;
    every record they make is of their own vocabulary; the GS core's ``Log`` actions hold records."""
    checked, bad = 0, []
    for path, vocabulary in NODE_WRITERS.items():
        names = {c.__name__ for c in vocabulary}
        for call in _calls(path):
            f = call.func
            if isinstance(f, ast.Attribute) and f.attr == "write" and call.args and _const(call.args[0]) is not None:
                bad.append(f"{path.name}:{call.lineno}: events.write({_const(call.args[0])!r}, ...) untyped")
            cls = _record_class(f)
            if cls is not None and cls[0].isupper() and hasattr(rec, cls) and isinstance(getattr(rec, cls), type):
                checked += 1
                if issubclass(getattr(rec, cls), rec.Record) and cls not in names and cls != "Record":
                    bad.append(f"{path.name}:{call.lineno}: {cls} is not a record of this writer")
            typed_at = {"write_as": 0, "close": 1}  # runtime.close(final, stop): the node names its stop record
            if isinstance(f, ast.Attribute) and f.attr in typed_at and len(call.args) > typed_at[f.attr]:
                arg = call.args[typed_at[f.attr]]
                if f.attr == "close" and not (isinstance(f.value, ast.Attribute) and f.value.attr == "rt"):
                    continue
                checked += 1
                if path.name == "runtime.py" and isinstance(arg, ast.Name) and arg.id == "stop":
                    continue  # the class its caller named (checked at the caller)
                if _record_class(arg) not in names:
                    bad.append(f"{path.name}:{call.lineno}: {f.attr} of {ast.dump(arg)[:60]}")
            if isinstance(f, ast.Name) and f.id == "Log":
                checked += 1
                if len(call.args) != 1 or isinstance(call.args[0], (ast.Constant, ast.Dict)):
                    bad.append(f"{path.name}:{call.lineno}: Log of no record")
    for call in _calls(ROOT / "core" / "authority.py"):  # the authority machine's notes, which the drone writes
        if isinstance(call.func, ast.Name) and call.func.id == "Note" and call.args:
            type_ = _const(call.args[0])
            checked += 1
            if type_ is None or not any(issubclass(c, rec.AuthorityNote) for c in rec.records_for(type_)):
                bad.append(f"authority.py:{call.lineno}: note {type_}")
    assert checked > 60 and not bad, "untyped events:\n" + "\n".join(bad)


def test_every_event_the_testbed_writes_has_its_record():
    """The testbed's attackers (``zdrone.sil.rogue`` and its package ``zdrone.sil.attackers``) write their
    records too; their ``attack_done`` alone is untyped by design (its fields are each attack's own)."""
    checked, bad = 0, []
    vocabulary = trec.TESTBED_RECORDS
    names = {c.__name__ for c in vocabulary}
    for path in [ROOT / "sil" / "rogue.py", *sorted((ROOT / "sil" / "attackers").glob("*.py"))]:
        for call in _calls(path):
            f = call.func
            if _is_event_write(call):
                type_, (written, unnamed) = _const(call.args[0]), _written_names(call)
                checked += 1
                if type_ not in UNTYPED_BY_DESIGN:
                    bad.append(f"{path.name}:{call.lineno}: {type_} {sorted(written)} untyped")
            elif isinstance(f, ast.Attribute) and f.attr == "write_record" and call.args and isinstance(call.args[0], ast.Call):
                inner = call.args[0].func
                cls = inner.attr if isinstance(inner, ast.Attribute) else None
                checked += 1
                if cls not in names:
                    bad.append(f"{path.name}:{call.lineno}: {cls}")
    assert checked > 20 and not bad, "\n".join(bad)


def test_testbed_records_live_in_the_testbed():
    """The product's vocabularies hold no testbed record; the testbed's module registers its own."""
    product = set(rec.DRONE_RECORDS) | set(rec.GS_RECORDS)
    assert not product & (set(trec.TESTBED_RECORDS) - {rec.Closed, rec.Suppressed})
    assert rec.VOCABULARIES["testbed"] == trec.TESTBED_RECORDS
    assert all(c.__module__ == "zdrone.sil.testbed_records" for c in set(trec.TESTBED_RECORDS) - {rec.Closed, rec.Suppressed})


def _returned_keys(path, name: str) -> set:
    tree = ast.parse(path.read_text())
    [fn] = [f for f in ast.walk(tree) if isinstance(f, ast.FunctionDef) and f.name == name]
    [returned] = [n.value for n in ast.walk(fn) if isinstance(n, ast.Return) and isinstance(n.value, ast.Dict)]
    return {_const(k) for k in returned.keys if k is not None}  # None: a ``**`` merge


def test_the_drone_status_has_the_fields_of_its_record():
    """The adapter's status (vehicle, inbox, paths, radio) merged with the core's report."""
    names = _returned_keys(ROOT / "nodes" / "drone.py", "status") | _returned_keys(ROOT / "nodes" / "drone_core.py", "report")
    assert _fits("status", names, False, rec.DRONE_RECORDS)  # type: ignore[misc]


# ----------------------------------------------------------------------------------- misfits
@pytest.mark.parametrize("type_, fields, words", [
    ("paired", {"gss": "A"}, "unknown field `gss`"),
    ("failsafe", {"action": "LAND", "reason": "lost", "position": None}, "detect_to_command_ms"),
    ("link_state", {"gs": "A", "state": "gone"}, "Invalid enum value 'gone'"),
    ("handover_complete", {"frm": "A", "to": "B", "epoch": 2, "kind": "handover", "time": 1.0, "position": None}, "frm"),
    ("failsafe", {"action": "LAND", "reason": "lost", "detect_to_command_ms": float("nan"), "position": None}, "not an event line"),
], ids=["misspelled", "missing", "mistyped", "misspelled-from", "nan"])
def test_a_misfit_is_an_error_in_tests(tmp_path, type_, fields, words):
    log = EventLog(tmp_path / "d.jsonl", "d1", strict=True)
    with pytest.raises(EventShapeError, match=words):
        log.write(type_, **fields)
    log.close()
    assert (tmp_path / "d.jsonl").read_text() == ""


def test_a_misfit_is_counted_logged_once_and_kept_in_production(tmp_path, caplog):
    log = EventLog(tmp_path / "d.jsonl", "d1", strict=False)
    with caplog.at_level(logging.ERROR, logger="zdrone.net.eventlog"):
        for _ in range(3):
            log.write("paired", gss="A")
    log.write("paired", gs="A")
    log.close()
    assert log.misfits == {"paired": 3} and len(caplog.records) == 1 and "gss" in caplog.text
    got = read_records(tmp_path / "d.jsonl").records
    assert [type(r) for r in got] == [rec.UntypedRecord] * 3 + [rec.Paired]
    assert got[0].fields == {"gss": "A"}  # nothing lost


def test_events_of_a_type_without_record_are_written_unchecked(tmp_path):
    log = EventLog(tmp_path / "r.jsonl", "rogue-x", strict=True)
    log.write("attack_done", sent=3, replies={"ok": 0})
    log.close()
    [done] = read_records(tmp_path / "r.jsonl").records
    assert isinstance(done, rec.UntypedRecord) and done.fields == {"sent": 3, "replies": {"ok": 0}}


def test_strictness_comes_from_the_environment(monkeypatch):
    monkeypatch.setenv(STRICT_ENV, "1")
    assert EventLog(None, "d1").strict
    monkeypatch.setenv(STRICT_ENV, "0")
    assert not EventLog(None, "d1").strict


def test_a_record_made_with_a_wrong_value_is_caught_when_written():
    with pytest.raises(EventShapeError, match="Expected `str`"):
        EventLog(None, "d1", strict=True).write_record(rec.Paired(gs=3))  # type: ignore[arg-type]


def test_reading_skips_a_half_written_last_line_and_counts_other_bad_lines(tmp_path):
    good = '{"t": 1.0, "node": "d1", "type": "paired", "gs": "A"}'
    path = tmp_path / "d.jsonl"
    path.write_text(f"{good}\nnot json\n\n{{\"type\": \"paired\", \"gs\": \"A\"}}\n{good}\n{good[:20]}")
    got = read_records(path)
    assert got.records == [rec.Paired(t=1.0, node="d1", gs="A")] * 2 and got.undecodable == 2
    path.write_text(good)  # a complete last line without its newline is kept
    assert len(read_records(path).records) == 1
