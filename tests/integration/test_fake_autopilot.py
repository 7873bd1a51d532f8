"""Only the real autopilot speaks for the vehicle (issue 29, behaviours 4 and 5), tried as the attacker
would: a separate process on the companion host (``python -m zdrone.sil.rogue --mode fake-autopilot``)
writing into the companion's UDP vehicle link, against ``zdrone sim`` as a process.

* Behaviour 5 (a fake autopilot wins the start): the attacker sends a fake autopilot's HEARTBEAT
  (sysid 7) and positions before the real autopilot says anything. Control: a naive link (pymavlink's
  ``udpin`` with the old rule, "the first autopilot HEARTBEAT is the vehicle") adopts system 7 and
  sends it what it sends the vehicle (SETUP_SIGNING with the key); the vehicle link adopts system 1,
  sends the attacker nothing and counts its datagrams by reason.
* Behaviour 4 (a forged position makes an heir): positions at B's centre with the autopilot's own
  ids, written into the link of the default topology (``udpout``: the companion's port found as a
  local process finds it). Control: pymavlink's ``udpout`` takes them; the vehicle link drops them
  (``foreign_endpoint``) and its position stays the vehicle's.
* The reflection (a stored key, both booting): the attacker claims the autopilot's ids first and
  sends the companion's own signed frames back to it (``tests/integration/reflector.py``, its own
  process). Control: the old rule takes the attacker for the autopilot, signed; the vehicle link
  drops the reflections and takes the real autopilot.
* The ``fake-autopilot`` scenario end to end (both personalities; ArduPilot with ``--fc-signing off``,
  the issue's own configuration): never system 7, nothing sent to the fake, no position near B, no
  hand-over to B, the failsafe LAND confirmed by the real autopilot.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import sys
import threading
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import common as mav  # noqa: E402

from tests.integration.test_flight_e2e import _clean_shutdown, run_demo  # noqa: E402
from tests.procs import ZDRONE, Proc, free_port, spawn, wait_until  # noqa: E402
from zdrone.core import fcsign  # noqa: E402
from zdrone.core.geometry import GeoPoint, distance_m  # noqa: E402
from zdrone.core.reference import COVERAGE_RADIUS_M, GS_B, HOME  # noqa: E402
from zdrone.fleet.files import init_fleet  # noqa: E402
from zdrone.net.eventlog import read_events  # noqa: E402
from zdrone.sil.rogue import fake_autopilot_frames  # noqa: E402
from zdrone.vehicle.fcsigning import FcKeyStore, FcSigning  # noqa: E402
from zdrone.vehicle.link import VehicleLink  # noqa: E402


def _attacker(fleet: Path, port: int, events: Path, duration: float = 3.0, wait_go: bool = False):
    """The attacker as its own process: races from its start, forges with the autopilot's ids after
    (half of ``duration`` each; ``wait_go``: races until SIGUSR2, then forges for ``duration``)."""
    return spawn(sys.executable, "-m", "zdrone.sil.rogue", "--mode", "fake-autopilot", "--fleet", str(fleet),
                 "--router", "tcp/127.0.0.1:1", "--vehicle-port", str(port), "--duration", str(duration),
                 "--events", str(events), *(["--wait-go"] if wait_go else []))


def _done(events: Path) -> dict:
    return next(e for e in read_events(events) if e["type"] == "attack_done")


@pytest.fixture
def fleet(tmp_path: Path) -> Path:
    init_fleet(tmp_path / "fleet")
    return tmp_path / "fleet"


def test_a_fake_autopilot_racing_the_start_wins_a_naive_link(fleet, tmp_path):
    """The control of behaviour 5: what the vehicle link used to be (pymavlink ``udpin``, the first
    autopilot HEARTBEAT is the vehicle) adopts system 7 and sends it the signing key."""
    port = free_port(socket.SOCK_DGRAM)
    naive = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=191)
    try:
        with _attacker(fleet, port, tmp_path / "rogue.jsonl") as attacker:
            attacker.wait_line("rogue: ready", 20)
            first = wait_until(lambda: naive.recv_match(type="HEARTBEAT", blocking=False), 10)
            assert first is not None and first.autopilot != mav.MAV_AUTOPILOT_INVALID
            adopted = first.get_srcSystem()
            assert adopted == 7  # the fake is "the vehicle"
            setup = mav.MAVLink_setup_signing_message(adopted, 1, list(bytes(range(32))), 1)
            naive.mav.send(setup)  # what the drone sent next: the key, in clear, to the fake
            assert attacker.p.wait(20) == 0
        assert _done(tmp_path / "rogue.jsonl")["heard"].get("SETUP_SIGNING", 0) >= 1
    finally:
        naive.close()


def test_the_vehicle_link_never_adopts_the_fake_sends_it_nothing_and_counts_its_datagrams(fleet, tmp_path):
    """Behaviour 5 tried again: the attacker starts first and races (sysid 7) until the link has chosen;
    the vehicle link listens where the simulator sends (PX4's onboard link) and adopts system 1 only.
    Only then, the autopilot signing, is the attacker told to forge with the autopilot's own ids (a
    process claiming them before the choice is the next test's: refused, ``ConfigError``); before, the
    switch came after a fixed 5 s and a slow simulator start let it land before the choice."""
    port = free_port(socket.SOCK_DGRAM)
    with _attacker(fleet, port, tmp_path / "rogue.jsonl", duration=3.0, wait_go=True) as attacker:
        attacker.wait_line("rogue: ready", 20)
        link = VehicleLink(f"udpin:127.0.0.1:{port}",
                           signing=FcSigning(FcKeyStore(tmp_path / "d1.fc-signing.json"), "prefer", confirm_timeout=30.0))
        try:
            with spawn(ZDRONE, "sim", "--mavlink", f"udpout:127.0.0.1:{port}", "--speedup", "4") as sim:
                sim.wait_line("zdrone sim:", 20)
                assert link.wait_vehicle(20)
                assert link.sysid == 1 and link.signing_status()["signed"]
                assert link.endpoint.how == "signed" and not link.endpoint.claimants, link.endpoint.status()
                attacker.p.send_signal(signal.SIGUSR2)  # now forge with the autopilot's own ids
                attacker.wait_line("rogue: forging with the autopilot's own ids", 20)
                assert wait_until(lambda: (link.heartbeat(), link.recv(0.05), link.position_signed)[2], 10)
                assert attacker.p.wait(30) == 0
                link.recv(0.2)
                assert distance_m(HOME, link.position) < 5.0 and link.sysid == 1
                counters = link.stream_stats()["endpoint"]["counters"]
                assert counters.get("dropped:foreign_endpoint", 0) > 0, counters
                assert link.tracker.counters.get("foreign_heartbeat", 0) == 0  # none reached the tracker
        finally:
            link.close()
    done = _done(tmp_path / "rogue.jsonl")
    assert done["sent"]["raced"] > 0 and done["sent"]["forged_own_ids"] > 0
    assert done["heard_total"] == 0, done["heard"]  # no key, no stream request, no command: nothing


def test_a_fake_that_claims_the_autopilot_ids_before_it_leaves_the_vehicle_unknown_not_taken(fleet, tmp_path):
    """The stronger race: the attacker sends the HEARTBEAT of the autopilot's own ids (1/1) before the
    real one. Over a listening socket nothing tells them apart before a key exists: the link refuses to
    pick either (and hands neither a key) instead of adopting the first."""
    from zdrone.core.fleet import ConfigError

    port = free_port(socket.SOCK_DGRAM)
    with _attacker(fleet, port, tmp_path / "rogue.jsonl", duration=30.0) as attacker:
        attacker.wait_line("rogue: forging with the autopilot's own ids", 30)
        link = VehicleLink(f"udpin:127.0.0.1:{port}",
                           signing=FcSigning(FcKeyStore(tmp_path / "d1.fc-signing.json"), "prefer", confirm_timeout=30.0))
        try:
            with spawn(ZDRONE, "sim", "--mavlink", f"udpout:127.0.0.1:{port}", "--speedup", "4") as sim:
                sim.wait_line("zdrone sim:", 20)
                with pytest.raises(ConfigError, match="which is the autopilot cannot be told"):
                    link.wait_vehicle(20)
                assert link.signing.counters.get("setup_sent", 0) == 0 and link.signing.key is None
        finally:
            link.close()
        attacker.stop()
    assert not (tmp_path / "d1.fc-signing.json").exists()


REFLECTOR = str(Path(__file__).with_name("reflector.py"))


class _Forget(set):
    """The old rule's memory of the streams the companion emits: none."""

    def add(self, item) -> None:  # noqa: D102
        pass


@pytest.mark.parametrize("old_rule", [True, False], ids=["control-old-rule", "vehicle-link"])
def test_a_stored_key_and_a_fake_that_reflects_the_companions_signed_frames(tmp_path, old_rule):
    """The reflection attack (a local process, no key) on a listening link that already holds a key the
    autopilot confirmed: the autopilot is not signing yet when the companion starts (both booting);
    the attacker sends the autopilot's HEARTBEAT (1/1) first and sends every signed frame it gets from
    the companion straight back. Control: with the old rule (any frame signed with the key proves the
    autopilot) the attacker's address becomes the autopilot, "signed", even under ``require``. The
    vehicle link drops the reflections (``reflected``): only the autopilot's own stream proves it, and
    the real autopilot, which signs back, is the endpoint."""
    port = free_port(socket.SOCK_DGRAM)
    store, sd = FcKeyStore(tmp_path / "d1.fc-signing.json"), tmp_path / "sd"
    sim_args = (ZDRONE, "sim", "--mavlink", f"udpout:127.0.0.1:{port}", "--speedup", "4", "--storage", str(sd))
    bench = VehicleLink(f"udpin:127.0.0.1:{port}", signing=FcSigning(store, "require"))  # the key installed once
    try:
        with spawn(*sim_args) as sim:
            sim.wait_line("zdrone sim:", 20)
            assert bench.wait_vehicle(20) and bench.signing_status()["signed"]
    finally:
        bench.close()
    assert store.load().confirmed
    sims: list[Proc] = []  # the autopilot boots 3 s after the companion (signing starts 1.5 s after its HEARTBEAT)
    boot = threading.Timer(3.0, lambda: sims.append(Proc(list(sim_args))))
    with spawn(sys.executable, REFLECTOR, str(port), "15") as attacker:
        me = tuple(json.loads(attacker.wait_line('"ready"', 20))["me"])
        wait_until(lambda: False, 0.3)  # the attacker's HEARTBEATs are on their way before the companion listens
        link = VehicleLink(f"udpin:127.0.0.1:{port}", signing=FcSigning(store, "require", confirm_timeout=10.0))
        try:
            if old_rule:
                key = link.signing.key
                link.endpoint.signed_by_us = lambda f: fcsign.is_signed(f) and fcsign.signed_with(f, key)
                link.signing.autopilot_ids, link.signing.emitted = None, _Forget()
            boot.start()
            assert link.wait_vehicle(20)
            ep = link.endpoint.status()
            attacker.wait_line('"reflected"', 10)
            if old_rule:  # taken: the attacker is "the autopilot, signed", the link "signed" by its own frames
                assert link.endpoint.address == me and link.endpoint.how == "signed", ep
                assert link.signing_status()["signed"]
                return
            assert link.endpoint.how == "signed" and link.endpoint.address != me, ep
            # the reflections were dropped: as ``reflected`` while the attacker was still the address that
            # sent the HEARTBEAT first, as ``foreign_endpoint`` once the autopilot signed
            assert link.signing_status()["signed"] and link.signing.counters["dropped:reflected"] > 0
            assert wait_until(lambda: (link.heartbeat(), link.recv(0.05), link.position_signed)[2], 10)
            assert distance_m(HOME, link.position) < 5.0 and link.sysid == 1
            for _ in range(20):
                link.heartbeat()
                link.recv(0.05)
            assert link.endpoint.address != me and link.endpoint.counters["dropped:foreign_endpoint"] > 0
        finally:
            boot.cancel()
            link.close()
            boot.join()
            for sim in sims:
                sim.stop()
        assert attacker.p.wait(30) == 0
    done = json.loads(attacker.wait_line('"done"', 5))
    assert done["heartbeats"] > 0 and done["reflected"] > 0


def _local_port(conn) -> int:
    return conn.port.getsockname()[1]


@pytest.mark.parametrize("naive", [True, False], ids=["control-naive", "vehicle-link"])
def test_forged_positions_into_the_default_udp_link(tmp_path, naive):
    """Behaviour 4: positions at B's centre with the autopilot's own ids, written into the companion's
    socket (``udpout`` to the simulator, the demo's topology) by a local process that found its port."""
    sim_port = free_port(socket.SOCK_DGRAM)
    forged = fake_autopilot_frames(1, GS_B.lat, GS_B.lon, 30.0, True, 0)
    with spawn(ZDRONE, "sim", "--mavlink", f"udpin:127.0.0.1:{sim_port}", "--speedup", "4") as sim:
        sim.wait_line("zdrone sim:", 20)
        if naive:
            conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{sim_port}", source_system=1, source_component=191)
        else:
            link = VehicleLink(f"udpout:127.0.0.1:{sim_port}",
                               signing=FcSigning(FcKeyStore(tmp_path / "k.json"), "off"))
            conn = link.m
        try:
            if naive:
                conn.mav.heartbeat_send(18, 8, 0, 0, 4)
                assert wait_until(lambda: conn.recv_match(type="GLOBAL_POSITION_INT", blocking=False), 10)
            else:
                assert link.wait_vehicle(20)
            attacker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                seen: list = []
                for _ in range(40):  # a separate socket: what any local process can do
                    for f in forged:
                        attacker.sendto(f, ("127.0.0.1", _local_port(conn)))
                    if naive:
                        m = conn.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=0.05)
                        if m is not None:
                            seen.append(GeoPoint(m.lat / 1e7, m.lon / 1e7))
                    else:
                        link.heartbeat()
                        link.recv(0.05)
                        seen.append(link.position)
            finally:
                attacker.close()
            near_b = [p for p in seen if p is not None and distance_m(GS_B, p) < COVERAGE_RADIUS_M]
            if naive:
                assert near_b, "the naive link took no forged position"
            else:
                assert not near_b and link.sysid == 1
                counters = link.stream_stats()["endpoint"]["counters"]
                assert counters.get("dropped:foreign_endpoint", 0) >= 40 * len(forged) - 5, counters
        finally:
            (conn.close() if naive else link.close())


@pytest.mark.slow
@pytest.mark.parametrize("autopilot,extra", [("px4", ()), ("ardupilot", ("--fc-signing", "off"))],
                         ids=["px4-signed", "ardupilot-unsigned"])
def test_fake_autopilot_scenario(tmp_path, autopilot, extra):
    s, out = run_demo(tmp_path, "fake-autopilot", autopilot=autopilot, extra=extra)
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    done = s["attacks"]["fake-autopilot"]
    assert done["sent"]["raced"] > 0 and done["sent"]["forged_own_ids"] > 0 and done["heard_total"] == 0
    found = [e for e in read_events(out / "drone.jsonl") if e["type"] == "vehicle_found"]
    assert [e["sysid"] for e in found] == [1]
    assert [e["to"] for e in s["handovers"]] == [] and s["failsafe"]["action"] == "LAND"
    assert any(e["type"] == "failsafe_confirmed" for e in read_events(out / "drone.jsonl"))
    assert "LAND" in s["vehicle"]["modes"]
    if extra:  # unsigned: every GS is told, the drone logs it, the demo opted in and said so
        assert s["fc_signing"]["state"] == "off" and s["fc_signing"]["trust_unsigned_position"] is True
        assert any(e["type"] == "fc_unsigned" for e in read_events(out / "drone.jsonl"))
        assert any("--trust-unsigned-position" in n for n in s["notes"])
        heard = [e for e in read_events(out / "A.jsonl") if e["type"] == "fc_signing"]  # B: out of range all flight
        assert heard and heard[-1]["signed"] is False
    _clean_shutdown(s, out, nodes=("drone", "B"), stopped=("gsA",))
    json.dumps(s)  # the summary stays plain JSON
