"""Issue 18, item 5: the insider's attacks end to end (``zdrone demo --scenario …``). The attacker is an
authorized ground station gone bad: B's own static key, router password and certificate, in a
process of its own (and, where the attack needs them, the other nodes' router passwords). Each
flight takes about 40 s of wall time at speed-up 4.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.integration.test_attacks import _unaffected
from tests.integration.test_flight_e2e import _clean_shutdown, run_demo, shared_demo
from zdrone.core.geometry import GeoPoint, distance_m
from zdrone.core.reference import COVERAGE_RADIUS_M, GS_B
from zdrone.core.records import GsLinkConfirmed, only
from zdrone.net.eventlog import read_events, read_records
from zdrone.sil.launcher import escrow_left_standing

@pytest.fixture(scope="module")
def heir_flight(tmp_path_factory):
    """One insider-heir flight for both of its checks (in the air; on the ground after the failsafe)."""
    return shared_demo(tmp_path_factory, "insider-heir")


def _moves_to_b(out: Path, airborne: bool) -> list[dict]:
    """Authority moves to B (in the air, or on the ground), each with its distance from B's centre."""
    moves = [e for e in read_events(out / "drone.jsonl") if e["type"] in ("authority", "handover_complete")
             and e["to"] == "B" and (e["position"] is None or e["position"][2] > 1.0) == airborne]
    return [e | {"from_b_m": round(distance_m(GS_B, GeoPoint(*e["position"][:2])))} for e in moves if e["position"]]


@pytest.mark.slow
def test_insider_heir_outside_its_coverage_never_gets_authority_in_the_air(heir_flight):
    """Two sites over mutual TLS: B's frames reach the drone through A's site over the backhaul, so
    radio range does not stop it. B pairs about once a second from take-off on; A hangs right after
    take-off, with the vehicle hundreds of metres outside B's coverage: the failsafe, never B."""
    s, out = heir_flight
    assert s["_rc"] in (0, 1) and not s["timed_out"], s["why_not_ok"]
    done = s["attacks"]["insider-heir"]
    assert done["pairings"] >= 2 and done["heartbeats"] > 0 and done["commands"] > 0
    fs = s["failsafe"]
    assert fs is not None and fs["reason"] == "authority link to A lost" and fs["detect_to_command_ms"] >= 0
    assert distance_m(GS_B, GeoPoint(*fs["position"][:2])) > COVERAGE_RADIUS_M + 50.0  # well outside B's coverage
    assert _moves_to_b(out, airborne=True) == []
    assert not [w for w in s["why_not_ok"] if "in the air" in w or "neither" in w]
    _clean_shutdown(s, out, nodes=("drone",), stopped=("gsA",))


@pytest.mark.slow
def test_insider_heir_outside_its_coverage_never_gets_authority_on_the_ground(heir_flight):
    """The same flight, watched 3 s on after the failsafe landed the vehicle: B, still pairing from
    outside its coverage, must not take the landed vehicle (nor arm it)."""
    s, out = heir_flight
    assert _moves_to_b(out, airborne=False) == []
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    assert not any(k.startswith("arm:accepted") for k in s["attacks"]["insider-heir"]["command_acks"])


@pytest.fixture(scope="module")
def escrow_flight(tmp_path_factory):
    """One key-escrow flight for both of its checks (while A's link is alive; the whole flight)."""
    return shared_demo(tmp_path_factory, "key-escrow")


def _escrowed(out: Path) -> list[dict]:
    """A's live key replaced by a secret A handed out over the backhaul."""
    return [e for e in read_events(out / "A.jsonl") if e["type"] == "link_confirmed" and e["how"].startswith("linkkey")]


@pytest.mark.slow
def test_key_escrow_a_gs_with_a_live_link_hands_out_no_key(escrow_flight):
    """B asks A for keys of link (drone, A) from take-off on: while A's own link is alive (A holding
    authority, up to the hand-over to B) A answers none (``linkkey_refused:live_link``), so there is
    nothing to inject under and A's live key stays."""
    s, out = escrow_flight
    assert not s["timed_out"], s["why_not_ok"]
    done = s["attacks"]["key-escrow"]
    assert done["queries"] >= 3
    a = read_events(out / "A.jsonl")
    refused = [e for e in a if e["type"] == "linkkey_refused" and e["reason"] == "live_link" and e["asker"] == "B"]
    assert refused and s["gs_counters"]["A"]["linkkey_refused:live_link"] >= 3
    released = next(e["t"] for e in a if e["type"] == "handover_release")  # A hands over to B in the overlap
    assert [e for e in a if e["type"] == "linkkey_shared" and e["t"] < released] == []
    assert [e for e in _escrowed(out) if e["t"] < released] == []
    assert s["handovers"][:1] and (s["handovers"][0]["from"], s["handovers"][0]["to"], s["handovers"][0]["kind"]) \
        == ("A", "B", "handover")
    _clean_shutdown(s, out, nodes=("drone",))


@pytest.mark.slow
def test_key_escrow_secret_never_replaces_the_answering_gs_live_link(escrow_flight):
    """The whole flight: whatever A hands out, its live key is never replaced for good, and the flight
    is unaffected (both hand-overs, no failsafe, landing at home)."""
    s, out = escrow_flight
    # while the drone is away A's link is LOST and a forged frame under an escrowed secret may replace A's
    # key, but never for good: the drone's first frame under A's own key takes it back (``revert``)
    confirmed = only(read_records(out / "A.jsonl").records, GsLinkConfirmed)
    assert escrow_left_standing(confirmed) == []
    if _escrowed(out):
        assert any(e.how == "revert" for e in confirmed)
    _unaffected(s)
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_stale_pairing_messages_replayed_after_a_restart_spend_no_tokens(tmp_path):
    """A's pairing message 1s (recorded earlier, and captured all flight long, A's tries while the
    companion is down included) replayed as A around a companion restart: none spends A's pairing
    allowance; A re-pairs within the loss threshold."""
    s, out = run_demo(tmp_path, "stale-pairing")
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    assert [(h["from"], h["to"], h["kind"]) for h in s["handovers"]] == [("A", "B", "handover"), ("B", "A", "handover")]
    assert s["failsafe"] is None and s["violations"] == [] and s["delivered_at_b"] and s["distance_from_home_m"] < 3.0
    # only those A sent (5/s) from the companion's kill until A re-paired with it: however long this machine
    # took to start it again
    [killed] = [f for f in s["faults"] if f["target"] == "drone"]
    [restarted] = [e for e in read_events(out / "drone.jsonl") if e["type"] == "restarted"]
    assert s["repair_after_restart_s"] is not None  # A re-paired, within the loss threshold (no failsafe, above)
    assert s["commands"]["lost"] <= 5.0 * (restarted["t"] - killed["t"] + s["repair_after_restart_s"] + 1.0)
    done = s["attacks"]["stale-pairing"]
    assert done["held"] >= 3 and done["replayed"] >= done["held"]
    assert s["drone_counters"].get("pair_refused:rate_limited", 0) == 0
    drone = read_events(out / "drone.jsonl")
    assert [(e["owner"], e["epoch"]) for e in drone if e["type"] == "restarted"] == [("A", 1)]
    _clean_shutdown(s, out, stopped=("drone",))
