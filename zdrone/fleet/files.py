"""Fleet files on disk: ``zdrone fleet init`` writes them, every node loads them.

Layout of a fleet directory::

    fleet.json5                  public: nodes, sysids, public keys, coverage, authorized lists
    secrets/<name>.json          private (mode 0600): the node's X25519 key, Ed25519 signing key and router password
    offline/fleet-signing.json   private (mode 0600): the fleet's Ed25519 signing key (signs revisions);
                                 stays on the offline machine like tls/ca.key: never in a bundle
    revision.json                public: the latest signed fleet revision (``zdrone fleet revoke`` ...);
    revisions/<n>.json           every one made (on the issuing machine)

``load_fleet`` gives the *effective* fleet: ``fleet.json5`` with the latest valid revision found
beside it, or in the node's state directory (``$ZDRONE_STATE_DIR/revision.json``, where a node
keeps the revisions it received); ``load_base_fleet`` the file alone.
    router/credentials.txt       private (mode 0600): user:password lines for the router
    router/router.json5          the router's config: auth from credentials.txt, default-deny ACL
"""

from __future__ import annotations

import json
import os
import secrets
import stat
from dataclasses import dataclass
from pathlib import Path

import msgspec

from zdrone.core.fleet import ConfigError, Coverage, Fleet, Home, Node, encode_fleet, parse_fleet
from zdrone.core.keys import Identity, SigningKey, b64, unb64

from zdrone.core.revision import Revision, RevisionAccepted, apply_revision, check_revision  # types built at import
from zdrone.core.geometry import GeoPoint, offset
from zdrone.core.reference import COVERAGE_RADIUS_M, DEFAULT_NODES, HOME

FLEET_FILE = "fleet.json5"
#: the fleet signing key's file, relative to the fleet directory (``load_fleet_signing_key``)
FLEET_SIGNING_FILE = "offline/fleet-signing.json"


@dataclass(frozen=True, slots=True, repr=False)
class NodeSecret:
    """What only one node knows: its static key, its router password and its Ed25519 signing key
    (None in a fleet made before nodes had one). ``signing.sign(msg)``; the public half is
    ``fleet.signing_public(name)``."""

    name: str
    identity: Identity
    router_password: str
    signing: SigningKey | None = None

    def __repr__(self) -> str:
        return f"NodeSecret({self.name})"


class _SecretFile(msgspec.Struct, forbid_unknown_fields=True):
    name: str
    private_key: str
    router_password: str
    signing_key: str = ""


class _FleetSigningFile(msgspec.Struct, forbid_unknown_fields=True):
    fleet_signing_key: str


#: built at import, in one thread: a Struct type's first use from two threads at once can crash
#: (``zdrone.core.fleet``)
_SECRET_FILE = msgspec.json.Decoder(_SecretFile)
_FLEET_SIGNING_FILE = msgspec.json.Decoder(_FleetSigningFile)


def fleet_path(where: str | Path) -> Path:
    p = Path(where)
    return p if p.suffix in (".json5", ".json") else p / FLEET_FILE


def write_durably(path: Path, data: bytes, writer: str = "") -> None:
    """Replace ``path`` with ``data`` atomically and durably, mode 0600: a temporary file written and
    fsynced, renamed over ``path``, the directory fsynced (a crash leaves the old file or the new).
    ``writer`` names the temporary file when several writers share the folder."""
    tmp = path.with_suffix(path.suffix + (f".{writer}" if writer else "") + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.fchmod(fd, 0o600)
        os.write(fd, data)
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, path)
    dfd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


def _write_private(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
    os.chmod(path, 0o600)


#: The most drones ``bench scale`` flies.
MAX_SCALE_DRONES = 300


def scale_nodes(drones: int, stations: int) -> list[tuple]:
    """A fleet for ``bench scale``: GSs A, B, C… 500 m apart eastwards; every drone authorized for all."""
    if not 1 <= drones <= MAX_SCALE_DRONES or not 2 <= stations <= 26:
        raise ConfigError(f"scale fleet: 1..{MAX_SCALE_DRONES} drones and 2..26 ground stations")
    gss = [chr(ord("A") + i) for i in range(stations)]
    nodes: list[tuple] = [(gs, "gs", 200 + i, offset(HOME, 0.0, 500.0 * i), []) for i, gs in enumerate(gss)]
    # sysids 1..199 in each MAVLink network (a GS's sysid is 200 + i)
    nodes += [(f"d{i + 1}", "drone", 1 + i % 199, None, list(gss), i // 199) for i in range(drones)]
    return nodes + [("V", "viewer", 250, None, [])]  # the viewer (``zdrone view``, ``bench view``)


#: A corridor's coverage radius as a share of the spacing of its GSs: neighbours overlap by a quarter of
#: the spacing along the line (571 m at 8 GSs over 16 km: 48 s at 12 m/s), no point is covered by three.
CORRIDOR_RADIUS_OF_SPACING = 0.625


def corridor_layout(stations: int, length_m: float) -> tuple[float, float]:
    """A corridor of ``stations`` GSs evenly along ``length_m`` metres eastwards from home: (spacing,
    coverage radius) in metres."""
    spacing = length_m / max(1, stations - 1)
    return spacing, CORRIDOR_RADIUS_OF_SPACING * spacing


def corridor_nodes(drones: int, stations: int, length_m: float) -> list[tuple]:
    """A corridor fleet (``bench scale --layout corridor``, ``demo --scenario corridor``): GSs A, B, C…
    evenly along ``length_m`` metres eastwards from home (``corridor_layout``); every drone authorized
    for all of them (its links follow it: ``Fleet.links_max``)."""
    if not 1 <= drones <= MAX_SCALE_DRONES or not 2 <= stations <= 26:
        raise ConfigError(f"corridor fleet: 1..{MAX_SCALE_DRONES} drones and 2..26 ground stations")
    spacing, _ = corridor_layout(stations, length_m)
    gss = [chr(ord("A") + i) for i in range(stations)]
    nodes: list[tuple] = [(gs, "gs", 200 + i, offset(HOME, 0.0, spacing * i), []) for i, gs in enumerate(gss)]
    nodes += [(f"d{i + 1}", "drone", 1 + i % 199, None, list(gss), i // 199) for i in range(drones)]
    return nodes + [("V", "viewer", 250, None, [])]


#: A new fleet's owner lease (s): an owner that alone reaches its drone (the rest of the fleet crashed,
#: or cut it off and revoked it) keeps it this long at most, then the drone takes a covered heir or its
#: failsafe; long enough for an honest owner whose fleet crashed to bring the reference flight home at
#: speed-up 1 (``gs-crash``). ``zdrone fleet init --revision-lease``, ``zdrone fleet revise --lease``.
DEFAULT_REVISION_LEASE_S = 300.0


def init_fleet(directory: str | Path, force: bool = False,
               nodes_spec: list[tuple] | None = None,
               tls: bool = False, sites: list[str] | None = None,
               revision_lease: float = DEFAULT_REVISION_LEASE_S, coverage_radius_m: float = COVERAGE_RADIUS_M) -> Fleet:
    """Write the fleet (default: d1, A, B, X), one secret file per node and router credentials;
    with ``tls`` also a fleet CA and certificates, and a router config that requires them; with
    ``sites`` (one router endpoint per site, two or more) also a router config per site;
    ``revision_lease``: the owners' lease (``Fleet.revision_lease``; 0: none); ``coverage_radius_m``: every
    GS's coverage radius."""
    d = Path(directory)
    if d.exists() and not d.is_dir():
        raise ConfigError(f"{d}: exists and is not a directory")
    if (d / FLEET_FILE).exists() and not force:
        raise ConfigError(f"{d / FLEET_FILE}: already exists (use --force to overwrite)")
    d.mkdir(parents=True, exist_ok=True)
    nodes: dict[str, Node] = {}
    creds: list[str] = []
    for name, role, sysid, centre, authorized, *net in nodes_spec or DEFAULT_NODES:  # net: the MAVLink network
        ident, signing = Identity.generate(), SigningKey.generate()
        password = secrets.token_urlsafe(18)
        cov = Coverage(centre.lat, centre.lon, coverage_radius_m) if centre is not None else None
        nodes[name] = Node(role=role, sysid=sysid, public_key=b64(ident.public), coverage=cov,  # type: ignore[arg-type]
                           authorized_gs=list(authorized), signing_key=b64(signing.public),
                           mavlink_net=net[0] if net else 0)
        write_secret(d, NodeSecret(name, ident, password, signing))
        creds.append(f"{name}:{password}")
    fleet_signing = SigningKey.generate()
    _write_private(d / FLEET_SIGNING_FILE, json.dumps({"fleet_signing_key": b64(fleet_signing.private)}, indent=2) + "\n")
    site_names = [f"site-{i + 1}" for i in range(len(sites or []))]
    site_passwords = {site: secrets.token_urlsafe(18) for site in site_names}  # for the router mesh
    creds += [f"router-{site}:{pw}" for site, pw in site_passwords.items()]
    fleet = Fleet(version=1, nodes=nodes, home=Home(HOME.lat, HOME.lon, HOME.alt), fleet_key=b64(fleet_signing.public),
                  revision_lease=revision_lease)
    (d / FLEET_FILE).write_text("// zdrone fleet: public, shared by every node\n" + encode_fleet(fleet))
    _write_private(d / "router" / "credentials.txt", "\n".join(creds) + "\n")
    from zdrone.fleet.routerconfig import HEADER, render, router_config

    if tls or sites:  # sites are meshed over mutual TLS
        from zdrone.fleet.tls import init_tls

        from zdrone.fleet.tls import DEFAULT_ROUTER_HOSTS

        # a site router's certificate also names the host of its endpoint (its radio address)
        hosts = tuple(dict.fromkeys(DEFAULT_ROUTER_HOSTS + tuple(ep.split("/", 1)[-1].rsplit(":", 1)[0]
                                                                   for ep in sites or ())))
        init_tls(d, fleet, router_hosts=hosts, sites=site_names)
    (d / "router" / "router.json5").write_text(render(router_config(fleet, "credentials.txt", tls=tls), HEADER))
    if sites:
        _write_sites(d, fleet, sites, site_passwords)
    return fleet


def write_secret(d: Path, secret: NodeSecret) -> None:
    """Write ``secrets/<name>.json`` (mode 0600) in fleet directory ``d``."""
    raw = {"name": secret.name, "private_key": b64(secret.identity.private), "router_password": secret.router_password}
    if secret.signing is not None:
        raw["signing_key"] = b64(secret.signing.private)
    _write_private(d / "secrets" / f"{secret.name}.json", json.dumps(raw, indent=2) + "\n")


def load_fleet_signing_key(where: str | Path, fleet: Fleet | None = None) -> SigningKey:
    """The fleet's Ed25519 signing key from ``offline/fleet-signing.json`` of a fleet directory (it is
    in no bundle); refuses a file readable by others or one that does not match ``fleet.fleet_key``."""
    path = fleet_path(where).parent / FLEET_SIGNING_FILE
    try:
        mode = stat.S_IMODE(path.stat().st_mode)
        data = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"{path}: no fleet signing key (it is kept on the machine that ran 'zdrone fleet init', "
                          f"never in a bundle)") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.__class__.__name__}") from None
    if mode & 0o077:
        raise ConfigError(f"{path}: key file is accessible by others (mode {mode:04o}); run chmod 600 {path}")
    try:
        key = SigningKey(unb64(_FLEET_SIGNING_FILE.decode(data).fleet_signing_key, 32))
    except (msgspec.DecodeError, msgspec.ValidationError, ValueError) as exc:
        raise ConfigError(f"{path}: malformed fleet signing key file: {str(exc).splitlines()[0]}") from None
    if fleet is not None and fleet.fleet_key_bytes != key.public:
        raise ConfigError(f"{path}: does not match the fleet's fleet_key")
    return key


def _write_sites(d: Path, fleet: Fleet, endpoints: list[str], passwords: dict[str, str]) -> None:
    """One router per site, meshed over mutual TLS (site n connects to sites 1..n-1):
    ``router/site-<n>.json5`` (private: it holds its router's password for the mesh) and
    ``router/sites.json`` (public: each site's endpoint and GSs)."""
    names = list(passwords)
    from zdrone.fleet.routerconfig import HEADER, render, site_router_config

    if len(endpoints) < 2:
        raise ConfigError("--sites: at least two site routers")
    if not all(ep.startswith("tls/") for ep in endpoints):
        raise ConfigError("--sites: site routers are meshed over mutual TLS: give tls/HOST:PORT endpoints")
    gss = fleet.ground_stations()
    layout = {site: {"endpoint": ep, "ground_stations": [g for i, g in enumerate(gss) if i % len(names) == n]}
              for n, (site, ep) in enumerate(zip(names, endpoints))}
    for n, site in enumerate(names):
        lower = [layout[s]["endpoint"] for s in names[:n]]  # one link per pair of sites
        cfg = site_router_config(fleet, "credentials.txt", site, endpoints[n], lower,
                                 tuple(f"router-{s}" for s in names if s != site), passwords[site])
        _write_private(d / "router" / f"{site}.json5", render(cfg, HEADER))
    (d / "router" / "sites.json").write_text(json.dumps(layout, indent=2) + "\n")


def load_sites(where: str | Path) -> dict[str, dict]:
    """``router/sites.json``: site -> {endpoint, ground_stations} (``ConfigError`` if there is none)."""
    path = fleet_path(where).parent / "router" / "sites.json"
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: no sites (run 'zdrone fleet init --sites EP,EP')") from None


REVISION_FILE = "revision.json"
STATE_DIR_ENV = "ZDRONE_STATE_DIR"


def revision_paths(where: str | Path) -> list[Path]:
    """Where a node's latest revision may be: beside fleet.json5, and its state directory's copy."""
    out = [fleet_path(where).parent / REVISION_FILE]
    state = os.environ.get(STATE_DIR_ENV)
    if state:
        out.append(Path(state) / REVISION_FILE)
    return out


def load_revision(where: str | Path, base: Fleet | None = None) -> "Revision | None":
    """The latest valid revision kept for this fleet (or bundle) folder, None if there is none;
    ``ConfigError`` if a kept one is not valid for the fleet (tampered, another fleet's)."""

    base = base if base is not None else load_base_fleet(where)
    best = None
    for got in read_revisions(revision_paths(where), base):
        if best is None or got.revision.number > best.number:
            best = got.revision
    return best


def read_revisions(paths: "list[Path]", base: Fleet) -> "list[RevisionAccepted]":
    """The revisions in ``paths`` (a missing file is skipped), each checked against ``base``;
    ``ConfigError`` (one line) for one that cannot be read or is not a valid revision of this fleet."""
    out = []
    for path in paths:
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            continue
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read: {exc.__class__.__name__}") from None
        got = check_revision(data, base, None)
        if not isinstance(got, RevisionAccepted):
            raise ConfigError(f"{path}: not a valid revision of this fleet ({got.reason.value})")
        out.append(got)
    return out


def load_fleet(where: str | Path, base: Fleet | None = None) -> Fleet:
    """The effective fleet: ``fleet.json5`` (a path to it or to its directory) with the latest
    revision kept for it (``load_revision``); ``base``: ``fleet.json5`` already parsed (it is then the
    same object when no revision is kept: a node parses its fleet once)."""

    base = load_base_fleet(where) if base is None else base
    rev = load_revision(where, base)
    return apply_revision(base, rev) if rev is not None else base


def load_base_fleet(where: str | Path) -> Fleet:
    """Load and validate ``fleet.json5`` (a path to it or to its directory), no revision applied."""
    path = fleet_path(where)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file (run 'zdrone fleet init --dir {path.parent}' to make one)") from None
    except (PermissionError, IsADirectoryError, UnicodeDecodeError, OSError) as exc:
        raise ConfigError(f"{path}: cannot read: {exc.__class__.__name__}") from None
    return parse_fleet(text, str(path))


def load_secret(where: str | Path, name: str, fleet: Fleet | None = None) -> NodeSecret:
    """Load node ``name``'s secret file; refuse one readable by group or others."""
    base = fleet_path(where).parent
    path = base / "secrets" / f"{name}.json"
    try:
        st = path.stat()
    except FileNotFoundError:
        raise ConfigError(f"{path}: no secret file for node {name!r}") from None
    mode = stat.S_IMODE(st.st_mode)
    if mode & 0o077:
        raise ConfigError(f"{path}: key file is accessible by others (mode {mode:04o}); run chmod 600 {path}")
    try:
        raw = _SECRET_FILE.decode(path.read_bytes())
        ident = Identity(unb64(raw.private_key, 32))
        signing = SigningKey(unb64(raw.signing_key, 32)) if raw.signing_key else None
    except (msgspec.DecodeError, msgspec.ValidationError, ValueError) as exc:
        raise ConfigError(f"{path}: malformed secret file: {str(exc).splitlines()[0]}") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.__class__.__name__}") from None
    if raw.name != name:
        raise ConfigError(f"{path}: field $.name: is {raw.name!r}, expected {name!r}")
    if fleet is not None:
        node = fleet.nodes.get(name)
        if node is None:
            raise ConfigError(f"{path}: node {name!r} is not in the fleet")
        if node.public_bytes != ident.public:
            raise ConfigError(f"{path}: private key does not match the fleet's public key for {name!r}")
        if node.signing_public_bytes is not None and (signing is None or signing.public != node.signing_public_bytes):
            raise ConfigError(f"{path}: signing key does not match the fleet's signing_key for {name!r}")
    return NodeSecret(name, ident, raw.router_password, signing)
