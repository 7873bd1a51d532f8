"""bench view's flood part: its pure pieces (the flood's rates from its stats file, the table's rows,
the part's failure, the half-open payloads). No timing: the figures are the bench's."""

import json

from zdrone.bench import view, viewflood
from zdrone.bench.viewflood import flood_rates, flood_rows, served
from zdrone.bench.viewload import half_client_hello, half_head


def _op(ok: int, tries: int) -> dict:
    return {"pages": ok, "page_tries": tries, "streams": ok, "stream_tries": tries, "errors": [], "p50_s": 0.01,
            "max_s": 0.2}


def test_the_flood_rates_are_over_its_lines_inside_the_window(tmp_path):
    path = tmp_path / "flood.jsonl"
    lines = [{"t": 99.0, "attempts": 0, "cut": 0, "held_max": 1, "connect_failed": 0},
             {"t": 100.0, "attempts": 300, "cut": 292, "held_max": 300, "connect_failed": 0},
             {"t": 102.0, "attempts": 4300, "cut": 4290, "held_max": 300, "connect_failed": 1}]
    path.write_text("".join(json.dumps(r) + "\n" for r in lines) + '{"t": 102.5, "attem')  # a line being written
    assert flood_rates(path, 100.0, 103.0) == {"connects_per_s": 2000.0, "cut_per_s": 1999.0, "held_max": 300,
                                               "connect_failed": 1, "span_s": 2.0}
    assert flood_rates(path, 101.0, 103.0) is None  # one line: no rate


def test_the_operator_is_served_only_when_every_request_was():
    assert served(_op(20, 20))
    assert not served(_op(19, 20))
    assert not served(_op(0, 0))  # asked nothing: nothing shown


def test_rows_a_control_and_a_flood_per_mode_and_a_failed_part(capsys):
    mode = {"connections": 1500, "tls": True, "control": _op(20, 20), "flood": _op(40, 41),
            "view": {"rss_start_mb": 70.0, "rss_max_mb": 519.0, "rss_end_mb": 518.0, "fds_max": 1520, "cpu_pct": 30.0},
            "attacker": {"connects_per_s": 1999.6}, "met": {"operator": False, "rss": False}}
    f = {"source": "127.0.0.2", "window_s": 8.0, "rate": 2000.0, "target_rss_mb": 150.0, "modes": {"handshakes": mode}}
    rows = flood_rows(f)
    assert rows[0][:4] == ["handshakes: none", "-", "20/20", "20/20"]
    assert rows[1][:8] == ["handshakes: 1500", 2000, "40/41", "40/41", 0.2, 519.0, 518.0, 1520]
    assert rows[1][-1] == "NO NO"
    viewflood.render_flood(f)
    assert "half-open" in capsys.readouterr().out
    assert view.failed({"parts": ["flood"], "flood": {"error": "the view did not start", "modes": {}}})
    assert not view.failed({"parts": ["flood"], "flood": f})


def test_the_halves_are_never_whole():
    head = half_head("view.test:8470")
    assert head.startswith(b"GET / HTTP/1.1\r\n") and b"\r\n\r\n" not in head and b"token" not in head
    hello = half_client_hello()
    assert hello[0] == 0x16 and len(hello) - 5 < int.from_bytes(hello[3:5], "big")  # a record not yet whole
