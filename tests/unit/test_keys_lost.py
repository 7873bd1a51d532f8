"""A GS that restarted gets its drones back through their owners (``zdrone.core.keyslost``): in memory,
real keys, a control without the notice, and the notice's misuses (forged, another GS's, stale,
replayed past a newer key), each refused with its reason."""

from __future__ import annotations

from pathlib import Path

from gs.core import CoreOptions, StationCore
from tests.coreflight import DRONE, WALL0, CoreFlight, Station
from zdrone.core import keyslost, wire
from zdrone.core import records as rec
from zdrone.core.keys import SigningKey
from zdrone.fleet.files import init_fleet, load_fleet, load_secret


def _fleet(tmp: Path):
    init_fleet(tmp)
    return load_fleet(tmp)


def _signing(tmp: Path, fleet, gs: str) -> SigningKey:
    key = load_secret(tmp, gs, fleet).signing
    assert key is not None
    return key


# ------------------------------------------------------------------ the drone's judgement, alone
def test_judge_takes_only_the_gs_own_fresh_word_about_a_key_older_than_its_restart(tmp_path: Path) -> None:
    fleet = _fleet(tmp_path)
    b = _signing(tmp_path, fleet, "B")
    t = WALL0 + 100.0
    good = keyslost.make_notice("B", since=t, wall=t + 1.0, key=b)
    assert isinstance(keyslost.judge(good, fleet, DRONE, "B", t + 2.0, key_wall=t - 30.0), keyslost.KeysLostNotice)
    assert isinstance(keyslost.judge(good, fleet, DRONE, "B", t + 2.0, key_wall=None), keyslost.KeysLostNotice)

    def why(data: bytes, gs: str = "B", wall: float = t + 2.0, key_wall: float | None = t - 30.0) -> str:
        v = keyslost.judge(data, fleet, DRONE, gs, wall, key_wall)
        assert isinstance(v, keyslost.NoticeRefused), v
        return v.reason

    forged = keyslost.make_notice("B", since=t, wall=t + 1.0, key=_signing(tmp_path, fleet, "A"))  # A signs as B
    assert why(forged) == "signature"
    assert why(good[:-3] + b"xyz") == "signature"
    assert why(b"junk") == "signature"
    assert why(good, gs="A") == "other_gs"  # B's word carried in a grant for A
    assert why(good, wall=t + 1.0 + keyslost.FRESH_S + 1.0) == "stale"
    assert why(good, wall=t + 1.0 - keyslost.AHEAD_S - 1.0) == "ahead"
    assert why(good, key_wall=t + 0.5) == "key_newer"  # a key made after the restart is never replaced
    assert why(good, key_wall=t - keyslost.SKEW_S / 2) == "key_newer"


# ------------------------------------------------------------------ a flight, B restarting on the ground
def _flight(tmp: Path) -> CoreFlight:
    f = CoreFlight(tmp, speedup=4.0)
    f.drone.wall_offset = WALL0  # the drone's time of day, as its node sets it (the GSs' is WALL0 + now)
    return f


def _restart(f: CoreFlight, gs: str, notice: bool) -> bytes:
    """GS ``gs`` dies and a new one starts in its place with no key; with ``notice``, its keys-lost notice
    reaches the other GSs (its revision key, heard by every node)."""
    old = f.gs[gs].core
    f.gs[gs] = Station(StationCore(gs, f.fleet, old.identity, (DRONE,), CoreOptions(command_rate=2.0)))
    since = WALL0 + f.now
    data = keyslost.make_notice(gs, since, since + 0.1, f._signing[gs])
    if notice:
        for name, st in f.gs.items():
            st.core.on_keys_lost(data, f.now, WALL0 + f.now)
    return data


def _granted(f: CoreFlight) -> dict[str, list[wire.KeyGrant]]:
    """Every grant A sends from now on (A carries the secrets it grants)."""
    grants: dict[str, list[wire.KeyGrant]] = {}
    a = f.gs["A"].core.sessions[DRONE]
    send = a.send_control

    def spy(msg, *args, **kw):
        if isinstance(msg, wire.KeyGrant):
            grants.setdefault(msg.gs, []).append(msg)
        return send(msg, *args, **kw)

    a.send_control = spy  # type: ignore[method-assign]
    return grants


def _linked_on_ground(f: CoreFlight) -> None:
    assert f.run_until(lambda: f.drone.machine.owner == "A" and "B" in f.drone.links, 60.0)
    f.run_until(lambda: False, 2.0)  # the keys of B are a couple of seconds old when it restarts


def test_without_the_notice_a_restarted_gs_stays_unlinked(tmp_path: Path) -> None:
    """The control: B restarts on the ground, out of the drone's radio; the drone keeps B's old key, A
    never shares again, and B holds no key for the whole wait."""
    f = _flight(tmp_path)
    _linked_on_ground(f)
    old = f.drone.links["B"]
    grants = _granted(f)
    _restart(f, "B", notice=False)
    f.run_until(lambda: False, 20.0)
    assert f.drone.links["B"] is old and "B" not in grants
    b = f.gs["B"].core.sessions[DRONE]
    assert b.link is None and not b.slot.candidates


def test_with_the_notice_the_owner_shares_again_and_the_drone_takes_the_new_key_at_once(tmp_path: Path) -> None:
    f = _flight(tmp_path)
    _linked_on_ground(f)
    old = f.drone.links["B"]
    grants = _granted(f)
    _restart(f, "B", notice=True)
    assert f.run_until(lambda: f.drone.links.get("B") is not old, 5.0), "the drone still holds the lost key"
    new = f.drone.links["B"]
    assert grants["B"] and grants["B"][-1].lost and new.key.same_as(
        type(new.key).from_secret(DRONE, "B", grants["B"][-1].secret))
    assert f.drone.counters["keys_lost_replaced"] == 1
    assert any(isinstance(r, rec.LinkInstalled) and r.how == "grant:keys_lost" for _, r in f.records)
    assert f.gs["A"].core.counters["linkkey_peer_restarted"] == 1
    # the new B holds the key as a candidate the drone proves (its first words under it, once in range)
    b = f.gs["B"].core.sessions[DRONE]
    assert b.slot.candidates or b.link is not None
    # and the flight goes on through B: the hand-over to B and back, landed
    assert f.run_until(f.flown, 900.0)
    moves = [(r.from_, r.to) for _, r in f.records if isinstance(r, rec.HandoverComplete)]
    assert ("A", "B") in moves, moves
    assert not f.commands  # no failsafe


def test_a_notice_heard_again_resets_nothing_more(tmp_path: Path) -> None:
    """B re-publishes its notice every few seconds for a minute: one share again per start, not per copy."""
    f = _flight(tmp_path)
    _linked_on_ground(f)
    grants = _granted(f)
    data = _restart(f, "B", notice=True)
    assert f.run_until(lambda: f.drone.counters["keys_lost_replaced"] == 1, 5.0)
    for _ in range(5):
        f.run_until(lambda: False, 2.5)
        f.gs["A"].core.on_keys_lost(data, f.now, WALL0 + f.now)
    f.run_until(lambda: False, 3.0)
    assert len(grants["B"]) == 1 or all(g.secret == grants["B"][0].secret for g in grants["B"])
    assert f.drone.counters["keys_lost_replaced"] == 1 and f.gs["A"].core.counters["linkkey_peer_restarted"] == 1


def test_a_hostile_owner_replaying_the_notice_cannot_replace_a_key_made_after_the_restart(tmp_path: Path) -> None:
    """The owner carries B's notice in a grant of a key it made itself, after B holds a newer key: the
    drone refuses the replacement (``key_newer``): B's key stays; the grant is a candidate B never proves."""
    f = _flight(tmp_path)
    _linked_on_ground(f)
    data = _restart(f, "B", notice=True)
    assert f.run_until(lambda: f.drone.counters["keys_lost_replaced"] == 1, 5.0)
    f.run_until(lambda: False, 3.0)
    live = f.drone.links["B"]
    a = f.gs["A"].core.sessions[DRONE]
    f.station("A", a.send_control(wire.KeyGrant("B", f.fleet.nodes["B"].sysid, bytes(range(32)), 9999, lost=data)))
    f.run_until(lambda: False, 1.0)
    assert f.drone.links["B"] is live
    assert f.drone.counters["keys_lost_refused:key_newer"] == 1 and f.drone.counters["keys_lost_replaced"] == 1


def test_forged_or_stale_notices_change_no_owner_share_and_no_drone_key(tmp_path: Path) -> None:
    """At the owner: a notice signed by another key, or an old one, is counted and dropped (B keeps its
    share GRANTED); at the drone: the same notice in a grant leaves B's live key in place."""
    f = _flight(tmp_path)
    _linked_on_ground(f)
    live = f.drone.links["B"]
    a = f.gs["A"].core
    t = WALL0 + f.now
    forged = keyslost.make_notice("B", t, t, f._signing["A"])
    stale = keyslost.make_notice("B", t - 100.0, t - 100.0, f._signing["B"])
    a.on_keys_lost(forged, f.now, t)
    a.on_keys_lost(stale, f.now, t)
    assert a.counters["keys_lost_refused:signature"] == 1 and a.counters["keys_lost_refused:stale"] == 1
    assert a.sessions[DRONE].linking.shares["B"].phase.name == "GRANTED"
    for n, bad in enumerate((forged, stale)):
        f.station("A", a.sessions[DRONE].send_control(wire.KeyGrant("B", f.fleet.nodes["B"].sysid, bytes([n]) * 32,
                                                                    500 + n, lost=bad)))
    f.run_until(lambda: False, 1.0)
    assert f.drone.links["B"] is live and f.drone.counters["keys_lost_replaced"] == 0
    assert f.drone.counters["keys_lost_refused:signature"] == 1 and f.drone.counters["keys_lost_refused:stale"] == 1


def test_a_notice_heard_before_any_key_was_shared_is_kept_for_the_first_grant(tmp_path: Path) -> None:
    """The fleet starting: B's notice reaches A before A owns the drone or asked anything; the first
    share still goes, the drone holding no key of B (nothing to replace), and the flight is linked."""
    f = _flight(tmp_path)
    t = WALL0 + f.now
    data = keyslost.make_notice("B", t, t, f._signing["B"])
    f.gs["A"].core.on_keys_lost(data, f.now, t)
    assert f.run_until(lambda: f.drone.machine.owner == "A" and "B" in f.drone.links, 60.0)
    assert f.drone.counters["keys_lost_replaced"] == 0


def test_a_gs_starting_with_the_fleet_is_not_shared_again_when_its_notice_comes_after_its_key(tmp_path: Path) -> None:
    """The fleet's start: B publishes its notice for a minute after it starts; A shared B's key after B
    started and the drone took it. A notice heard after that speaks of keys B never lost: A shares
    nothing again (else the drone, refusing the replacement, holds a key B no longer has)."""
    f = _flight(tmp_path)
    since = WALL0 + f.now - 0.5  # B started just before A asked it for its key
    _linked_on_ground(f)
    grants = _granted(f)
    live = f.drone.links["B"]
    for _ in range(3):
        f.gs["A"].core.on_keys_lost(keyslost.make_notice("B", since, WALL0 + f.now, f._signing["B"]), f.now, WALL0 + f.now)
        f.run_until(lambda: False, 2.5)
    assert "B" not in grants and f.drone.links["B"] is live
    assert f.gs["A"].core.counters["linkkey_peer_restarted"] == 0 and f.drone.counters["keys_lost_refused:key_newer"] == 0


def test_the_start_notice_of_a_gs_that_paired_after_it_makes_no_later_owner_ask_for_its_key(tmp_path: Path) -> None:
    """A starts, then pairs (its own key, made after its start); B hears A's start notice while not the
    owner. When B owns the drone and A's link goes quiet out of range, B must not ask A for a key of a
    link the drone has held since after that start (A would hand one out once its link is LOST)."""
    f = _flight(tmp_path)
    t = WALL0 + f.now
    notice = keyslost.make_notice("A", t, t, f._signing["A"])
    assert f.run_until(lambda: f.drone.machine.owner == "A" and "B" in f.drone.links, 60.0)
    f.run_until(lambda: False, 2.0)
    f.gs["B"].core.on_keys_lost(notice, f.now, WALL0 + f.now)
    assert f.run_until(lambda: f.drone.machine.owner == "B", 600.0)
    f.run_until(lambda: False, 20.0)
    assert f.gs["A"].core.counters["linkkey_shared"] == 0 and f.gs["B"].core.counters["linkkey_peer_restarted"] == 0
