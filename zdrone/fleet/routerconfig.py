"""The router's configuration: username/password auth and default-deny access control from the fleet.

The same file works for ``zdrone router -c`` (a Zenoh router in Python) and ``zenohd -c``.
Rules (the router checks ``ingress`` from the sender's session and ``egress`` to the receiver's):

* drone ``d``: publish on ``zdrone/d/down/*``, subscribe the lanes ``zdrone/d/up/*/<lane>``, answer pairing on
  ``zdrone/d/pair/*``;
* GS ``g``: publish on the lanes of its uplinks ``zdrone/*/up/g/<lane>`` (lanes 0..UP_LANES-1 only), subscribe ``zdrone/*/down/g``, declare and answer only its
  own ``backhaul/g/linkkey/*``; pair (``zdrone/d/pair/g``) and query ``backhaul/*/linkkey/d`` only for
  the drones ``d`` it is authorized for.

The ACL is the second wall: every exchange it allows is also authenticated end to end by the
fleet's static keys, so a leaked router password alone gets nothing.

Bounded in messages and bytes where a drone's radio begins, per credential where a credential is
more than a password. With TLS (a node is its certificate *and* its password) each GS ``g`` has one
budget per lane of its uplinks, ``zdrone/*/up/g/<lane>`` (Zenoh's downsampling), kept on **egress**
toward each drone's session: the router holds them once per session, and a drone's session only
ever carries its own uplinks, so the rule is one budget per (drone session, GS, lane) — every
session that writes as ``g`` (K parallel sessions with its certificate and password) shares it, and
no other GS's budget is touched; the rules grow with the GSs. Without TLS a leaked password is all
it takes to write as ``g``, and a budget shared with the thief would let it starve ``g`` itself: the
budgets are per sending session instead, one rule per (drone, lane) on **ingress** (a GS's session
may publish only its own lanes, so in it each rule is (drone, GS, lane)); they grow with the drones
(x ``UP_LANES`` rules, kept once per session) and K sessions get K budgets. Either way
``UPLINK_MAX_HZ`` puts/s over an uplink's lanes, each at most ``UPLINK_MAX_BYTES`` (Zenoh's low-pass
filter, on ingress: a bigger put never enters the router), so what one budget can push toward a drone
is bounded in bytes per second (``UPLINK_MAX_BYTES_S``), sized for a slow radio. Pairing queries
likewise (``PAIR_MAX_HZ``, ``PAIR_MAX_BYTES``).

The budgets apply to client transports only (``tcp``, ``tls``): site routers mesh over **QUIC**
(mutual TLS as well), so the backhaul between two routers — which carries every GS's frames for
every drone behind it — is never limited as if it were one drone; the ACL admits a node only over
``tcp``/``tls`` and a site router only over ``quic`` (a node's credentials over QUIC get nothing).

Fleet revisions (``zdrone.fleet.revisions``) travel on one key per sender, ``zdrone-fleet/revision/<g>``:
only GS ``g`` may put, declare a queryable and reply there; every node subscribes and queries
``zdrone-fleet/revision/*``. Each GS's key has its own budget: ``REVISION_MAX_HZ`` puts per second
from each sending session (on ingress: a flood with a GS's leaked credentials spends its own sessions'
budget, never the real GS's, whose signed stamps renew the drones' owner leases) and as many replies
per second toward each receiving session (egress), each at most ``REVISION_MAX_BYTES`` (low-pass on
ingress): the other GSs' revisions (the one revoking a flooder included) still reach every node. A
session asks at most ``REVISION_QUERY_HZ`` times per second (on ingress): a drone's leaked password
cannot make the GSs answer without end. These rules grow with the GSs, like the uplinks'.

Operations pictures (``zdrone.core.opspicture``, sealed end to end for the viewer) travel on
``OPS_LANES`` keys per GS, ``zdrone-ops/<g>/<lane>`` (part ``i`` of a picture on lane ``i``): only GS
``g`` may put there; only a viewer (role ``viewer``) may subscribe ``zdrone-ops/*/*`` and receive
them, and hear and ask for the fleet revisions like every node (so it follows revocations and
rotations live); it may do nothing else: no put, no queryable, no key that commands. A part is at
most ``OPS_MAX_BYTES`` (low-pass on ingress), and each (GS, lane) has a budget of ``OPS_LANE_HZ`` puts a
second on egress to the viewer (an honest GS publishes at most ``1 / OPS_MIN_GAP_S`` pictures a
second; the parts of one picture are on different lanes): whatever one GS's credential sends, the
viewer receives at most ``OPS_LANES * OPS_LANE_HZ`` of its parts a second.

Zenoh's limit is a minimum interval between puts on a key, measured when the router processes them,
with no burst allowance: a router that stalls (scheduling, load) processes the frames that waited back
to back and drops all but the first, at any rate (measured: ``experiments/router_stall.py``,
docs/results.md). So an uplink has ``UP_LANES`` keys, each with its own budget: the GS sends its frames
on the lanes in turn, one lane's frames ``UPLINK_LANE_GAP_S`` apart at least (``net/pacing.py``: four of
the lane's intervals), so that frames bunched by a stall are on different lanes. A burst of up to
``UP_LANES`` frames goes at once (a lane each); only frames beyond it wait, and the uplink's sustained
rate is ``1 / UPLINK_PACE_S``.

Not bounded here: the number of sessions one credential opens (Zenoh 1.x has one ``max_sessions``
for all, and no limit per username or certificate; with TLS extra sessions gain no budget), and a
holder of a GS's own certificate *and* password can spend that GS's budget toward a drone (it is that
GS as far as the network can tell: revoke it, ``zdrone fleet revoke``).
"""

from __future__ import annotations

import json
from typing import Any

from zdrone.core.fleet import Fleet
from zdrone.core.kk import MAX_MESSAGE
from zdrone.core.opspicture import OPS_MAX_BYTES
from zdrone.fleet import keyexprs

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
DEFAULT_TLS_LISTEN = "tls/127.0.0.1:7447"
#: The TLS fields of a router config that name files (resolved relative to the config file).
TLS_FILE_FIELDS = ("root_ca_certificate", "listen_certificate", "listen_private_key", "connect_certificate",
                   "connect_private_key")
#: The largest Zenoh message a router or node accepts (Zenoh's default is 1 GiB). zdrone's largest
#: is under 1 KiB; a bigger one is dropped by the receiving transport, and its sender's session stays.
MAX_MESSAGE_SIZE = 65536
#: Puts per second a router lets through toward a drone on each uplink ``zdrone/<drone>/up/<gs>``,
#: over all its lanes (``keyexprs.UP_LANES``), whoever sends them as ``<gs>``.
UPLINK_MAX_HZ = 200.0
#: Puts per second on each lane (Zenoh's downsampling: a put closer than 1/UPLINK_LANE_HZ s to the
#: previous one on that lane is dropped).
UPLINK_LANE_HZ = UPLINK_MAX_HZ / keyexprs.UP_LANES
#: A GS's frames on one uplink go out at most 1/UPLINK_PACE_S a second, sustained (50: a joystick's
#: MANUAL_CONTROL stream fits), on the lanes in turn ...
UPLINK_PACE_S = 4.0 / UPLINK_MAX_HZ
#: ... so that one lane's frames are at least this far apart: four of its router intervals, so that
#: delays on the way (a busy sender, batching) do not bring two closer than the limit. Up to UP_LANES
#: frames may go at once (a lane each; ``net/pacing.py``).
UPLINK_LANE_GAP_S = keyexprs.UP_LANES * UPLINK_PACE_S
#: The largest uplink put (a sealed envelope: one MAVLink frame, <= 280 bytes, or one small control
#: message, plus the envelope's 24): the router's low-pass filter drops a bigger one on ingress, and
#: the drone's own subscriber refuses it too (``net/inbox.py``).
UPLINK_MAX_BYTES = 512
#: What one credential can push toward one drone on an uplink, bytes/s: 0.8 Mbit/s, a fifth of a
#: 4 Mbit/s radio.
UPLINK_MAX_BYTES_S = UPLINK_MAX_HZ * UPLINK_MAX_BYTES
#: Pairing queries per second a router passes toward a drone from one GS (a GS re-pairing asks 5/s).
PAIR_MAX_HZ = 20.0
#: The largest pairing query (a Noise message and names, ``net/inbox.py``'s ``MAX_HANDSHAKE``).
PAIR_MAX_BYTES = MAX_MESSAGE + 256
#: The largest fleet revision a router passes and a node takes (put or reply, payload bytes): under
#: ``MAX_MESSAGE_SIZE`` with room for the message's own fields. A revision is cumulative; every list of
#: a 300-drone fleet changed is about 8 KB, every key rotated about 35 KB.
REVISION_MAX_BYTES = 60 * 1024
#: Revision puts per second, and as many replies, a router passes from one GS's revision key toward
#: each session (a GS pushes at most one put per ``2 / REVISION_MAX_HZ`` s: ``revisions.PUSH_GAP_S``).
REVISION_MAX_HZ = 2.0
#: What one credential can push toward one node on its revision key, bytes/s: 0.98 Mbit/s, under a
#: quarter of a 4 Mbit/s radio (replies only answer the node's own queries, a few a minute).
REVISION_MAX_BYTES_S = REVISION_MAX_HZ * REVISION_MAX_BYTES
#: Revision queries per second a router takes from one session (a node asks at most every
#: ``revisions.ASK_GAP_S``).
REVISION_QUERY_HZ = 1.0
#: Client transports: what the budgets and a node's ACL apply to. Site routers mesh over QUIC.
CLIENT_LINKS = ["tcp", "tls"]
MESH_LINK = "quic"


def _rule(rid: str, messages: list[str], flows: list[str], keys: list[str]) -> dict[str, Any]:
    return {"id": rid, "messages": messages, "flows": flows, "permission": "allow", "key_exprs": keys}


def access_control(fleet: Fleet, tls: bool = False, routers: tuple[str, ...] = ()) -> dict[str, Any]:
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    if routers:  # the other sites' routers (router-to-router over the backhaul, mutual TLS) carry everything
        rules.append(_rule("routers-all", ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply"],
                           ["ingress", "egress"], ["**"]))
        # by certificate only: a router-to-router link has a username on one side at most, but
        # mutual TLS shows each side the other's certificate
        subjects.append({"id": "routers", "cert_common_names": list(routers), "link_protocols": [MESH_LINK]})
        policies.append({"id": "policy-routers", "rules": ["routers-all"], "subjects": ["routers"]})

    def enrol(name: str, ids: list[str]) -> None:
        """Node ``name`` gets rules ``ids``; with TLS, a client is this node only with its certificate
        *and* its password."""
        subjects.append({"id": f"user-{name}", "usernames": [name], **({"cert_common_names": [name]} if tls else {}),
                         "link_protocols": CLIENT_LINKS})
        policies.append({"id": f"policy-{name}", "rules": ids, "subjects": [f"user-{name}"]})

    for name, node in fleet.nodes.items():
        if fleet.is_revoked(name):  # a revoked node (fleet revision) is no subject: it gets nothing
            continue
        ids: list[str] = []

        def add(suffix: str, messages: list[str], flows: list[str], keys: list[str]) -> None:
            rid = f"{name}-{suffix}"
            rules.append(_rule(rid, messages, flows, keys))
            ids.append(rid)

        if node.role == "viewer":  # reads the GSs' pictures sealed for it and the fleet's revisions, nothing else
            add("ops-sub", ["declare_subscriber"], ["ingress"], [keyexprs.ops_all()])
            add("ops-recv", ["put"], ["egress"], [keyexprs.ops_all()])  # bounded per (GS, lane): ops_downsampling
            add("revision", ["declare_subscriber", "query"], ["ingress"], [keyexprs.revision_all()])
            add("revision-recv", ["put", "reply"], ["egress"], [keyexprs.revision_all()])
            enrol(name, ids)
            continue
        if node.role == "drone":
            add("pub-down", ["put"], ["ingress"], [f"zdrone/{name}/down/*"])
            # exactly the lanes: a key under an uplink that is not one (unlimited: no rule) never reaches it
            add("sub-up", ["declare_subscriber"], ["ingress"], keyexprs.up_lanes(name, "*"))
            add("recv-up", ["put"], ["egress"], keyexprs.up_lanes(name, "*"))
            add("pair", ["declare_queryable", "reply"], ["ingress"], [keyexprs.pair_all(name)])
            add("pair-q", ["query"], ["egress"], [keyexprs.pair_all(name)])
        else:
            drones = [d for d in fleet.drones() if fleet.is_authorized(d, name)]
            add("pub-up", ["put"], ["ingress"], keyexprs.up_lanes("*", name))
            add("sub-down", ["declare_subscriber"], ["ingress"], [keyexprs.down("*", name)])
            add("recv-down", ["put"], ["egress"], [keyexprs.down("*", name)])
            add("linkkey-own", ["declare_queryable", "reply"], ["ingress"], [keyexprs.linkkey_all(name)])
            add("linkkey-own-q", ["query"], ["egress"], [keyexprs.linkkey_all(name)])
            if fleet.viewers():  # its operations picture, sealed for the viewer
                add("ops-own", ["put"], ["ingress"], keyexprs.ops_lanes(name))
            if drones:  # pairing and key sharing only for the drones this GS is authorized for
                add("pair", ["query"], ["ingress"], [keyexprs.pair(d, name) for d in drones])
                add("pair-r", ["reply"], ["egress"], [keyexprs.pair(d, name) for d in drones])
                add("linkkey-ask", ["query"], ["ingress"], [keyexprs.linkkey("*", d) for d in drones])
                add("linkkey-ans", ["reply"], ["egress"], [keyexprs.linkkey("*", d) for d in drones])
        # fleet revisions (signed by the fleet key, checked by every node): every node hears and asks
        # on every sender's key; a GS alone publishes and answers, on its own key only
        add("revision", ["declare_subscriber", "query"], ["ingress"], [keyexprs.revision_all()])
        add("revision-recv", ["put", "reply"], ["egress"], [keyexprs.revision_all()])
        if node.role != "drone":
            add("revision-own", ["put", "declare_queryable", "reply"], ["ingress"], [keyexprs.revision(name)])
            # the queries on every sender's key (a query names no GS): only GSs declare the queryable
            add("revision-q", ["query"], ["egress"], [keyexprs.revision_all()])
        enrol(name, ids)
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def uplink_downsampling(fleet: Fleet, per_credential: bool = True) -> list[dict[str, Any]]:
    """Zenoh downsampling of what GSs send toward the drones (uplink lanes and pairing queries).

    ``per_credential`` (a router that wants a node's certificate *and* password): one rule per (GS,
    lane) and one per GS's pairing key, on egress of client transports — a drone's session carries
    only its own uplinks, so each is one budget per (drone, GS, lane) shared by every session sending
    as that GS. Otherwise (a password is all it takes to be a GS, and passwords leak): one rule per
    (drone, lane) and per drone's pairing key, on ingress, so per sending session — a GS's session
    may publish only its own lanes (the ACL), so each is that session's budget for (drone, GS, lane),
    and a thief's sessions never spend the real GS's."""
    gss, drones = fleet.ground_stations(), fleet.drones()
    if not gss or not drones:
        return []
    if per_credential:
        flow = "egress"
        lanes = [keyexprs.up_lane("*", g, lane) for g in gss for lane in range(keyexprs.UP_LANES)]
        pairs = [keyexprs.pair("*", g) for g in gss]
    else:
        flow = "ingress"
        lanes = [keyexprs.up_lane(d, "*", lane) for d in drones for lane in range(keyexprs.UP_LANES)]
        pairs = [keyexprs.pair_all(d) for d in drones]
    return [{"id": "uplink-rate", "flows": [flow], "messages": ["put"], "link_protocols": CLIENT_LINKS,
             "rules": [{"key_expr": k, "freq": UPLINK_LANE_HZ} for k in lanes]},
            {"id": "pair-rate", "flows": [flow], "messages": ["query"], "link_protocols": CLIENT_LINKS,
             "rules": [{"key_expr": k, "freq": PAIR_MAX_HZ} for k in pairs]}]


def revision_downsampling(fleet: Fleet) -> list[dict[str, Any]]:
    """Zenoh downsampling of fleet revisions: one rule per GS's revision key, puts and replies each
    with a budget of their own (a push and the answer to a query never spend each other's): puts on
    ingress of client transports, one budget per sending session (a thief's sessions never spend the
    real GS's: its signed stamps renew the drones' owner leases), replies on egress, one budget per
    (receiving session, GS); and one rule on ingress bounding each session's revision queries."""
    gss = [g for g in fleet.ground_stations() if not fleet.is_revoked(g)]
    if not gss:
        return []
    rules = [{"key_expr": keyexprs.revision(g), "freq": REVISION_MAX_HZ} for g in gss]
    # puts (the GSs' pushes and stamps) on ingress: per sending session, so a flood with a GS's leaked
    # credentials spends its own sessions' budget, never the real GS's (its stamps renew the drones' leases)
    return [{"id": "revision-put-rate", "flows": ["ingress"], "messages": ["put"], "link_protocols": CLIENT_LINKS,
             "rules": rules},
            {"id": "revision-reply-rate", "flows": ["egress"], "messages": ["reply"], "link_protocols": CLIENT_LINKS,
             "rules": rules}] + [
            {"id": "revision-query-rate", "flows": ["ingress"], "messages": ["query"], "link_protocols": CLIENT_LINKS,
             "rules": [{"key_expr": keyexprs.revision_all(), "freq": REVISION_QUERY_HZ}]}]


#: Puts a second on each lane of a GS's operations picture, at the viewer's egress (an honest GS: at
#: most 10 pictures a second, one part of each on a lane)
OPS_LANE_HZ = 12.0


def ops_downsampling(fleet: Fleet) -> list[dict[str, Any]]:
    """Zenoh downsampling of the GSs' operations pictures: one rule per (GS, lane) on egress of client
    transports, so one budget per (viewer session, GS, lane) shared by every session sending as that GS."""
    gss = [g for g in fleet.ground_stations() if not fleet.is_revoked(g)]
    if not gss or not fleet.viewers():
        return []
    return [{"id": "ops-rate", "flows": ["egress"], "messages": ["put"], "link_protocols": CLIENT_LINKS,
             "rules": [{"key_expr": k, "freq": OPS_LANE_HZ} for g in gss for k in keyexprs.ops_lanes(g)]}]


def size_limits(fleet: Fleet) -> list[dict[str, Any]]:
    """Zenoh's low-pass filter on ingress: the largest uplink put and pairing query (bytes of payload
    and attachment); a bigger one is dropped where it enters the router."""
    if not fleet.drones():
        return []
    return [{"id": "uplink-size", "flows": ["ingress"], "messages": ["put"], "key_exprs": ["zdrone/*/up/**"],
             "size_limit": UPLINK_MAX_BYTES},
            {"id": "pair-size", "flows": ["ingress"], "messages": ["query"], "key_exprs": ["zdrone/*/pair/*"],
             "size_limit": PAIR_MAX_BYTES}]


def ops_size_limits(fleet: Fleet) -> list[dict[str, Any]]:
    """Zenoh's low-pass filter on ingress: the largest part of an operations picture."""
    if not fleet.viewers():
        return []
    return [{"id": "ops-size", "flows": ["ingress"], "messages": ["put"], "key_exprs": [keyexprs.ops_all()],
             "size_limit": OPS_MAX_BYTES}]


def revision_size_limits() -> list[dict[str, Any]]:
    """Zenoh's low-pass filter on ingress: the largest revision put or reply (``REVISION_MAX_BYTES``)."""
    return [{"id": "revision-size", "flows": ["ingress"], "messages": ["put", "reply"],
             "key_exprs": [keyexprs.revision_all()], "size_limit": REVISION_MAX_BYTES}]


def router_config(fleet: Fleet, credentials_file: str, listen: str | None = None, tls: bool = False) -> dict[str, Any]:
    """The router's config; with ``tls``, mutual TLS only (paths relative to the router directory)."""
    link: dict[str, Any] = {"rx": {"max_message_size": MAX_MESSAGE_SIZE}}
    if tls:
        link["tls"] = {"root_ca_certificate": "../tls/ca.crt", "listen_certificate": "router.crt",
                       "listen_private_key": "router.key", "connect_certificate": "router.crt",
                       "connect_private_key": "router.key", "enable_mtls": True}
    return {
        "mode": "router",
        "listen": {"endpoints": [listen or (DEFAULT_TLS_LISTEN if tls else DEFAULT_LISTEN)]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"dictionary_file": credentials_file}},
                      "link": link,
                      # shared memory would carry big messages between processes of one host around
                      # the size limit (and zdrone's messages are small): off
                      "shared_memory": {"enabled": False}},
        "access_control": access_control(fleet, tls),
        "downsampling": uplink_downsampling(fleet, per_credential=tls) + revision_downsampling(fleet)
        + ops_downsampling(fleet),
        "low_pass_filter": size_limits(fleet) + revision_size_limits() + ops_size_limits(fleet),
    }


#: A site router's and a drone's per-site session's lease (ms) and keep-alives per lease: a dead path
#: (radio out of range, router hung) is given up after 1 s of silence.
SITE_LEASE_MS = 1000
SITE_KEEP_ALIVE = 4


def site_router_config(fleet: Fleet, credentials_file: str, site: str, listen: str, peers: list[str],
                       peer_routers: tuple[str, ...], password: str) -> dict[str, Any]:
    """The router of one site, mutual TLS only: the fleet's ACL for its clients (certificate CN and
    username) on ``listen`` (``tls/HOST:PORT``), and a mesh link to the routers in ``peers`` (their
    client endpoints; the mesh runs over QUIC on the same host and port, ``mesh_endpoint``;
    router-to-router, certificate ``router-<site>``); the other sites' routers (``peer_routers``,
    their CNs) may carry everything."""
    cfg = router_config(fleet, credentials_file, listen, tls=True)
    cfg["listen"]["endpoints"].append(mesh_endpoint(listen))
    peers = [mesh_endpoint(p) for p in peers]
    tls = cfg["transport"]["link"]["tls"]
    for field in ("listen_certificate", "connect_certificate"):
        tls[field] = f"{site}.crt"
    for field in ("listen_private_key", "connect_private_key"):
        tls[field] = f"{site}.key"
    cfg["connect"] = {"endpoints": peers, "retry": {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 1.5}}
    # a radio out of range or a hung router closes nothing: each side must notice the silence, well
    # inside the drone's 3 s loss threshold (Zenoh's default lease is 10 s)
    cfg["transport"]["link"]["tx"] = {"lease": SITE_LEASE_MS, "keep_alive": SITE_KEEP_ALIVE}
    cfg["transport"]["auth"]["usrpwd"].update({"user": f"router-{site}", "password": password})  # to the others
    cfg["access_control"] = access_control(fleet, tls=True, routers=peer_routers)
    return cfg


def mesh_endpoint(endpoint: str) -> str:
    """The router-to-router (QUIC) endpoint of a site router whose client endpoint is ``endpoint``
    (``tls/HOST:PORT`` -> ``quic/HOST:PORT``: UDP, the same port number)."""
    proto, _, addr = endpoint.partition("/")
    if proto not in ("tls", "quic") or not addr:
        raise ValueError(f"{endpoint!r}: a site router's endpoint is tls/HOST:PORT")
    return f"{MESH_LINK}/{addr}"


def render(config: dict[str, Any], header: str = "") -> str:
    text = json.dumps(config, indent=2) + "\n"
    return (header + "\n" if header else "") + text


HEADER = """// zdrone router: Zenoh router configuration (valid for `zdrone router -c` and `zenohd -c`).
// Generated by `zdrone fleet init` from fleet.json5: username/password auth, default-deny ACL.
// TLS: add a tls/ endpoint to listen.endpoints and set transport.link.tls (see README)."""
