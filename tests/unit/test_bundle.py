"""A bundle per host (``zdrone fleet export``): exactly what the node needs, no byte of any other
node's secret nor of the CA key, and ``fleet show --check-secrets`` says whose it is and refuses a
folder that holds another's secret. Every flight of the testbed runs each node from its bundle
(``Demo._export_bundles``), with and without TLS (the reference flight, ``rogue-no-cert``)."""

from __future__ import annotations

import json
import shutil
import stat
from pathlib import Path

import pytest

from zdrone.cli import main
from zdrone.core.errors import ConfigError
from zdrone.core.keys import unb64
from zdrone.fleet.bundle import check_bundle, export_bundle
from zdrone.fleet.files import init_fleet, load_fleet

NODES = ("d1", "A", "B", "X", "V")


@pytest.fixture(scope="module", params=[False, True], ids=["plain", "tls"])
def fleet(request, tmp_path_factory) -> tuple[Path, bool]:
    d = tmp_path_factory.mktemp("fleet") / "fleet"
    init_fleet(d, tls=request.param, sites=["tls/127.0.0.1:7447", "tls/127.0.0.1:7448"] if request.param else None)
    return d, request.param


def _secret_bytes(fleet_dir: Path, node: str) -> list[bytes]:
    """Every form of ``node``'s secrets: its key (raw, base64), its router password, its TLS key
    (the PEM, and the key's body lines)."""
    raw = json.loads((fleet_dir / "secrets" / f"{node}.json").read_text())
    key = unb64(raw["private_key"], 32)
    out = [key, raw["private_key"].encode(), raw["router_password"].encode()]
    tls_key = fleet_dir / "secrets" / f"{node}.tls.key"
    if tls_key.exists():
        pem = tls_key.read_bytes()
        out += [pem] + [line for line in pem.splitlines() if line and not line.startswith(b"-----")]
    return out


def _ca_key_bytes(fleet_dir: Path) -> list[bytes]:
    p = fleet_dir / "tls" / "ca.key"
    if not p.exists():
        return []
    return [line for line in p.read_bytes().splitlines() if line and not line.startswith(b"-----")]


def _all_bytes(folder: Path) -> bytes:
    return b"\n".join(p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file())


@pytest.mark.parametrize("node", NODES)
def test_a_node_bundle_holds_its_own_secret_and_no_byte_of_anyone_elses(fleet, node, tmp_path):
    fleet_dir, tls = fleet
    b = export_bundle(fleet_dir, node, tmp_path / node)
    expected = {"bundle.json", "fleet.json5", f"secrets/{node}.json"}
    expected |= {"tls/ca.crt", f"tls/{node}.crt", f"secrets/{node}.tls.key"} if tls else set()
    assert set(b.files) == expected and b.node == node and b.tls == tls
    for rel in b.files:
        mode = stat.S_IMODE((tmp_path / node / rel).stat().st_mode)
        assert mode == (0o600 if rel.startswith("secrets/") else 0o644), (rel, oct(mode))
    blob = _all_bytes(tmp_path / node)
    assert all(s in blob for s in _secret_bytes(fleet_dir, node)[1:])  # the key as its file holds it
    for other in NODES:
        if other != node:
            leaked = [s for s in _secret_bytes(fleet_dir, other) if s in blob]
            assert not leaked, f"{node}'s bundle holds {other}'s secret"
    assert not [s for s in _ca_key_bytes(fleet_dir) if s in blob], "the CA key left its machine"
    assert b"credentials" not in blob.replace(b'"router/credentials.txt"', b"")


@pytest.mark.parametrize("router", ["router", "site-2"])
def test_a_router_bundle_holds_its_config_and_credentials_and_no_private_key_of_a_node(fleet, router, tmp_path):
    fleet_dir, tls = fleet
    if router.startswith("site-") and not tls:
        with pytest.raises(ConfigError, match="no router config router/site-2.json5"):
            export_bundle(fleet_dir, router, tmp_path / router)
        return
    b = export_bundle(fleet_dir, router, tmp_path / router)
    cfg = "router" if router == "router" else router
    assert {f"router/{cfg}.json5", "router/credentials.txt"} <= set(b.files)
    assert ({f"router/{cfg}.crt", f"router/{cfg}.key", "tls/ca.crt"} <= set(b.files)) == tls
    blob = _all_bytes(tmp_path / router)
    for node in NODES:  # the router checks every password; it holds nobody's private key
        s = _secret_bytes(fleet_dir, node)
        assert s[2] in blob
        assert not [x for x in s[:2] + s[3:] if x in blob], f"the router's bundle holds {node}'s private key"
    assert not [s for s in _ca_key_bytes(fleet_dir) if s in blob]


def test_show_says_whose_bundle_it_is_and_refuses_any_other_secret(fleet, tmp_path, capsys):
    fleet_dir, tls = fleet
    b = tmp_path / "A"
    export_bundle(fleet_dir, "A", b)
    assert main(["fleet", "show", "--dir", str(b), "--check-secrets"]) == 0
    assert "bundle of A (gs" in capsys.readouterr().out
    intruders = [(fleet_dir / "secrets" / "B.json", "secrets/B.json", "B's secret"),
                 (fleet_dir / "secrets" / "d1.json", "notes/backup.txt", "d1's secret"),  # renamed: found by content
                 (fleet_dir / "router" / "credentials.txt", "router/credentials.txt", "not A's")]
    if tls:
        intruders += [(fleet_dir / "tls" / "ca.key", "tls/ca.key", "the fleet CA's private key"),
                      (fleet_dir / "secrets" / "B.tls.key", "keys/spare.pem", "a private key that is not A's")]
    for src, rel, says in intruders:
        (b / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, b / rel)
        assert main(["fleet", "show", "--dir", str(b), "--check-secrets"]) == 2
        err = capsys.readouterr().err
        assert says in err and err.count("\n") == 1, err
        (b / rel).unlink()
    (b / "secrets" / "A.json").chmod(0o644)
    with pytest.raises(ConfigError, match="accessible by others"):
        check_bundle(b)


def test_export_refuses_an_unknown_node_and_a_folder_in_use(fleet, tmp_path, capsys):
    fleet_dir, _ = fleet
    assert main(["fleet", "export", "Z", "--dir", str(fleet_dir), "--out", str(tmp_path / "z")]) == 2
    assert "node 'Z': not in the fleet" in capsys.readouterr().err
    (tmp_path / "used").mkdir()
    (tmp_path / "used" / "something").write_text("x")
    assert main(["fleet", "export", "A", "--dir", str(fleet_dir), "--out", str(tmp_path / "used")]) == 2
    assert "exists and is not an empty folder" in capsys.readouterr().err
    assert load_fleet(fleet_dir).nodes.keys() == set(NODES)
