"""Changing a fleet after its bundles left: ``zdrone fleet revoke | rotate | revise | publish``.

Each change is made on the machine that holds the fleet directory (and its offline keys) and gives
the next signed revision (``zdrone.core.revision``): ``revisions/<n>.json`` and ``revision.json``
(the latest), and the router files regenerated from the effective fleet (a revoked node has no
password in ``router/credentials.txt`` and is no ACL subject; a rotated node has its new password,
and with TLS a new certificate).

* ``revoke NODE``: the node is out for good: every drone drops its links, erases its keys and
  refuses its requests; the routers refuse its password and certificate once restarted on the
  regenerated files.
* ``rotate NODE [--out DIR] [--password]``: a new X25519 key and Ed25519 signing key for NODE, its
  new public keys in the revision, its bundle re-exported. A running GS adopts the new key in flight
  (its station re-pairs every drone under it, make-before-break); with ``--password`` also a new
  router password (and with TLS a new key and certificate), which take effect at the node's restart.
* ``revise [--authorize DRONE=GS,GS] [--coverage GS=LAT,LON,RADIUS] [--pairing-pq on|off]``.
* ``publish --fleet BUNDLE --id NODE --router EP``: put the latest revision on the fleet's revision
  key through a router, as NODE (any node of the fleet may relay a revision: it is signed).

A revision reaches the nodes over Zenoh (``zdrone.fleet.revisions``: each node subscribes, asks at
start and on reconnect, answers others' queries, and keeps the latest in its state directory).
"""

from __future__ import annotations

import json
import os
import secrets
from typing import Any, Callable
from dataclasses import dataclass
from pathlib import Path

from zdrone.core.errors import ConfigError
from zdrone.core.fleet import Coverage, Fleet
from zdrone.core.keys import Identity, SigningKey
from zdrone.core.revision import (Changes, Revision, apply_revision, encode_revision, make_revision, next_changes,
                             with_authorized, with_coverage, with_keys, with_lease, with_revoked)
from zdrone.fleet.files import (REVISION_FILE, NodeSecret, _write_private, _write_sites, fleet_path, load_base_fleet,
                    load_fleet_signing_key, load_revision, load_secret, write_secret)

REVISIONS_DIR = "revisions"


@dataclass(frozen=True, slots=True)
class Revised:
    """What a change wrote: the revision, the effective fleet under it, the files."""

    revision: Revision
    fleet: Fleet
    path: Path


def _fleet_dir(where: str | Path) -> Path:
    d = fleet_path(where).parent
    if (d / "bundle.json").is_file():
        raise ConfigError(f"{d}: a node's bundle: revisions are made in the fleet directory (with its offline keys)")
    return d


def _next(d: Path, change, note: str) -> Revised:
    """Sign the revision after the one in force, with ``change(changes) -> changes``; write it and the
    router files."""
    base = load_base_fleet(d)
    key = load_fleet_signing_key(d, base)
    current = load_revision(d, base)
    number = (current.number if current is not None else 0) + 1
    rev = make_revision(base, number, change(next_changes(current)), key, note=note)
    fleet = apply_revision(base, rev)
    data = encode_revision(rev)
    (d / REVISIONS_DIR).mkdir(exist_ok=True)
    path = d / REVISIONS_DIR / f"{number:04d}.json"
    path.write_bytes(data)
    tmp = d / (REVISION_FILE + ".tmp")
    tmp.write_bytes(data)
    os.chmod(tmp, 0o644)
    os.replace(tmp, d / REVISION_FILE)
    regenerate_router_files(d, fleet)
    return Revised(rev, fleet, path)


def _node(base: Fleet, node: str, role: str | None = None) -> None:
    if node not in base.nodes:
        raise ConfigError(f"node {node!r}: not in the fleet ({', '.join(base.nodes)})")
    if role is not None and base.nodes[node].role != role:
        raise ConfigError(f"node {node!r}: not a {'ground station' if role == 'gs' else role}")


def _live_node(where: str | Path, node: str, revoked: str) -> Path:
    """The fleet directory, once ``node`` is known to be a node of it not revoked yet (``revoked``:
    what to say if it is)."""
    d = _fleet_dir(where)
    base = load_base_fleet(d)
    _node(base, node)
    current = load_revision(d, base)
    if current is not None and node in current.changes.revoked:
        raise ConfigError(f"node {node!r}: {revoked} (revision {current.number})")
    return d


def revoke(where: str | Path, node: str, note: str = "") -> Revised:
    d = _live_node(where, node, "already revoked")
    return _next(d, lambda c: with_revoked(c, node), note or f"revoke {node}")


def rotate(where: str | Path, node: str, out: str | Path | None = None, note: str = "",
           password: bool = False) -> Revised:
    """New keys for ``node`` (and with ``password`` a new router password and TLS certificate); its
    bundle re-exported into ``out`` (a new folder)."""
    d = _live_node(where, node, "revoked: a revoked node is not rotated")
    if out is not None and Path(out).exists() and (not Path(out).is_dir() or any(Path(out).iterdir())):
        raise ConfigError(f"{out}: exists and is not an empty folder (a bundle is written into a new one)")
    ident, signing = Identity.generate(), SigningKey.generate()
    old = load_secret(d, node)  # the old one is sound (and the folder writable) before anything changes
    revised = _next(d, lambda c: with_keys(c, node, ident.public, signing.public), note or f"rotate {node}")
    # a crash right here leaves the revision with the new keys and the old secret: load_secret names
    # the mismatch, and rotating again makes a fresh pair under the next revision
    write_secret(d, NodeSecret(node, ident, secrets.token_urlsafe(18) if password else old.router_password, signing))
    if password and (d / "tls" / "ca.key").is_file():
        _reissue_certificate(d, node)
    regenerate_router_files(d, revised.fleet)
    if out is not None:
        from zdrone.fleet.bundle import export_bundle

        export_bundle(d, node, out)
    return revised


def revise(where: str | Path, authorize: dict[str, list[str]] | None = None,
           coverage: dict[str, Coverage] | None = None, pairing_pq: bool | None = None, note: str = "",
           lease: float | None = None) -> Revised:
    d = _fleet_dir(where)
    base = load_base_fleet(d)
    for drone in authorize or {}:
        _node(base, drone, "drone")
    for gs in coverage or {}:
        _node(base, gs, "gs")
    if not authorize and not coverage and pairing_pq is None and lease is None:
        raise ConfigError("zdrone fleet revise: nothing to change (--authorize, --coverage, --pairing-pq or --lease)")
    if lease is not None and not 0 <= lease <= 86400:
        raise ConfigError(f"zdrone fleet revise: --lease {lease:g}: seconds from 0 (none) to 86400")

    def change(c: Changes) -> Changes:
        for drone, gss in (authorize or {}).items():
            c = with_authorized(c, drone, gss)
        for gs, cov in (coverage or {}).items():
            c = with_coverage(c, gs, cov)
        if pairing_pq is not None:
            import msgspec

            c = msgspec.structs.replace(c, pairing_pq=pairing_pq)
        if lease is not None:
            c = with_lease(c, lease)
        return c

    return _next(d, change, note or "revise")


def regenerate_router_files(d: Path, fleet: Fleet) -> None:
    """``router/credentials.txt`` (the nodes not revoked, and the site routers' mesh passwords),
    ``router/router.json5`` and each site's config, from the effective fleet."""
    from zdrone.fleet.routerconfig import HEADER, render, router_config

    creds_path = d / "router" / "credentials.txt"
    old = dict(line.split(":", 1) for line in creds_path.read_text().splitlines() if ":" in line)
    creds = [f"{n}:{load_secret(d, n).router_password}" for n in fleet.nodes if not fleet.is_revoked(n)]
    site_passwords = {u.removeprefix("router-"): pw for u, pw in old.items() if u.startswith("router-site-")}
    creds += [f"router-{site}:{pw}" for site, pw in site_passwords.items()]
    _write_private(creds_path, "\n".join(creds) + "\n")
    router_json = d / "router" / "router.json5"
    tls = "root_ca_certificate" in router_json.read_text() if router_json.is_file() else False
    router_json.write_text(render(router_config(fleet, "credentials.txt", tls=tls), HEADER))
    sites_file = d / "router" / "sites.json"
    if sites_file.is_file():
        layout = json.loads(sites_file.read_text())
        _write_sites(d, fleet, [layout[s]["endpoint"] for s in layout], {s: site_passwords[s] for s in layout})


def _reissue_certificate(d: Path, node: str) -> None:
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    from zdrone.fleet.tls import _pem_key, _write, issue, node_files

    ca = x509.load_pem_x509_certificate((d / "tls" / "ca.crt").read_bytes())
    ca_key = serialization.load_pem_private_key((d / "tls" / "ca.key").read_bytes(), password=None)
    cert, key = issue(ca, ca_key, node)  # type: ignore[arg-type]
    files = node_files(d, node)
    _write(files.cert, cert.public_bytes(serialization.Encoding.PEM), private=False)
    _write(files.key, _pem_key(key), private=True)


def parse_authorize(specs: list[str]) -> dict[str, list[str]]:
    """``DRONE=GS,GS`` options (one line naming the bad one)."""
    out: dict[str, list[str]] = {}
    for spec in specs:
        drone, sep, gss = spec.partition("=")
        if not sep or not drone:
            raise ConfigError(f"--authorize {spec!r}: expected DRONE=GS,GS")
        out[drone] = [g for g in gss.split(",") if g]
    return out


def parse_coverage(specs: list[str]) -> dict[str, Coverage]:
    """``GS=LAT,LON,RADIUS_M`` options."""
    import msgspec

    out: dict[str, Coverage] = {}
    for spec in specs:
        gs, sep, rest = spec.partition("=")
        parts = rest.split(",")
        try:
            if not sep or len(parts) != 3:
                raise ValueError
            out[gs] = msgspec.convert({"lat": float(parts[0]), "lon": float(parts[1]), "radius_m": float(parts[2])},
                                      Coverage)
        except (ValueError, msgspec.ValidationError):
            raise ConfigError(f"--coverage {spec!r}: expected GS=LAT,LON,RADIUS_M (degrees, metres > 0)") from None
    return out


# ------------------------------------------------------------------------------ command line
def add_parsers(fsub, publish_command: Callable[[Any], int]) -> None:
    """``zdrone fleet revoke | rotate | revise | publish`` (``zdrone/cli.py`` calls this)."""
    rv = fsub.add_parser("revoke", help="revoke a node for good: the next signed fleet revision")
    rv.add_argument("node", metavar="NODE")
    rv.add_argument("--dir", default="fleet", help="the fleet directory, with its offline keys (default: ./fleet)")
    rv.add_argument("--note", default="", help="why (kept in the revision)")
    rv.set_defaults(func=_cli_revoke)
    rt = fsub.add_parser("rotate", help="new keys and router password for a node: the next signed fleet revision, "
                                        "its bundle re-exported")
    rt.add_argument("node", metavar="NODE")
    rt.add_argument("--dir", default="fleet", help="the fleet directory, with its offline keys (default: ./fleet)")
    rt.add_argument("--out", help="write the node's new bundle into this new folder")
    rt.add_argument("--password", action="store_true",
                    help="also a new router password (and with TLS a new certificate): effective at the node's restart")
    rt.add_argument("--note", default="")
    rt.set_defaults(func=_cli_rotate)
    rs = fsub.add_parser("revise", help="change authorized lists, coverage or the pairing: the next signed revision")
    rs.add_argument("--dir", default="fleet", help="the fleet directory, with its offline keys (default: ./fleet)")
    rs.add_argument("--authorize", action="append", default=[], metavar="DRONE=GS,GS",
                    help="the drone's new authorized list (repeatable)")
    rs.add_argument("--coverage", action="append", default=[], metavar="GS=LAT,LON,RADIUS_M",
                    help="the GS's new coverage circle (repeatable)")
    rs.add_argument("--pairing-pq", choices=["on", "off"], help="hybrid post-quantum pairing required (on) or not")
    rs.add_argument("--lease", type=float, metavar="S",
                    help="the owners' lease from now on (s; 0: none): renewed only by the signed stamp of another "
                         "GS authorized for the drone")
    rs.add_argument("--note", default="")
    rs.set_defaults(func=_cli_revise)
    pb = fsub.add_parser("publish", help="put the latest revision on a GS's revision key through a router")
    pb.add_argument("--fleet", required=True, help="a node's bundle (or the fleet directory) holding revision.json")
    pb.add_argument("--revision", help="the revision file (default: revision.json of --fleet)")
    pb.add_argument("--id", required=True, help="the GS whose credentials publish it (on its own revision key)")
    pb.add_argument("--router", required=True, help="router endpoint, e.g. tcp/127.0.0.1:7447")
    pb.set_defaults(func=publish_command)  # the network's part: zdrone.net.revisions


def _said(r: Revised) -> int:
    c = r.revision.changes
    print(f"wrote {r.path} (revision {r.revision.number}, signed by the fleet key): revoked "
          f"{', '.join(c.revoked) or 'none'}; rotated {', '.join(c.keys) or 'none'}; pairing_pq {c.pairing_pq}")
    print("router files regenerated: restart the site routers one at a time on them (zdrone fleet export router)")
    return 0


def _cli_revoke(args) -> int:
    return _said(revoke(args.dir, args.node, args.note))


def _cli_rotate(args) -> int:
    r = rotate(args.dir, args.node, args.out, args.note, args.password)
    _said(r)
    if args.out:
        print(f"wrote {args.out}: the new bundle of {args.node}")
    return 0


def _cli_revise(args) -> int:
    pq = None if args.pairing_pq is None else args.pairing_pq == "on"
    return _said(revise(args.dir, parse_authorize(args.authorize), parse_coverage(args.coverage), pq, args.note,
                        args.lease))
