"""``zdrone bench overhead``'s pure parts: arguments, the per-class figures and ratios, the latency
matching and the table (no figure of a run is asserted here)."""

from __future__ import annotations

import pytest

from zdrone.bench import latency as lat
from zdrone.bench import overhead as ov
from zdrone.bench.bare import msgid_of, nearest_covering
from zdrone.core.geometry import Circle, GeoPoint, offset
from zdrone.core.reference import HOME


def test_drone_counts_default_by_quick_and_are_checked() -> None:
    assert ov.parse_drones(None, quick=False) == [100, 300] and ov.parse_drones("", quick=True) == [ov.QUICK_K]
    assert ov.parse_drones("25,50", quick=True) == [25, 50]
    for bad in ("ten", "0", "25,,50", "100000"):
        with pytest.raises(ov.OverheadArgsError):
            ov.parse_drones(bad, quick=False)


@pytest.mark.parametrize("sites,stations,flight", [(1, 3, None), (4, 3, None), (0, 1, None), (0, 27, None),
                                                   (3, 3, 5.0), (0, 3, 5000.0)])
def test_bad_layouts_and_flights_are_refused(sites: int, stations: int, flight: float | None) -> None:
    with pytest.raises(ov.OverheadArgsError):
        ov.check_args(sites, stations, flight)


def test_good_layouts_pass() -> None:
    ov.check_args(0, 3, None)
    ov.check_args(3, 3, 120.0)


def test_cpu_is_milliseconds_per_second_per_drone_and_the_ratio_is_zdrone_over_bare() -> None:
    assert ov.ms_per_s_per_drone(100.0, 100) == 10.0  # a whole core for 100 drones: 10 ms/s each
    assert ov.ms_per_s_per_drone(None, 100) is None and ov.ms_per_s_per_drone(5.0, 0) is None
    assert ov.ratio(3.0, 2.0) == 1.5 and ov.ratio(1.0, 0.0) is None and ov.ratio(None, 1.0) is None
    assert ov.added(12.5, 10.0) == 2.5 and ov.added(None, 1.0) is None


def test_processes_are_summed_per_class() -> None:
    row = {"cpu_percent": {"router site-1": 10.0, "router site-2": 5.5, "stations host": 20.0, "drones host": 70.0},
           "memory_mb": {"router site-1": {"rss": 50.0, "peak": 60.0}, "router site-2": {"rss": 40.0, "peak": 41.0},
                         "stations host": None, "drones host": {"rss": 300.0, "peak": 320.0}}}
    assert ov.by_class(row, "cpu_percent") == {"routers": 15.5, "GSs host": 20.0, "drones host": 70.0}
    mem = ov.by_class(row, "memory_mb")
    assert mem == {"routers": 90.0, "GSs host": None, "drones host": 300.0}  # an unmeasured process: no figure


def _run(cpu: dict[str, float], p50: float, p99: float, samples: float) -> dict:
    return {"cpu_percent": cpu, "memory_mb": {n: {"rss": 100.0, "peak": 100.0} for n in cpu}, "samples_per_s": samples,
            "latency": {"gs_to_vehicle": {"n": 10, "p50_ms": p50, "p99_ms": p99},
                        "vehicle_to_gs": {"n": 20, "p50_ms": p50 / 2, "p99_ms": p99 / 2}}}


def test_compare_gives_every_class_both_ways_and_the_goals() -> None:
    bare = _run({"router": 10.0, "stations host": 10.0, "drones host": 50.0}, 5.0, 10.0, 1000.0)
    zd = _run({"router": 14.0, "stations host": 30.0, "drones host": 60.0}, 5.5, 14.0, 900.0)
    c = ov.compare(100, zd, bare)
    assert c["classes"]["drones host"]["cpu_ms_per_s_per_drone"] == {"bare": 5.0, "zdrone": 6.0, "ratio": 1.2}
    assert c["classes"]["GSs host"]["cpu_ms_per_s_per_drone"]["ratio"] == 3.0
    assert c["classes"]["routers"]["rss_mb"]["ratio"] == 1.0
    assert c["latency_ms"]["gs_to_vehicle"]["p50"]["added_ms"] == 0.5
    assert c["latency_ms"]["gs_to_vehicle"]["p99"]["added_ms"] == 4.0
    assert c["samples_per_s"]["ratio"] == 0.9
    assert c["goals"] == {"cpu_ratio_max": 3.0, "cpu_within": False, "added_p50_within": True, "added_p99_within": True}


def test_a_missing_half_is_shown_as_no_figure_not_as_zero() -> None:
    c = ov.compare(25, {"error": "no results"}, _run({"router": 1.0, "stations host": 1.0, "drones host": 1.0}, 1, 2, 3))
    assert c["classes"]["routers"]["cpu_ms_per_s_per_drone"] == {"bare": 0.4, "zdrone": None, "ratio": None}
    assert c["goals"]["cpu_within"] is False and c["goals"]["added_p50_within"] is False
    rows = ov.table_rows(c)
    assert rows[0][:5] == ["CPU ms/s per drone", "drones host", "0.400", "-", "-"]


def test_the_table_has_a_row_per_class_and_measure(capsys: pytest.CaptureFixture[str]) -> None:
    bare = _run({"router": 10.0, "stations host": 10.0, "drones host": 50.0}, 5.0, 10.0, 1000.0)
    zd = _run({"router": 14.0, "stations host": 30.0, "drones host": 60.0}, 7.0, 30.0, 900.0)
    cmp = ov.compare(100, zd, bare)
    rows = ov.table_rows(cmp)
    assert rows[3][:5] == ["CPU µs per vehicle frame", "drones host", "-", "-", "-"]  # no message rates: no figure
    zd["messages_per_s"] = {"down": {"sent": 2000.0, "got": 2100.0}, "up": {"sent": 300.0, "got": 100.0}}
    bare["messages_per_s"] = {"down": {"sent": 2500.0, "got": 2600.0}, "up": {"sent": 300.0, "got": 300.0}}
    cmp = ov.compare(100, zd, bare)
    assert cmp["classes"]["drones host"]["cpu_us_per_vehicle_frame"] == {"bare": 200.0, "zdrone": 300.0, "ratio": 1.5}
    assert cmp["messages_per_s"]["GS frames into the vehicles"] == {"bare": 300.0, "zdrone": 100.0, "ratio": 0.33}
    rows = ov.table_rows(cmp)
    assert [r[:2] for r in rows[:9]] == [[m, c] for m in ("CPU ms/s per drone", "CPU µs per vehicle frame", "RSS MB")
                                         for c in ov.CLASSES]
    assert ["latency p50 ms", "GS -> vehicle", "5.00", "7.00", "1.40", "+2.00 ms"] in rows
    ov.render({"rows": [{"k": 100, "g": 3, "layout": "1 router", "flight_s": 30.0, "speedup": 4.0, "zdrone": zd,
                         "bare": bare, "compare": cmp, "errors": {}}],
               "goals": {"cpu_ratio": 1.5, "added_gs_to_vehicle_p50_ms": 1.0, "added_gs_to_vehicle_p99_ms": 5.0}})
    out = capsys.readouterr().out
    assert "100 drones x 3 GSs, 1 router" in out and "GSs host" in out and "not met" in out


def test_latency_matches_each_arrival_to_the_latest_sending_of_the_same_bytes_to_the_same_drone() -> None:
    sent = [("d1", 7, 1.0), ("d1", 7, 80.0), ("d2", 7, 1.5), ("d1", 9, 2.0)]
    got = [("d1", 7, 1.004), ("d1", 7, 80.002), ("d2", 7, 1.51), ("d1", 9, 9.0), ("d3", 7, 1.2), ("d1", 8, 2.0)]
    xs = lat.match(sent, got)
    assert [round(x, 4) for x in xs] == [0.004, 0.002, 0.01]  # d1/9 came 7 s late: out of the window; d3, d1/8 never sent


def test_percentiles_are_nearest_rank() -> None:
    xs = [float(i) for i in range(1, 101)]
    assert lat.percentile(xs, 0.5) == 50.0 and lat.percentile(xs, 0.99) == 99.0 and lat.percentile([], 0.5) is None
    assert lat.percentile([3.0], 0.99) == 3.0


def test_a_log_notes_only_from_its_start_and_only_the_sample() -> None:
    log = lat.LatencyLog()
    frames = [i.to_bytes(2, "big") for i in range(512)]
    log.note_many("down", "sent", "d1", frames, 1.0)
    assert log.notes["down"]["sent"] == []  # before the take-off
    log.start(0.5)
    log.note_many("down", "sent", "d1", frames, 1.0)
    for f in frames:
        log.note("up", "sent", "d1", f, 2.0)
    assert {c % lat.SAMPLE_DOWN for _, c, _ in log.notes["down"]["sent"]} == {0}
    assert len(log.notes["up"]["sent"]) == sum(1 for f in frames if lat.crc(f) % lat.SAMPLE_UP == 0)
    assert log.counts["down"]["sent"] == {0: 512} and log.counts["up"]["sent"] == {1: 512}  # every one counted


def test_rates_are_per_second_over_the_window_summed_over_hosts(tmp_path) -> None:
    a, b = lat.LatencyLog(), lat.LatencyLog()
    a.counts["down"]["sent"] = {0: 100, 1: 100, 2: 100, 9: 1000}  # second 9: after the window
    b.counts["down"]["got"] = {0: 50, 1: 50, 2: 50}
    a.dump(tmp_path / "a.json")
    b.dump(tmp_path / "b.json")
    r = lat.rates([tmp_path / "a.json", tmp_path / "b.json"], 3.4)
    assert r["down"] == {"sent": 100.0, "got": 50.0} and r["up"] == {"sent": 0.0, "got": 0.0}


def test_summary_per_direction_in_milliseconds(tmp_path) -> None:
    a, b = lat.LatencyLog(), lat.LatencyLog()
    a.notes["up"]["sent"] = [("d1", 1, 10.0), ("d1", 2, 11.0)]
    b.notes["up"]["got"] = [("d1", 1, 10.002), ("d1", 2, 11.004)]
    a.dump(tmp_path / "a.json")
    b.dump(tmp_path / "b.json")
    s = lat.summary(lat.load([tmp_path / "a.json", tmp_path / "b.json", tmp_path / "missing.json"]))
    assert s["gs_to_vehicle"] == {"n": 2, "p50_ms": 2.0, "p99_ms": 4.0}
    assert s["vehicle_to_gs"] == {"n": 0, "p50_ms": None, "p99_ms": None}


def test_bare_application_rules() -> None:
    hb_v2 = bytes([0xFD, 9, 0, 0, 5, 1, 1, 0, 0, 0]) + bytes(11)
    pos_v2 = bytes([0xFD, 28, 0, 0, 5, 1, 1, 33, 0, 0]) + bytes(30)
    assert msgid_of(hb_v2) == 0 and msgid_of(pos_v2) == 33 and msgid_of(b"\xfd\x01") == -1
    circles = {g: Circle(offset(HOME, 0.0, 500.0 * i), 300.0) for i, g in enumerate("ABC")}
    assert nearest_covering(offset(HOME, 0.0, 200.0), circles, None) == "A"
    assert nearest_covering(offset(HOME, 0.0, 300.0), circles, "A") == "B"  # both cover it: the nearer
    assert nearest_covering(GeoPoint(0.0, 0.0), circles, "C") == "C"  # none: the last one


def test_gs_to_vehicle_is_split_where_the_drones_host_takes_it_from_zenoh(tmp_path) -> None:
    """The wire (sent -> arrived in the host's callback) and the host (arrived -> forwarded to the
    vehicle: the wait for the drone's turn in the pass), each matched by the same bytes."""
    gs, host = lat.LatencyLog(), lat.LatencyLog()
    frames = [f for f in (i.to_bytes(2, "big") for i in range(2000)) if lat.crc(f) % lat.SAMPLE_UP == 0][:2]
    host.note("up", "arrived", "d1", frames[0], 10.001)
    assert host.notes["up"]["arrived"] == []  # before the take-off
    gs.start(9.0)
    host.start(9.0)
    for i, f in enumerate(frames):
        gs.note("up", "sent", "d1", f, 10.0 + i)
        host.note("up", "arrived", "d1", f, 10.001 + i)
        host.note("up", "got", "d1", f, 10.011 + i * 1.02)
    outside = next(f for f in (i.to_bytes(2, "big") for i in range(2000)) if lat.crc(f) % lat.SAMPLE_UP)
    host.note("up", "arrived", "d1", outside, 12.0)  # not in the sample: not noted
    assert len(host.notes["up"]["arrived"]) == 2 and host.counts["up"].get("arrived") is None  # noted, not counted
    gs.dump(tmp_path / "gs.json")
    host.dump(tmp_path / "host.json")
    s = lat.summary(lat.load([tmp_path / "gs.json", tmp_path / "host.json"]))
    assert s["gs_to_vehicle_wire"] == {"n": 2, "p50_ms": 1.0, "p99_ms": 1.0}
    assert s["gs_to_vehicle_host"] == {"n": 2, "p50_ms": 10.0, "p99_ms": 30.0}
    assert s["gs_to_vehicle"]["p99_ms"] == 31.0


def test_the_split_is_compared_and_judged_on_the_wire_alone() -> None:
    bare = _run({"router": 10.0, "stations host": 10.0, "drones host": 50.0}, 5.0, 10.0, 1000.0)
    zd = _run({"router": 14.0, "stations host": 30.0, "drones host": 60.0}, 30.0, 80.0, 900.0)
    bare["latency"]["gs_to_vehicle_wire"] = {"n": 9, "p50_ms": 2.0, "p99_ms": 8.0}
    zd["latency"]["gs_to_vehicle_wire"] = {"n": 9, "p50_ms": 2.5, "p99_ms": 12.0}
    bare["latency"]["gs_to_vehicle_host"] = {"n": 9, "p50_ms": 3.0, "p99_ms": 5.0}
    zd["latency"]["gs_to_vehicle_host"] = {"n": 9, "p50_ms": 27.0, "p99_ms": 70.0}
    c = ov.compare(300, zd, bare)
    assert c["latency_ms"]["gs_to_vehicle_wire"]["p50"]["added_ms"] == 0.5
    assert c["goals"]["added_p50_within"] is False
    assert c["goals"]["wire_added_p50_within"] is True and c["goals"]["wire_added_p99_within"] is True
    rows = ov.table_rows(c)
    assert ["latency p50 ms", "  GS -> drone's host (wire)", "2.00", "2.50", "1.25", "+0.50 ms"] in rows
    assert ["latency p99 ms", "  drone's host -> vehicle", "5.00", "70.00", "14.00", "+65.00 ms"] in rows


def test_a_catch_up_is_timed_from_its_sending_again_and_its_age_kept_apart(tmp_path) -> None:
    """A frame a standby GS was not sent, sent to it as its new owner's catch-up 0.2 s after the
    vehicle gave it: its delivery is timed from the catch-up (2 ms), its age (200 ms) reported apart."""
    drone, gs = lat.LatencyLog(), lat.LatencyLog()
    drone.start(0.0)
    gs.start(0.0)
    frame = next(i.to_bytes(2, "big") for i in range(4096) if lat.crc(i.to_bytes(2, "big")) % lat.SAMPLE_DOWN == 0)
    drone.note_many("down", "sent", "d1", [frame], 10.0)  # the vehicle gave it; to the owner only
    gs.note("down", "got", "d1", frame, 10.001)  # the owner got it
    drone.note_catch_up("d1", [(frame, 10.0)], 10.2)  # the hand-over: the new owner's catch-up
    gs.note("down", "got", "d1", frame, 10.202)
    drone.dump(tmp_path / "d.json")
    gs.dump(tmp_path / "g.json")
    files = [tmp_path / "d.json", tmp_path / "g.json"]
    assert lat.summary(lat.load(files))["vehicle_to_gs"] == {"n": 2, "p50_ms": 1.0, "p99_ms": 2.0}
    assert lat.catch_up(files) == {"n": 1, "p50_ms": 200.0, "p99_ms": 200.0, "max_ms": 200.0}


def test_vehicle_to_gs_is_split_at_the_drones_put_and_the_gss_inbox(tmp_path) -> None:
    drone, gs = lat.LatencyLog(), lat.LatencyLog()
    drone.notes["down"]["sent"] = [("d1", 1, 10.0)]
    drone.notes["down"]["put"] = [("d1", 1, 10.001)]
    gs.notes["down"]["arrived"] = [("d1", 1, 10.004)]
    gs.notes["down"]["got"] = [("d1", 1, 10.010)]
    drone.dump(tmp_path / "d.json")
    gs.dump(tmp_path / "g.json")
    s = lat.summary(lat.load([tmp_path / "d.json", tmp_path / "g.json"]))
    assert s["vehicle_to_gs"]["p50_ms"] == 10.0
    assert (s["vehicle_to_gs_drone"]["p50_ms"], s["vehicle_to_gs_wire"]["p50_ms"], s["vehicle_to_gs_host"]["p50_ms"]) == (1.0, 3.0, 6.0)
    c = ov.compare(100, {"latency": s}, {"latency": {}})
    assert c["latency_ms"]["vehicle_to_gs_wire"]["p50"]["zdrone"] == 3.0


def test_gs_to_vehicle_shows_the_gss_own_part_of_the_wire(tmp_path) -> None:
    gs, host = lat.LatencyLog(), lat.LatencyLog()
    gs.notes["up"]["sent"] = [("d1", 1, 10.0)]  # the GS's pass began
    gs.notes["up"]["put"] = [("d1", 1, 10.012)]  # on its lane: after the pass and the pacing
    host.notes["up"]["arrived"] = [("d1", 1, 10.015)]
    host.notes["up"]["got"] = [("d1", 1, 10.016)]
    gs.dump(tmp_path / "g.json")
    host.dump(tmp_path / "h.json")
    s = lat.summary(lat.load([tmp_path / "g.json", tmp_path / "h.json"]))
    assert (s["gs_to_vehicle_gs"]["p50_ms"], s["gs_to_vehicle_wire"]["p50_ms"], s["gs_to_vehicle_host"]["p50_ms"]) == (12.0, 15.0, 1.0)
