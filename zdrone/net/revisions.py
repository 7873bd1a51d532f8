"""Fleet revisions on the network, outside any node: ``zdrone fleet publish`` puts a signed revision
on a GS's revision key (``zdrone.fleet.revisions`` holds what every node does with one)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from zdrone.core.errors import ConfigError
from zdrone.core.revision import RevisionAccepted, check_revision
from zdrone.fleet import keyexprs
from zdrone.fleet.files import REVISION_FILE, fleet_path, load_base_fleet, load_fleet, load_secret
from zdrone.fleet.tls import node_files
from zdrone.net.session import open_client


def publish(fleet_dir: str | Path, node: str, router: str, data: bytes) -> None:
    """Put revision ``data`` on GS ``node``'s revision key through ``router`` with its bundle's
    credentials, and close. ``ConfigError`` if ``node`` is not a GS (only GSs publish revisions)."""
    fleet = load_fleet(fleet_dir)
    entry = fleet.nodes.get(node)
    if entry is None or entry.role != "gs":
        raise ConfigError(f"--id {node}: revisions are published as a ground station of the fleet "
                          f"({', '.join(fleet.ground_stations())})")
    secret = load_secret(fleet_dir, node, fleet)
    tls = node_files(fleet_dir, node).check() if router.startswith("tls/") else None
    session = open_client(router, node, secret.router_password, tls, None)
    try:
        session.put(keyexprs.revision(node), data)
    finally:
        session.close()


def publish_command(args: Any) -> int:
    """``zdrone fleet publish``: check the revision file against the fleet, then put it as GS ``--id``."""
    path = Path(args.revision) if args.revision else fleet_path(args.fleet).parent / REVISION_FILE
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.__class__.__name__}") from None
    got = check_revision(data, load_base_fleet(args.fleet), None)
    if not isinstance(got, RevisionAccepted):
        raise ConfigError(f"{path}: not a valid revision of this fleet ({got.reason.value})")
    publish(args.fleet, args.id, args.router, data)
    print(f"published revision {got.revision.number} on {args.router} as {args.id}")
    return 0
