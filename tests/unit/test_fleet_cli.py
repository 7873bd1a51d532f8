"""Fleet files and CLI errors: one clear line on stderr, exit code 2."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from zdrone.cli import main
from zdrone.core.fleet import FleetError, parse_fleet
from zdrone.fleet.files import init_fleet, load_fleet, load_secret
from zdrone.fleet.routerconfig import mesh_endpoint


@pytest.fixture()
def fleet_dir(tmp_path: Path) -> Path:
    init_fleet(tmp_path / "fleet")
    return tmp_path / "fleet"


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_init_writes_default_fleet(fleet_dir: Path):
    fleet = load_fleet(fleet_dir)
    assert {n: (v.role, v.sysid) for n, v in fleet.nodes.items()} == {
        "d1": ("drone", 1), "A": ("gs", 4), "B": ("gs", 3), "X": ("gs", 7), "V": ("viewer", 250)}
    assert fleet.is_authorized("d1", "A") and fleet.is_authorized("d1", "B")
    assert not fleet.is_authorized("d1", "X")
    for name in fleet.nodes:
        path = fleet_dir / "secrets" / f"{name}.json"
        assert oct(path.stat().st_mode & 0o777) == "0o600"
        assert load_secret(fleet_dir, name, fleet).identity.public == fleet.nodes[name].public_bytes
    creds = (fleet_dir / "router" / "credentials.txt").read_text().split()
    assert sorted(c.split(":")[0] for c in creds) == ["A", "B", "V", "X", "d1"]
    assert (fleet_dir / "router" / "credentials.txt").stat().st_mode & 0o077 == 0


def test_init_refuses_to_overwrite(capsys, fleet_dir: Path):
    code, _, err = run_cli(capsys, "fleet", "init", "--dir", str(fleet_dir))
    assert code == 2 and err.count("\n") == 1 and "already exists" in err


def test_show_ok(capsys, fleet_dir: Path):
    code, out, err = run_cli(capsys, "fleet", "show", "--dir", str(fleet_dir), "--check-secrets")
    assert code == 0 and "d1" in out and "authorized: A,B" in out and err == ""


@pytest.mark.parametrize("edit, field", [
    (lambda f: f["nodes"]["d1"].__setitem__("sysid", "one"), "$.nodes.d1.sysid"),
    (lambda f: f["nodes"]["d1"].__setitem__("sysid", 300), "$.nodes.d1.sysid"),
    (lambda f: f["nodes"]["A"].__setitem__("public_key", "abc"), "$.nodes.A.public_key"),
    (lambda f: f["nodes"]["B"].__setitem__("sysid", 4), "$.nodes.B.sysid"),
    (lambda f: f["nodes"]["d1"].__setitem__("authorized_gs", ["Q"]), "$.nodes.d1.authorized_gs"),
    (lambda f: f["nodes"]["A"].pop("coverage"), "$.nodes.A.coverage"),
    (lambda f: f["nodes"]["A"].__setitem__("colour", "red"), "$.nodes.A"),
    (lambda f: f.__setitem__("version", 2), "$.version"),
])
def test_malformed_fleet_names_file_and_field(capsys, fleet_dir: Path, edit, field):
    path = fleet_dir / "fleet.json5"
    data = json.loads("\n".join(line for line in path.read_text().splitlines() if not line.startswith("//")))
    edit(data)
    path.write_text(json.dumps(data))
    code, _, err = run_cli(capsys, "fleet", "show", "--dir", str(fleet_dir))
    assert code == 2
    assert err.count("\n") == 1 and str(path) in err and field in err, err


def test_unparseable_fleet(capsys, tmp_path: Path):
    (tmp_path / "fleet.json5").write_text("{nodes: [1, 2,, }")
    code, _, err = run_cli(capsys, "fleet", "show", "--dir", str(tmp_path))
    assert code == 2 and "not valid JSON5" in err and err.count("\n") == 1


def test_missing_and_unreadable_paths(capsys, tmp_path: Path, fleet_dir: Path):
    code, _, err = run_cli(capsys, "fleet", "show", "--dir", str(tmp_path / "nope"))
    assert code == 2 and "no such file" in err
    (tmp_path / "d.json5").mkdir()
    code, _, err = run_cli(capsys, "fleet", "show", "--dir", str(tmp_path / "d.json5"))
    assert code == 2 and "cannot read" in err and err.count("\n") == 1


def test_key_file_with_wrong_permissions(capsys, fleet_dir: Path):
    key = fleet_dir / "secrets" / "A.json"
    os.chmod(key, 0o644)
    code, _, err = run_cli(capsys, "fleet", "show", "--dir", str(fleet_dir), "--check-secrets")
    assert code == 2 and "chmod 600" in err and str(key) in err and err.count("\n") == 1


def test_malformed_and_mismatched_key_files(fleet_dir: Path):
    key = fleet_dir / "secrets" / "A.json"
    key.write_text("{not json")
    with pytest.raises(Exception, match="malformed secret file"):
        load_secret(fleet_dir, "A")
    b = json.loads((fleet_dir / "secrets" / "B.json").read_text())
    b["name"] = "A"
    key.write_text(json.dumps(b))
    with pytest.raises(Exception, match="does not match the fleet's public key"):
        load_secret(fleet_dir, "A", load_fleet(fleet_dir))


def test_bad_cli_input_is_one_line(capsys):
    code, _, err = run_cli(capsys, "nonsense")
    assert code == 2 and err.startswith("zdrone: error:") and err.count("\n") == 1
    code, _, err = run_cli(capsys, "fleet", "show", "--bogus")
    assert code == 2 and err.count("\n") == 1


def test_parse_fleet_error_type():
    with pytest.raises(FleetError):
        parse_fleet("{version: 1, nodes: {d1: {role: 'plane', sysid: 1, public_key: ''}}}")


def test_console_script_help_and_exit_codes(tmp_path: Path):
    exe = Path(sys.executable).parent / "zdrone"
    out = subprocess.run([str(exe), "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "fleet" in out.stdout and "bench" in out.stdout
    out = subprocess.run([str(exe), "fleet", "show", "--dir", str(tmp_path)], capture_output=True, text=True)
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and "Traceback" not in out.stderr


def test_fleet_with_sites_makes_a_meshed_router_per_site(tmp_path):
    import json5
    import pytest

    from zdrone.core.errors import ConfigError
    from zdrone.fleet.files import init_fleet, load_sites

    eps = ["tls/127.0.0.1:17447", "tls/127.0.0.1:17448"]
    init_fleet(tmp_path / "f", sites=eps)
    sites = load_sites(tmp_path / "f")
    assert [s["endpoint"] for s in sites.values()] == eps
    assert sites["site-1"]["ground_stations"] == ["A", "X"] and sites["site-2"]["ground_stations"] == ["B"]
    s2 = json5.loads((tmp_path / "f" / "router" / "site-2.json5").read_text())
    assert s2["connect"]["endpoints"] == [mesh_endpoint(eps[0])] and s2["transport"]["link"]["tls"]["enable_mtls"]
    routers = [x for x in s2["access_control"]["subjects"] if x["id"] == "routers"]
    assert routers == [{"id": "routers", "cert_common_names": ["router-site-1"], "link_protocols": ["quic"]}]
    assert all("cert_common_names" in x for x in s2["access_control"]["subjects"])  # every subject by certificate
    assert (tmp_path / "f" / "router" / "site-2.key").stat().st_mode & 0o077 == 0
    with pytest.raises(ConfigError):
        init_fleet(tmp_path / "g", sites=["tcp/127.0.0.1:1", "tcp/127.0.0.1:2"])  # the mesh is TLS only


def test_fleet_with_three_sites_puts_gs_i_at_site_i_in_a_full_mesh(tmp_path):
    import json5

    from zdrone.fleet.files import init_fleet, load_sites, scale_nodes

    eps = [f"tls/127.0.0.1:{p}" for p in (17450, 17451, 17452)]
    init_fleet(tmp_path / "f", nodes_spec=scale_nodes(4, 3), tls=True, sites=eps)
    sites = load_sites(tmp_path / "f")
    assert {s: v["ground_stations"] for s, v in sites.items()} == {"site-1": ["A"], "site-2": ["B"], "site-3": ["C"]}
    for n, site in enumerate(sites):  # site n connects to sites 1..n-1: one link per pair
        cfg = json5.loads((tmp_path / "f" / "router" / f"{site}.json5").read_text())
        assert cfg["connect"]["endpoints"] == [mesh_endpoint(e) for e in eps[:n]]  # the mesh: QUIC
        assert cfg["listen"]["endpoints"] == [eps[n], mesh_endpoint(eps[n])]
        routers = next(x for x in cfg["access_control"]["subjects"] if x["id"] == "routers")
        assert routers["cert_common_names"] == [f"router-site-{i + 1}" for i in range(3) if i != n]
    creds = (tmp_path / "f" / "router" / "credentials.txt").read_text().split()
    assert sorted(c.split(":")[0] for c in creds if c.startswith("router-")) == [f"router-site-{i}" for i in (1, 2, 3)]
    assert all((tmp_path / "f" / "tls" / f"d{i}.crt").is_file() for i in range(1, 5))


def test_a_drones_sysid_is_unique_in_its_mavlink_network_and_a_gss_in_the_fleet(tmp_path):
    """More than 255 drones: each MAVLink network (what one GCS shows) has its own sysids; a GS's
    sysid names it to every drone's GCS, so no drone in any network may take it."""
    from zdrone.core.fleet import encode_fleet
    from zdrone.fleet.files import scale_nodes

    fleet = init_fleet(tmp_path / "f", nodes_spec=scale_nodes(300, 3))
    drones = [fleet.nodes[d] for d in fleet.drones()]
    assert len({(n.mavlink_net, n.sysid) for n in drones}) == 300 and max(n.sysid for n in drones) < 200
    assert parse_fleet(encode_fleet(fleet)) == fleet
    text = encode_fleet(fleet)
    with pytest.raises(FleetError, match=r"nodes\.d200\.sysid: 1 already used by d1"):  # the same network
        parse_fleet(text.replace('"mavlink_net": 1', '"mavlink_net": 0', 1))
    with pytest.raises(FleetError, match=r"\.sysid: 200 already used by A"):  # a GS's sysid, in another network
        parse_fleet(text.replace('"sysid": 2,', '"sysid": 200,').replace('"sysid": 1,\n      "public_key"', '"sysid": 1,\n      "public_key"'))
