"""The simulated autopilot's parameters and the MAVLink parameter protocol.

Theory of operation: ``ParamProtocol`` owns the parameter table of one autopilot: the personality's
names, defaults and ranges, in the personality's order (the index of PARAM_VALUE). PARAM_REQUEST_LIST
is answered with every PARAM_VALUE (ArduPilot sends its banner first), PARAM_REQUEST_READ with one
(by index when ``param_index`` >= 0, else by name), PARAM_SET with the value it now holds.

The two autopilots differ in how they carry and check values: PX4 packs an integer's bytes into
the float (``param_bytewise``) and refuses a value out of range or not finite, answering with the
unchanged value and a STATUSTEXT; ArduPilot casts, takes any finite value and ignores NaN and
infinities without an answer. An integer parameter is clamped to its type. After a set,
``after_set(name, now)`` lets the rest of the autopilot follow (ArduPilot's stream rates).

Bad input never raises: an unknown name or index is counted (``param_unknown``, and PX4 says so),
a refused value is counted (``param_rejected``).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import Any

from pymavlink.dialects.v20 import common as mav

from zdrone.vehicle.personality import Param, Personality, Say
from zdrone.vehicle.sim.outbox import Outbox

#: the value range of each integer MAV_PARAM_TYPE
INT_RANGES: Mapping[int, tuple[int, int]] = MappingProxyType({
    mav.MAV_PARAM_TYPE_UINT8: (0, 255), mav.MAV_PARAM_TYPE_INT8: (-128, 127),
    mav.MAV_PARAM_TYPE_UINT16: (0, 65535), mav.MAV_PARAM_TYPE_INT16: (-32768, 32767),
    mav.MAV_PARAM_TYPE_UINT32: (0, 2**32 - 1), mav.MAV_PARAM_TYPE_INT32: (-2**31, 2**31 - 1)})


def param_id(raw: Any) -> str:
    """A parameter name as sent: bytes or str, NUL-padded."""
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).rstrip("\x00")


class ParamProtocol:
    """The parameters of one autopilot (``params``, name -> ``Param``) and their MAVLink protocol."""

    def __init__(self, personality: Personality, sysid: int, out: Outbox,
                 after_set: Callable[[str, float], None]) -> None:
        self.p = personality
        self.out = out
        self.after_set = after_set
        self.params: dict[str, Param] = personality.params(sysid)
        self.names = list(self.params)
        self.handlers: Mapping[str, Callable[[Any, float], None]] = MappingProxyType({
            "PARAM_REQUEST_LIST": self.on_request_list,
            "PARAM_REQUEST_READ": self.on_request_read,
            "PARAM_SET": self.on_set,
        })

    def value(self, name: str) -> float:
        return self.params[name].value

    def param_value(self, name: str) -> mav.MAVLink_param_value_message:
        prm = self.params[name]
        if prm.kind in INT_RANGES and self.p.param_bytewise:  # PX4: the integer's bytes in the float
            value = struct.unpack("<f", struct.pack("<i", int(prm.value)))[0]
        else:
            value = float(prm.value)
        idx = self.names.index(name)
        return mav.MAVLink_param_value_message(name.encode(), value, prm.kind, len(self.params), idx)

    def on_request_list(self, msg: Any, now: float) -> None:
        for text in self.p.banner:  # ArduPilot answers a parameter list request with its banner first
            self.out.say(Say(text))
        for name in self.names:
            self.out.send(self.param_value(name))

    def on_request_read(self, msg: Any, now: float) -> None:
        name = param_id(msg.param_id)
        if msg.param_index >= 0:
            if msg.param_index >= len(self.names):
                self.out.count("param_unknown", f"index {msg.param_index}")
                return
            name = self.names[msg.param_index]
        if name not in self.params:
            self.out.count("param_unknown", name)
            return
        self.out.send(self.param_value(name))

    def on_set(self, msg: Any, now: float) -> None:
        name = param_id(msg.param_id)
        prm = self.params.get(name)
        if prm is None:
            self.out.count("param_unknown", name)
            if self.p.param_range_checked:
                self.out.say(Say(f"unknown parameter {name}", mav.MAV_SEVERITY_WARNING))
            return  # ArduPilot ignores it silently
        if prm.kind in INT_RANGES and self.p.param_bytewise and msg.param_type in INT_RANGES:
            value: float = struct.unpack("<i", struct.pack("<f", msg.param_value))[0]
        else:
            value = msg.param_value
        if not math.isfinite(value) and not self.p.param_range_checked:
            self.out.count("param_rejected", f"{name}={value}")
            return  # ArduPilot ignores NaN and infinities without an answer
        in_range = prm.low <= value <= prm.high or not self.p.param_range_checked
        if not prm.writable or not math.isfinite(value) or not in_range:
            # PX4 answers a refused set with the unchanged value; say why in a STATUSTEXT
            self.out.count("param_rejected", f"{name}={value}")
            self.out.say(Say(f"{name}: {value} refused", mav.MAV_SEVERITY_WARNING))
        elif prm.kind in INT_RANGES:
            lo, hi = INT_RANGES[prm.kind]
            prm.value = int(max(lo, min(hi, value)))
        else:
            prm.value = float(value)
        self.out.send(self.param_value(name))
        self.after_set(name, now)
