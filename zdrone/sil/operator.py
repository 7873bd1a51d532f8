"""TESTBED ONLY: two ground-station operators for the ``operator-consent`` scenario, each a MAVLink
application (pymavlink messages over UDP, sysid 255 as QGroundControl and MAVProxy by default) on its
GS's GCS gateway.

The script, once the drone is inside both coverages (seen in its GLOBAL_POSITION_INT on A's gateway):

1. A's operator holds the vehicle there (DO_SET_MODE hold), then waits until B's application sees
   CONTROL_STATUS naming A (the GS in control) and no takeover allowed.
2. **No consent**: B asks (MAV_CMD_REQUEST_OPERATOR_CONTROL p1 = 1, p2 = 1, p3 = 3 s): answered
   FAILED; A's application is shown the request (the vehicle's COMMAND_LONG 32100, p4 = B's sysid) and
   acknowledges it, nothing more. Past the timeout, B still sees A in control.
3. **Consent**: B asks again (p3 = 10 s): FAILED; a consent naming X and one given before the request
   could be read (p4 = its own sysid at once) are DENIED; after ``CONSENT_READ_S`` A's operator consents
   with p1 = 1, p2 = 1 and p4 = its own sysid, as QGroundControl (allow B takeover for the window).
   A's application sees TAKEOVER_ALLOWED; B's standing request, sent again each second, is its ask
   again: B's application must see itself in control (``gcs_main`` = its own sysid) within the window.
4. **Takeover allowed for the request read**: A asks (p2 = 1: no standing setting, FAILED); B's operator
   reads it and allows takeover (p1 = 1, p2 = 1, p4 its own sysid): A takes control. Then B asks and A's
   operator allows it the same way.
5. **Back to the mission**: A asks (B now refuses takeover: FAILED); B's operator releases (p1 = 0, p4 =
   the requester it was shown) to A; A's operator lets go of held control (p1 = 0, nobody asking) and resumes the mission (DO_SET_MODE
   mission): the flight goes on with its automatic hand-overs.

Every step and its timing goes to the events file (``operator_step``; ``operator_done`` with
``ok`` and the failed step, if any). Exit status 0 when every step passed.
"""

from __future__ import annotations

import argparse
import socket
import sys
import time
from typing import Any, Callable

from pymavlink.dialects.v20 import common as mav

from zdrone.core.geometry import GeoPoint, distance_m
from gs.opcontrol import CONSENT_READ_S
from zdrone.core.mavcontrol import MAV_CMD_REQUEST_OPERATOR_CONTROL, ControlStatus, decode_control_status
from zdrone.core.mavlink import FrameCodec
from zdrone.core.reference import COVERAGE_RADIUS_M, DEFAULT_NODES, GS_A, GS_B
from zdrone.net.eventlog import EventLog
from zdrone.vehicle.px4modes import FlightMode

APP_SYSID = 255
#: the fleet sysids of GS A and GS B (the reference fleet)
A_SYSID, B_SYSID, X_SYSID = (next(n[2] for n in DEFAULT_NODES if n[0] == g) for g in ("A", "B", "X"))
#: custom-mode params 2 and 3 of DO_SET_MODE, per autopilot: hold where it is, and fly the mission
MODES = {mav.MAV_AUTOPILOT_PX4: {"hold": FlightMode.HOLD.value, "mission": FlightMode.MISSION.value},
         mav.MAV_AUTOPILOT_ARDUPILOTMEGA: {"hold": (5, 0), "mission": (3, 0)}}  # LOITER, AUTO
#: hold the vehicle once it is this far inside both coverages (metres from each circle's edge)
INSIDE_MARGIN_M = 15.0


def inside_both(app: "OperatorApp") -> bool:
    """The drone, as ``app`` hears it, flies inside A's and B's coverages with a margin."""
    p = app.position
    return p is not None and p.alt > 10 and all(
        distance_m(c, p) < COVERAGE_RADIUS_M - INSIDE_MARGIN_M for c in (GS_A, GS_B))


class StepFailed(Exception):
    pass


class OperatorApp:
    """One MAVLink application on a gateway's ``udpin`` port: sends pymavlink messages, reads what
    comes back (CONTROL_STATUS decoded with today's layout, the rest with pymavlink)."""

    def __init__(self, name: str, port: int) -> None:
        self.name = name
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.codec = FrameCodec(APP_SYSID, 190)
        self.status: ControlStatus | None = None
        self.statuses: list[tuple[float, ControlStatus]] = []
        self.messages: list[tuple[float, Any]] = []
        self.autopilot: int | None = None
        self.position: GeoPoint | None = None
        self.last_heartbeat = 0.0

    def send(self, msg: Any) -> None:
        self.sock.send(self.codec.encode(msg))

    def command(self, command: int, *params: float) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.send(mav.MAVLink_command_long_message(1, 1, command, 0, *p))

    def pump(self) -> None:
        now = time.monotonic()
        if now - self.last_heartbeat >= 1.0:
            self.last_heartbeat = now
            self.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        while True:
            try:
                data = self.sock.recv(65536)
            except (BlockingIOError, ConnectionRefusedError):
                return
            st = decode_control_status(data)
            if st is not None:
                self.status = st
                self.statuses.append((now, st))
                continue
            msg = self.codec.decode(data)
            if msg is None:
                continue
            t = msg.get_type()
            if t == "HEARTBEAT" and msg.get_srcComponent() == 1 and msg.type != mav.MAV_TYPE_GCS:
                self.autopilot = msg.autopilot
            elif t == "GLOBAL_POSITION_INT" and (msg.lat or msg.lon):
                self.position = GeoPoint(msg.lat / 1e7, msg.lon / 1e7, msg.relative_alt / 1000.0)
            elif t in ("COMMAND_ACK", "COMMAND_LONG"):
                self.messages.append((now, msg))

    def acks(self, command: int, since: float) -> list[int]:
        return [m.result for (t, m) in self.messages if t >= since and m.get_type() == "COMMAND_ACK" and m.command == command]

    def requests_shown(self, since: float) -> list[Any]:
        return [m for (t, m) in self.messages
                if t >= since and m.get_type() == "COMMAND_LONG" and m.command == MAV_CMD_REQUEST_OPERATOR_CONTROL]

    def in_control(self) -> int | None:
        return None if self.status is None else self.status.gcs_main


class Script:
    def __init__(self, a: OperatorApp, b: OperatorApp, events: EventLog, deadline: float) -> None:
        self.a, self.b, self.events, self.deadline = a, b, events, deadline
        self.results: dict[str, Any] = {}

    def pump(self) -> None:
        self.a.pump()
        self.b.pump()

    def wait(self, what: str, cond: Callable[[], bool], timeout: float) -> float:
        """Pump until ``cond``; the seconds it took. ``StepFailed`` after ``timeout``."""
        t0 = time.monotonic()
        end = min(t0 + timeout, self.deadline)
        while True:
            self.pump()
            if cond():
                return time.monotonic() - t0
            if time.monotonic() >= end:
                raise StepFailed(f"{what}: not within {timeout:g} s")
            time.sleep(0.01)

    def hold_for(self, seconds: float, check: Callable[[], bool], what: str) -> None:
        """Pump for ``seconds``; ``check`` must hold throughout."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.pump()
            if not check():
                raise StepFailed(what)
            time.sleep(0.02)

    def step(self, name: str, **fields: Any) -> None:
        self.results[name] = fields
        self.events.write("operator_step", step=name, **fields)
        print(f"operator: {name} {fields}", flush=True)

    def ask(self, app: OperatorApp, p1: float, p2: float = 0.0, p3: float = 5.0, p4: float = APP_SYSID) -> float:
        """MAV_CMD_REQUEST_OPERATOR_CONTROL; p4 is the application's own sysid (as QGroundControl sends
        it, a consent included: the gateway binds it to the request it showed this application)."""
        since = time.monotonic()
        app.command(MAV_CMD_REQUEST_OPERATOR_CONTROL, p1, p2, p3, p4)
        return since

    def read(self, app: OperatorApp, since: float, what: str, sysid: int | None = None, timeout: float = 3.0) -> float:
        """Wait until ``app`` is shown a request (from ``sysid``, if given) after ``since``, then as long
        as an operator takes to read it (``CONSENT_READ_S`` and a little more): when it was shown."""
        def shown() -> list[tuple[float, Any]]:
            return [(t, m) for (t, m) in app.messages if t >= since and m.get_type() == "COMMAND_LONG"
                    and m.command == MAV_CMD_REQUEST_OPERATOR_CONTROL and (sysid is None or int(m.param4) == sysid)]
        self.wait(what, lambda: bool(shown()), timeout)
        t_shown = shown()[0][0]
        self.hold_for(max(0.0, t_shown + CONSENT_READ_S + 0.3 - time.monotonic()), lambda: True, "")
        return t_shown

    def first_ack(self, app: OperatorApp, since: float, timeout: float = 3.0) -> int:
        self.wait(f"{app.name}: answer to 32100", lambda: bool(app.acks(MAV_CMD_REQUEST_OPERATOR_CONTROL, since)), timeout)
        return app.acks(MAV_CMD_REQUEST_OPERATOR_CONTROL, since)[0]

    def set_mode(self, app: OperatorApp, which: str) -> None:
        modes = MODES.get(app.autopilot or mav.MAV_AUTOPILOT_PX4, MODES[mav.MAV_AUTOPILOT_PX4])
        since = time.monotonic()
        for _ in range(5):
            app.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, *modes[which])
            try:
                self.wait(f"{app.name}: {which} accepted",
                          lambda: mav.MAV_RESULT_ACCEPTED in app.acks(mav.MAV_CMD_DO_SET_MODE, since), 1.0)
                return
            except StepFailed:
                continue
        raise StepFailed(f"{app.name}: DO_SET_MODE {which} never accepted: {app.acks(mav.MAV_CMD_DO_SET_MODE, since)}")

    def run(self) -> None:
        a, b = self.a, self.b
        # 1. in both coverages: A's operator holds the vehicle there
        self.wait("the drone inside both coverages", lambda: inside_both(a), 150.0)
        self.set_mode(a, "hold")
        took = self.wait("B sees A in control", lambda: b.in_control() == A_SYSID and a.in_control() == APP_SYSID, 10.0)
        assert b.status is not None
        self.step("held", b_sees=b.status.gcs_main, takeover_allowed=b.status.takeover_allowed, waited_s=round(took, 2))
        if b.status.takeover_allowed:
            raise StepFailed("takeover allowed before anyone allowed it")

        # 2. no consent: nothing moves
        since = self.ask(b, 1, 1, 3)
        answer = self.first_ack(b, since)
        if answer != mav.MAV_RESULT_FAILED:
            raise StepFailed(f"B's request answered {answer}, not FAILED")
        self.wait("A's application shown B's request", lambda: bool(a.requests_shown(since)), 3.0)
        shown = a.requests_shown(since)[0]
        a.send(mav.MAVLink_command_ack_message(MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_ACCEPTED, 0, 0, 1, 1))
        t_open = time.time()
        self.hold_for(4.5, lambda: b.in_control() == A_SYSID and a.in_control() == APP_SYSID, "control moved without consent")
        self.step("no_consent", answer=answer, shown_p4=shown.param4, shown_timeout=shown.param3,
                  window=[round(t_open - 0.5, 3), round(time.time(), 3)], still_in_control="A")

        # 3. consent: A's operator allows takeover; B takes control within the window
        since = self.ask(b, 1, 1, 10)
        answer = self.first_ack(b, since)
        self.wait("A's application shown B's second request", lambda: bool(a.requests_shown(since)), 3.0)
        shown = a.requests_shown(since)[0]
        unnamed = self.first_ack(a, self.ask(a, 1, 1, 10, X_SYSID))  # p4 names another GS of the fleet: refused
        if unnamed != mav.MAV_RESULT_DENIED:
            raise StepFailed(f"a consent naming another GS answered {unnamed}, not DENIED")
        hasty = self.first_ack(a, self.ask(a, 1, 1, 10))  # p4 = its own sysid before the request could be read
        if hasty != mav.MAV_RESULT_DENIED:
            raise StepFailed(f"a consent given before the request could be read answered {hasty}, not DENIED")
        self.read(a, since, "A's operator reads B's request")
        consent = self.ask(a, 1, 1, 10)  # as QGroundControl: p4 = its own sysid, bound to the request it was shown
        consent_answer = self.first_ack(a, consent)
        self.wait("B in control after A's consent", lambda: b.in_control() == APP_SYSID, 10.0)
        took = time.monotonic() - consent
        self.wait("A's application sees B in control", lambda: a.in_control() == B_SYSID, 3.0)
        took_a = time.monotonic() - consent
        self.step("consent", answer=answer, unnamed_answer=unnamed, consent_answer=consent_answer,
                  to_control_s=round(took, 3), a_sees_s=round(took_a, 3), within_window=took < 10.0)

        # 4. takeover allowed by the owner's operator for the request it read, both ways (a requester's p2 is
        #    no standing setting: A's request is shown to B's operator)
        since = self.ask(a, 1, 1, 10)
        first = self.first_ack(a, since)
        self.read(b, since, "B's application shown A's request")
        allow = self.ask(b, 1, 1, 10)  # p4 = its own sysid: the request it read
        allowed_a = self.first_ack(b, allow)
        self.wait("A in control after B allowed it", lambda: a.in_control() == APP_SYSID, 3.0)
        took_a = time.monotonic() - allow
        since = self.ask(b, 1, 0, 10)
        first_b = self.first_ack(b, since)
        self.read(a, since, "A's application shown B's request")
        allow = self.ask(a, 1, 1, 10)
        allowed_b = self.first_ack(a, allow)
        self.wait("B in control after A allowed it", lambda: b.in_control() == APP_SYSID, 3.0)
        took_b = time.monotonic() - allow
        self.step("takeover", a_first_answer=first, a_to_control_s=round(took_a, 3), b_first_answer=first_b,
                  b_to_control_s=round(took_b, 3), allow_answers=[allowed_a, allowed_b])
        if first != mav.MAV_RESULT_FAILED or first_b != mav.MAV_RESULT_FAILED:
            raise StepFailed(f"requests answered {first}/{first_b}, not FAILED (the owner's operator is asked)")
        if (allowed_a, allowed_b) != (mav.MAV_RESULT_ACCEPTED, mav.MAV_RESULT_ACCEPTED):
            raise StepFailed(f"allow-takeover answered {allowed_a}/{allowed_b}, not ACCEPTED")

        # 5. back to A and the mission: B's operator releases to A's request
        self.wait("A sees no takeover allowed", lambda: a.status is not None and not a.status.takeover_allowed, 3.0)
        since = self.ask(a, 1, 0, 10)
        answer = self.first_ack(a, since)
        self.wait("B's application shown A's request", lambda: bool(b.requests_shown(since)), 3.0)
        release = self.ask(b, 0, 0, 5, b.requests_shown(since)[0].param4)
        self.first_ack(b, release)
        self.wait("A in control after B's release", lambda: a.in_control() == APP_SYSID, 5.0)
        took = time.monotonic() - release
        let_go = self.ask(a, 0)
        self.first_ack(a, let_go)
        self.set_mode(a, "mission")
        self.step("released", answer=answer, to_control_s=round(took, 3))


def main(argv: list[str] | None = None) -> int:
    from zdrone.crashes import stacks_on_crash

    stacks_on_crash()  # a crash leaves every thread's stack in our log
    p = argparse.ArgumentParser(prog="python -m zdrone.sil.operator", description="TESTBED ONLY operators")
    p.add_argument("--a-port", type=int, required=True, help="GS A's gateway udpin port")
    p.add_argument("--b-port", type=int, required=True, help="GS B's gateway udpin port")
    p.add_argument("--events", default="operator.jsonl")
    p.add_argument("--duration", type=float, default=200.0, help="give up after this many seconds")
    args = p.parse_args(argv)
    events = EventLog(args.events, "operator")
    a, b = OperatorApp("A", args.a_port), OperatorApp("B", args.b_port)
    return play(Script(a, b, events, time.monotonic() + args.duration))


def play(script: Script) -> int:
    """Run an operators' script: every step to its events file, ``operator_done`` last; the exit status."""
    print("operator: ready", flush=True)
    try:
        script.run()
    except StepFailed as exc:
        script.events.write("operator_done", ok=False, failed=str(exc), steps=list(script.results))
        print(f"operator: FAILED: {exc}", flush=True)
        return 1
    script.events.write("operator_done", ok=True, failed=None, steps=list(script.results))
    print("operator: done", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
