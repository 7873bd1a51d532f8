"""Opening Zenoh sessions: every node is a client of the router, scouting off, authenticated."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import zenoh

from zdrone.core.fleet import ConfigError, read_json5
from zdrone.fleet.routerconfig import MAX_MESSAGE_SIZE, SITE_KEEP_ALIVE, TLS_FILE_FIELDS
from zdrone.fleet.tls import TlsFiles

log = logging.getLogger(__name__)


def client_config(router: str, user: str, password: str, tls: "TlsFiles | None" = None,
                  lease_ms: int | None = None) -> zenoh.Config:
    """A client that connects only to ``router`` (e.g. ``tcp/127.0.0.1:7447``), never to peers;
    with ``tls`` (for a ``tls/`` endpoint) it shows its fleet certificate and checks the router's;
    with ``lease_ms``, the router gives it up after that long without a word (a path per site)."""
    cfg: dict[str, Any] = {
        "mode": "client",
        # after losing the router (a restart), try again every 100-400 ms: back within ~0.2 s of its
        # return. Several routers (sites, comma-separated): Zenoh's client keeps one session and moves
        # to the next router when its router dies (measured: ~40 ms without a sample)
        "connect": {"endpoints": router.split(","), "timeout_ms": 5000, "exit_on_failure": True,
                    "retry": {"period_init_ms": 100, "period_max_ms": 400, "period_increase_factor": 1.5}},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"user": user, "password": password}},
                      "link": {"rx": {"max_message_size": MAX_MESSAGE_SIZE}},
                      "shared_memory": {"enabled": False}},  # see routerconfig: no way around the size limit
    }
    if lease_ms is not None:
        cfg["transport"]["link"]["tx"] = {"lease": lease_ms, "keep_alive": SITE_KEEP_ALIVE}
    if tls is not None:
        cfg["transport"]["link"]["tls"] = {"root_ca_certificate": str(tls.ca), "connect_certificate": str(tls.cert),
                                           "connect_private_key": str(tls.key), "enable_mtls": True}
    return zenoh.Config.from_json5(json.dumps(cfg))


#: Queries waiting for a node's loop: the oldest are dropped beyond this (a flood cannot grow memory
#: or block a Zenoh thread).
QUERY_QUEUE_SIZE = 256


def query_queue() -> "zenoh.handlers.RingChannel":
    """The handler of every queryable: a bounded ring, drained by the node's loop."""
    return zenoh.handlers.RingChannel(QUERY_QUEUE_SIZE)


def open_client(router: str, user: str, password: str, tls: "TlsFiles | None" = None,
                lease_ms: int | None = None) -> zenoh.Session:
    """Open a client session; ``ConfigError`` (one line) if the router refuses or is not there."""
    if router.startswith("tls/") and tls is None:
        raise ConfigError(f"router {router}: a TLS endpoint needs the node's fleet certificate (zdrone fleet init --tls)")
    try:
        return zenoh.open(client_config(router, user, password, tls, lease_ms))
    except zenoh.ZError as exc:
        detail = str(exc).split(" at ")[0].splitlines()[0]
        raise ConfigError(f"cannot connect to router {router} as {user!r} (wrong password or no router): {detail}") from None


def load_router_config(path: str | Path, listen: list[str] | str | None = None,
                       connect: list[str] | None = None) -> zenoh.Config:
    """Read a router JSON5 file; resolve the credentials path relative to the file."""
    p = Path(path)
    try:
        raw = read_json5(p.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such file") from None
    except ValueError as exc:
        raise ConfigError(f"{p}: not valid JSON5: {str(exc).splitlines()[0]}") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read: {exc.__class__.__name__}") from None
    if not isinstance(raw, dict) or raw.get("mode") != "router":
        raise ConfigError(f"{p}: field $.mode: must be \"router\"")
    try:
        dict_file = raw["transport"]["auth"]["usrpwd"]["dictionary_file"]
    except (KeyError, TypeError):
        raise ConfigError(f"{p}: field $.transport.auth.usrpwd.dictionary_file: missing (auth is required)") from None
    cred = Path(dict_file)
    if not cred.is_absolute():
        cred = (p.parent / cred).resolve()
    if not cred.is_file():
        raise ConfigError(f"{p}: field $.transport.auth.usrpwd.dictionary_file: {cred} does not exist (run 'zdrone fleet init')")
    raw["transport"]["auth"]["usrpwd"]["dictionary_file"] = str(cred)
    tls = raw["transport"].get("link", {}).get("tls") or {}
    for field in TLS_FILE_FIELDS:
        if isinstance(tls.get(field), str) and not Path(tls[field]).is_absolute():
            f = (p.parent / tls[field]).resolve()
            if not f.is_file():
                raise ConfigError(f"{p}: field $.transport.link.tls.{field}: {f} does not exist (run 'zdrone fleet init --tls')")
            tls[field] = str(f)
    if listen:
        raw["listen"] = {"endpoints": [listen] if isinstance(listen, str) else list(listen)}
    if connect:  # other routers reached another way (e.g. the testbed's backhaul link); retry as configured
        raw.setdefault("connect", {})["endpoints"] = list(connect)
    acl = raw.get("access_control", {})
    if not acl.get("enabled") or acl.get("default_permission") != "deny":
        log.warning("%s: access control is not enabled with default deny", p)
    try:
        return zenoh.Config.from_json5(json.dumps(raw))
    except zenoh.ZError as exc:
        raise ConfigError(f"{p}: rejected by zenoh: {str(exc).splitlines()[0]}") from None
