"""The GCS gateway decodes an application's frame at most once on its way (``gs.apptable.AppFrame``):
a command that reaches the drone, one refused because the GS is not in control, a mission write refused,
and a frame that needs no field of its message at all (decoded never)."""

from __future__ import annotations

from collections import Counter

import pytest
from pymavlink.dialects.v20 import common as mav

from zdrone.core.mavlink import FrameCodec

from tests.unit.test_gateway_apps import command_long, heartbeat, make_gateway

APP = 255


def counted(gw) -> Counter:
    """Count each application's full decodes from now on (its parser's ``decode``)."""
    calls: Counter = Counter()
    for app in gw.apps:
        real = app.decoder.decode

        def decode(frame: bytes, real=real, app=app):
            calls[app.sysid] += 1
            return real(frame)

        app.decoder.decode = decode
    return calls


@pytest.mark.parametrize("authority", [True, False])
def test_a_command_is_decoded_once_whether_it_goes_to_the_drone_or_is_refused(authority):
    gw, station, t = make_gateway(signing="off")
    gw.on_app_frame(0, "peer", heartbeat(APP), 0.0)
    calls = counted(gw)
    station.authority = authority
    before = len(station.sent)
    gw.on_app_frame(0, "peer", command_long(APP), 0.1)
    assert calls[APP] == 1
    assert (len(station.sent) == before + 1) is authority  # refused with a COMMAND_ACK when not in control
    assert authority or gw.counters["refused"] == 1


def test_a_refused_mission_write_is_decoded_once_and_a_heartbeat_never():
    gw, station, t = make_gateway(signing="off")
    gw.on_app_frame(0, "peer", heartbeat(APP), 0.0)
    calls = counted(gw)
    station.authority = False
    item = FrameCodec(APP, 190).encode(mav.MAVLink_mission_count_message(1, 1, 3, 0))
    gw.on_app_frame(0, "peer", item, 0.1)
    assert calls[APP] == 1 and gw.counters["refused"] == 1
    gw.on_app_frame(0, "peer", heartbeat(APP), 0.2)
    assert calls[APP] == 1
