"""The router's limits: the size limit holds for a client on the same host (no shared-memory way
around it); each uplink's rate is limited, so a flood on one GS's uplink leaves another's alone;
frames the router processes back to back pass when they are on an uplink's lanes in turn."""

from __future__ import annotations

import contextlib
import socket
import sys
import threading
import time

import zenoh

from tests.procs import ZDRONE, free_port, spawn, wait_until
from zdrone.fleet.files import init_fleet, load_secret
from zdrone.fleet import keyexprs as kx
from zdrone.fleet.routerconfig import UPLINK_LANE_HZ, UPLINK_MAX_BYTES, UPLINK_MAX_HZ, UPLINK_PACE_S
from zdrone.fleet.tls import node_files
from zdrone.net.session import open_client


def test_a_message_over_64_kib_is_dropped_and_the_sender_stays_connected(tmp_path):
    init_fleet(tmp_path / "fleet")
    port = free_port(socket.SOCK_STREAM)
    ep = f"tcp/127.0.0.1:{port}"
    with spawn(ZDRONE, "router", "-c", str(tmp_path / "fleet" / "router" / "router.json5"), "--listen", ep) as router:
        router.wait_line("listening", 20)
        fleet = tmp_path / "fleet"
        a = open_client(ep, "A", load_secret(fleet, "A").router_password)
        d = open_client(ep, "d1", load_secret(fleet, "d1").router_password)
        got: list[int] = []
        small = threading.Event()
        subs = [d.declare_subscriber(lane, lambda s: (got.append(len(s.payload)),
                                                      small.set() if len(s.payload) == 500 else None))
                for lane in kx.up_lanes("d1", "A")]
        try:
            for _ in range(50):  # until the route exists
                a.put(kx.up_lane("d1", "A", 0), b"p" * 10)
                if got:
                    break
                threading.Event().wait(0.1)
            assert got, "no route from A to the drone"
            a.put(kx.up_lane("d1", "A", 1), b"x" * 70_000)
            threading.Event().wait(UPLINK_PACE_S)
            a.put(kx.up_lane("d1", "A", 2), b"y" * 500)
            assert small.wait(10.0), "the small message after the big one never arrived"
            assert 70_000 not in got
        finally:
            for sub in subs:
                sub.undeclare()


@contextlib.contextmanager
def _router_with_d1_and_a(tmp_path, tls: bool = False):
    """A fleet's router on a free port (with ``tls``: mutual TLS, a node is its certificate and
    password), with sessions of the drone d1 and of GS A (closed after)."""
    init_fleet(tmp_path / "fleet", tls=tls)
    fleet = tmp_path / "fleet"
    ep = f"{'tls' if tls else 'tcp'}/127.0.0.1:{free_port(socket.SOCK_STREAM)}"

    def client(name: str) -> zenoh.Session:
        return open_client(ep, name, load_secret(fleet, name).router_password, node_files(fleet, name) if tls else None)

    with spawn(ZDRONE, "router", "-c", str(fleet / "router" / "router.json5"), "--listen", ep) as router:
        router.wait_line("listening", 20)
        d, a = client("d1"), client("A")
        try:
            yield fleet, ep, d, a
        finally:
            a.close()
            d.close()


FLOODER = """
import sys, time, zenoh
from zdrone.fleet import keyexprs as kx
from zdrone.fleet.files import load_secret
from zdrone.fleet.tls import node_files
from zdrone.net.session import open_client
router, fleet, who, seconds, k = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), int(sys.argv[5])
tls = node_files(fleet, who) if router.startswith("tls/") else None
sessions = [open_client(router, who, load_secret(fleet, who).router_password, tls) for _ in range(k)]
lanes = kx.up_lanes("d1", who)
small, big = b"j" * 40, b"J" * 1000
print("flooding", flush=True)
n, t0 = 0, time.monotonic()
while time.monotonic() - t0 < seconds:
    for i in range(496):
        # every lane from every session; a third of the frames big
        sessions[(i // len(lanes)) % len(sessions)].put(lanes[i % len(lanes)], big if i % 3 == 0 else small,
                                                        congestion_control=zenoh.CongestionControl.DROP)
    n += 496
print("sent", n, round(time.monotonic() - t0, 3), flush=True)
for s in sessions:
    s.close()
"""


def _flood(tmp_path, tls: bool, who: str, k: int) -> tuple[int, int, float, int, int, list[int]]:
    """``k`` sessions with ``who``'s credentials flood ``who``'s lanes to d1 for 2 s as fast as they
    can while A sends a frame every 20 ms on its lanes in turn; (junk frames that reached d1, sent,
    seconds, A's frames that reached d1, A's sent, the sizes that reached d1)."""
    with _router_with_d1_and_a(tmp_path, tls) as (fleet, ep, d, a):
        got: dict[str, list[tuple[float, bytes]]] = {"A": [], "B": []}
        subs = [d.declare_subscriber(lane, lambda s: got[kx.gs_of_uplink(s.key_expr)].append(
            (time.monotonic(), s.payload.to_bytes()))) for lane in kx.up_lanes("d1", "*")]
        lanes = kx.up_lanes("d1", "A")
        try:
            def routed() -> bool:  # until the route exists
                a.put(lanes[0], b"a")
                return bool(wait_until(lambda: got["A"], 0.1, 0.02))

            assert wait_until(routed, 5.0, 0.0), "no route from A to the drone"
            with spawn(sys.executable, "-c", FLOODER, ep, str(fleet), who, "2.0", str(k)) as flooder:
                flooder.wait_line("flooding", 20)
                t0, sent_a = time.monotonic(), 0
                got["A"].clear()
                tick = threading.Event()  # A's pace: a frame every 20 ms while the flood lasts
                while flooder.p.poll() is None and time.monotonic() - t0 < 20.0:
                    tick.wait(0.02)
                    a.put(lanes[sent_a % len(lanes)], b"a" * 40, priority=zenoh.Priority.INTERACTIVE_HIGH)
                    sent_a += 1
                _, n, seconds = flooder.wait_line("sent", 10).split()
            every = lambda: sum(len(v) for v in got.values())  # noqa: E731
            counts = [every()]  # the last samples in flight: until the count stops growing
            wait_until(lambda: counts.append(every()) or counts[-1] == counts[-2], 1.0, 0.15)
            frames = [p for v in got.values() for t, p in v if t >= t0]
            junk = sum(1 for p in frames if p[:1] in (b"j", b"J"))
            mine = sum(1 for p in got["A"] if p[1] == b"a" * 40)
            return junk, int(n), float(seconds), mine, sent_a, [len(p) for p in frames]
        finally:
            for sub in subs:
                sub.undeclare()


def test_with_tls_a_credentials_four_sessions_get_one_budget_and_another_gs_is_not_held_back(tmp_path):
    """Bounded per credential (mutual TLS: B's certificate and password): four sessions flood every
    lane of up/B as fast as they can, a third of their frames over the uplink's size limit; the drone
    gets up/B at ONE uplink's rate limit at most, none of the big frames, and A's frames keep coming (a
    few may be lost while the flood saturates the machine). Counts, not speed."""
    junk, n, seconds, mine, sent_a, sizes = _flood(tmp_path, tls=True, who="B", k=4)
    allowed = 1.2 * UPLINK_MAX_HZ * seconds + 20  # what one budget lets through in the flood's time
    assert junk <= min(n, allowed), f"up/B not limited to one budget: {junk} of {n} in {seconds} s"
    assert mine >= 0.9 * sent_a, f"A's frames held back: {mine} of {sent_a}"
    assert max(sizes) <= UPLINK_MAX_BYTES < 1000, "a frame over the uplink's size limit reached the drone"


def test_with_a_password_alone_a_thief_flooding_as_a_never_spends_as_own_budget(tmp_path):
    """No TLS: A's leaked password is all it takes to write as A, so the budgets are per sending
    session: two sessions of a thief flooding A's own lanes get their own budgets (never A's), and
    A's frames keep coming; none of the big frames reaches the drone."""
    junk, n, seconds, mine, sent_a, sizes = _flood(tmp_path, tls=False, who="A", k=2)
    assert junk <= min(n, 2 * 1.2 * UPLINK_MAX_HZ * seconds + 40), f"the thief's sessions not limited: {junk} of {n}"
    assert mine >= 0.9 * sent_a, f"A's frames lost to a thief with its password: {mine} of {sent_a}"
    assert max(sizes) <= UPLINK_MAX_BYTES < 1000


def test_frames_processed_back_to_back_pass_on_the_lanes_and_not_on_one_key(tmp_path):
    """What a stalled router does to a GS's paced frames: it processes the ones that waited back to
    back. Puts sent back to back on an uplink's lanes in turn all reach the drone (a burst of
    UP_LANES); the same burst on one lane loses all but about the first (Zenoh's limit is a
    minimum interval, with no burst allowance: why an uplink has lanes)."""
    with _router_with_d1_and_a(tmp_path) as (fleet, ep, d, a):
        got: list[bytes] = []
        subs = [d.declare_subscriber(lane, lambda s: got.append(s.payload.to_bytes())) for lane in kx.up_lanes("d1", "A")]
        lanes = kx.up_lanes("d1", "A")
        try:
            def routed() -> bool:  # until the route exists
                a.put(lanes[0], b"r")
                return bool(wait_until(lambda: got, 0.1, 0.02))

            assert wait_until(routed, 5.0, 0.0), "no route from A to the drone"
            wait_until(lambda: False, 1.0 / UPLINK_LANE_HZ * 4, 0.01)  # the lane's interval has passed
            got.clear()
            for i, key in enumerate(lanes):
                a.put(key, b"lane%d" % i, express=True)
            assert wait_until(lambda: len(got) == len(lanes), 5.0, 0.01), f"a burst on the lanes lost frames: {got}"
            wait_until(lambda: False, 0.2, 0.01)  # every lane's interval has passed
            got.clear()
            for i in range(len(lanes)):
                a.put(lanes[0], b"one%d" % i, express=True)
            wait_until(lambda: False, 0.5, 0.05)  # what gets through has arrived
            assert got and got[0] == b"one0" and len(got) < len(lanes), f"one lane let a burst through: {got}"
        finally:
            for sub in subs:
                sub.undeclare()
