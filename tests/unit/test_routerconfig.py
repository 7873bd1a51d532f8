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
    assert not any(r["id"].startswith("d1-") and "query" in r["messages"] and "ingress" in r["flows"]
                   and r["id"] != "d1-revision" for r in acl["rules"])  # a drone asks for nothing but revisions
    subjects = {s["id"]: s["usernames"] for s in acl["subjects"]}
    assert subjects == {"user-d1": ["d1"], "user-A": ["A"], "user-B": ["B"], "user-X": ["X"], "user-V": ["V"]}


def test_with_tls_each_gs_has_one_budget_per_lane_toward_each_drone_session():
    """Bounded per credential (certificate and password): one downsampling rule per (GS, lane) on
    egress of client transports — a drone's session carries only its own uplinks, so each rule is one
    budget per (drone, GS, lane) that every session sending as that GS shares; the rules grow with the
    GSs, not drones x GSs."""
    from zdrone.fleet import keyexprs
    from zdrone.fleet.routerconfig import (PAIR_MAX_HZ, UPLINK_LANE_GAP_S, UPLINK_LANE_HZ, UPLINK_MAX_HZ, UPLINK_PACE_S)

    ups, pairs, *_revisions = router_config(default_fleet(), "c.txt", tls=True)["downsampling"]
    assert ups["flows"] == pairs["flows"] == ["egress"] and ups["messages"] == ["put"] and pairs["messages"] == ["query"]
    assert ups["link_protocols"] == pairs["link_protocols"] == ["tcp", "tls"]  # never the mesh (QUIC)
    assert {r["key_expr"] for r in ups["rules"]} == {f"zdrone/*/up/{g}/{i}" for g in "ABX" for i in range(keyexprs.UP_LANES)}
    assert len(ups["rules"]) == 3 * keyexprs.UP_LANES  # no key twice (each rule its own budget)
    assert all(r["freq"] == UPLINK_LANE_HZ for r in ups["rules"])
    assert {r["key_expr"]: r["freq"] for r in pairs["rules"]} == {f"zdrone/*/pair/{g}": PAIR_MAX_HZ for g in "ABX"}
    assert UPLINK_LANE_HZ * keyexprs.UP_LANES == UPLINK_MAX_HZ
    assert UPLINK_LANE_GAP_S >= 4 / UPLINK_LANE_HZ  # a lane's frames four of its intervals apart
    assert UPLINK_LANE_GAP_S / keyexprs.UP_LANES == UPLINK_PACE_S  # sustained: a frame per pace


def test_with_a_password_alone_each_sending_session_has_its_own_budget_per_drone_and_lane():
    """A leaked password is all it takes to write as a GS without TLS: the budgets are per sending
    session (ingress), one rule per (drone, lane), so a thief's sessions never spend the real GS's."""
    from zdrone.fleet import keyexprs

    ups, pairs, *_revisions = router_config(default_fleet(), "c.txt")["downsampling"]
    assert ups["flows"] == pairs["flows"] == ["ingress"]
    assert {r["key_expr"] for r in ups["rules"]} == {f"zdrone/d1/up/*/{i}" for i in range(keyexprs.UP_LANES)}
    assert [r["key_expr"] for r in pairs["rules"]] == ["zdrone/d1/pair/*"]


def test_the_policy_grows_with_nodes_not_with_drones_times_stations():
    from zdrone.fleet.files import scale_nodes

    def size(k: int) -> tuple[int, int]:
        nodes = {n: Node(role=r, sysid=s, public_key="A" * 43 + "=", coverage=None, authorized_gs=a)  # type: ignore[arg-type]
                 for n, r, s, _c, a, *_net in scale_nodes(k, 3)}
        cfg = router_config(Fleet(version=1, nodes=nodes), "c.txt", tls=True)
        return sum(len(d["rules"]) for d in cfg["downsampling"]), len(cfg["access_control"]["rules"])

    assert size(10)[0] == size(100)[0]  # budgets (with TLS): per GS only
    assert size(100)[1] - size(10)[1] == 90 * (size(11)[1] - size(10)[1])  # ACL rules: linear in the nodes


def test_uplinks_and_pairing_queries_are_bounded_in_bytes_on_ingress():
    """The drone's own size limit, enforced where a put enters the router."""
    from zdrone.fleet.routerconfig import PAIR_MAX_BYTES, UPLINK_MAX_BYTES, UPLINK_MAX_BYTES_S
    from zdrone.net.inbox import MAX_HANDSHAKE

    by_id = {d["id"]: d for d in router_config(default_fleet(), "c.txt")["low_pass_filter"]}
    ups, pairs = by_id["uplink-size"], by_id["pair-size"]
    assert ups["flows"] == ["ingress"] and ups["key_exprs"] == ["zdrone/*/up/**"] and ups["size_limit"] == UPLINK_MAX_BYTES
    assert pairs["messages"] == ["query"] and pairs["size_limit"] == PAIR_MAX_BYTES == MAX_HANDSHAKE
    assert UPLINK_MAX_BYTES_S * 8 <= 4_000_000 / 4  # a credential's uplink: at most a quarter of a 4 Mbit/s radio


def test_nodes_only_over_client_links_and_routers_only_over_the_mesh():
    from zdrone.fleet.routerconfig import access_control

    acl = access_control(default_fleet(), tls=True, routers=("router-site-2",))
    by_id = {s["id"]: s for s in acl["subjects"]}
    assert by_id["routers"]["link_protocols"] == ["quic"]
    assert all(s["link_protocols"] == ["tcp", "tls"] for i, s in by_id.items() if i != "routers")


def test_lanes_are_keys_of_their_uplink_and_name_its_gs():
    from zdrone.fleet import keyexprs

    assert keyexprs.up_lane("d1", "A", 3) == "zdrone/d1/up/A/3" == keyexprs.lane_of(keyexprs.up("d1", "A"), 3)
    assert keyexprs.gs_of_uplink("zdrone/d1/up/A/3") == "A"
    import pytest
    for bad in (-1, keyexprs.UP_LANES):
        with pytest.raises(ValueError):
            keyexprs.up_lane("d1", "A", bad)


def test_every_site_router_limits_its_clients_and_meshes_over_quic():
    """A site router's clients meet the same budgets; its mesh links are QUIC on the same ports."""
    from zdrone.fleet.routerconfig import (mesh_endpoint, ops_downsampling, revision_downsampling, site_router_config,
                                           uplink_downsampling)

    cfg = site_router_config(default_fleet(), "c.txt", "site-2", "tls/127.0.0.1:7448", ["tls/127.0.0.1:7447"],
                             ("router-site-1",), "pw")
    assert cfg["downsampling"] == (uplink_downsampling(default_fleet()) + revision_downsampling(default_fleet())
                                   + ops_downsampling(default_fleet()))
    assert uplink_downsampling(default_fleet()) != [] != revision_downsampling(default_fleet())
    assert cfg["downsampling"][0]["flows"] == ["egress"]  # mutual TLS: per credential
    assert cfg["listen"]["endpoints"] == ["tls/127.0.0.1:7448", "quic/127.0.0.1:7448"]
    assert cfg["connect"]["endpoints"] == ["quic/127.0.0.1:7447"]
    assert mesh_endpoint("tls/10.0.0.1:7447") == "quic/10.0.0.1:7447"
    import pytest
    with pytest.raises(ValueError):
        mesh_endpoint("tcp/10.0.0.1:7447")


def test_revisions_have_one_key_and_one_budget_per_sending_gs():
    """Only GS g puts, declares a queryable and replies on zdrone-fleet/revision/g; every node hears
    and asks every sender's key; drones never answer. Each GS's key has its own budget toward each
    session (puts and replies apart), bounded in bytes, and each session's queries are bounded: the
    rules grow with the GSs."""
    from zdrone.fleet import keyexprs
    from zdrone.fleet.revisions import ASK_GAP_S, MAX_REVISION_BYTES, PUSH_GAP_S, PUSH_PERIOD_S
    from zdrone.fleet.routerconfig import (MAX_MESSAGE_SIZE, REVISION_MAX_BYTES, REVISION_MAX_BYTES_S, REVISION_MAX_HZ,
                                           REVISION_QUERY_HZ)

    cfg = router_config(default_fleet(), "c.txt")
    rules = {r["id"]: r for r in cfg["access_control"]["rules"]}
    assert keyexprs.revision("A") == "zdrone-fleet/revision/A" and keyexprs.revision_all() == "zdrone-fleet/revision/*"
    for n in ("d1", "A", "B", "X"):
        assert rules[f"{n}-revision"]["messages"] == ["declare_subscriber", "query"]
        assert rules[f"{n}-revision"]["key_exprs"] == rules[f"{n}-revision-recv"]["key_exprs"] == [keyexprs.revision_all()]
        assert rules[f"{n}-revision-recv"]["flows"] == ["egress"]
    for g in ("A", "B", "X"):  # its own key only
        own = rules[f"{g}-revision-own"]
        assert own["key_exprs"] == [keyexprs.revision(g)] and own["flows"] == ["ingress"]
        assert own["messages"] == ["put", "declare_queryable", "reply"]
    assert "d1-revision-own" not in rules and "d1-revision-q" not in rules  # a drone publishes and answers nothing
    assert not any(keyexprs.revision("d1") in r["key_exprs"] for r in cfg["access_control"]["rules"])

    by_id = {d["id"]: d for d in cfg["downsampling"]}
    for m, flow in (("put", "ingress"), ("reply", "egress")):  # puts: per sending session
        d = by_id[f"revision-{m}-rate"]
        assert d["flows"] == [flow] and d["messages"] == [m] and d["link_protocols"] == ["tcp", "tls"]
        assert d["rules"] == [{"key_expr": keyexprs.revision(g), "freq": REVISION_MAX_HZ} for g in "ABX"]
    q = by_id["revision-query-rate"]
    assert q["flows"] == ["ingress"] and q["messages"] == ["query"]
    assert q["rules"] == [{"key_expr": keyexprs.revision_all(), "freq": REVISION_QUERY_HZ}]
    (size,) = [f for f in cfg["low_pass_filter"] if f["id"] == "revision-size"]
    assert size == {"id": "revision-size", "flows": ["ingress"], "messages": ["put", "reply"],
                    "key_exprs": [keyexprs.revision_all()], "size_limit": REVISION_MAX_BYTES}
    assert MAX_REVISION_BYTES == REVISION_MAX_BYTES < MAX_MESSAGE_SIZE - 1024  # a router passes the largest
    assert REVISION_MAX_BYTES_S * 8 <= 4_000_000 / 4  # one credential: at most a quarter of a 4 Mbit/s radio
    # an honest node never meets its budget: a GS's puts two intervals apart, a node's queries too
    assert PUSH_GAP_S >= 2 / REVISION_MAX_HZ and ASK_GAP_S >= 2 / REVISION_QUERY_HZ and PUSH_PERIOD_S > PUSH_GAP_S


def test_a_revoked_gs_has_no_revision_budget_or_rights():
    import msgspec

    cfg = router_config(msgspec.structs.replace(default_fleet(), revoked=frozenset({"B"})), "c.txt")
    assert not any(r["id"].startswith("B-") for r in cfg["access_control"]["rules"])
    by_id = {d["id"]: d for d in cfg["downsampling"]}
    # a flood with a GS's leaked credentials spends its own sessions' budget (ingress), never the real
    # GS's: found by review, the stamps that renew the drones' leases were starved on egress
    assert by_id["revision-put-rate"]["flows"] == ["ingress"] and by_id["revision-reply-rate"]["flows"] == ["egress"]
    assert {r["key_expr"] for r in by_id["revision-put-rate"]["rules"]} == {"zdrone-fleet/revision/A",
                                                                           "zdrone-fleet/revision/X"}
