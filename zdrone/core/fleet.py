"""The fleet: every node's public identity, each GS's coverage, each drone's authorized GSs.

``fleet.json5`` is public and shared by all nodes. Parsing is pure (text in, ``Fleet`` out) and
validated with msgspec; every problem is a ``FleetError`` naming the file, the field and what is
wrong, so the CLI can print one line.
"""

from __future__ import annotations

from zdrone.core.errors import ConfigError

from typing import Any, Annotated, Literal

import json5
import msgspec

from zdrone.core.geometry import Circle, GeoPoint
from zdrone.core.keys import unb64, verify_signature
from zdrone.core.uplink import UplinkPolicy

SysId = Annotated[int, msgspec.Meta(ge=1, le=255)]
Name = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_-]{1,32}$")]


class FleetError(ConfigError):
    pass


class Coverage(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    lat: Annotated[float, msgspec.Meta(ge=-90, le=90)]
    lon: Annotated[float, msgspec.Meta(ge=-180, le=180)]
    radius_m: Annotated[float, msgspec.Meta(gt=0)]

    def circle(self) -> Circle:
        return Circle(GeoPoint(self.lat, self.lon), self.radius_m)


class Node(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    #: a "viewer" (``zdrone view``) only reads the GSs' operations pictures sealed for it
    #: (``zdrone.core.opspicture``): no coverage, no link to any drone, nothing it may publish; its
    #: sysid is reserved (unique like a GS's) and never spoken
    role: Literal["drone", "gs", "viewer"]
    sysid: SysId
    public_key: str
    coverage: Coverage | None = None
    authorized_gs: list[Name] = []
    uplink: UplinkPolicy = UplinkPolicy()  # drones only: what a GS may send up (zdrone.core.uplink)
    signing_key: str = ""  # the node's Ed25519 public key (what it signs, e.g. its authority record)
    #: drones only: the MAVLink network the drone's sysid is unique in (a GCS that shows drones together
    #: shows one network; a fleet of more than 255 drones spreads them over several)
    mavlink_net: Annotated[int, msgspec.Meta(ge=0, le=255)] = 0

    @property
    def public_bytes(self) -> bytes:
        return unb64(self.public_key, 32)

    @property
    def signing_public_bytes(self) -> bytes | None:
        """The node's Ed25519 public key (32 bytes), None in a fleet made before nodes had one."""
        return unb64(self.signing_key, 32) if self.signing_key else None


class Home(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    lat: Annotated[float, msgspec.Meta(ge=-90, le=90)]
    lon: Annotated[float, msgspec.Meta(ge=-180, le=180)]
    alt: float = 0.0


class Fleet(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The parsed, validated fleet."""

    version: Literal[1]
    nodes: dict[Name, Node]
    home: Home | None = None
    #: the fleet's Ed25519 public key, pinned by every bundle: the only key a fleet revision
    #: (``zdrone.core.revision``) is signed with; its private half stays offline with the CA key
    fleet_key: str = ""
    #: pairing and key sharing add ML-KEM-768 to X25519 (``zdrone.core.kk``); once on, a classical
    #: pairing is refused (no downgrade)
    pairing_pq: bool = False
    #: the owner's lease (s; 0: none): from its first pairing a drone's owner keeps authority only while
    #: the drone hears, within this long, a signed revision stamp from a GS *other than the owner*
    #: (``zdrone.core.revision.RevisionStamp``); a signed revision may change it
    revision_lease: Annotated[float, msgspec.Meta(ge=0, le=86400)] = 0.0
    #: the live links a drone holds at most (``zdrone.core.linkplan``): a drone authorized for more GSs
    #: than this holds links only with the GSs that cover it and the next on its course, and closes the
    #: others'; one authorized for this many or fewer keeps a link with each
    links_max: Annotated[int, msgspec.Meta(ge=2, le=64)] = 3
    #: set by a fleet revision (``zdrone.core.revision.apply_revision``), never in fleet.json5: the
    #: revision in force (0: none) and the nodes it revoked
    revision: int = 0
    revoked: frozenset[Name] = frozenset()

    def is_revoked(self, name: str) -> bool:
        return name in self.revoked

    def gs_signed(self, gs: str, message: bytes, signature: bytes) -> bool:
        """Whether ``signature`` over ``message`` is GS ``gs``'s, under its signing key in force (a GS of
        the fleet, not revoked): a revision stamp's, a keys-lost notice's."""
        node = self.nodes.get(gs)
        if node is None or node.role != "gs" or self.is_revoked(gs):
            return False
        key = node.signing_public_bytes
        return key is not None and verify_signature(key, message, signature)

    @property
    def fleet_key_bytes(self) -> bytes | None:
        """The fleet signing public key (32 bytes), None in a fleet made before it had one."""
        return unb64(self.fleet_key, 32) if self.fleet_key else None

    def signing_public(self, name: str) -> bytes | None:
        """Node ``name``'s Ed25519 public key (``KeyError`` if no such node; None if it has none)."""
        return self.node(name).signing_public_bytes

    def node(self, name: str) -> Node:
        try:
            return self.nodes[name]
        except KeyError:
            raise KeyError(f"no node named {name!r} in the fleet") from None

    def drones(self) -> list[str]:
        return [n for n, v in self.nodes.items() if v.role == "drone"]

    def ground_stations(self) -> list[str]:
        return [n for n, v in self.nodes.items() if v.role == "gs"]

    def viewers(self) -> list[str]:
        """The nodes that read the GSs' operations pictures (``zdrone view``), revoked ones left out."""
        return [n for n, v in self.nodes.items() if v.role == "viewer" and n not in self.revoked]

    def is_authorized(self, drone: str, gs: str) -> bool:
        node = self.nodes.get(drone)
        return (node is not None and node.role == "drone" and gs in node.authorized_gs
                and gs not in self.revoked and drone not in self.revoked)

    def links_follow(self, drone: str) -> bool:
        """Whether ``drone``'s links follow it (``links_max``): it is authorized for more GSs than that."""
        node = self.nodes.get(drone)
        return node is not None and len(node.authorized_gs) > self.links_max

    def by_sysid(self, sysid: int) -> str | None:
        for name, node in self.nodes.items():
            if node.sysid == sysid:
                return name
        return None


#: msgspec builds a Struct type's validation info on the type's first use, and two threads doing it at
#: once can crash the process (SIGSEGV: a bench's flights, each in a thread of its own, parsed their
#: fleets at the same moment). Built here, once, at import: parsing a fleet never builds it.
_BUILT_AT_IMPORT = (msgspec.json.Decoder(Fleet), msgspec.json.Decoder(Node))


def read_json5(text: str) -> Any:
    """JSON5 text: what zdrone writes (``encode_fleet``, router configs) is plain JSON after a header of
    ``//`` lines, read fast (the JSON5 parser takes seconds over a fleet of 300 drones); anything else
    (a hand-edited file) by the JSON5 parser. ``ValueError`` if neither reads it."""
    body = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("//"))
    try:
        return msgspec.json.decode(body)
    except msgspec.DecodeError:
        return json5.loads(text)


def parse_fleet(text: str, source: str = "fleet.json5") -> Fleet:
    """Parse and validate fleet text. Raises ``FleetError`` with a one-line message."""
    try:
        raw = read_json5(text)
    except ValueError as exc:
        raise FleetError(f"{source}: not valid JSON5: {str(exc).splitlines()[0]}") from None
    # Nodes are validated one by one so an error names the node ($.nodes.d1.sysid, not $.nodes[...]).
    nodes_raw = raw.get("nodes") if isinstance(raw, dict) else None
    if isinstance(nodes_raw, dict):
        nodes: dict[str, Node] = {}
        for name, node_raw in nodes_raw.items():
            try:
                nodes[name] = msgspec.convert(node_raw, Node)
            except msgspec.ValidationError as exc:
                raise FleetError(f"{source}: {_where(exc, f'$.nodes.{name}')}") from None
        raw = {**raw, "nodes": {n: msgspec.to_builtins(v) for n, v in nodes.items()}}
    try:
        fleet = msgspec.convert(raw, Fleet)
    except msgspec.ValidationError as exc:
        raise FleetError(f"{source}: {_where(exc)}") from None
    _check(fleet, source)
    return fleet


def _where(exc: msgspec.ValidationError, prefix: str = "$") -> str:
    msg = str(exc)
    if " - at `" in msg:
        what, at = msg.rsplit(" - at `", 1)
        return f"field {prefix}{at.rstrip('`')[1:]}: {what}"
    return f"field {prefix}: {msg}"


def _check(fleet: Fleet, source: str) -> None:
    try:
        fleet.fleet_key_bytes
    except ValueError as exc:
        raise FleetError(f"{source}: field $.fleet_key: {exc}") from None
    seen: dict[tuple[int | None, int], str] = {}  # (MAVLink network, None for a GS; sysid) -> node
    nets: set[int | None] = {None} | {n.mavlink_net for n in fleet.nodes.values() if n.role == "drone"}
    for name, node in fleet.nodes.items():
        where = f"{source}: field $.nodes.{name}"
        try:
            node.public_bytes
        except ValueError as exc:
            raise FleetError(f"{where}.public_key: {exc}") from None
        try:
            node.signing_public_bytes
        except ValueError as exc:
            raise FleetError(f"{where}.signing_key: {exc}") from None
        # a GS's sysid is unique in the whole fleet (it names the GS to every drone's GCS); a drone's
        # within its MAVLink network
        taken = [seen.get((net, node.sysid)) for net in (nets if node.role != "drone" else (node.mavlink_net, None))]
        if any(taken):
            raise FleetError(f"{where}.sysid: {node.sysid} already used by {next(t for t in taken if t)}")
        seen[(node.mavlink_net if node.role == "drone" else None, node.sysid)] = name
        if node.role != "drone" and node.mavlink_net:
            raise FleetError(f"{where}.mavlink_net: only drones have a MAVLink network")
        if node.role == "viewer":
            if node.coverage is not None or node.authorized_gs or not node.uplink.is_default:
                raise FleetError(f"{where}: a viewer has no coverage, authorized list or uplink policy")
            continue
        if node.role == "gs":
            if node.coverage is None:
                raise FleetError(f"{where}.coverage: a ground station needs a coverage circle")
            if node.authorized_gs:
                raise FleetError(f"{where}.authorized_gs: only drones have an authorized list")
            if not node.uplink.is_default:
                raise FleetError(f"{where}.uplink: only drones have an uplink policy")
        else:
            for gs in node.authorized_gs:
                other = fleet.nodes.get(gs)
                if other is None or other.role != "gs":
                    raise FleetError(f"{where}.authorized_gs: {gs!r} is not a ground station of the fleet")


def encode_fleet(fleet: Fleet) -> str:
    """Serialize a fleet as (JSON-compatible) JSON5 text; a default ``uplink`` is left out."""
    raw = msgspec.to_builtins(fleet)
    if not fleet.fleet_key:
        raw.pop("fleet_key", None)
    for field, default in (("revision", 0), ("revoked", [])):
        if raw.get(field) == default:
            raw.pop(field, None)
    if not fleet.pairing_pq:
        raw.pop("pairing_pq", None)
    if not fleet.revision_lease:
        raw.pop("revision_lease", None)
    for name, node in fleet.nodes.items():
        if node.uplink.is_default:
            del raw["nodes"][name]["uplink"]
        if not node.signing_key:
            raw["nodes"][name].pop("signing_key", None)
        if not node.mavlink_net:
            raw["nodes"][name].pop("mavlink_net", None)
    return msgspec.json.format(msgspec.json.encode(raw), indent=2).decode() + "\n"
