"""Every Zenoh key expression zdrone uses. No other module spells one out."""

from __future__ import annotations


#: A GS's uplink to a drone travels on this many keys ("lanes") in turn, each with its own rate
#: budget at the router (``fleet/routerconfig.py``): frames that a stalled router processes back to
#: back are on different lanes, so the per-key minimum interval drops none of them.
UP_LANES = 8


def up(drone: str, gs: str) -> str:
    """GS -> drone: the name of link (drone, gs)'s uplink (what its frames are sealed to); they
    travel on its lanes (``up_lane``)."""
    return f"zdrone/{drone}/up/{gs}"


def up_lane(drone: str, gs: str, lane: int) -> str:
    """One lane of link (drone, gs)'s uplink: the key a GS publishes its sealed frames on."""
    return lane_of(up(drone, gs), lane)


def up_lanes(drone: str, gs: str) -> list[str]:
    """Every lane of link (drone, gs)'s uplink (``drone`` or ``gs`` may be ``*``)."""
    return [lane_of(up(drone, gs), lane) for lane in range(UP_LANES)]


def lane_of(uplink: str, lane: int) -> str:
    """The key of lane ``lane`` of the uplink named ``uplink`` (``up(drone, gs)``)."""
    if not 0 <= lane < UP_LANES:
        raise ValueError(f"lane {lane} not in 0..{UP_LANES - 1}")
    return f"{uplink}/{lane}"


def down(drone: str, gs: str) -> str:
    """drone -> GS: sealed telemetry and control messages of link (drone, gs)."""
    return f"zdrone/{drone}/down/{gs}"


def pair(drone: str, gs: str) -> str:
    """Noise KK pairing: the GS queries, the drone's queryable replies."""
    return f"zdrone/{drone}/pair/{gs}"


def pair_all(drone: str) -> str:
    return f"zdrone/{drone}/pair/*"


def linkkey(gs: str, drone: str) -> str:
    """Queryable declared by ``gs``: Noise KK key sharing, a fresh key for link (drone, gs)."""
    return f"backhaul/{gs}/linkkey/{drone}"


def linkkey_all(gs: str) -> str:
    return f"backhaul/{gs}/linkkey/*"


def gs_of_uplink(keyexpr: str) -> str:
    """The fourth chunk: the GS of an uplink lane ``zdrone/<drone>/up/<gs>/<lane>``."""
    return str(keyexpr).split("/")[3]


def gs_of(keyexpr: str) -> str:
    """The last chunk: the GS of an up/down/pair key expression."""
    return str(keyexpr).rsplit("/", 1)[-1]


def drone_of(keyexpr: str) -> str:
    """The second chunk: the drone of a ``zdrone/<drone>/...`` key expression."""
    return str(keyexpr).split("/")[1]


def revision(sender: str) -> str:
    """Fleet revisions (``zdrone.core.revision``) as GS ``sender`` publishes them (its pushes, its
    answers to revision queries, ``zdrone fleet publish`` with its credentials): one key per sender,
    so the router budgets each sender on its own (``fleet/routerconfig.py``). Signed by the fleet
    key, so any GS may hand one on. Its first chunk is no ``zdrone/<drone>`` key: a node may be
    named ``fleet``."""
    return f"zdrone-fleet/revision/{sender}"


def revision_all() -> str:
    """Every sender's revision key: what every node subscribes to and asks."""
    return "zdrone-fleet/revision/*"


#: Lanes of a GS's operations picture: part ``i`` of a picture goes on lane ``i`` (the last lane takes
#: the rest), each lane with its own router budget (``OPS_LANE_HZ``), so one GS's parts per second are
#: bounded at the router (a picture of 300 drones is about 6 parts).
OPS_LANES = 8


def ops(gs: str) -> str:
    """GS ``gs``'s operations picture, sealed for the fleet's viewer (``zdrone.core.opspicture``): the
    name its parts are sealed under; they travel on its lanes (``ops_lane``)."""
    return f"zdrone-ops/{gs}"


def ops_lane(gs: str, lane: int) -> str:
    """Lane ``lane`` of GS ``gs``'s picture: only ``gs`` may put there, only a viewer subscribes."""
    return f"zdrone-ops/{gs}/{lane}"


def ops_lanes(gs: str) -> list[str]:
    return [ops_lane(gs, i) for i in range(OPS_LANES)]


def gs_of_ops(keyexpr: str) -> str:
    """The GS of an operations picture's lane ``zdrone-ops/<gs>/<lane>``."""
    return str(keyexpr).split("/")[1]


def ops_all() -> str:
    """Every GS's operations picture, every lane: what a viewer subscribes to."""
    return "zdrone-ops/*/*"
