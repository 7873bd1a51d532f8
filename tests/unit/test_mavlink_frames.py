"""Every well-formed frame passes: the header needs no message table (MAVLink 1 and 2, signed or not,
any id, any dialect); decoding knows common + development + ardupilotmega and never raises; the GCS
gateway's source rewrite keeps each frame's own checksum seed, ids of no dialect included."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, strategies as st
from pymavlink.dialects.v10 import common as mav1
from pymavlink.dialects.v20 import all as every_dialect
from pymavlink.dialects.v20 import ardupilotmega as apm, common as mav, development as dev
from pymavlink.generator import mavparse

import zdrone.core.mavlink as core_mavlink
from zdrone.core.mavlink import (CRC_EXTRA, EXTRA_CRC, MESSAGE_CLASSES, SIGNED_FLAG, FrameCodec, FrameError, crc_ok,
                                 crc_seed, encode_raw, read_header, rewrite_source, split_frames)
from zdrone.vehicle.personality import RAW_CRC_EXTRA

#: ids no pymavlink dialect at all defines (not even ``all``)
NOWHERE = [i for i in (4242, 20000, 54321, 0xABCDE, 0xFFFFFF) if i not in every_dialect.mavlink_map]


def _signed(msg: object, sysid: int = 1, compid: int = 1) -> bytes:
    m = apm.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    m.signing.secret_key, m.signing.link_id, m.signing.sign_outgoing, m.signing.timestamp = b"k" * 32, 1, True, 1
    return bytes(msg.pack(m))  # type: ignore[attr-defined]


# ---------------------------------------------------------------------------- the header
def test_read_header_reads_mavlink_1_2_and_signed_frames_without_any_table(monkeypatch):
    v1 = bytes(mav1.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(mav1.MAVLink(None, 3, 4)))
    v2 = FrameCodec(5, 6).encode(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
    signed = _signed(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3), 7, 9)
    unknown = encode_raw(NOWHERE[0], 0x11, b"\x01\x02\x03", 1, 1, seq=200)
    monkeypatch.setattr(core_mavlink, "CRC_EXTRA", {})  # no table consulted
    monkeypatch.setattr(core_mavlink, "MESSAGE_CLASSES", {})
    assert (read_header(v1).version, read_header(v1).sysid, read_header(v1).compid) == (1, 3, 4)
    assert (read_header(v2).version, read_header(v2).sysid, read_header(v2).compid) == (2, 5, 6)
    h = read_header(signed)
    assert signed[2] & SIGNED_FLAG and (h.sysid, h.compid, h.length) == (7, 9, len(signed))
    h = read_header(unknown)
    assert (h.msgid, h.seq) == (NOWHERE[0], 200)


@given(msgid=st.integers(0, 0xFFFFFF), payload=st.binary(min_size=1, max_size=255), seed=st.integers(0, 255),
       sysid=st.integers(1, 255))
def test_any_id_is_a_frame_and_its_seed_is_recovered_from_its_checksum(msgid: int, payload: bytes, seed: int,
                                                                       sysid: int):
    f = encode_raw(msgid, seed, payload, sysid, 1)
    assert read_header(f).msgid == msgid
    assert crc_seed(f) == seed
    g = rewrite_source(f, 4, 100)
    assert read_header(g).sysid == 4 and read_header(g).compid == 100 and crc_seed(g) == seed
    assert g[10:-2] == f[10:-2]  # the payload untouched


@given(st.binary(min_size=0, max_size=400))
def test_garbage_never_raises_anything_but_frame_error(data: bytes):
    try:
        read_header(data)
    except FrameError:
        pass
    assert FrameCodec(1).decode(data) is None or data[:1] in (b"\xfd", b"\xfe")


# ---------------------------------------------------------------------------- the seeds
def test_the_crc_seeds_of_every_dialect_are_recovered_and_corruption_is_seen():
    for msgid, cls in MESSAGE_CLASSES.items():
        f = encode_raw(msgid, cls.crc_extra, b"\x01\x02\x03\x04", 1, 1)
        assert crc_seed(f) == cls.crc_extra == CRC_EXTRA[msgid] and crc_ok(f)
        bad = f[:-2] + bytes([f[-2] ^ 0x55, f[-1]])
        assert crc_seed(bad) != cls.crc_extra and not crc_ok(bad)


_PX4_EXTRA_XML = """<?xml version="1.0"?>
<mavlink><version>3</version><dialect>0</dialect><enums/><messages>
<message id="8" name="LINK_NODE_STATUS"><description>.</description>
 <field type="uint64_t" name="timestamp">.</field><field type="uint8_t" name="tx_buf">.</field>
 <field type="uint8_t" name="rx_buf">.</field><field type="uint32_t" name="tx_rate">.</field>
 <field type="uint32_t" name="rx_rate">.</field><field type="uint16_t" name="rx_parse_err">.</field>
 <field type="uint16_t" name="tx_overflows">.</field><field type="uint16_t" name="rx_overflows">.</field>
 <field type="uint32_t" name="messages_sent">.</field><field type="uint32_t" name="messages_received">.</field>
 <field type="uint32_t" name="messages_lost">.</field></message>
<message id="380" name="TIME_ESTIMATE_TO_TARGET"><description>.</description>
 <field type="int32_t" name="safe_return">.</field><field type="int32_t" name="land">.</field>
 <field type="int32_t" name="mission_next_item">.</field><field type="int32_t" name="mission_end">.</field>
 <field type="int32_t" name="commanded_action">.</field></message>
<message id="410" name="EVENT"><description>.</description>
 <field type="uint8_t" name="destination_component">.</field><field type="uint8_t" name="destination_system">.</field>
 <field type="uint32_t" name="id">.</field><field type="uint32_t" name="event_time_boot_ms">.</field>
 <field type="uint16_t" name="sequence">.</field><field type="uint8_t" name="log_levels">.</field>
 <field type="uint8_t[40]" name="arguments">.</field></message>
<message id="411" name="CURRENT_EVENT_SEQUENCE"><description>.</description>
 <field type="uint16_t" name="sequence">.</field><field type="uint8_t" name="flags">.</field></message>
<message id="412" name="REQUEST_EVENT"><description>.</description>
 <field type="uint8_t" name="target_system">.</field><field type="uint8_t" name="target_component">.</field>
 <field type="uint16_t" name="first_sequence">.</field><field type="uint16_t" name="last_sequence">.</field></message>
<message id="413" name="RESPONSE_EVENT_ERROR"><description>.</description>
 <field type="uint8_t" name="target_system">.</field><field type="uint8_t" name="target_component">.</field>
 <field type="uint16_t" name="sequence">.</field><field type="uint16_t" name="sequence_oldest_available">.</field>
 <field type="uint8_t" name="reason">.</field></message>
</messages></mavlink>
"""


def test_the_extra_seeds_are_those_of_the_mavlink_definitions(tmp_path: Path):
    xml = tmp_path / "px4_extra.xml"
    xml.write_text(_PX4_EXTRA_XML)
    computed = {m.id: m.crc_extra for m in mavparse.MAVXML(str(xml), "2.0").message}
    assert computed == dict(EXTRA_CRC)
    assert not set(EXTRA_CRC) & set(MESSAGE_CLASSES)  # none of the dialects here has them
    assert all(CRC_EXTRA[i] == EXTRA_CRC[i] for i in EXTRA_CRC)
    assert all(EXTRA_CRC[i] == c for i, c in RAW_CRC_EXTRA.items())  # the simulator sends the same


def test_px4_event_frames_are_checked_and_split_like_any_known_id():
    event = encode_raw(410, 160, bytes(range(1, 20)), 1, 1)
    assert crc_ok(event) and not crc_ok(encode_raw(410, 161, bytes(range(1, 20)), 1, 1))
    frames, rest, skipped = split_frames(b"\x00\x01" + event + event)
    assert frames == [event, event] and rest == b"" and skipped == 2


# ---------------------------------------------------------------------------- rewriting
@pytest.mark.parametrize("msgid", [0, 76, 152, 178, 193, 436, 410, 411, 412, *NOWHERE])
def test_rewrite_source_handles_every_dialect_and_ids_of_none(msgid: int):
    seed = CRC_EXTRA.get(msgid, 0x77)
    f = encode_raw(msgid, seed, bytes(range(1, 30)), 245, 190, seq=17)
    g = rewrite_source(f, 4, 101)
    h = read_header(g)
    assert (h.sysid, h.compid, h.msgid, h.seq) == (4, 101, msgid, 17) and crc_seed(g) == seed
    assert crc_ok(g) is (msgid in CRC_EXTRA)


def test_rewrite_source_drops_the_signature_and_keeps_mavlink_1():
    signed = _signed(mav.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0), 245, 190)
    g = rewrite_source(signed, 4, 100)
    assert not g[2] & SIGNED_FLAG and len(g) == len(signed) - 13 and crc_ok(g)
    assert FrameCodec(9).decode(g).command == 400
    v1 = bytes(mav1.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(mav1.MAVLink(None, 245, 190)))
    g = rewrite_source(v1, 4, 100)
    assert g[0] == 0xFE and (g[3], g[4]) == (4, 100) and crc_ok(g)


# ---------------------------------------------------------------------------- decoding
def test_decode_knows_development_and_ardupilotmega_and_answers_none_for_the_rest():
    vehicle = FrameCodec(1, 1)
    current_mode = vehicle.encode(dev.MAVLink_current_mode_message(6, 0x04040000, 0x04040000))
    meminfo = vehicle.encode(apm.MAVLink_meminfo_message(0, 65535, 131072))
    hb = vehicle.encode(mav.MAVLink_heartbeat_message(2, 3, 0, 3, 3, 3))
    gs = FrameCodec(4, 190)
    assert gs.decode(current_mode).get_type() == "CURRENT_MODE" and 436 not in apm.mavlink_map
    assert gs.decode(meminfo).get_type() == "MEMINFO" and 152 not in mav.mavlink_map
    assert gs.decode(hb).custom_mode == 3
    for unknown in [encode_raw(410, 160, b"\x01" * 53, 1, 1), *(encode_raw(i, 1, b"\x01", 1, 1) for i in NOWHERE)]:
        assert gs.decode(unknown) is None  # never raises; the frame is still relayed (read_header takes it)
        read_header(unknown)
    assert gs.decode(hb[:-1] + bytes([hb[-1] ^ 1])) is None  # bad checksum
    assert gs.decode(hb + hb) is None  # exactly one frame
