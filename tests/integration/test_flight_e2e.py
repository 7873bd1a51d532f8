"""The reference flight and its attack / fault scenarios, end to end: a real Zenoh router, the
simulator, the drone node and the ground stations as separate processes (``zdrone demo``)."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

from tests.procs import ZDRONE, once_per_run
from zdrone.core.fleet import parse_fleet
from zdrone.core.geometry import GeoPoint
from zdrone.net.eventlog import read_events
from zdrone.sil.netns import netns_refusal

SPEEDUP = "4"


def run_demo(tmp_path: Path, scenario: str, report: bool = False, autopilot: str = "px4",
             extra: tuple[str, ...] = ()) -> tuple[dict, Path]:
    out = tmp_path / f"{scenario}-{autopilot}"
    proc = subprocess.run([ZDRONE, "demo", "--scenario", scenario, "--speedup", SPEEDUP, "--out", str(out), "--no-live",
                           "--autopilot", autopilot, *extra] + ([] if report else ["--no-report"]),
                          capture_output=True, text=True, timeout=240)
    assert "Traceback" not in proc.stderr, proc.stderr
    assert (out / "summary.json").exists(), (f"no summary (exit {proc.returncode}): {proc.stderr[-2000:]}\n"
                                             f"{proc.stdout[-1500:]}")
    summary = json.loads((out / "summary.json").read_text())
    summary |= {"_rc": proc.returncode, "_stdout": proc.stdout[-2000:], "_stderr": proc.stderr[-2000:]}
    if not summary["ok"]:
        for log in sorted(out.glob("*.log")):  # show what each process said, to diagnose
            print(f"== {log.name}\n{log.read_text()[-1500:]}")
    return summary, out


def shared_demo(tmp_path_factory, scenario: str, **kw) -> tuple[dict, Path]:
    """``run_demo`` once per test run for all the tests that check one flight (a module fixture's
    body), even when they land in different xdist workers (``once_per_run``)."""

    def fly(folder: Path) -> dict:
        s, out = run_demo(folder, scenario, **kw)
        return {"summary": s, "out": str(out)}

    shared, _ = once_per_run(tmp_path_factory, f"demo-{scenario}-{kw.get('autopilot', 'px4')}", fly)
    return shared["summary"], Path(shared["out"])


def _no_orphans(out: Path) -> None:
    mine = []
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            try:
                if os.readlink(f"/proc/{pid}/cwd") == str(out):
                    mine.append(pid)
            except OSError:
                pass
    assert mine == [], f"processes left running in {out}: {mine}"


def _clean_shutdown(summary: dict, out: Path, nodes=("drone", "A", "B"), stopped: tuple[str, ...] = ()) -> None:
    """Every process the scenario did not stop or kill on purpose exited 0 on SIGTERM, having closed
    its session, and none is left."""
    for name, code in summary["exit_codes"].items():
        if name not in stopped:
            assert code == 0, (name, code, summary["notes"])
    for node in nodes:
        evs = read_events(out / f"{node}.jsonl")
        assert evs[-1]["type"] == "closed", f"{node} did not close its session"
    _no_orphans(out)


def _inside(fleet, gs: str, pos) -> bool:
    return fleet.nodes[gs].coverage.circle().contains(GeoPoint(pos[0], pos[1]))


def _exactly_one_authority(out: Path) -> None:
    status = [e for e in read_events(out / "drone.jsonl") if e["type"] in ("status", "stop")]
    owned = [e for e in status if e["owner"]]
    first = status.index(owned[0])
    assert all(e["owner"] in ("A", "B") for e in status[first:]), "an instant without an authority"
    epochs = [e["epoch"] for e in status[first:]]
    assert epochs == sorted(epochs)


@pytest.mark.slow
def test_nominal_reference_flight(tmp_path):
    s, out = run_demo(tmp_path, "nominal", report=True, extra=("--ready-after", "10"))  # PX4's real start-up
    assert s["_rc"] == 0 and s["ok"], s
    fleet = parse_fleet((out / "fleet" / "fleet.json5").read_text())
    assert [(h["from"], h["to"], h["epoch"]) for h in s["handovers"]] == [("A", "B", 2), ("B", "A", 3)]
    for h in s["handovers"]:  # both hand-overs inside the overlap of the two coverages
        assert _inside(fleet, "A", h["position"]) and _inside(fleet, "B", h["position"]), h
    assert s["authority_gap_ms"] == 0.0
    _exactly_one_authority(out)
    c = s["commands"]
    assert c["lost"] == 0 and c["refused_not_authority"] == 0
    assert c["sent_as_authority"]["A"] > 0 and c["sent_as_authority"]["B"] > 0  # both commanded in their turn
    assert c["forwarded"] == {g: n for g, n in c["sent_as_authority"].items() if n}  # none lost, none doubled
    assert s["distance_from_home_m"] < 3.0
    drone = read_events(out / "drone.jsonl")
    # B held authority at the delivery and saw the mission go past its gripper item on the ground there
    # (issue 22: from MAVLink both autopilots send; PX4 says nothing of its gripper)
    b_events = read_events(out / "B.jsonl")
    assert s["delivered_at_b"] and any(e["type"] == "mission_progress" for e in b_events)
    assert not any(e["type"] == "vehicle_text" and "payload" in e["text"].lower() for e in b_events)
    a_events = read_events(out / "A.jsonl")
    assert [e["type"] for e in a_events if e["type"] in ("mission_started", "takeoff_confirmed")] == \
        ["mission_started", "takeoff_confirmed"]  # flying only once it left the ground
    delivery = fleet.nodes["B"].coverage
    near_delivery = [e for e in drone if e["type"] == "status" and e["position"]
                     and abs(e["position"][1] - delivery.lon) < 3e-5 and e["position"][2] < 0.5]
    assert near_delivery, "the vehicle never landed at the delivery point"
    assert s["security_drops"] == {} and s["violations"] == []
    _clean_shutdown(s, out)
    page = (out / "report.html").read_text()  # written at the end of the demo
    assert page.count("data:image/png;base64,") == 3 and "A→B" in page and (out / "track.png").stat().st_size > 10_000


@pytest.mark.slow
def test_rogue_without_keys_is_refused_by_the_security_module(tmp_path):
    s, out = run_demo(tmp_path, "rogue-no-key")
    assert s["_rc"] == 0 and s["ok"], s
    d = s["security_drops"]
    assert d.get("unknown_epoch", 0) > 0  # unsealed MAVLink commands
    assert d.get("auth_failed", 0) > 0  # envelopes sealed with a made-up key
    assert d.get("replay", 0) > 0  # captured sealed frames replayed from a third process
    assert s["pairing"].get("pair_refused:bad_mac", 0) >= 1  # Noise KK with the wrong static key: fails the tag
    rogue = read_events(out / "rogue.jsonl")
    assert any(e["type"] == "router_refused" for e in rogue)  # wrong router password
    done = next(e for e in rogue if e["type"] == "attack_done")
    assert done["plain"] > 0 and done["forged"] > 0 and done["replayed"] > 0
    # no effect on the vehicle: it flew the whole mission and landed at home
    assert [(h["from"], h["to"]) for h in s["handovers"]] == [("A", "B"), ("B", "A")]
    assert s["distance_from_home_m"] < 3.0 and s["commands"]["lost"] == 0
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_unauthorized_gs_is_refused_by_the_acl_and_never_linked(tmp_path):
    """GS X (in the fleet, its own keys and router account, not authorized for d1): the router's ACL
    lets it neither pair with d1 nor ask for d1's keys (the drone's own guard, tested in the unit
    tests, is the wall behind it); it never gets a link, let alone authority."""
    s, out = run_demo(tmp_path, "rogue-unauthorized")
    assert s["_rc"] == 0 and s["ok"], s
    x = read_events(out / "X.jsonl")
    assert x and not any(e["type"] in ("paired", "link_confirmed") for e in x)
    drone = read_events(out / "drone.jsonl")
    assert not any(e["type"] in ("paired", "link_confirmed", "pair_answered") and e.get("gs") == "X" for e in drone)
    assert all(owner in ("A", "B") for owner in [e.get("to") for e in drone if e["type"] in ("authority", "handover_complete")])
    rogue = [e for e in read_events(out / "rogue.jsonl") if e["type"] == "unauthorized_attempt"]
    assert rogue and all(e["linkkey_replies"] == 0 and e["pair_answered"] == 0 for e in rogue)
    assert all(h["to"] in ("A", "B") for h in s["handovers"]) and len(s["handovers"]) == 2
    assert s["distance_from_home_m"] < 3.0
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_link_loss_lands_the_drone(tmp_path):
    s, out = run_demo(tmp_path, "link-loss")
    assert s["_rc"] == 0 and s["ok"], s
    fs = s["failsafe"]
    assert fs["action"] == "LAND" and fs["reason"] == "authority link to A lost"
    assert fs["detect_to_command_ms"] >= 0  # after the threshold, never before (how soon: zdrone bench handover)
    assert s["handovers"] == []
    assert s["distance_from_home_m"] > 20.0  # landed where it was, not at home
    final = [e for e in read_events(out / "drone.jsonl") if e["type"] == "stop"][0]
    assert final["state"] == "failsafe" and not final["armed"] and final["landed_state"] == 1
    _clean_shutdown(s, out, nodes=("drone", "B"), stopped=("gsA",))


@pytest.mark.slow
def test_failsafe_is_recovered_only_by_an_explicit_request(tmp_path):
    """Issue 11: A (silent, the drone in its failsafe) wakes; its operator's request takes control back."""
    s, out = run_demo(tmp_path, "failsafe-recover")
    assert s["_rc"] == 0 and s["ok"], s
    assert s["failsafe"]["action"] == "LAND"
    assert [(r["from"], r["to"], r["epoch"]) for r in s["regained"]] == [("A", "A", 2)]
    drone = read_events(out / "drone.jsonl")
    fs_t = next(e["t"] for e in drone if e["type"] == "failsafe")
    # failsafe, then linked again in epoch 2 (the status events, twice a second, may miss the failsafe itself)
    assert any(e["type"] == "status" and e["t"] > fs_t and e["state"] == "linked" and e["epoch"] == 2 for e in drone)
    assert any(e["type"] == "control_requested" for e in read_events(out / "A.jsonl"))
    final = [e for e in drone if e["type"] == "stop"][0]
    assert final["owner"] == "A" and final["epoch"] == 2 and not final["armed"] and final["landed_state"] == 1
    assert s["distance_from_home_m"] > 20.0  # it went on landing where it was
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_a_router_restart_shorter_than_the_loss_threshold_costs_nothing(tmp_path):
    """Issue 11: every node reconnects by itself (Zenoh client retry 100-400 ms); no failsafe, no re-pairing."""
    s, out = run_demo(tmp_path, "router-restart")
    assert s["_rc"] == 0 and s["ok"], s
    assert "router restarted after 0.8 s down" in s["notes"]
    assert s["failsafe"] is None and [(h["from"], h["to"]) for h in s["handovers"]] == [("A", "B"), ("B", "A")]
    assert s["authority_link"]["worst_state"] != "lost"  # the link never reached the loss threshold
    drone = read_events(out / "drone.jsonl")
    assert [e["gs"] for e in drone if e["type"] == "paired"] == ["A"]
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_a_hung_authority_loses_authority_and_learns_it_on_waking(tmp_path):
    """Issue 11: SIGSTOP of the authority in the overlap for 5 s: emergency hand-over to the proven B."""
    s, out = run_demo(tmp_path, "gs-hang")
    assert s["_rc"] == 0 and s["ok"], s
    assert [(h["from"], h["to"], h["kind"]) for h in s["handovers"]] == [("A", "B", "emergency"), ("B", "A", "handover")]
    a = read_events(out / "A.jsonl")
    woke = [e for e in a if e["type"] == "authority_status" and e["owner"] == "B"]
    assert woke and woke[0]["epoch"] == 2
    assert s["ha_drops"].get("not_authority", 0) == 0  # it never even tried to command in B's epoch
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_twenty_percent_radio_loss_is_no_reason_for_a_failsafe(tmp_path):
    """Issue 11: 20 % loss, 50 +- 20 ms delay on every radio link: no false failsafe, both hand-overs."""
    s, out = run_demo(tmp_path, "lossy-radio")
    assert s["_rc"] == 0 and s["ok"], s
    assert s["failsafe"] is None and s["authority_link"]["worst_state"] != "lost"
    lost = s["radio_lost"]
    assert lost.get("up:A:loss", 0) > 10 and lost.get("down:A:loss", 0) > 100  # the radio really lost frames
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_a_companion_restart_in_flight_comes_back_with_its_authority(tmp_path):
    """Issue 11: kill -9 of the drone node in flight; it restores LINKED(A, 1) from disk, A re-pairs with
    fresh keys before the loss threshold, shares B's key again; the flight goes on."""
    s, out = run_demo(tmp_path, "companion-restart")
    assert s["_rc"] == 0 and s["ok"], s
    drone = read_events(out / "drone.jsonl")
    assert [(e["owner"], e["epoch"]) for e in drone if e["type"] == "restarted"] == [("A", 1)]
    restart = next(e["t"] for e in drone if e["type"] == "restarted")
    repaired = next(e["t"] for e in drone if e["type"] == "paired" and e["t"] > restart)
    assert repaired - restart < 3.0  # within the loss threshold: no failsafe
    assert s["failsafe"] is None and [(h["from"], h["to"]) for h in s["handovers"]] == [("A", "B"), ("B", "A")]
    assert s["commands"]["lost"] <= 10  # only those sent while the node was down
    _clean_shutdown(s, out, stopped=("drone",))


@pytest.mark.slow
def test_gs_crash_during_handover_keeps_authority_with_a(tmp_path):
    s, out = run_demo(tmp_path, "gs-crash")
    assert s["_rc"] == 0 and s["ok"], s
    assert all(h["to"] != "B" or h["kind"] == "emergency" for h in s["handovers"])
    drone = read_events(out / "drone.jsonl")
    assert any(e["type"] in ("handover_timeout", "handover_aborted") for e in drone)
    assert [e for e in drone if e["type"] == "stop"][0]["owner"] == "A"
    assert any(e["type"] == "handover_failed" for e in read_events(out / "A.jsonl"))
    assert s["distance_from_home_m"] < 3.0  # A brought it home
    _clean_shutdown(s, out, nodes=("drone", "A"), stopped=("gsB",))


@pytest.mark.slow
def test_the_reference_flight_on_the_ardupilot_personality(tmp_path):
    """Issue 10: ArduPilot keeps item 0 as home, streams nothing until asked, disarms after a landing
    unless MIS_OPTIONS says to go on; the GS and the vehicle link adapt, and the outcome is the PX4 one.
    ArduCopter's real start-up here (fix at 10 s, its EKF using GPS at 40 s, simulated). Its faults,
    link loss and the heir's crash, are flown in memory on this personality: tests/unit/test_core_flight.py."""
    s, out = run_demo(tmp_path, "nominal", autopilot="ardupilot", extra=("--ready-after", "40"))
    assert s["_rc"] == 0 and s["ok"], s
    a = read_events(out / "A.jsonl")
    assert [e["autopilot"] for e in a if e["type"] == "autopilot"] == ["ardupilot"]
    uploads = [e for e in a if e["type"] == "mission_upload"]
    assert uploads and uploads[0]["items"] == 9  # home placeholder + the plan with both take-offs
    assert any(e["type"] == "vehicle_param" and e["name"] == "MIS_OPTIONS" for e in a)
    assert any(e["type"] == "takeoff_confirmed" for e in a)
    assert [(h["from"], h["to"]) for h in s["handovers"]] == [("A", "B"), ("B", "A")]
    assert s["delivered_at_b"] and s["distance_from_home_m"] < 5.0
    assert any(e["type"] == "vehicle_text" and e["text"] == "Gripper Released" for e in read_events(out / "B.jsonl"))
    # issue 22: no position before the fix (never 0, 0); issue 18: the first pairing gives authority, so
    # it waits for the vehicle's own position inside A's coverage (A is told why and tries again); the
    # GS said what it waited for after that, if anything, and ended ready
    waits = [e["waiting"] for e in a if e["type"] == "vehicle_waiting"]
    assert any("position is unknown" in e["reason"] for e in a if e["type"] == "pair_refused"), \
        [e for e in a if e["type"] == "pair_refused"]
    assert not waits or waits[-1] is None, waits
    status = [e for e in read_events(out / "drone.jsonl") if e["type"] == "status"]
    unknown = [e for e in status if e["vehicle_streams"].get("position", {}).get("known") is False]
    assert unknown and all(e["position"] is None for e in unknown)
    assert all(e["position"] is None or abs(e["position"][0]) > 1 for e in status)
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_the_reference_flight_across_two_sites_with_the_backhaul_cut_after_key_sharing(tmp_path):
    """Issue 13: a router per site, meshed over mutual TLS; GS A at site 1, B at site 2; the drone has
    a session through each site's radio link, which the testbed brings up and down from the
    vehicle's true position: coverage is which links exist, no frame filter. The backhaul between
    the sites is cut after take-off (after key sharing): both hand-overs still complete, gap 0,
    nothing lost, because each site hears the drone through its own radio.

    As root, each site and the drone run in their own network namespace and the links are veth pairs
    (a radio out of range is a link without carrier: only the Zenoh lease notices); otherwise the
    same topology runs on loopback, the links being relays that close the drone's connections."""
    netns = netns_refusal() is None
    s, out = run_demo(tmp_path, "backhaul-cut-late", extra=("--netns",) if netns else ())
    assert s["_rc"] == 0 and s["ok"], s
    assert [(h["from"], h["to"], h["kind"]) for h in s["handovers"]] == [("A", "B", "handover"), ("B", "A", "handover")]
    assert s["authority_gap_ms"] == 0 and s["commands"]["lost"] == 0 and s["failsafe"] is None
    assert s["exit_codes"].get("router2") == 0  # two routers ran
    radio = s["radio_links"]
    changes = [(c["site"] or c["link"], c["up"]) for c in radio["changes"]]
    # in range of site 1 at home; the backhaul cut; site 2 comes into range, site 1 goes out of range, and back
    assert changes == [("site-1", True), ("backhaul-site-1-site-2", False), ("site-2", True), ("site-1", False),
                       ("site-1", True), ("site-2", False)], changes
    assert s["out_of_coverage"] == {}  # nothing was filtered by a gate
    # each site lost while the other path was connected already: the C2 link went on without a break
    assert [(x["site"], x["other_paths_connected"]) for x in radio["site_losses"]] == [("site-1", ["site-2"]),
                                                                                       ("site-2", ["site-1"])]
    # each loss noticed (a closed connection at once, a silent one by the 1 s lease), inside the 3 s threshold:
    # the link was never LOST (how soon: the summary's noticed_ms, a figure of this machine)
    assert all(x["noticed_ms"] is not None for x in radio["site_losses"]) and s["authority_link"]["worst_state"] != "lost"
    assert s["security_drops"] == {}
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_a_backhaul_cut_before_key_sharing_refuses_the_hand_over_cleanly(tmp_path):
    """A cannot share B's key over the cut backhaul: no hand-over, A keeps authority and brings the
    drone home; no failsafe; B never holds a link key of the drone."""
    s, out = run_demo(tmp_path, "backhaul-cut")
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    assert s["handovers"] == [] and s["final_owner"] == "A" and s["failsafe"] is None
    assert s["commands"]["lost"] == 0
    a_events = read_events(out / "A.jsonl")
    assert any(e["type"] == "handover_failed" for e in a_events)
    assert not any(e["type"] == "linkkey_shared" for e in read_events(out / "B.jsonl"))
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_the_authoritys_site_router_dying_out_of_the_overlap_is_a_failsafe_on_time(tmp_path):
    s, out = run_demo(tmp_path, "site-router-down-alone")
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    assert s["handovers"] == [] and s["failsafe"]["action"] == "LAND"
    assert s["failsafe"]["detect_to_command_ms"] >= 0  # after the threshold, never before
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_the_other_site_carries_the_link_when_the_authoritys_site_router_dies(tmp_path):
    s, out = run_demo(tmp_path, "site-router-down")
    assert s["_rc"] == 0 and s["ok"], s
    kinds = [(h["from"], h["to"], h["kind"]) for h in s["handovers"]]
    assert kinds == [("A", "B", "emergency"), ("B", "A", "handover")] and s["failsafe"] is None
    _clean_shutdown(s, out)


@pytest.fixture(scope="module")
def lease_flight(tmp_path_factory):
    """One ``lease-stamper`` flight for the lease's two checks: ``revoked-alone`` (the split, B revoked
    on A's side only) with GS X, authorized for no drone, stamping for the drone on its side of the
    split. X's stamps can only keep B's lease alive, never end it sooner, so the flight checks what
    ``revoked-alone`` checks (its verdict is part of this one's) at no further flight in the suite;
    ``zdrone demo --scenario revoked-alone`` flies it without X."""
    return shared_demo(tmp_path_factory, "lease-stamper")


def _lease_lapse(s: dict, out: Path) -> tuple[dict, dict]:
    """(the backhaul cut, the drone's single lease lapse) of a flight."""
    drone = read_events(out / "drone.jsonl")
    lapse = [e for e in drone if e["type"] == "drop" and e.get("reason") == "lease_lapsed"]
    assert len(lapse) == 1 and lapse[0]["gs"] == "B", lapse
    return next(f for f in s["faults"] if f["target"] == "backhaul"), lapse[0]


@pytest.mark.slow
def test_a_revoked_owner_alone_with_the_drone_loses_it_when_its_lease_lapses(lease_flight):
    """``revoked-alone`` (checked on ``lease_flight``, which adds X's stamps to it): the network splits at
    the delivery point (backhaul cut, site 1's radio gone), B is revoked on A's side only. The revision
    never reaches the drone and B's own stamps renew nothing: the lease lapses within the lease of the
    split, and the failsafe follows (no heir covers the drone); no command of B forwarded after it."""
    from zdrone.sil.scenarios import REVOKED_ALONE_LEASE_S

    s, out = lease_flight
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    cut, lapse = _lease_lapse(s, out)
    assert 0 < lapse["t"] - cut["t"] <= REVOKED_ALONE_LEASE_S + 6.0
    assert s["drone_counters"].get("stamp_refused:owner", 0) >= 1  # B's own stamps heard, renewing nothing
    assert not any(e["type"] == "revision_applied" for e in read_events(out / "drone.jsonl"))
    assert s["failsafe"] is not None and s["failsafe"]["reason"].startswith("authority of B lost: lease lapsed")
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_stamps_of_a_gs_not_authorized_for_the_drone_do_not_keep_a_revoked_owners_lease(lease_flight):
    """``lease-stamper``: X (in the fleet, its own signing key, password and certificate, authorized for
    no drone) puts a genuine stamp naming the revision in force and the drone every 2 s from the cut
    on, at the router the drone still reaches. The drone refuses every one it hears as unauthorized and
    B's lease lapses as in ``revoked-alone`` (before the fix X kept it: B held the drone 45.7 s at a
    15 s lease)."""
    from zdrone.fleet.revisions import STAMP_PERIOD_S
    from zdrone.sil.scenarios import REVOKED_ALONE_LEASE_S

    s, out = lease_flight
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    cut, lapse = _lease_lapse(s, out)
    stamps = [e for e in read_events(out / "rogue.jsonl") if e["type"] == "stamp_put"]
    during = [e for e in stamps if cut["t"] <= e["t"] <= lapse["t"]]
    assert len(during) >= 3 and all(e["gs"] == "X" and e["drones"] == ["d1"] for e in stamps), stamps
    assert s["attacks"]["lease-stamper"]["stamps"] == len(stamps) and s["attacks"]["lease-stamper"]["failed"] == 0
    assert lapse["t"] - cut["t"] <= REVOKED_ALONE_LEASE_S + STAMP_PERIOD_S + 1.0  # as if X had said nothing
    refused = s["drone_counters"].get("stamp_refused:unauthorized", 0)
    assert len(during) <= refused <= len(stamps), (refused, len(during), len(stamps))  # each one heard, refused
    status = [e for e in read_events(out / "drone.jsonl") if e["type"] == "status" and e["t"] <= lapse["t"]]
    assert status[-1]["counters"].get("stamp_refused:unauthorized", 0) >= len(during) - 1  # while the lease ran
    _clean_shutdown(s, out, nodes=("drone", "A", "B", "rogue"))
