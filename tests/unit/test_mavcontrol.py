"""The operator-control codec (CONTROL_STATUS 512, MAV_CMD_REQUEST_OPERATOR_CONTROL 32100) against a
dialect pymavlink's own generator makes from today's definition of CONTROL_STATUS."""

from __future__ import annotations

import math
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from zdrone.core.mavcontrol import (CRC_EXTRA_CONTROL_STATUS, FLAG_SYSTEM_MANAGER, FLAG_TAKEOVER_ALLOWED,
                                    MSG_ID_CONTROL_STATUS, ControlStatus, decode_control_status,
                                    encode_control_status, parse_operator_request)
from zdrone.core.mavlink import encode_raw, read_header

from tests.mavgen_dialect import generated_dialect

#: CONTROL_STATUS as development.xml defines it since mavlink PR 2313 (three fields)
SPEC_XML = """<?xml version="1.0"?>
<mavlink>
  <version>3</version>
  <dialect>0</dialect>
  <messages>
    <message id="512" name="CONTROL_STATUS">
      <description>Information about GCS in control of this MAV.</description>
      <field type="uint8_t" name="flags" display="bitmask">Control status.</field>
      <field type="uint8_t" name="gcs_main">System ID of GCS in control.</field>
      <field type="uint8_t[10]" name="gcs_secondary">System IDs of secondary GCS.</field>
    </message>
  </messages>
</mavlink>
"""


@pytest.fixture(scope="module")
def spec_dialect(tmp_path_factory):
    """The Python dialect pymavlink's generator makes from ``SPEC_XML``."""
    yield generated_dialect(SPEC_XML, tmp_path_factory.mktemp("dialect"), "opcontrol_gen")
    sys.modules.pop("opcontrol_gen", None)


def test_the_generated_definition_has_crc_extra_21_and_12_bytes(spec_dialect):
    cls = spec_dialect.MAVLink_control_status_message
    assert cls.crc_extra == CRC_EXTRA_CONTROL_STATUS == 21
    assert cls.unpacker.size == 12


def _generated(spec_dialect, sysid: int = 1, compid: int = 1):
    mav = spec_dialect.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.robust_parsing = True
    return mav


@given(flags=st.integers(0, 255), main=st.integers(0, 255), secondary=st.lists(st.integers(0, 255), min_size=10, max_size=10),
       seq=st.integers(0, 255))
def test_our_frames_are_the_generated_dialects_bytes_both_ways(spec_dialect, flags, main, secondary, seq):
    status = ControlStatus(flags, main, tuple(secondary))
    ours = encode_control_status(status, 1, 1, seq)
    mav = _generated(spec_dialect)
    mav.seq = seq
    theirs = bytes(spec_dialect.MAVLink_control_status_message(flags, main, secondary).pack(mav))
    assert ours == theirs
    parsed = _generated(spec_dialect).parse_buffer(ours)
    assert parsed and parsed[0].get_type() == "CONTROL_STATUS"
    assert (parsed[0].flags, parsed[0].gcs_main, list(parsed[0].gcs_secondary)) == (flags, main, secondary)
    assert decode_control_status(theirs) == status


def test_the_single_owner_status_truncates_its_zeros_and_reads_back():
    frame = encode_control_status(ControlStatus(FLAG_SYSTEM_MANAGER | FLAG_TAKEOVER_ALLOWED, 255), 1, 1)
    hdr = read_header(frame)
    assert (hdr.version, hdr.msgid, frame[1]) == (2, MSG_ID_CONTROL_STATUS, 2)  # gcs_secondary all zero: cut
    got = decode_control_status(frame)
    assert got == ControlStatus(3, 255) and got.takeover_allowed and got.system_manager


def test_the_old_two_field_layout_and_other_frames_are_not_a_control_status():
    old = encode_raw(MSG_ID_CONTROL_STATUS, 184, bytes([255, 3]), 1, 1)  # sysid_in_control, flags (CRC extra 184)
    assert decode_control_status(old) is None
    assert decode_control_status(b"\xfd\x00") is None
    assert decode_control_status(encode_raw(0, 50, bytes(9), 1, 1)) is None  # a HEARTBEAT
    too_long = encode_raw(MSG_ID_CONTROL_STATUS, 21, bytes(range(1, 14)), 1, 1)
    assert decode_control_status(too_long) is None
    corrupted = bytearray(encode_control_status(ControlStatus(1, 4), 1, 1))
    corrupted[10] ^= 0x40
    assert decode_control_status(bytes(corrupted)) is None


def test_bad_fields_are_refused_when_encoding():
    with pytest.raises(ValueError):
        encode_control_status(ControlStatus(1, 256), 1, 1)
    with pytest.raises(ValueError):
        encode_control_status(ControlStatus(1, 4, (0,) * 9), 1, 1)


def test_request_parameters():
    req = parse_operator_request(1, 0, 30, 255)
    assert req is not None and (req.request, req.takeover, req.timeout, req.sysid) == (True, False, 30.0, 255)
    assert req.params()[:4] == (1.0, 0.0, 30.0, 255.0)
    release = parse_operator_request(0, 1, 5, 3)
    assert release is not None and not release.request and release.takeover
    assert parse_operator_request(1, 0, 0, 3).timeout == 3.0  # clamped to 3..60
    assert parse_operator_request(1, 0, 600, 3).timeout == 60.0
    assert parse_operator_request(1, 0, math.nan, 3).timeout == 10.0
    for bad in ((2, 0, 10, 3), (1, 0.5, 10, 3), (1, 0, 10, 256), (1, 0, 10, 3.5), (1, 0, 10, math.nan),
                (math.nan, 0, 10, 3), (1, 0, 10, -1)):
        assert parse_operator_request(*bad) is None, bad
