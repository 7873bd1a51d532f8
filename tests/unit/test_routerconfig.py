"""The router's access-control rules follow the fleet; the repository's router.json5 stays in sync."""

import json5

from pathlib import Path

from zdrone.core.fleet import Coverage, Fleet, Node
from zdrone.core.reference import COVERAGE_RADIUS_M, DEFAULT_NODES
from zdrone.fleet.routerconfig import router_config

ROOT = Path(__file__).resolve().parents[2]


def default_fleet() -> Fleet:
    nodes = {n: Node(role=r, sysid=s, public_key="A" * 43 + "=",  # type: ignore[arg-type]
                     coverage=Coverage(c.lat, c.lon, COVERAGE_RADIUS_M) if c else None, authorized_gs=a)
             for n, r, s, c, a in DEFAULT_NODES}
    return Fleet(version=1, nodes=nodes)


def test_repository_router_json5_matches_the_default_fleet():
    on_disk = json5.loads((ROOT / "router.json5").read_text())
    assert on_disk == router_config(default_fleet(), "fleet/router/credentials.txt")


def test_acl_is_default_deny_and_scoped_per_identity():
    acl = router_config(default_fleet(), "c.txt")["access_control"]
    assert acl["enabled"] and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["d1-pub-down"]["key_exprs"] == ["zdrone/d1/down/*"] and rules["d1-pub-down"]["messages"] == ["put"]
    assert rules["A-pub-up"]["key_exprs"] == [f"zdrone/*/up/A/{i}" for i in range(8)]  # its lanes, nothing else
    assert rules["d1-sub-up"]["key_exprs"] == rules["d1-recv-up"]["key_exprs"] == [f"zdrone/d1/up/*/{i}" for i in range(8)]
    assert rules["B-linkkey-own"]["key_exprs"] == ["backhaul/B/linkkey/*"]
    assert rules["A-linkkey-ask"]["key_exprs"] == ["backhaul/*/linkkey/d1"]
    assert "X-linkkey-ask" not in rules  # X is not authorized for any drone: it may not ask for keys
    assert not any(r["id"].startswith("d1-") and "query" in r["messages"] and "ingress" in r["flows"] for r in acl["rules"])
    subjects = {s["id"]: s["usernames"] for s in acl["subjects"]}
    assert subjects == {"user-d1": ["d1"], "user-A": ["A"], "user-B": ["B"], "user-X": ["X"]}


def test_each_uplink_lane_has_its_own_rate_limit_per_sending_session():
    """Bounded ingress: one downsampling rule per (drone, GS, lane), on ingress (per sending
    session), so a flood on up/B spends up/B's budget only, UPLINK_MAX_HZ over its lanes; a GS paces
    its frames so that one lane's are far above the lane's interval."""
    from zdrone.fleet import keyexprs as kx
    from zdrone.fleet.routerconfig import UPLINK_LANE_HZ, UPLINK_MAX_HZ, UPLINK_PACE_S

    (ds,) = router_config(default_fleet(), "c.txt")["downsampling"]
    assert ds["flows"] == ["ingress"] and ds["messages"] == ["put"]
    assert {r["key_expr"] for r in ds["rules"]} == {f"zdrone/d1/up/{g}/{i}" for g in "ABX" for i in range(kx.UP_LANES)}
    assert len(ds["rules"]) == 3 * kx.UP_LANES  # no key twice (each rule its own budget)
    assert all(r["freq"] == UPLINK_LANE_HZ for r in ds["rules"])
    assert UPLINK_LANE_HZ * kx.UP_LANES == UPLINK_MAX_HZ
    assert kx.UP_LANES * UPLINK_PACE_S >= 20 / UPLINK_LANE_HZ


def test_lanes_are_keys_of_their_uplink_and_name_its_gs():
    from zdrone.fleet import keyexprs as kx

    assert kx.up_lane("d1", "A", 3) == "zdrone/d1/up/A/3" == kx.lane_of(kx.up("d1", "A"), 3)
    assert kx.gs_of_uplink("zdrone/d1/up/A/3") == "A"
    import pytest
    for bad in (-1, kx.UP_LANES):
        with pytest.raises(ValueError):
            kx.up_lane("d1", "A", bad)


def test_every_site_router_limits_the_uplink_keys_too():
    """A site router's clients (and the mesh's copies) meet the same per-lane limit."""
    from zdrone.fleet.routerconfig import site_router_config, uplink_downsampling

    cfg = site_router_config(default_fleet(), "c.txt", "site-2", "tls/127.0.0.1:7448", ["tls/127.0.0.1:7447"],
                             ("router-site-1",), "pw")
    assert cfg["downsampling"] == uplink_downsampling(default_fleet()) != []
