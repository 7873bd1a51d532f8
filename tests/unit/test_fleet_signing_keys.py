"""The fleet signing key (Ed25519, offline like the CA key: only its public half, ``fleet_key``, is in
``fleet.json5`` and so pinned by every bundle) and each node's Ed25519 signing key (its public half
in the fleet, its private half in its own secret file)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from zdrone.core.errors import ConfigError
from zdrone.core.keys import verify_signature
from zdrone.fleet.bundle import check_bundle, export_bundle
from zdrone.fleet.files import FLEET_SIGNING_FILE, init_fleet, load_fleet, load_fleet_signing_key, load_secret


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("fleet") / "fleet"
    init_fleet(d)
    return d


def test_init_makes_a_fleet_signing_key_whose_public_half_the_fleet_pins(fleet_dir):
    fleet = load_fleet(fleet_dir)
    key = load_fleet_signing_key(fleet_dir, fleet)
    assert fleet.fleet_key_bytes == key.public
    assert (fleet_dir / FLEET_SIGNING_FILE).stat().st_mode & 0o077 == 0
    assert verify_signature(fleet.fleet_key_bytes, b"m", key.sign(b"m"))
    assert not verify_signature(fleet.fleet_key_bytes, b"n", key.sign(b"m"))


@pytest.mark.parametrize("node", ["d1", "A", "B", "X"])
def test_every_node_has_a_signing_key_whose_public_half_is_in_the_fleet(fleet_dir, node):
    fleet = load_fleet(fleet_dir)
    secret = load_secret(fleet_dir, node, fleet)
    assert secret.signing is not None
    assert fleet.signing_public(node) == secret.signing.public
    assert verify_signature(fleet.signing_public(node), b"entry", secret.signing.sign(b"entry"))


@pytest.mark.parametrize("node", ["d1", "A", "router"])
def test_a_bundle_pins_the_fleet_key_and_never_holds_its_private_half(fleet_dir, node, tmp_path):
    export_bundle(fleet_dir, node, tmp_path / "b")
    assert load_fleet(tmp_path / "b").fleet_key == load_fleet(fleet_dir).fleet_key
    assert not (tmp_path / "b" / FLEET_SIGNING_FILE).exists()
    private = (fleet_dir / FLEET_SIGNING_FILE).read_bytes()
    assert all(private not in p.read_bytes() for p in (tmp_path / "b").rglob("*") if p.is_file())
    with pytest.raises(ConfigError, match="no fleet signing key"):
        load_fleet_signing_key(tmp_path / "b")


@pytest.mark.parametrize("where", [FLEET_SIGNING_FILE, "notes/anything.json"])
def test_a_bundle_holding_the_fleet_signing_key_is_refused(fleet_dir, tmp_path, where):
    b = tmp_path / "b"
    export_bundle(fleet_dir, "A", b)
    (b / where).parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(fleet_dir / FLEET_SIGNING_FILE, b / where)
    with pytest.raises(ConfigError, match="fleet signing key"):
        check_bundle(b)


def test_a_secret_whose_signing_key_does_not_match_the_fleet_is_refused(fleet_dir, tmp_path):
    import json

    d = tmp_path / "f"
    shutil.copytree(fleet_dir, d)
    other = json.loads((d / "secrets" / "B.json").read_text())["signing_key"]
    raw = json.loads((d / "secrets" / "A.json").read_text())
    (d / "secrets" / "A.json").write_text(json.dumps({**raw, "signing_key": other}))
    with pytest.raises(ConfigError, match="signing key does not match"):
        load_secret(d, "A", load_fleet(d))
