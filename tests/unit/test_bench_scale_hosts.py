"""``zdrone bench scale``'s drones hosts: how many, and their results merged as one."""

from __future__ import annotations

from zdrone.bench.scalehosts import drones_file, merge_drone_hosts


def _part(names: list[str], cpu_s: float, flight_s: float, worst_pass: float, released: str = "keys") -> dict:
    return {"results": {n: {"handovers": 4} for n in names}, "loops": 100, "timed_out": False, "flight_s": flight_s,
            "cpu_s": cpu_s, "memory_mb": {"rss": 50.0, "peak": 60.0}, "ground_s": 40.0, "released": released,
            "router_zid": {n: "z" for n in names}, "delivered": {n: {"A": 1} for n in names},
            "slow": {"worst_pass_s": worst_pass, "passes_over_0_5s": 1, "worst_step_s": worst_pass / 10,
                     "worst_step_node": names[0], "listen_worst_s": 0.01, "listen_total_s": 0.5}}


def test_one_host_writes_drones_json_and_several_one_file_each() -> None:
    assert drones_file(0, 1) == "drones.json" and drones_file(2, 3) == "drones-2.json"


def test_merged_results_hold_every_drone_the_worst_pass_and_the_summed_cpu() -> None:
    a, b = _part(["d1", "d3"], 50.0, 100.0, 0.4), _part(["d2"], 30.0, 60.0, 0.9, released="hold timeout")
    m = merge_drone_hosts([a, b])
    assert set(m["results"]) == {"d1", "d2", "d3"} and set(m["delivered"]) == {"d1", "d2", "d3"}
    assert m["cpu_percent"] == 100.0 and m["memory_mb"] == {"rss": 100.0, "peak": 120.0}  # 50 % + 50 %
    assert m["slow"]["worst_pass_s"] == 0.9 and m["slow"]["worst_step_node"] == "d2" and m["slow"]["hosts"] == 2
    assert m["released"] == "hold timeout"  # one host held to its limit: the whole fleet did
    assert merge_drone_hosts([a]) is a


def test_a_host_gives_way_to_the_routers_by_its_session_when_the_kernel_groups_sessions():
    import subprocess
    import sys
    from pathlib import Path

    from zdrone.bench.scale import give_way

    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"], start_new_session=True)
    try:
        assert give_way(child.pid, 0) == "no"
        how = give_way(child.pid, 7)
        if Path("/proc/self/autogroup").exists():
            assert how == "autogroup" and Path(f"/proc/{child.pid}/autogroup").read_text().split()[-1] == "7"
        else:
            assert how == "threads only"
    finally:
        child.kill()
        child.wait()


def test_a_drone_a_gs_frame_reached_is_handed_its_inputs_between_turns_and_nothing_else_is() -> None:
    """``wake_on_uplink``: the inbox's ``put`` (Zenoh's thread) still queues every sample, and a GS's
    frame (kind "up") also marks the drone woken; ``serve_woken`` hands each woken drone its inputs."""
    import collections
    from types import SimpleNamespace

    from zdrone.bench.scalehosts import serve_woken, wake_on_uplink

    queued: list[tuple[str, str, bytes]] = []
    taken: list[str] = []
    node = SimpleNamespace(name="d1", rt=SimpleNamespace(inbox=SimpleNamespace(put=lambda *item: queued.append(item))),
                           take_inputs=lambda: taken.append("d1"))
    woken: collections.deque = collections.deque()
    wake_on_uplink(node, woken)
    node.rt.inbox.put("revision", "A", b"stamp")  # not a GS's link frame: waits for the drone's turn
    assert queued == [("revision", "A", b"stamp")] and not woken
    node.rt.inbox.put("up", "A", b"frame")
    assert queued[-1] == ("up", "A", b"frame") and list(woken) == [node]
    serve_woken(woken)
    assert taken == ["d1"] and not woken


def test_a_gs_per_process_merges_into_one_result_each_gs_its_own_counts() -> None:
    from zdrone.bench.scalehosts import merge_station_hosts

    def gs_host(g: str, started: float) -> dict:
        return {"commands_sent": {g: {"d1": 3}}, "commands_sent_epochs": {g: {"d1": {"1": 3}}}, "router_zid": {g: "z"},
                "delivered": {g: {"d1": 9}}, "counters": {g: {"x": 1}}, "linked_all": {g: started + 2.0},
                "gc": {"n": 1}, "loops": {"p": 1}}

    a, b = gs_host("A", 10.0), gs_host("B", 20.0)
    m = merge_station_hosts([a, b])
    assert m["commands_sent"] == {"A": {"d1": 3}, "B": {"d1": 3}} and set(m["delivered"]) == {"A", "B"}
    assert m["linked_all"] == {"A": 12.0, "B": 22.0}
    assert m["gc"] == [{"n": 1}, {"n": 1}]
    assert merge_station_hosts([a]) is a


def test_bench_scale_refuses_restarting_the_gs_that_pairs_or_one_of_a_corridor() -> None:
    from zdrone.cli import main

    for argv in (["--restart-gs", "A", "--sites", "3"], ["--restart-gs", "D"], ["--restart-gs", "B", "--layout", "corridor"]):
        assert main(["bench", "scale", *argv]) == 2, argv
