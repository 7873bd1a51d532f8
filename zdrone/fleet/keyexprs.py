"""Every Zenoh key expression zdrone uses. No other module spells one out."""

from __future__ import annotations


def up(drone: str, gs: str) -> str:
    """GS -> drone: sealed MAVLink and control messages of link (drone, gs)."""
    return f"zdrone/{drone}/up/{gs}"


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


def gs_of(keyexpr: str) -> str:
    """The last chunk: the GS of an up/down/pair key expression."""
    return str(keyexpr).rsplit("/", 1)[-1]


def drone_of(keyexpr: str) -> str:
    """The second chunk: the drone of a ``zdrone/<drone>/...`` key expression."""
    return str(keyexpr).split("/")[1]
