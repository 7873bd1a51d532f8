"""bench view's attack part: its pure pieces (the page's picture gap, the view's counters, the targets,
the table's rows, the load's stats file). No timing: the figures are the bench's."""

import json

from zdrone.bench import view, viewattack
from zdrone.bench.viewattack import attack_rows, counter_delta, meets_targets, picture_gaps
from zdrone.bench.viewload import StatsFile, last_stats


def test_gaps_are_between_consecutive_pictures_the_one_before_the_window_included():
    g = picture_gaps([9.8, 10.1, 10.3, 11.3, 11.5], 10.0, 11.6)
    assert g["pictures"] == 4
    assert g["max_s"] == 1.0  # 10.3 -> 11.3
    assert g["p50_s"] == 0.2  # 9.8 -> 10.1 is 0.3, then 0.2, 1.0, 0.2


def test_a_stream_gone_silent_shows_as_a_gap_to_the_window_end():
    g = picture_gaps([10.0, 10.5], 10.0, 14.0)
    assert g["max_s"] == 3.5
    assert g["p95_s"] == 0.5


def test_no_picture_at_all_is_the_whole_window():
    g = picture_gaps([], 10.0, 40.0)
    assert g == {"pictures": 0, "max_s": 30.0, "p95_s": None, "p50_s": None}


def test_stamps_out_of_order_are_sorted():
    assert picture_gaps([10.4, 10.0, 10.2], 10.0, 10.4)["max_s"] == 0.2


def test_counter_delta_counts_x_parts_by_the_drone_outside_the_fleet():
    first = {"opened": 100, "drops": {"unknown_drone": 5, "replay": 1}, "server_time": 1000.0}
    last = {"opened": 400, "drops": {"unknown_drone": 255, "replay": 1, "not_authorized": 250}, "server_time": 1010.0}
    d = counter_delta(first, last)
    assert d == {"opened": 300, "x_opened": 250, "drops": {"not_authorized": 250, "unknown_drone": 250}, "span_s": 10.0}


def test_counter_delta_without_pictures_has_no_figures():
    assert counter_delta(None, {"opened": 3, "drops": {}})["opened"] is None


def _window(rss: float, cpu: float, gap: float, not_live: int = 0) -> dict:
    return {"rss_max_mb": rss, "cpu_pct": cpu, "gap": {"max_s": gap, "p95_s": gap / 2, "pictures": 10},
            "samples": 10, "page_not_live": not_live, "d1_not_live": 0, "pictures_per_s": 1.0}


def test_targets_each_judged_on_its_own():
    met = meets_targets(_window(151.0, 50.0, 1.0, not_live=1))
    assert met == {"rss": False, "cpu": True, "gap": True, "page_live": False, "d1_live": True}
    assert meets_targets({"samples": 0, "gap": {}})["rss"] is None


def test_rows_show_both_windows_and_the_targets():
    control, load = _window(70.0, 2.0, 0.4), _window(160.0, 80.0, 2.0)
    control["targets_met"], load["targets_met"] = meets_targets(control), meets_targets(load)
    rows = attack_rows({"control": control, "load": load})
    assert [r[0] for r in rows] == ["control (no load)", "under attack", "target"]
    assert rows[0][-1] == "rss:yes cpu:yes gap:yes"
    assert rows[1][-1] == "rss:NO cpu:NO gap:NO"
    assert rows[2][1:4] == [f"<= {viewattack.TARGET_RSS_MB:g}", f"<= {viewattack.TARGET_CPU_PCT:g}",
                              f"<= {viewattack.TARGET_GAP_S:g}"]


def test_render_attack_prints_the_tables(capsys):
    control, load = _window(70.0, 2.0, 0.4), _window(80.0, 20.0, 0.5)
    control["targets_met"], load["targets_met"] = meets_targets(control), meets_targets(load)
    load.update(view={"opened": 10, "x_opened": 8, "drops": {"unknown_drone": 8}, "span_s": 10.0},
                clients={"held_open": {"min": 250, "max": 256}, "streaming": {"min": 63, "max": 63},
                         "attempts_per_s": 700.0, "refused_503_per_s": 100.0, "cut_before_answer_per_s": 600.0},
                forger={"sent_per_s": 1000.0, "reached_per_s": 0.8})
    viewattack.render_attack({"clients": 1000, "forged_rate": 1000.0, "window_s": 10.0, "control": control, "load": load})
    out = capsys.readouterr().out
    assert "under attack" in out and "unknown_drone 8" in out


def test_a_part_that_gave_no_figures_fails_the_bench():
    assert view.failed({"parts": ["attack"], "attack": {"error": "x"}})
    assert not view.failed({"parts": ["attack"], "attack": {"control": {}, "load": {}}})


def test_stats_file_gives_its_last_whole_line(tmp_path):
    path = tmp_path / "s.jsonl"
    s = StatsFile(str(path))
    assert last_stats(path) is None
    s.write({"sent": 1})
    s.write({"sent": 2})
    with open(path, "a") as f:
        f.write('{"sent": 3')  # a line being written
    assert last_stats(path)["sent"] == 2
    assert json.loads(path.read_text().splitlines()[0])["sent"] == 1
