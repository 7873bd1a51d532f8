import json

from zdrone.cli import main


def test_bench_crypto_json_shape(capsys):
    assert main(["bench", "crypto", "--quick", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    msgs = [f["message"] for f in result["frames"]]
    assert msgs == ["HEARTBEAT", "GLOBAL_POSITION_INT", "COMMAND_LONG", "MISSION_ITEM_INT"]
    for f in result["frames"]:
        assert f["added_bytes"]["zdrone"] == 24  # the target is a wire-format fact, not a timing
        assert 90 <= f["added_bytes"]["fernet"] <= 115
        assert 21 <= f["frame_bytes"] <= 50
    assert set(result["seal_open_us"]) == {"zdrone", "fernet", "raw ChaCha20-Poly1305"} == set(result["frames_per_s"])
    assert isinstance(result["seal_open_vs_raw"], float)  # a figure for the bench table, not asserted
    assert all(v > 0 for v in result["seal_open_us"].values())


def test_bench_crypto_table(capsys):
    assert main(["bench", "crypto", "--quick"]) == 0
    out = capsys.readouterr().out
    assert "HEARTBEAT" in out and "µs / frame" in out


def test_bench_crypto_has_the_flight_controller_signing_row(capsys):
    assert main(["bench", "crypto", "--quick", "--json"]) == 0
    fc = json.loads(capsys.readouterr().out)["fc_signing"]
    assert set(fc["added_bytes"].values()) == {13}  # the MAVLink 2 signature block: a wire-format fact
    assert fc["sign_us"] > 0 and fc["verify_us"] > 0


def test_bench_crypto_has_the_classical_and_hybrid_handshake_rows(capsys):
    assert main(["bench", "crypto", "--quick", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["handshake"]
    assert [r["mode"].split()[0] for r in rows] == ["classical", "hybrid"]
    classical, hybrid = rows
    assert (classical["message1_bytes"], classical["message2_bytes"]) == (72, 97)  # wire-format facts
    assert (hybrid["message1_bytes"], hybrid["message2_bytes"]) == (72 + 1184, 97 + 1088)
    assert all(r["gs_us"] > 0 and r["drone_us"] > 0 for r in rows)


def test_bench_crypto_has_the_authority_record_row(capsys):
    assert main(["bench", "crypto", "--quick", "--json"]) == 0
    au = json.loads(capsys.readouterr().out)["audit"]
    assert au["entries"] == 10_000 and au["verify_s"] > 0 and au["append_us"] > 0
