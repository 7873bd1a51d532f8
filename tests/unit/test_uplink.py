"""Uplink policy: allowlist classification of every known message id, policy validation, the fleet's
``uplink`` field, and MAVLink frames with ids no dialect defines."""

from __future__ import annotations

import json
from pathlib import Path

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega, common

from tests.corepair import make_pair
from zdrone.cli import main
from zdrone.core.authority import (RegionChanged, AuthorityMachine, Config, DropFrame, Forward, Frame, HaDrop, GrantHeard, LinkChanged,
                                   PairingDone)
from zdrone.core.envelope import Opened
from zdrone.core.fleet import FleetError, encode_fleet, parse_fleet
from zdrone.core.mavlink import (CRC_EXTRA, MESSAGE_CLASSES, FrameCodec, FrameError, crc_ok, crc_seed, encode_raw, read_header,
                                 rewrite_source, split_frames)
from zdrone.core.tbm import LinkState
from zdrone.core.uplink import (DEFAULT_DENIED, DEFAULT_POLICY, DEFAULT_READ_ONLY, DENIED_NAMES, MAX_MSGID,
                                READ_ONLY_NAMES, UplinkClass, UplinkPolicy)
from zdrone.fleet.files import init_fleet, load_fleet

try:
    from pymavlink.dialects.v20 import development
except ImportError:  # pragma: no cover
    development = None

DIALECTS = [d for d in (common, development, ardupilotmega) if d is not None]
UNKNOWN_IDS = [410, 411, 512, 60000, MAX_MSGID]  # PX4's EVENT and friends, CONTROL_STATUS, made-up ids
SYSIDS = {"A": 4, "B": 3}


def name_to_id() -> dict[str, int]:
    out: dict[str, int] = {}
    for d in DIALECTS:
        out.update({cls.msgname: msgid for msgid, cls in d.mavlink_map.items()})
    return out


def dialect_frame(dialect, msgid: int, sysid: int) -> bytes:
    """A real MAVLink 2 frame of ``msgid``: full-length payload, the dialect's CRC_EXTRA."""
    cls = dialect.mavlink_map[msgid]
    payload = bytes((7 + i) % 255 + 1 for i in range(cls.unpacker.size))  # no zero byte: nothing truncated
    frame = encode_raw(msgid, cls.crc_extra, payload, sysid, 190)
    msgs = dialect.MAVLink(None).parse_buffer(frame)
    assert msgs and msgs[0].get_msgId() == msgid, (dialect.__name__, msgid)  # the dialect decodes it
    return frame


def every_frame(sysid: int) -> list[tuple[int, bytes]]:
    frames = [(msgid, dialect_frame(d, msgid, sysid)) for d in DIALECTS for msgid in sorted(d.mavlink_map)]
    frames += [(msgid, encode_raw(msgid, 0x5A, b"\x01\x02\x03", sysid, 190)) for msgid in UNKNOWN_IDS]
    return frames


def linked_a_and_b() -> AuthorityMachine:
    """LINKED with owner A; B linked too (its key granted by A)."""
    m = AuthorityMachine(Config(authorized=frozenset({"A", "B"})))
    m.handle(RegionChanged(0.0, frozenset({"A"})))  # home, in A's coverage: the first pairing needs it
    m.handle(PairingDone(0.0, "A"))
    m.handle(LinkChanged(0.1, "A", LinkState.OK))
    m.handle(GrantHeard(0.2, "A", "B"))
    m.handle(LinkChanged(0.3, "B", LinkState.OK))
    assert m.owner == "A" and set(m.links) == {"A", "B"}
    return m


def expected(policy: UplinkPolicy, msgid: int, gs: str) -> Forward | DropFrame:
    """The outcome spelled out from the policy's definition, independently of ``classify``."""
    if msgid in DEFAULT_DENIED and msgid not in policy.allow:
        return DropFrame(gs, HaDrop.DENIED_BY_POLICY)
    if msgid in DEFAULT_READ_ONLY or msgid in policy.read_only_extra:
        return Forward(gs)
    return Forward(gs) if gs == "A" else DropFrame(gs, HaDrop.NOT_AUTHORITY)


CUSTOM = UplinkPolicy(read_only_extra=[111, 60000], allow=[126])  # TIMESYNC and an unknown id; SERIAL_CONTROL


# ------------------------------------------------------------------ the whole table
@pytest.mark.parametrize("policy", [DEFAULT_POLICY, CUSTOM], ids=["default", "custom"])
def test_every_message_id_gets_exactly_the_policys_outcome(policy: UplinkPolicy):
    m = linked_a_and_b()
    links = {gs: make_pair(gs=gs, gs_sysid=sysid) for gs, sysid in SYSIDS.items()}
    seen: set[int] = set()
    want_drops: dict[HaDrop, int] = {}
    for gs, pair in links.items():
        for msgid, frame in every_frame(SYSIDS[gs]):
            opened = pair.drone.open(pair.gs.seal(frame), 1.0)  # through the envelope, as on the drone
            assert isinstance(opened, Opened) and opened.header is not None, (msgid, opened)
            assert opened.header.msgid == msgid and opened.header == read_header(frame)
            got = m.handle(Frame(1.0, gs, policy.classify(opened.header.msgid)))
            want = expected(policy, msgid, gs)
            assert got == [want], (gs, msgid, MESSAGE_CLASSES.get(msgid, "unknown"))
            if isinstance(want, DropFrame):
                want_drops[want.reason] = want_drops.get(want.reason, 0) + 1
            seen.add(msgid)
    assert {r: n for r, n in m.drops.items() if n} == want_drops
    assert m.owner == "A" and m.epoch == 1
    assert seen >= set(MESSAGE_CLASSES) and len(MESSAGE_CLASSES) > 250


def test_the_reported_gaps_are_closed():
    """Ids a GS without authority could send while only a denylist of commanding ids was blocked."""
    ids = name_to_id()
    m = linked_a_and_b()
    for name in ("SET_GPS_GLOBAL_ORIGIN", "GPS_INPUT", "VISION_POSITION_ESTIMATE", "FILE_TRANSFER_PROTOCOL",
                 "PARAM_EXT_SET", "SET_ACTUATOR_CONTROL_TARGET", "LOG_ERASE", "LOG_REQUEST_DATA", "MISSION_REQUEST_LIST",
                 "MISSION_ACK", "REQUEST_DATA_STREAM", "SYSTEM_TIME", "TIMESYNC", "GPS_RTCM_DATA", "COMMAND_LONG"):
        cls = DEFAULT_POLICY.classify(ids[name])
        assert cls is UplinkClass.AUTHORITY_ONLY, name
        assert m.handle(Frame(1.0, "B", cls)) == [DropFrame("B", HaDrop.NOT_AUTHORITY)], name
        assert m.handle(Frame(1.0, "A", cls)) == [Forward("A")], name
    for name in ("SERIAL_CONTROL", "SETUP_SIGNING"):
        cls = DEFAULT_POLICY.classify(ids[name])
        assert cls is UplinkClass.DENIED, name
        for gs in ("A", "B"):
            assert m.handle(Frame(1.0, gs, cls)) == [DropFrame(gs, HaDrop.DENIED_BY_POLICY)], name
    for name in ("HEARTBEAT", "PARAM_REQUEST_LIST", "PARAM_REQUEST_READ"):
        assert m.handle(Frame(1.0, "B", DEFAULT_POLICY.classify(ids[name]))) == [Forward("B")], name


def test_allowlists_name_the_right_ids_and_nothing_else_is_read_only():
    ids = name_to_id()
    assert {n: ids[n] for n in READ_ONLY_NAMES} == READ_ONLY_NAMES
    assert {n: ids[n] for n in DENIED_NAMES} == DENIED_NAMES
    read_only = {i for i in MESSAGE_CLASSES if DEFAULT_POLICY.classify(i) is UplinkClass.READ_ONLY}
    assert read_only == DEFAULT_READ_ONLY  # widening the allowlist is a deliberate edit of uplink.py
    assert not any(MESSAGE_CLASSES[i].msgname.startswith(("MISSION_", "LOG_", "COMMAND_")) for i in read_only)


def test_frame_header_commanding_means_not_read_only():
    a = make_pair()
    assert not read_header(a.heartbeat()).commanding
    assert read_header(a.command()).commanding
    assert read_header(encode_raw(126, CRC_EXTRA[126], b"\x01", 4, 190)).commanding  # denied: commanding too
    assert read_header(encode_raw(60000, 0, b"\x01", 4, 190)).commanding  # unknown: authority only


# ------------------------------------------------------------------ classification and validation
ids = st.integers(0, MAX_MSGID)
policies = st.builds(
    lambda extra, allow: UplinkPolicy(read_only_extra=sorted(extra), allow=sorted(allow)),
    st.sets(ids.filter(lambda i: i not in DEFAULT_DENIED), max_size=8),
    st.sets(st.sampled_from(sorted(DEFAULT_DENIED))),
)


@given(policies, st.one_of(ids, st.sampled_from(sorted(DEFAULT_READ_ONLY | DEFAULT_DENIED))))
def test_any_id_is_in_exactly_one_class(policy: UplinkPolicy, msgid: int):
    classes = {c for c in UplinkClass if policy.classify(msgid) is c}
    assert len(classes) == 1
    read_only = msgid in DEFAULT_READ_ONLY or msgid in policy.read_only_extra
    denied = msgid in DEFAULT_DENIED and msgid not in policy.allow
    assert not (read_only and denied)
    want = UplinkClass.READ_ONLY if read_only else UplinkClass.DENIED if denied else UplinkClass.AUTHORITY_ONLY
    assert classes == {want}
    # the policy survives the fleet file's round trip with the same verdicts
    again = msgspec.convert(msgspec.to_builtins(policy), UplinkPolicy)
    assert again == policy and again.classify(msgid) is want


def test_default_policy_classes():
    assert DEFAULT_POLICY.is_default and UplinkPolicy() == DEFAULT_POLICY
    assert DEFAULT_POLICY.classify(0) is UplinkClass.READ_ONLY
    assert DEFAULT_POLICY.classify(126) is UplinkClass.DENIED
    assert DEFAULT_POLICY.classify(76) is UplinkClass.AUTHORITY_ONLY
    assert DEFAULT_POLICY.classify(MAX_MSGID) is UplinkClass.AUTHORITY_ONLY
    assert CUSTOM.classify(126) is UplinkClass.AUTHORITY_ONLY and CUSTOM.classify(256) is UplinkClass.DENIED
    assert CUSTOM.classify(111) is UplinkClass.READ_ONLY and CUSTOM.classify(60000) is UplinkClass.READ_ONLY


@pytest.mark.parametrize("raw, words", [
    ({"read_only_extra": [-1]}, ">= 0"),
    ({"read_only_extra": [MAX_MSGID + 1]}, "<= 16777215"),
    ({"allow": ["SERIAL_CONTROL"]}, "Expected `int`"),
    ({"allow": [126], "read_only_extra": [126]}, "in both read_only_extra and allow"),
    ({"read_only_extra": [256]}, "256 is denied by default"),
    ({"allow": [76]}, "76 in allow is not denied by default"),
    ({"deny": [76]}, "unknown field `deny`"),
])
def test_policy_validation_errors(raw: dict, words: str):
    with pytest.raises(msgspec.ValidationError, match=words.replace("`", ".").replace("=", ".")):
        msgspec.convert(raw, UplinkPolicy)


def test_policy_constructor_validates_too():
    with pytest.raises(ValueError, match="in both"):
        UplinkPolicy(read_only_extra=[126], allow=[126])


# ------------------------------------------------------------------ frames with unknown ids
@pytest.mark.parametrize("msgid", UNKNOWN_IDS + [152, 436])  # MEMINFO (ardupilotmega), CURRENT_MODE
def test_read_header_accepts_any_message_id(msgid: int):
    f = encode_raw(msgid, CRC_EXTRA.get(msgid, 0x33), b"\x05\x06\x07", 1, 1, seq=9)
    h = read_header(f)
    assert (h.msgid, h.sysid, h.compid, h.seq, h.length, h.version) == (msgid, 1, 1, 9, len(f), 2)
    assert crc_ok(f) is (msgid in CRC_EXTRA)
    with pytest.raises(FrameError):
        read_header(f[:-1])  # the length checks stay
    with pytest.raises(FrameError):
        read_header(bytes([f[0], f[1], 0x02]) + f[3:])  # and the incompat-flag check


def test_the_crc_extra_map_covers_the_dialects():
    for d in DIALECTS:
        for msgid, cls in d.mavlink_map.items():
            assert CRC_EXTRA[msgid] == cls.crc_extra
    meminfo = encode_raw(152, ardupilotmega.mavlink_map[152].crc_extra, b"\x01\x02\x03\x04", 1, 1)
    assert crc_ok(meminfo) and not crc_ok(meminfo[:-1] + bytes([meminfo[-1] ^ 1]))


def test_rewrite_source_of_an_unknown_id_keeps_its_own_checksum_seed():
    unknown = encode_raw(60000, 0x5A, b"\x01", 1, 1)  # an id of no dialect here
    g = rewrite_source(unknown, 4, 100)
    assert read_header(g).sysid == 4 and crc_seed(g) == 0x5A
    broken = unknown[:-1] + bytes([unknown[-1] ^ 0x40])
    assert crc_seed(broken) is None  # a checksum no seed fits: a corrupted frame
    with pytest.raises(FrameError, match="fits no CRC_EXTRA"):
        rewrite_source(broken, 4, 100)
    meminfo = encode_raw(152, CRC_EXTRA[152], b"\x01\x02", 245, 190)
    g = rewrite_source(meminfo, 4, 100)
    assert read_header(g).sysid == 4 and crc_ok(g)


def test_split_frames_passes_unknown_ids_between_frames():
    hb = FrameCodec(1).encode(common.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3))
    event = encode_raw(410, 160, bytes(range(1, 20)), 1, 1)  # PX4's EVENT: no dialect here defines it
    frames, rest, skipped = split_frames(hb + event + hb)
    assert frames == [hb, event, hb] and rest == b"" and skipped == 0
    assert split_frames(event) == ([event], b"", 0)  # a datagram of its own
    # garbage that looks like an unknown-id frame but is not delimited is skipped, not taken
    frames, _, skipped = split_frames(b"\xfd\x01\x00\x00\x00\x01\x01\x60\xea\x00\x07\xaa\xbb" + b"zz" + hb)
    assert frames == [hb] and skipped == 15


# ------------------------------------------------------------------ the fleet's uplink field
@pytest.fixture()
def fleet_dir(tmp_path: Path) -> Path:
    init_fleet(tmp_path / "fleet")
    return tmp_path / "fleet"


def edit_fleet(fleet_dir: Path, edit) -> Path:
    path = fleet_dir / "fleet.json5"
    data = json.loads("\n".join(line for line in path.read_text().splitlines() if not line.startswith("//")))
    edit(data)
    path.write_text(json.dumps(data))
    return path


def test_default_fleet_has_default_policies_and_writes_no_uplink(fleet_dir: Path):
    fleet = load_fleet(fleet_dir)
    assert all(n.uplink == DEFAULT_POLICY for n in fleet.nodes.values())
    assert "uplink" not in (fleet_dir / "fleet.json5").read_text()


def test_drone_uplink_policy_is_read_and_written(fleet_dir: Path):
    edit_fleet(fleet_dir, lambda f: f["nodes"]["d1"].__setitem__("uplink", {"read_only_extra": [111], "allow": [126]}))
    fleet = load_fleet(fleet_dir)
    assert fleet.nodes["d1"].uplink == UplinkPolicy(read_only_extra=[111], allow=[126])
    assert fleet.nodes["d1"].uplink.classify(126) is UplinkClass.AUTHORITY_ONLY
    again = parse_fleet(encode_fleet(fleet))
    assert again == fleet and again.nodes["d1"].uplink.classify(111) is UplinkClass.READ_ONLY


@pytest.mark.parametrize("node, uplink, field, words", [
    ("d1", {"allow": [126], "read_only_extra": [126]}, "$.nodes.d1.uplink", "in both"),
    ("d1", {"read_only_extra": [-5]}, "$.nodes.d1.uplink.read_only_extra[0]", ">= 0"),
    ("d1", {"allow": [16777216]}, "$.nodes.d1.uplink.allow[0]", "<= 16777215"),
    ("d1", {"allow": [0]}, "$.nodes.d1.uplink", "not denied by default"),
    ("d1", {"colour": "red"}, "$.nodes.d1.uplink", "unknown field"),
    ("d1", [0], "$.nodes.d1.uplink", "Expected `object`"),
    ("A", {"read_only_extra": [111]}, "$.nodes.A.uplink", "only drones have an uplink policy"),
])
def test_bad_uplink_is_one_line_naming_the_field(capsys, fleet_dir: Path, node, uplink, field, words):
    path = edit_fleet(fleet_dir, lambda f: f["nodes"][node].__setitem__("uplink", uplink))
    with pytest.raises(FleetError) as exc:
        load_fleet(fleet_dir)
    assert f"field {field}:" in str(exc.value) and words in str(exc.value), str(exc.value)
    code = main(["fleet", "show", "--dir", str(fleet_dir)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and str(path) in err and field in err, err


def test_a_gs_may_carry_an_empty_uplink(fleet_dir: Path):
    edit_fleet(fleet_dir, lambda f: f["nodes"]["A"].__setitem__("uplink", {}))
    assert load_fleet(fleet_dir).nodes["A"].uplink.is_default


def test_a_policy_finds_its_table_on_first_use_only(fleet_dir: Path):
    """A drone holds every drone's policy and classifies under its own: the others hold no table."""
    fleet = load_fleet(fleet_dir)
    policies = [v.uplink for v in fleet.nodes.values() if v.role == "drone"]
    assert all("_table" not in p.__dict__ for p in policies)
    assert policies[0].classify(common.MAVLINK_MSG_ID_HEARTBEAT) is UplinkClass.READ_ONLY
    assert "_table" in policies[0].__dict__ and all("_table" not in p.__dict__ for p in policies[1:])
