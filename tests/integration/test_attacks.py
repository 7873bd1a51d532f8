"""The attack scenarios end to end (``zdrone demo --scenario …``): each attacker is its own process with
real router credentials (and, where the scenario says so, a real private key) from the run's fleet;
the flight must complete unaffected and the counters must show every attack seen and refused.

Each flight takes about 40 s of wall time at speed-up 4. Run one at a time on a small machine.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

from tests.integration.test_flight_e2e import _clean_shutdown, _exactly_one_authority, run_demo
from tests.procs import ZDRONE, once_per_run
from zdrone.core.pairing import PAIR_BURST, PAIR_RATE
from zdrone.net.eventlog import read_events
from zdrone.sil.launcher import ATTACK_SCENARIOS, SCENARIO_TABLE, TRIGGERS
from zdrone.sil.moments import GSS_STARTED
from zdrone.sil.rogue import MODES, dangerous_messages


def _unaffected(s: dict) -> None:
    """Both ordinary hand-overs to the real GSs, the authority link never LOST, no failsafe, the
    delivery at B, landing at home, nothing forwarded beyond what the authority sent."""
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    assert [(h["from"], h["to"], h["kind"]) for h in s["handovers"]] == [("A", "B", "handover"), ("B", "A", "handover")]
    assert s["failsafe"] is None and s["violations"] == []
    assert s["authority_link"]["worst_state"] != "lost"
    assert s["delivered_at_b"] and s["distance_from_home_m"] < 3.0
    c = s["commands"]
    assert c["lost"] == 0 and c["forwarded"] == {g: n for g, n in c["sent_as_authority"].items() if n}


def _attack(s: dict, mode: str) -> dict:
    return s["attacks"][mode]


def test_scenario_table_is_consistent_and_listed():
    """Every scenario is one row: known attacker modes, known moments, and listed in --help."""
    assert set(ATTACK_SCENARIOS) >= {"key-injection", "linkkey-knockout", "pair-replay", "pair-flood", "uplink-policy",
                                     "gateway-flood"}
    for spec in SCENARIO_TABLE:
        for r in spec.rogues:
            assert r.mode in MODES and r.launch in TRIGGERS and (r.go is None or r.go in TRIGGERS), (spec.name, r)
        assert spec.gcs_a == any(r.mode == "gateway-flood" for r in spec.rogues)
        for ops in (spec.operators, spec.consent_ops):  # operators start at a moment, or once every GS is up
            assert ops is None or ops in TRIGGERS or ops == GSS_STARTED, spec.name
    out = subprocess.run([ZDRONE, "demo", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and all(f"  {s.name} " in out.stdout for s in SCENARIO_TABLE)
    bad = subprocess.run([ZDRONE, "bench", "attack", "--scenarios", "nominal"], capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1


@pytest.mark.slow
def test_key_injection_forged_replies_are_refused_and_the_real_key_is_taken(tmp_path):
    s, out = run_demo(tmp_path, "key-injection")
    _unaffected(s)
    done = _attack(s, "key-injection")
    assert done["queries"] >= 1 and done["random"] >= 1 and done["noise_own_key"] >= 1
    a = s["gs_counters"]["A"]
    assert a.get("linkkey_reply:bad_mac", 0) >= 1  # neither forged reply carries A's and B's tag
    a_events = read_events(out / "A.jsonl")
    assert any(e["type"] == "linkkey_bad_reply" and e["reason"] == "bad_mac" for e in a_events)
    assert [e["gs"] for e in a_events if e["type"] == "linkkey_received"] == ["B"]  # the real B's key, once
    assert s["gs_counters"]["B"].get("linkkey_shared", 0) >= 1
    # the key A granted is the one the real B holds: B proved it to the drone, which handed over to B
    assert any(e["type"] == "link_confirmed" and e["how"].startswith("linkkey") for e in read_events(out / "B.jsonl"))
    _exactly_one_authority(out)
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_linkkey_knockout_queries_claiming_b_are_refused(tmp_path):
    s, out = run_demo(tmp_path, "linkkey-knockout")
    _unaffected(s)
    done = _attack(s, "linkkey-knockout")
    assert done["forged_m1"] > 0 and done["junk"] > 0
    assert done["replies"].get("ok", 0) == 0  # never a secret for the attacker
    a = s["gs_counters"]["A"]
    assert a.get("linkkey_refused:bad_mac", 0) > 0 and a.get("linkkey_refused:malformed", 0) > 0
    assert a.get("linkkey_refused:auth_failed", 0) == 0  # refused by the tag: no Diffie-Hellman spent
    assert a.get("linkkey_shared", 0) == 0
    # A's live link never changed key: no confirmation of anything but the pairing at the start
    assert [e["how"] for e in read_events(out / "A.jsonl") if e["type"] == "link_confirmed"] in ([], ["pair"])
    assert s["authority_link"]["worst_state"] == "ok" or s["authority_link"]["longest_silence_s"] < 2.0
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_replayed_pairing_message_is_answered_but_never_replaces_a_key(tmp_path):
    s, out = run_demo(tmp_path, "pair-replay")
    _unaffected(s)
    rogue = read_events(out / "rogue.jsonl")
    assert any(e["type"] == "captured" for e in rogue)
    done = _attack(s, "pair-replay")
    assert done["replayed"] >= 5
    counters = s["drone_counters"]
    # a message 1 seen before gets its first answer again: no new key
    seen = (counters.get("pair_repeated", 0) + counters.get("pair_answered", 0) + counters.get("pair_refused:stale", 0)
            + counters.get("pair_refused:linked", 0))  # refused with no handshake while the drone hears A
    assert seen >= 1 + done["replayed"] // 2
    # every handshake the drone made answered one of A's own message 1s (its first pairing, and the
    # re-pairing probes it sends after a second of silence, answered "I kept your key"): a replay draws no
    # new key, neither from the response cache nor once stale (older than 30 s by its tagged stamp)
    [a_stop] = [e for e in read_events(out / "A.jsonl") if e["type"] == "stop"]
    assert 1 <= counters.get("pair_answered", 0) <= a_stop["counters"]["pair_sent"]
    drone = read_events(out / "drone.jsonl")
    assert [e["gs"] for e in drone if e["type"] == "link_confirmed" and e["how"] == "pair"] == ["A"]  # the genuine one
    assert [e["gs"] for e in drone if e["type"] == "paired"] == ["A"]
    keys = s["keys"]["A"]
    assert keys["live"] and keys["candidates"] <= 1  # at most one unproven pairing key, never proven
    assert [e["owner"] for e in drone if e["type"] == "status" and e["owner"]][:1] == ["A"]
    _exactly_one_authority(out)
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_oversized_payloads_are_refused_by_length_and_cost_nothing(tmp_path):
    """Review F1: 4-8 MB payloads on up/B, pair/B and A's linkkey queryable froze the loops."""
    s, out = run_demo(tmp_path, "big-flood")
    _unaffected(s)
    done = _attack(s, "big-flood")
    assert done["big"] >= 30 and done["huge"] >= 3
    # the router's size limits drop them where they enter it: none reaches the drone
    assert s["drone_inbox_dropped"].get("up:oversize", 0) == 0
    assert s["drone_counters"].get("pair_refused:oversize", 0) == 0
    assert s["gs_counters"]["A"].get("linkkey_refused:oversize", 0) > 0
    assert s["authority_link"]["longest_silence_s"] <= 2.0
    assert [h["to"] for h in s["handovers"]] == ["B", "A"]  # both hand-overs, through the flood
    _clean_shutdown(s, out)


@pytest.fixture(scope="module")
def bench_attack_quick(tmp_path_factory) -> tuple[dict, Path]:
    """One ``zdrone bench attack --quick`` per test run (its pair-flood flight, then a failsafe trial
    under the flood): its JSON, and the folder of its pair-flood flight (the bench's runs go under TMPDIR)."""

    def bench(folder: Path) -> dict:
        out = subprocess.run([ZDRONE, "bench", "attack", "--quick", "--json"], capture_output=True, text=True,
                             timeout=240, env={**os.environ, "TMPDIR": str(folder)})
        [base] = folder.glob("zdrone-bench-attack-*")
        return {"rc": out.returncode, "stderr": out.stderr[-2000:], "bench": json.loads(out.stdout),
                "flight": str(base.resolve() / "pair-flood")}

    shared, _ = once_per_run(tmp_path_factory, "bench-attack-quick", bench)
    return shared, Path(shared["flight"])


@pytest.mark.slow
@pytest.mark.xdist_group("bench-attack-quick")
def test_pairing_flood_is_refused_before_crypto_and_telemetry_goes_on(bench_attack_quick):
    """Checked on the bench's pair-flood flight: the same ``zdrone demo --scenario pair-flood``
    (speed-up 4) as a flight of its own would be. Counts, not speed: however many queries a second
    the machine let the attacker send, every handshake beyond B's allowance is refused, by reason."""
    _, out = bench_attack_quick
    s = json.loads((out / "summary.json").read_text()) | {"_rc": 0}  # run in-process by the bench: no exit code
    _unaffected(s)
    done = _attack(s, "pair-flood")
    allowance = 1 + PAIR_BURST + PAIR_RATE * (int(done["seconds"]) + 1)  # A's first pairing + B's bucket
    assert done["sent"] > allowance, done  # a flood: more queries than the allowance answers
    counters = s["drone_counters"]
    # refused before any crypto: over B's allowance, or older than a message 1 of B's already answered
    assert counters.get("pair_refused:rate_limited", 0) + counters.get("pair_refused:stale", 0) > 0, counters
    assert counters.get("pair_answered", 0) <= allowance, counters  # handshakes: never beyond the allowance
    assert not [e for e in read_events(out / "drone.jsonl") if e["type"] == "link_confirmed" and e["gs"] == "B"
                and e["how"] == "pair"]
    assert s["authority_link"]["longest_silence_s"] <= 2.0  # never DEGRADED for more than a second
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_uplink_policy_keeps_dangerous_ids_from_the_vehicle(tmp_path):
    s, out = run_demo(tmp_path, "uplink-policy")
    _unaffected(s)
    sealed, unsealed = _attack(s, "uplink-sealed"), _attack(s, "uplink-unsealed")
    names = {n for n, _ in dangerous_messages(1)}
    assert set(sealed["sealed"]) == names and sealed["total"] > 0
    assert unsealed["unsealed"] > 0 and unsealed["random_key"] > 0
    # (a) B's key: its frames are authentic, the HA refuses every one of them
    ha = s["ha_drops"]
    assert ha.get("denied_by_policy", 0) > 0 and ha.get("not_authority", 0) > 0
    assert ha["denied_by_policy"] + ha["not_authority"] <= sealed["total"]  # the rest: sent after it left B's coverage
    drone = read_events(out / "drone.jsonl")
    second_handover = [e["t"] for e in drone if e["type"] == "handover_complete"][1]
    proven = [e for e in drone if e["type"] == "link_confirmed" and e["gs"] == "B" and e["how"] == "pair"]
    assert len(proven) == 1 and proven[0]["t"] > second_handover  # the attacker's key, after both hand-overs
    # (b) no key: dropped by the security module before the HA
    d = s["security_drops"]
    assert d.get("auth_failed", 0) > 0 and d.get("unknown_epoch", 0) + d.get("malformed", 0) > 0
    # the vehicle got none of it: nothing forwarded beyond the authorities' own commands (checked in
    # _unaffected), and the simulator saw no frame it does not use (it logs each one it ignores)
    # (signing_refused: at most a SETUP_SIGNING of the drone's own sent again on a machine too loaded to
    # read the autopilot's first signed frame within a second; no attacker frame reaches the vehicle
    # but through the drone, which forwards none of them)
    assert {k: v for k, v in s["vehicle"]["counters"].items() if k != "signing_refused"} == {}
    assert s["vehicle"]["ignored"] == []
    assert [e["owner"] for e in drone if e["type"] == "stop"] == ["A"]
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_gateway_flood_is_counted_and_the_station_keeps_flying(tmp_path):
    s, out = run_demo(tmp_path, "gateway-flood")
    _unaffected(s)
    done = _attack(s, "gateway-flood")
    assert done["source_ports"] >= 300 and done["heartbeat"] > 0 and done["garbage"] > 0
    gw = s["gateway_A"]
    assert gw.get("app_table_full", 0) > 0 and "from_log" not in gw
    assert s["exit_codes"]["gsA"] == 0
    _clean_shutdown(s, out)


@pytest.mark.slow
@pytest.mark.xdist_group("bench-attack-quick")
def test_bench_attack_quick(bench_attack_quick):
    shared, _ = bench_attack_quick
    assert shared["rc"] == 0, shared["stderr"] + json.dumps(shared["bench"])[-2000:]
    r = shared["bench"]
    [row] = r["scenarios"]
    assert row["scenario"] == "pair-flood" and row["ok"] and row["flight_completed"]
    assert (row["refusals"].get("drone pair_refused:rate_limited", 0)
            + row["refusals"].get("drone pair_refused:stale", 0)) > 0  # how many: the attacker's pace on this machine
    f = r["failsafe_under_pairing_flood"]
    # the failsafe under the flood, after the threshold (how soon, and the CPU per query: the bench's figures)
    assert f["missing"] == 0 and all(v >= 0 for v in f["detect_to_command_ms"]["values"])
    assert f["trials"][0]["queries_handled"] > 0 and f["cpu_us_per_query"]["values"][0] > 0


@pytest.mark.slow
def test_rogue_without_a_fleet_certificate_gets_nothing_through(tmp_path):
    """Mutual TLS (``--tls``), A's stolen router password: no client certificate, a certificate for
    A from another CA, and X's real certificate, each from the attacker's own process and Zenoh
    configuration. The first two are refused at connect; X's certificate as A speaks on no key."""
    s, out = run_demo(tmp_path, "rogue-no-cert")
    _unaffected(s)
    done = _attack(s, "no-cert")
    assert done["no_certificate"] == "refused" and done["other_ca"] == "refused"
    if done["x_certificate"] == "connected":  # the router's ACL wants CN *and* user A: nothing gets through
        assert done["sent"] > 0 and done["pair_answered"] == 0 and done["captured"] == 0
    assert s["security_drops"] == {}  # not one of its frames reached the drone to be dropped there
    _clean_shutdown(s, out)
