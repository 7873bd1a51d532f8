"""``zdrone fleet revoke | rotate | revise``: each change is the next signed revision, the router
files follow the effective fleet (a revoked node has no password and is no ACL subject), a rotated
node's re-exported bundle holds its new key, every node's bundle loads the effective fleet, and bad
input is one line with exit code 2."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from zdrone.cli import main
from zdrone.core.revision import RevisionAccepted, check_revision
from zdrone.fleet.bundle import check_bundle, export_bundle
from zdrone.fleet.files import REVISION_FILE, load_base_fleet, load_fleet, load_secret


@pytest.fixture()
def fleet_dir(tmp_path) -> Path:
    d = tmp_path / "fleet"
    assert main(["fleet", "init", "--dir", str(d)]) == 0
    return d


def test_revoke_signs_the_next_revision_and_takes_the_node_out_of_the_router(fleet_dir, capsys):
    assert main(["fleet", "revoke", "B", "--dir", str(fleet_dir), "--note", "host lost"]) == 0
    fleet = load_fleet(fleet_dir)
    assert fleet.revision == 1 and fleet.is_revoked("B") and not fleet.is_authorized("d1", "B")
    creds = (fleet_dir / "router" / "credentials.txt").read_text()
    assert not any(line.startswith("B:") for line in creds.splitlines())
    assert "user-B" not in (fleet_dir / "router" / "router.json5").read_text()
    assert (fleet_dir / "revisions" / "0001.json").read_bytes() == (fleet_dir / REVISION_FILE).read_bytes()
    assert main(["fleet", "revoke", "B", "--dir", str(fleet_dir)]) == 2
    assert "already revoked" in capsys.readouterr().err


def test_rotate_gives_a_new_key_whose_bundle_loads_and_the_old_key_is_gone(fleet_dir, tmp_path):
    old = load_secret(fleet_dir, "A").identity.public
    assert main(["fleet", "rotate", "A", "--dir", str(fleet_dir), "--out", str(tmp_path / "A")]) == 0
    fleet = load_fleet(fleet_dir)
    new = load_secret(fleet_dir, "A", fleet)
    assert new.identity.public != old and fleet.nodes["A"].public_bytes == new.identity.public
    assert load_base_fleet(fleet_dir).nodes["A"].public_bytes == old  # fleet.json5 never changes
    b = check_bundle(tmp_path / "A")
    assert b.node == "A" and REVISION_FILE in b.files
    assert load_fleet(tmp_path / "A").nodes["A"].public_bytes == new.identity.public


def test_a_bundle_exported_before_the_revision_takes_it_when_it_arrives(fleet_dir, tmp_path):
    export_bundle(fleet_dir, "d1", tmp_path / "d1")
    assert main(["fleet", "revise", "--dir", str(fleet_dir), "--authorize", "d1=A", "--pairing-pq", "on"]) == 0
    data = (fleet_dir / REVISION_FILE).read_bytes()
    got = check_revision(data, load_base_fleet(tmp_path / "d1"), None)
    assert isinstance(got, RevisionAccepted) and got.fleet.nodes["d1"].authorized_gs == ["A"] and got.fleet.pairing_pq
    shutil.copyfile(fleet_dir / REVISION_FILE, tmp_path / "d1" / REVISION_FILE)
    assert load_fleet(tmp_path / "d1").revision == 1
    check_bundle(tmp_path / "d1")  # a revision is public: still the bundle of d1 alone


def test_a_tampered_kept_revision_is_refused_at_load(fleet_dir):
    main(["fleet", "revoke", "X", "--dir", str(fleet_dir)])
    raw = json.loads((fleet_dir / REVISION_FILE).read_text())
    raw["changes"]["revoked"] = []
    (fleet_dir / REVISION_FILE).write_text(json.dumps(raw))
    assert main(["fleet", "show", "--dir", str(fleet_dir)]) == 2


@pytest.mark.parametrize("argv, said", [
    (["fleet", "revoke", "Z"], "not in the fleet"),
    (["fleet", "revise", "--authorize", "A=B"], "not a drone"),
    (["fleet", "revise", "--coverage", "A=1,2"], "expected GS=LAT,LON,RADIUS_M"),
    (["fleet", "revise"], "nothing to change"),
])
def test_bad_changes_are_one_line_and_exit_2(fleet_dir, capsys, argv, said):
    assert main([*argv, "--dir", str(fleet_dir)]) == 2
    err = capsys.readouterr().err.strip()
    assert said in err and len(err.splitlines()) == 1


def test_revisions_are_made_only_where_the_offline_key_is(fleet_dir, tmp_path, capsys):
    export_bundle(fleet_dir, "A", tmp_path / "A")
    assert main(["fleet", "revoke", "B", "--dir", str(tmp_path / "A")]) == 2
    assert "offline keys" in capsys.readouterr().err


def test_a_node_keeps_the_next_revision_durably_and_counts_the_rest(fleet_dir, tmp_path, monkeypatch):
    from zdrone.core.revision import RevisionRefused
    from zdrone.fleet.revisions import RevisionKeeper

    export_bundle(fleet_dir, "d1", tmp_path / "d1")
    state = tmp_path / "state"
    state.mkdir()
    monkeypatch.setenv("ZDRONE_STATE_DIR", str(state))
    keeper = RevisionKeeper(tmp_path / "d1", "d1")
    main(["fleet", "revoke", "B", "--dir", str(fleet_dir)])
    data = (fleet_dir / REVISION_FILE).read_bytes()
    assert isinstance(keeper.offer(data), RevisionAccepted) and (state / REVISION_FILE).read_bytes() == data
    assert isinstance(keeper.offer(data), RevisionRefused) and isinstance(keeper.offer(b"\xff" * 9), RevisionRefused)
    assert keeper.stats() == {"number": 1, "applied": 1, "refused:replayed": 1, "refused:malformed": 1}
    assert load_fleet(tmp_path / "d1").is_revoked("B")  # a restart comes back under it
    monkeypatch.setenv("ZDRONE_STATE_DIR", str(tmp_path / "gone"))  # a folder that cannot take it:
    main(["fleet", "revoke", "X", "--dir", str(fleet_dir)])  # counted, applied all the same
    assert isinstance(keeper.offer((fleet_dir / REVISION_FILE).read_bytes()), RevisionAccepted)
    assert keeper.counters["store_failed"] == 1 and keeper.number == 2


def test_a_node_parses_its_fleet_once_and_its_keeper_checks_against_that_parse(fleet_dir, tmp_path, monkeypatch):
    """The runtime's base is the keeper's (a companion in a fleet of 300 held two parses of 0.4 MB), and
    the fleet in force is that same object while no revision is kept; a revision still applies."""
    from zdrone.fleet.files import load_base_fleet
    from zdrone.fleet.revisions import RevisionKeeper

    export_bundle(fleet_dir, "d1", tmp_path / "d1")
    monkeypatch.setenv("ZDRONE_STATE_DIR", str(tmp_path))
    base = load_base_fleet(tmp_path / "d1")
    keeper = RevisionKeeper(tmp_path / "d1", "d1", base)
    assert keeper.base is base and load_fleet(tmp_path / "d1", base) is base
    main(["fleet", "revoke", "B", "--dir", str(fleet_dir)])
    got = keeper.offer((fleet_dir / REVISION_FILE).read_bytes())
    assert isinstance(got, RevisionAccepted) and got.fleet.is_revoked("B") and not base.is_revoked("B")
    again = load_fleet(tmp_path / "d1", base)
    assert again is not base and again.is_revoked("B")
