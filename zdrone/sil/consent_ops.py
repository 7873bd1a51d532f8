"""TESTBED ONLY: three ground-station operators for the ``consent-bound`` scenario, each a MAVLink
application (pymavlink messages over UDP, sysid 255) on its GS's GCS gateway; A, B and X are all
authorized for the drone.

The script, once the drone is inside A's and B's coverages:

1. A's operator holds the vehicle there; every application sees A in control.
2. **Consent to B while X asks, and the race**: B asks (p3 = 3 s), FAILED; A's application is shown B's
   request (p4 = B's sysid). 1.1 s later X asks: FAILED, and A's application is *not* shown it (one
   pending request at a time). A's operator consents naming X: DENIED, nothing moves. X asks every
   0.25 s; 3.5 s after B's request appeared (B's expired, X's shown since) A's operator answers as
   QGroundControl does (p1 = 0, p4 = its own sysid): DENIED (X's request not shown long enough to be
   read), nothing moves for 1 s. A's operator declines X naming it; B asks again, A's operator reads it
   (``CONSENT_READ_S``) and consents with p4 = its own sysid: B's application sees itself in control, A's
   and X's see B; the seconds from the consent to each application's CONTROL_STATUS are recorded.
3. **A decline**: X asks; its request reaches B, now the owner; B's application is shown it and B's
   operator declines it (p1 = 1, p2 = 0, p4 = X). X's operator asks again at once: B's application is
   not shown it for the next 5 s, and X never holds control.
4. **A window across epochs**: A asks (FAILED); B's operator reads it and allows takeover (p1 = 1, p2 = 1,
   p4 its own sysid): A takes control; A's late "allow takeover" with nothing pending is DENIED (never
   a standing setting). B asks, A's operator releases to B (p4 = B).
   A asks again: FAILED, shown to B's operator, and nothing moves for 4 s (B's "allow takeover" was for
   an earlier epoch). B's operator releases to A.
5. **Back to the mission**: A's operator lets go of held control and resumes the mission.

Every step goes to the events file (``operator_step``; ``operator_done`` with ``ok`` and the failed step).
Exit status 0 when every step passed.
"""

from __future__ import annotations

import argparse
import sys
import time

from pymavlink.dialects.v20 import common as mav

from zdrone.core.reference import DEFAULT_NODES
from zdrone.net.eventlog import EventLog
from zdrone.crashes import stacks_on_crash
from zdrone.sil.operator import A_SYSID, APP_SYSID, B_SYSID, OperatorApp, Script, StepFailed, inside_both, play

X_SYSID = next(n[2] for n in DEFAULT_NODES if n[0] == "X")


class ConsentScript(Script):
    def __init__(self, a: OperatorApp, b: OperatorApp, x: OperatorApp, events: EventLog, deadline: float) -> None:
        super().__init__(a, b, events, deadline)
        self.x = x

    def pump(self) -> None:
        super().pump()
        self.x.pump()

    def shown(self, app: OperatorApp, since: float, sysid: int) -> bool:
        return any(int(m.param4) == sysid for m in app.requests_shown(since))

    def in_control(self, owner: str) -> bool:
        """Every application sees ``owner`` in control (its own application: itself)."""
        sysid = {"A": A_SYSID, "B": B_SYSID, "X": X_SYSID}
        return all(app.in_control() == (APP_SYSID if app.name == owner else sysid[owner])
                   for app in (self.a, self.b, self.x))

    def run(self) -> None:
        a, b, x = self.a, self.b, self.x
        # 1. in both coverages: A's operator holds the vehicle there
        self.wait("the drone inside both coverages", lambda: inside_both(a), 150.0)
        self.set_mode(a, "hold")
        self.wait("every application sees A in control", lambda: self.in_control("A"), 10.0)
        self.step("held")

        # 2. consent to B while X asks; the race: X's request slipped in as B's expired is not consented to
        since = self.ask(b, 1, 0, 3)
        b_answer = self.first_ack(b, since)
        self.wait("A's application shown B's request", lambda: self.shown(a, since, B_SYSID), 3.0)
        t_b = next(t for (t, m) in a.messages if t >= since and m.get_type() == "COMMAND_LONG" and int(m.param4) == B_SYSID)
        self.hold_for(1.1, lambda: True, "")
        x_since = self.ask(x, 1, 0, 10)
        x_answer = self.first_ack(x, x_since)
        self.hold_for(0.4, lambda: not self.shown(a, x_since, X_SYSID), "X's request shown while B's stands")
        wrong = self.first_ack(a, self.ask(a, 0, 0, 5, X_SYSID))
        if wrong != mav.MAV_RESULT_DENIED:
            raise StepFailed(f"a consent naming X (not the one shown) answered {wrong}, not DENIED")
        while time.monotonic() < t_b + 3.5:  # X asks every 0.25 s while B's 3 s request runs out
            self.ask(x, 1, 0, 10)
            self.hold_for(0.25, lambda: self.in_control("A"), "control moved while X asked")
        raced = self.first_ack(a, self.ask(a, 0, 0, 5))  # A's operator answers, as QGroundControl, 3.5 s after B's
        x_shown_s = [round(t - t_b, 3) for (t, m) in a.messages if t >= t_b and m.get_type() == "COMMAND_LONG"
                     and int(m.param4) == X_SYSID]
        if raced != mav.MAV_RESULT_DENIED:
            raise StepFailed(f"a consent 3.5 s after B's 3 s request (X's just shown) answered {raced}, not DENIED")
        self.hold_for(1.0, lambda: self.in_control("A"), "control moved on a consent to a request not read")
        self.step("consent_race", answer=raced, x_shown_after_b_s=x_shown_s[:3])
        declined_x = self.first_ack(a, self.ask(a, 1, 0, 5, X_SYSID))  # A's operator declines X, naming it
        self.ask(x, 0)  # X's operator withdraws
        since = self.ask(b, 1, 0, 10)  # the control: B asks again, A's operator reads it and consents
        self.first_ack(b, since)
        self.read(a, since, "A's operator reads B's request", B_SYSID)
        consent = self.ask(a, 0, 0, 5)  # p4 = its own sysid (QGroundControl): B's request, read
        consent_answer = self.first_ack(a, consent)
        seen: dict[str, float] = {}

        def everyone_sees_b() -> bool:
            for app, want in ((a, B_SYSID), (b, APP_SYSID), (x, B_SYSID)):
                if app.name not in seen and app.in_control() == want:
                    seen[app.name] = time.monotonic() - consent
            return len(seen) == 3
        self.wait("every application sees B in control after A's consent", everyone_sees_b, 5.0)
        if b_answer != mav.MAV_RESULT_FAILED or x_answer != mav.MAV_RESULT_FAILED or consent_answer != mav.MAV_RESULT_ACCEPTED:
            raise StepFailed(f"answers: B {b_answer}, X {x_answer}, A's consent {consent_answer}")
        if declined_x != mav.MAV_RESULT_ACCEPTED:
            raise StepFailed(f"A's decline of X answered {declined_x}")
        self.step("consent_to_b_while_x_asks", wrong_named_answer=wrong, consent_answer=consent_answer,
                  a_sees_s=round(seen["A"], 3), b_sees_s=round(seen["B"], 3), x_sees_s=round(seen["X"], 3))

        # 3. a decline: X asks; its request reaches B, the owner now
        x_since = self.ask(x, 1, 0, 10)
        self.wait("B's application shown X's request", lambda: self.shown(b, x_since, X_SYSID), 5.0)
        declined = self.first_ack(b, self.ask(b, 1, 0, 5, X_SYSID))
        again = self.ask(x, 1, 0, 10)
        self.first_ack(x, again)
        self.hold_for(5.0, lambda: not self.shown(b, again, X_SYSID) and self.in_control("B"),
                      "X's request shown again within the decline's hold, or control moved")
        self.ask(x, 0)  # X's operator withdraws
        self.step("decline", answer=declined, not_shown_for_s=5.0)

        # 4. a window across epochs: B's operator allows takeover for A's request, read; a late one is refused
        since = self.ask(a, 1, 0, 10)
        a_first = self.first_ack(a, since)
        self.read(b, since, "B's operator reads A's request", A_SYSID)
        self.first_ack(b, self.ask(b, 1, 1, 5))  # p4 = its own sysid: takeover allowed for A's request, this epoch
        self.wait("A in control (takeover allowed)", lambda: self.in_control("A"), 5.0)
        late = self.first_ack(a, self.ask(a, 1, 1, 5))  # a late "allow takeover", nothing pending: no setting
        if late != mav.MAV_RESULT_DENIED:
            raise StepFailed(f"an allow-takeover with nothing pending answered {late}, not DENIED")
        since = self.ask(b, 1, 0, 10)
        self.first_ack(b, since)
        self.wait("A's application shown B's request", lambda: self.shown(a, since, B_SYSID), 3.0)
        self.first_ack(a, self.ask(a, 0, 0, 5, B_SYSID))
        self.wait("B in control again", lambda: self.in_control("B"), 5.0)
        self.wait("A sees no takeover allowed in B's new epoch", lambda: a.status is not None and not a.status.takeover_allowed, 3.0)
        since = self.ask(a, 1, 0, 10)
        across = self.first_ack(a, since)
        self.wait("B's application shown A's request", lambda: self.shown(b, since, A_SYSID), 3.0)
        self.hold_for(4.0, lambda: self.in_control("B"), "control moved on an allow-takeover of an earlier epoch")
        if a_first != mav.MAV_RESULT_FAILED or across != mav.MAV_RESULT_FAILED:
            raise StepFailed(f"A's requests answered {a_first} (B's operator asked) and {across} (a later epoch)")
        release = self.ask(b, 0, 0, 5, A_SYSID)
        self.first_ack(b, release)
        self.wait("A in control after B's release", lambda: self.in_control("A"), 5.0)
        self.step("window_across_epochs", first_answer=a_first, later_epoch_answer=across, late_allow_answer=late)

        # 5. back to the mission
        self.first_ack(a, self.ask(a, 0))
        self.set_mode(a, "mission")
        self.step("resumed")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m zdrone.sil.consent_ops", description="TESTBED ONLY operators")
    p.add_argument("--a-port", type=int, required=True, help="GS A's gateway udpin port")
    p.add_argument("--b-port", type=int, required=True, help="GS B's gateway udpin port")
    p.add_argument("--x-port", type=int, required=True, help="GS X's gateway udpin port")
    p.add_argument("--events", default="operator.jsonl")
    p.add_argument("--duration", type=float, default=240.0, help="give up after this many seconds")
    args = p.parse_args(argv)
    stacks_on_crash()  # a crash leaves every thread's stack in our log
    events = EventLog(args.events, "operator")
    apps = OperatorApp("A", args.a_port), OperatorApp("B", args.b_port), OperatorApp("X", args.x_port)
    return play(ConsentScript(*apps, events, time.monotonic() + args.duration))


if __name__ == "__main__":
    sys.exit(main())
