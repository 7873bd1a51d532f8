"""The simulated autopilot's telemetry: which messages it streams, how often, and what each says.

Theory of operation: ``Telemetry`` keeps the effective interval of every streamed message id, built
in three layers (``rebuild``): the personality's defaults (PX4 streams its set from boot, ArduPilot
only HEARTBEAT), then ArduPilot's stream groups at their ``MAV1_<group>`` rates (set by
REQUEST_DATA_STREAM or PARAM_SET), then explicit SET_MESSAGE_INTERVAL requests (an interval, or
off; 0 returns to the default). ``stream(now)``, from the autopilot's step, sends every message that
is due and schedules the next one interval later (never more than one interval behind).

``send_message(mid)`` builds one message from the vehicle's state at the autopilot's time, through
the table of message ids: common ones with pymavlink, PX4's extra ids raw or from the development
dialect, ArduPilot's from the ardupilotmega dialect. With ``gps_noise`` every message draws a
noisy position, used by those that report one. The command table answers REQUEST_MESSAGE and
SET_MESSAGE_INTERVAL through ``send_message`` and ``set_interval``.

Bad input never raises: an id the personality cannot send is UNSUPPORTED (ArduPilot says so and
answers FAILED), an interval not finite or out of range is DENIED; PX4 ignores REQUEST_DATA_STREAM
(counted as ``ignored``).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Protocol

from pymavlink.dialects.v20 import ardupilotmega as apm
from pymavlink.dialects.v20 import common as mav

from zdrone.core.geometry import GeoPoint, offset
from zdrone.vehicle.personality import (AP_STREAM_PARAMS, MSG_AHRS2, MSG_CURRENT_EVENT_SEQUENCE, MSG_CURRENT_MODE,
                           MSG_EKF_STATUS_REPORT, MSG_LINK_NODE_STATUS, MSG_MEMINFO, MSG_TIME_ESTIMATE_TO_TARGET)
from zdrone.vehicle.sim.kinematics import battery_millivolts, wrap_pi

try:  # CURRENT_MODE (436) lives in the development dialect
    from pymavlink.dialects.v20 import development as dev
except ImportError:  # pragma: no cover
    dev = None  # type: ignore[assignment]

if TYPE_CHECKING:
    from zdrone.vehicle.sim.vehicle import VehicleState
    import random
    from zdrone.vehicle.sim.mission import MissionProtocol
    from zdrone.vehicle.sim.outbox import Outbox
    from zdrone.vehicle.personality import ModeRow, Param, Personality


class ReportedAutopilot(Protocol):
    """What the telemetry reads of its autopilot (it reports the whole vehicle, and changes none of
    it): all it may reach (``tests/unit/test_sim_parts.py``)."""

    out: Outbox
    p: Personality
    params: dict[str, Param]
    sysid: int
    t: float
    boot: float
    ready_after: float
    rng: random.Random
    home: GeoPoint
    home_amsl: float
    vehicle: VehicleState
    mode_row: ModeRow
    mission_protocol: MissionProtocol

    @property
    def position(self) -> GeoPoint: ...

    def landed_state(self) -> int: ...

    def phys(self, what: str) -> float: ...

    def gps_fixed(self, now: float | None = None) -> bool: ...

    def position_ok(self, now: float | None = None) -> bool: ...

    def ready_to_arm(self, now: float | None = None) -> bool: ...


UNIX_EPOCH_AT_BOOT = 1_790_000_000  # SYSTEM_TIME: a fixed, deterministic wall clock
MIN_INTERVAL_S = 0.02  # SET_MESSAGE_INTERVAL: at most 50 Hz
MAX_INTERVAL_US = 60e6
SENSORS = (mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL | mav.MAV_SYS_STATUS_SENSOR_3D_MAG
           | mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | mav.MAV_SYS_STATUS_SENSOR_GPS
           | mav.MAV_SYS_STATUS_SENSOR_BATTERY | mav.MAV_SYS_STATUS_PREARM_CHECK)


class Telemetry:
    """The streams of one autopilot (``ap``) and the messages they carry."""

    def __init__(self, ap: ReportedAutopilot, now: float) -> None:
        self.ap = ap
        self.requested: dict[int, float | None] = {}  # SET_MESSAGE_INTERVAL: id -> interval, None = off
        self.streams: dict[int, float] = dict(ap.p.default_streams)  # id -> interval (s)
        self.next_due: dict[int, float] = {m: now for m in self.streams}
        self.frames_streamed = 0
        self.handlers: Mapping[str, Callable[[Any, float], None]] = MappingProxyType({
            "REQUEST_DATA_STREAM": self.on_request_data_stream})
        messages: dict[int, Callable[[int, GeoPoint], None]] = {
            mav.MAVLINK_MSG_ID_HEARTBEAT: self._heartbeat,
            mav.MAVLINK_MSG_ID_SYS_STATUS: self._sys_status,
            mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._global_position_int,
            mav.MAVLINK_MSG_ID_ATTITUDE: self._attitude,
            mav.MAVLINK_MSG_ID_HOME_POSITION: self._home_position,
            mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._extended_sys_state,
            mav.MAVLINK_MSG_ID_BATTERY_STATUS: self._battery_status,
            mav.MAVLINK_MSG_ID_GPS_RAW_INT: self._gps_raw_int,
            mav.MAVLINK_MSG_ID_MISSION_CURRENT: self._mission_current,
            mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._autopilot_version,
            mav.MAVLINK_MSG_ID_VFR_HUD: self._vfr_hud,
            mav.MAVLINK_MSG_ID_SYSTEM_TIME: self._system_time,
            MSG_LINK_NODE_STATUS: self._link_node_status,
            MSG_TIME_ESTIMATE_TO_TARGET: self._time_estimate_to_target,
            MSG_CURRENT_EVENT_SEQUENCE: self._current_event_sequence,
            MSG_MEMINFO: self._meminfo,
            MSG_AHRS2: self._ahrs2,
            MSG_EKF_STATUS_REPORT: self._ekf_status_report,
        }
        if dev is not None:
            messages[MSG_CURRENT_MODE] = self._current_mode
        #: message id -> builder(boot_ms, reported position)
        self.messages: Mapping[int, Callable[[int, GeoPoint], None]] = MappingProxyType(messages)

    # ------------------------------------------------------------------ streams
    def stream(self, now: float) -> None:
        """Send every streamed message that is due at ``now``."""
        for mid, interval in list(self.streams.items()):
            due = self.next_due.get(mid, now)
            if now >= due:
                self.send_message(mid)
                self.frames_streamed += 1
                self.next_due[mid] = max(due + interval, now - interval)

    def on_request_data_stream(self, msg: Any, now: float) -> None:
        """ArduPilot's stream groups: REQUEST_DATA_STREAM sets MAV1_<group> (0 = off); PX4 ignores it."""
        ap = self.ap
        groups = ap.p.stream_groups
        if not groups:
            ap.out.count("ignored", "REQUEST_DATA_STREAM")
            return
        rate = float(min(max(msg.req_message_rate, 0), 50)) if msg.start_stop else 0.0
        ids = list(groups) if msg.req_stream_id == mav.MAV_DATA_STREAM_ALL else [msg.req_stream_id]
        for g in ids:
            if g in AP_STREAM_PARAMS:
                ap.params[f"MAV1_{AP_STREAM_PARAMS[g]}"].value = int(rate)
        self.rebuild(now)

    def after_param_set(self, name: str, now: float) -> None:
        """A parameter was set: ArduPilot's ``MAV1_*`` are its stream rates."""
        if self.ap.p.stream_groups and name.startswith("MAV1_"):
            self.rebuild(now)

    def set_interval(self, p: tuple[float, float, float, float], now: float) -> int:
        """MAV_CMD_SET_MESSAGE_INTERVAL (param 1 the id, param 2 µs, -1 off, 0 default): the MAV_RESULT."""
        ap = self.ap
        mid = int(p[0]) if math.isfinite(p[0]) and abs(p[0]) < 2**31 else -1
        if mid not in ap.p.sendable:
            if ap.p.text("interval_unknown") is not None:  # ArduPilot says so and fails
                ap.out.say("interval_unknown", msgid=mid)
                return mav.MAV_RESULT_FAILED
            return mav.MAV_RESULT_UNSUPPORTED
        if not math.isfinite(p[1]) or p[1] < -1 or p[1] > MAX_INTERVAL_US:
            return mav.MAV_RESULT_DENIED
        if p[1] == -1:
            self.requested[mid] = None
        elif p[1] == 0:
            self.requested.pop(mid, None)  # back to the default rate
        else:
            self.requested[mid] = max(p[1] / 1e6, MIN_INTERVAL_S)
        self.next_due[mid] = now
        self.rebuild(now)
        return mav.MAV_RESULT_ACCEPTED

    def rebuild(self, now: float) -> None:
        """Effective intervals: the personality's defaults, ArduPilot's group rates, then explicit
        SET_MESSAGE_INTERVAL requests."""
        ap = self.ap
        streams = dict(ap.p.default_streams)
        for group, ids in ap.p.stream_groups.items():
            rate = ap.params[f"MAV1_{AP_STREAM_PARAMS[group]}"].value
            if rate > 0:
                for mid in ids:
                    streams[mid] = min(streams.get(mid, math.inf), 1.0 / rate)
        for mid, interval in self.requested.items():
            if interval is None:
                streams.pop(mid, None)
            else:
                streams[mid] = interval
        for mid in streams:
            if mid not in self.streams:
                self.next_due[mid] = now
        self.streams = streams

    # ----------------------------------------------------------------- messages
    def send_message(self, mid: int) -> None:
        """Send message ``mid`` now (nothing for an id without a builder)."""
        ap = self.ap
        boot_ms = int((ap.t - ap.boot) * 1000) & 0xFFFFFFFF
        pos = ap.position
        noise = ap.phys("gps_noise")
        if noise > 0:
            pos = offset(pos, ap.rng.gauss(0, noise), ap.rng.gauss(0, noise))
        build = self.messages.get(mid)
        if build is not None:
            build(boot_ms, pos)

    def _heartbeat(self, boot_ms: int, pos: GeoPoint) -> None:
        ap = self.ap
        base, status = ap.p.heartbeat(ap.mode_row, ap.vehicle.armed, ap.vehicle.landed)
        ap.out.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, ap.p.autopilot, base,
                                                  ap.mode_row.custom_mode, status, 3))

    def _sys_status(self, boot_ms: int, pos: GeoPoint) -> None:
        ap = self.ap
        # the pre-arm bit is healthy once the arming checks pass (or while armed), as on both autopilots
        health = SENSORS if ap.vehicle.armed or ap.ready_to_arm(ap.t) else SENSORS & ~mav.MAV_SYS_STATUS_PREARM_CHECK
        ap.out.send(mav.MAVLink_sys_status_message(SENSORS, SENSORS, health, 150, battery_millivolts(ap.vehicle.battery),
                                                   800 if ap.vehicle.armed else 50, int(ap.vehicle.battery), 0, 0, 0, 0, 0, 0))

    def _global_position_int(self, boot_ms: int, pos: GeoPoint) -> None:
        """ArduPilot: lat = lon = 0 until the GPS fix, then the GPS position; PX4: nothing until its
        estimate is global."""
        ap, k = self.ap, self.ap.vehicle.k
        if ap.p.zeros_before_fix and not ap.gps_fixed(ap.t):
            ap.out.send(mav.MAVLink_global_position_int_message(boot_ms, 0, 0, 0, 0, 0, 0, 0, 0))
            return
        if not ap.p.zeros_before_fix and not ap.position_ok(ap.t):
            return
        hdg = int(math.degrees(k.yaw) % 360 * 100)
        ap.out.send(mav.MAVLink_global_position_int_message(
            boot_ms, int(pos.lat * 1e7), int(pos.lon * 1e7), int((ap.home_amsl + k.alt) * 1000), int(k.alt * 1000),
            int(k.vn * 100), int(k.ve * 100), int(-k.vz * 100), hdg))

    def _attitude(self, boot_ms: int, pos: GeoPoint) -> None:
        k = self.ap.vehicle.k
        roll, pitch = k.tilt()
        self.ap.out.send(mav.MAVLink_attitude_message(boot_ms, roll, pitch, wrap_pi(k.yaw), 0.0, 0.0, 0.0))

    def _home_position(self, boot_ms: int, pos: GeoPoint) -> None:
        ap = self.ap
        ap.out.send(mav.MAVLink_home_position_message(int(ap.home.lat * 1e7), int(ap.home.lon * 1e7),
                                                      int(ap.home_amsl * 1000), 0, 0, 0, [1, 0, 0, 0], 0, 0, 0,
                                                      int(ap.t * 1e6)))

    def _extended_sys_state(self, boot_ms: int, pos: GeoPoint) -> None:
        self.ap.out.send(mav.MAVLink_extended_sys_state_message(mav.MAV_VTOL_STATE_UNDEFINED, self.ap.landed_state()))

    def _battery_status(self, boot_ms: int, pos: GeoPoint) -> None:
        ap = self.ap
        cells = [battery_millivolts(ap.vehicle.battery) // 4] * 4 + [65535] * 6
        ap.out.send(mav.MAVLink_battery_status_message(0, mav.MAV_BATTERY_FUNCTION_ALL, mav.MAV_BATTERY_TYPE_LIPO, 2500,
                                                       cells, 800 if ap.vehicle.armed else 50, -1, -1, int(ap.vehicle.battery)))

    def _gps_raw_int(self, boot_ms: int, pos: GeoPoint) -> None:
        ap, k = self.ap, self.ap.vehicle.k
        speed = math.hypot(k.vn, k.ve)
        cog = int(math.degrees(math.atan2(k.ve, k.vn)) % 360 * 100) if speed > 0.1 else 65535
        if not ap.gps_fixed(ap.t):
            ap.out.send(mav.MAVLink_gps_raw_int_message(int(ap.t * 1e6), mav.GPS_FIX_TYPE_NO_FIX, 0, 0, 0, 65535, 65535,
                                                        0, 65535, 0))
            return
        ap.out.send(mav.MAVLink_gps_raw_int_message(int(ap.t * 1e6), mav.GPS_FIX_TYPE_3D_FIX, int(pos.lat * 1e7),
                                                    int(pos.lon * 1e7), int((ap.home_amsl + k.alt) * 1000), 80, 120,
                                                    int(speed * 100), cog, 14))

    def _mission_current(self, boot_ms: int, pos: GeoPoint) -> None:
        self.ap.mission_protocol.send_current()

    def _autopilot_version(self, boot_ms: int, pos: GeoPoint) -> None:
        ap = self.ap
        ap.out.send(mav.MAVLink_autopilot_version_message(ap.p.capabilities, ap.p.version, 0, 0, 0, [0] * 8, [0] * 8,
                                                          [0] * 8, 0, 0, 0x5A44524F4E45 + ap.sysid))

    def _vfr_hud(self, boot_ms: int, pos: GeoPoint) -> None:
        ap, k = self.ap, self.ap.vehicle.k
        ap.out.send(mav.MAVLink_vfr_hud_message(math.hypot(k.vn, k.ve), math.hypot(k.vn, k.ve),
                                                int(math.degrees(k.yaw) % 360), 40 if ap.vehicle.armed else 0,
                                                ap.home_amsl + k.alt, k.vz))

    def _system_time(self, boot_ms: int, pos: GeoPoint) -> None:
        ap = self.ap
        ap.out.send(mav.MAVLink_system_time_message(int((UNIX_EPOCH_AT_BOOT + ap.t - ap.boot) * 1e6), boot_ms))

    # PX4's ids outside pymavlink's common dialect (raw, or the development dialect)
    def _link_node_status(self, boot_ms: int, pos: GeoPoint) -> None:
        ap = self.ap
        ap.out.send_raw(MSG_LINK_NODE_STATUS, struct.pack("<QIIIIIHHHBB", int((ap.t - ap.boot) * 1e6), 0, 0,
                                                          self.frames_streamed & 0xFFFFFFFF, 0, 0, 0, 0, 0, 100, 100))

    def _time_estimate_to_target(self, boot_ms: int, pos: GeoPoint) -> None:
        ap, k = self.ap, self.ap.vehicle.k
        land = -1 if ap.vehicle.landed else int(k.alt / max(ap.phys("down"), 0.1))
        home = int(math.hypot(k.north, k.east) / max(ap.phys("cruise"), 0.1)) if not ap.vehicle.landed else -1
        ap.out.send_raw(MSG_TIME_ESTIMATE_TO_TARGET, struct.pack("<iiiii", home, land, -1, -1, -1))

    def _current_event_sequence(self, boot_ms: int, pos: GeoPoint) -> None:
        out = self.ap.out
        out.send_raw(MSG_CURRENT_EVENT_SEQUENCE, struct.pack("<HB", (out.event_seq - 1) & 0xFFFF, 0))

    def _current_mode(self, boot_ms: int, pos: GeoPoint) -> None:
        row = self.ap.mode_row
        self.ap.out.send(dev.MAVLink_current_mode_message(row.standard_mode, row.custom_mode, row.custom_mode))

    # ArduPilot's ids (ardupilotmega dialect)
    def _meminfo(self, boot_ms: int, pos: GeoPoint) -> None:
        self.ap.out.send(apm.MAVLink_meminfo_message(0, 65535, 131072))

    def _ahrs2(self, boot_ms: int, pos: GeoPoint) -> None:
        ap, k = self.ap, self.ap.vehicle.k
        roll, pitch = k.tilt()
        ap.out.send(apm.MAVLink_ahrs2_message(roll, pitch, wrap_pi(k.yaw), ap.home_amsl + k.alt,
                                              int(pos.lat * 1e7), int(pos.lon * 1e7)))

    def _ekf_status_report(self, boot_ms: int, pos: GeoPoint) -> None:
        self.ap.out.send(apm.MAVLink_ekf_status_report_message(self._ekf_flags(), 0.02, 0.02, 0.02, 0.03, 0.0, 0.0))

    def _ekf_flags(self) -> int:
        """ArduPilot's EKF_STATUS_REPORT flags along the readiness stages (absolute position last)."""
        ap = self.ap
        r = ap.p.readiness
        if r.stages and ap.t - ap.boot < r.stages[0].until * ap.ready_after:
            return apm.EKF_UNINITIALIZED  # still aligning: no usable solution yet
        flags = (apm.EKF_ATTITUDE | apm.EKF_VELOCITY_HORIZ | apm.EKF_VELOCITY_VERT | apm.EKF_POS_VERT_ABS
                 | apm.EKF_POS_HORIZ_REL)
        if ap.position_ok(ap.t):
            flags |= apm.EKF_POS_HORIZ_ABS | apm.EKF_PRED_POS_HORIZ_REL | apm.EKF_PRED_POS_HORIZ_ABS
        else:
            flags |= apm.EKF_CONST_POS_MODE
        return flags
