"""MAVLink operator control as development.xml defines it today: CONTROL_STATUS (512) and
MAV_CMD_REQUEST_OPERATOR_CONTROL (32100).

pymavlink's released dialects have neither (and an older two-field CONTROL_STATUS, CRC extra 184,
was replaced in 2025), so both are packed and parsed here, sans-IO:

* CONTROL_STATUS: ``flags`` (uint8: 1 SYSTEM_MANAGER, 2 TAKEOVER_ALLOWED), ``gcs_main`` (uint8, the
  GCS in control), ``gcs_secondary`` (uint8[10], zeros in single-owner mode); 12 bytes, CRC extra 21.
  A frame is MAVLink 2, its trailing zero bytes truncated as the protocol says.
* MAV_CMD_REQUEST_OPERATOR_CONTROL, a COMMAND_LONG / COMMAND_INT: param 1 is 1 to request control,
  0 to release it; param 2 allows takeover (1: requests are granted automatically, 0: the owner is
  asked); param 3 the request's timeout, 3..60 s; param 4 the requesting GCS's sysid.
* MAV_RESULT_NOT_IN_CONTROL (10): the answer to a state-changing command from a GCS not in control.
"""

from __future__ import annotations

import math

import msgspec

from zdrone.core.mavlink import FrameError, crc_seed, encode_raw, read_header

MSG_ID_CONTROL_STATUS = 512
CRC_EXTRA_CONTROL_STATUS = 21
CONTROL_STATUS_LEN = 12
GCS_SECONDARY_LEN = 10
FLAG_SYSTEM_MANAGER = 1
FLAG_TAKEOVER_ALLOWED = 2
MAV_CMD_REQUEST_OPERATOR_CONTROL = 32100
MAV_RESULT_NOT_IN_CONTROL = 10
#: param 3's range, seconds; values outside it are clamped into it
REQUEST_TIMEOUT_MIN_S, REQUEST_TIMEOUT_MAX_S = 3.0, 60.0
#: the timeout of a request whose param 3 is not a number
DEFAULT_REQUEST_TIMEOUT_S = 10.0


class ControlStatus(msgspec.Struct, frozen=True):
    """One CONTROL_STATUS message."""

    flags: int
    gcs_main: int
    gcs_secondary: tuple[int, ...] = (0,) * GCS_SECONDARY_LEN

    @property
    def takeover_allowed(self) -> bool:
        return bool(self.flags & FLAG_TAKEOVER_ALLOWED)

    @property
    def system_manager(self) -> bool:
        return bool(self.flags & FLAG_SYSTEM_MANAGER)


def encode_control_status(status: ControlStatus, sysid: int, compid: int, seq: int = 0) -> bytes:
    """A MAVLink 2 CONTROL_STATUS frame from (``sysid``, ``compid``). ``ValueError`` for a field out of
    uint8 range or a ``gcs_secondary`` of another length than 10."""
    if len(status.gcs_secondary) != GCS_SECONDARY_LEN:
        raise ValueError(f"gcs_secondary has {GCS_SECONDARY_LEN} entries, not {len(status.gcs_secondary)}")
    payload = bytes([status.flags, status.gcs_main, *status.gcs_secondary])  # ValueError outside 0..255
    return encode_raw(MSG_ID_CONTROL_STATUS, CRC_EXTRA_CONTROL_STATUS, payload, sysid, compid, seq)


def decode_control_status(frame: bytes) -> ControlStatus | None:
    """The CONTROL_STATUS in ``frame``, or None: not exactly one MAVLink 2 frame of id 512 whose
    checksum fits CRC extra 21 (the two-field layout of before 2025 does not), or a payload too long."""
    try:
        hdr = read_header(frame)
    except FrameError:
        return None
    if hdr.version != 2 or hdr.msgid != MSG_ID_CONTROL_STATUS or frame[1] > CONTROL_STATUS_LEN:
        return None
    if crc_seed(frame) != CRC_EXTRA_CONTROL_STATUS:
        return None
    payload = frame[10 : 10 + frame[1]].ljust(CONTROL_STATUS_LEN, b"\x00")  # truncated zeros come back
    return ControlStatus(payload[0], payload[1], tuple(payload[2:CONTROL_STATUS_LEN]))


class OperatorControlRequest(msgspec.Struct, frozen=True):
    """The parameters of one MAV_CMD_REQUEST_OPERATOR_CONTROL."""

    request: bool  # param 1: True request control, False release it
    takeover: bool  # param 2: allow takeover (grant later requests automatically)
    timeout: float  # param 3, seconds, clamped to 3..60
    sysid: int  # param 4: the requesting GCS's sysid (as it says: proves nothing)

    def params(self) -> tuple[float, float, float, float, float, float, float]:
        """The seven params of a COMMAND_LONG carrying this request."""
        return (float(self.request), float(self.takeover), float(self.timeout), float(self.sysid), 0.0, 0.0, 0.0)


def sysid_as_seen_by(sysid: int, app_sysid: int) -> int:
    """``sysid`` (another GCS) as an application with ``app_sysid`` is shown it: never its own sysid
    (several applications share 255, and "in control" must mean "me" only when it is); 0 stays 0."""
    if sysid == 0 or sysid != app_sysid:
        return sysid
    return 255 if app_sysid != 255 else 254


def parse_operator_request(p1: float, p2: float, p3: float, p4: float) -> OperatorControlRequest | None:
    """The request in params 1-4, or None if param 1 or 2 is not 0 or 1 or param 4 is no sysid
    (0..255). A param 3 outside 3..60 s is clamped into it; one that is not a number is 10 s."""
    if p1 not in (0.0, 1.0) or p2 not in (0.0, 1.0):
        return None
    if not (math.isfinite(p4) and p4 == int(p4) and 0 <= p4 <= 255):
        return None
    timeout = min(max(p3, REQUEST_TIMEOUT_MIN_S), REQUEST_TIMEOUT_MAX_S) if math.isfinite(p3) else DEFAULT_REQUEST_TIMEOUT_S
    return OperatorControlRequest(p1 == 1.0, p2 == 1.0, timeout, int(p4))
