"""A bundle per host: exactly the files one node (or the router) needs, and a check that a folder
holds nobody else's secret.

``export_bundle(fleet_dir, node, out)`` writes, in the fleet directory's own layout (so every
command takes a bundle where it takes a fleet directory):

* a drone or GS: ``fleet.json5`` (public), ``secrets/<node>.json`` (0600) and, with TLS,
  ``tls/ca.crt``, ``tls/<node>.crt`` and ``secrets/<node>.tls.key`` (0600);
* ``router``: ``fleet.json5``, ``router/router.json5``, ``router/credentials.txt`` (0600: every
  node's router password, which the router checks) and, with TLS, ``router/router.crt``,
  ``router/router.key`` (0600) and ``tls/ca.crt``; a site router ``site-N`` likewise with
  ``router/site-N.*`` and ``router/sites.json``;

and ``bundle.json`` (public) naming the node. Never the CA's private key, never the fleet signing
key (``offline/fleet-signing.json``: only its public half travels, pinned in ``fleet.json5`` as
``fleet_key``), never another node's secret.

``check_bundle(folder)`` says which node a bundle is for and refuses one that holds any other
secret: another node's secret file or TLS key, the CA key, the router's credentials or key in a
node's bundle, the fleet signing key, or any file holding a private key (PEM, or a secret file's
key) that is not the node's own, wherever it lies and whatever its name.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
from dataclasses import dataclass
from pathlib import Path

from zdrone.core.errors import ConfigError
from zdrone.core.fleet import Fleet
from zdrone.core.keys import Identity, SigningKey, unb64
from zdrone.fleet.files import FLEET_FILE, FLEET_SIGNING_FILE, REVISION_FILE, load_fleet, load_secret

BUNDLE_FILE = "bundle.json"
ROUTER = "router"


@dataclass(frozen=True)
class Bundle:
    """What ``check_bundle`` found: whose bundle it is, its role, whether it has TLS, its files."""

    node: str
    role: str  # drone, gs, router
    tls: bool
    files: tuple[str, ...]


def _is_router(name: str) -> bool:
    return name == ROUTER or name.startswith("site-")


def bundle_files(fleet_dir: Path, fleet: Fleet, node: str) -> dict[str, bool]:
    """The files of ``node``'s bundle (relative path -> private), as they exist in ``fleet_dir``."""
    tls = (fleet_dir / "tls" / "ca.crt").is_file()
    files: dict[str, bool] = {FLEET_FILE: False}
    if (fleet_dir / REVISION_FILE).is_file():  # the latest signed revision: public, applied on load
        files[REVISION_FILE] = False
    if _is_router(node):
        cfg = "router" if node == ROUTER else node
        if not (fleet_dir / "router" / f"{cfg}.json5").is_file():
            raise ConfigError(f"{fleet_dir}: no router config router/{cfg}.json5 "
                              f"({'run zdrone fleet init --sites' if node != ROUTER else 'run zdrone fleet init'})")
        files |= {f"router/{cfg}.json5": node != ROUTER, "router/credentials.txt": True}
        if tls:
            files |= {f"router/{cfg}.crt": False, f"router/{cfg}.key": True, "tls/ca.crt": False}
        if node != ROUTER:
            files["router/sites.json"] = False
        return files
    if node not in fleet.nodes:
        raise ConfigError(f"node {node!r}: not in the fleet ({', '.join(fleet.nodes)}, or router"
                          + (", site-N" if (fleet_dir / "router" / "sites.json").is_file() else "") + ")")
    files[f"secrets/{node}.json"] = True
    if tls:
        files |= {"tls/ca.crt": False, f"tls/{node}.crt": False, f"secrets/{node}.tls.key": True}
    return files


def export_bundle(fleet_dir: str | Path, node: str, out: str | Path) -> Bundle:
    """Write ``node``'s bundle into ``out`` (a new or empty folder)."""
    src, dst = Path(fleet_dir), Path(out)
    fleet = load_fleet(src)
    if _is_router(node):
        role = ROUTER
    else:
        role = fleet.nodes[node].role if node in fleet.nodes else ""
    files = bundle_files(src, fleet, node)
    if FLEET_SIGNING_FILE in files or "tls/ca.key" in files:
        raise ConfigError(f"{src / FLEET_SIGNING_FILE}: the fleet's offline keys never go into a bundle")
    if not _is_router(node):
        load_secret(src, node, fleet)  # the secret is sound before it travels
    if dst.exists() and (not dst.is_dir() or any(dst.iterdir())):
        raise ConfigError(f"{dst}: exists and is not an empty folder (a bundle is written into a new one)")
    missing = [f for f in files if not (src / f).is_file()]
    if missing:
        raise ConfigError(f"{src / missing[0]}: missing (is {src} a fleet directory made by zdrone fleet init?)")
    dst.mkdir(parents=True, exist_ok=True)
    os.chmod(dst, 0o700)
    for rel, private in files.items():
        target = dst / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        if private:
            fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(fd, "wb") as fh:
                fh.write((src / rel).read_bytes())
        else:
            shutil.copyfile(src / rel, target)
            os.chmod(target, 0o644)
    tls = "tls/ca.crt" in files
    (dst / BUNDLE_FILE).write_text(json.dumps({"node": node, "role": role, "tls": tls, "files": sorted(files)},
                                              indent=2) + "\n")
    return check_bundle(dst)


def _private_keys_in(path: Path) -> list[bytes]:
    """The X25519 private keys a file holds as a secret file (``private_key``), if it is one."""
    try:
        raw = json.loads(path.read_bytes())
    except (ValueError, OSError):
        return []
    if isinstance(raw, dict) and isinstance(raw.get("private_key"), str):
        try:
            return [unb64(raw["private_key"], 32)]
        except ValueError:
            return []
    return []


def _holds_fleet_signing_key(path: Path, fleet: Fleet) -> bool:
    """Whether a file is (or holds, as JSON or raw) the fleet's signing key."""
    data = path.read_bytes()
    if b"fleet_signing_key" in data:
        return True
    pinned = fleet.fleet_key_bytes
    if pinned is None:
        return False
    try:
        raw = json.loads(data)
    except ValueError:
        return False
    values = [v for v in raw.values() if isinstance(v, str)] if isinstance(raw, dict) else []
    for v in values:
        try:
            if SigningKey(unb64(v, 32)).public == pinned:
                return True
        except ValueError:
            continue
    return False


def check_bundle(folder: str | Path) -> Bundle:
    """Whose bundle ``folder`` is; ``ConfigError`` if it holds any secret that is not that node's,
    if its own secret does not match the fleet, or if a private file is readable by others."""
    d = Path(folder)
    try:
        meta = json.loads((d / BUNDLE_FILE).read_text())
        node, role, tls = str(meta["node"]), str(meta["role"]), bool(meta["tls"])
    except FileNotFoundError:
        raise ConfigError(f"{d}: no {BUNDLE_FILE}: not a bundle (make one with zdrone fleet export NODE)") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{d / BUNDLE_FILE}: malformed: {exc}") from None
    fleet = load_fleet(d)
    own = bundle_files(d, fleet, node) if (d / FLEET_FILE).is_file() else {}
    found = sorted(str(p.relative_to(d)) for p in d.rglob("*") if p.is_file())
    for rel in found:
        p = d / rel
        if rel == BUNDLE_FILE:
            continue
        if rel == "tls/ca.key":
            raise ConfigError(f"{p}: the fleet CA's private key: it never leaves the machine that issues certificates")
        if rel == FLEET_SIGNING_FILE or _holds_fleet_signing_key(p, fleet):
            raise ConfigError(f"{p}: the fleet signing key: it stays offline with the CA key, never in a bundle")
        if rel in (f"secrets/{node}.authority.json", f"secrets/{node}.authority.tmp", f"secrets/{node}.fc-signing.json",
                   f"secrets/{node}.fc-signing.tmp") and role == "drone":
            continue  # the drone's own authority state and autopilot signing key, run from the bundle outside systemd
        if rel not in own:
            data = p.read_bytes()
            if b"PRIVATE KEY" in data:
                raise ConfigError(f"{p}: a private key that is not {node}'s: a bundle holds its own node's secrets only")
            others = [n for k in _private_keys_in(p) for n, v in fleet.nodes.items() if v.public_bytes == Identity(k).public]
            if others or _private_keys_in(p):
                raise ConfigError(f"{p}: {others[0] if others else 'another node'}'s secret: "
                                  f"a bundle holds its own node's secrets only")
            if rel.startswith("secrets/") or rel == "router/credentials.txt" or rel.endswith(".key"):
                raise ConfigError(f"{p}: not {node}'s: a bundle holds its own node's secrets only")
        elif own[rel]:
            mode = stat.S_IMODE(p.stat().st_mode)
            if mode & 0o077:
                raise ConfigError(f"{p}: private file accessible by others (mode {mode:04o}); run chmod 600 {p}")
    missing = [rel for rel in own if not (d / rel).is_file()]
    if missing:
        raise ConfigError(f"{d / missing[0]}: missing from {node}'s bundle")
    if not _is_router(node):
        load_secret(d, node, fleet)  # matches the fleet's public key, mode 0600
        if tls:
            _check_cert_pair(d / "tls" / f"{node}.crt", d / "secrets" / f"{node}.tls.key", d / "tls" / "ca.crt")
    elif tls:
        cfg = "router" if node == ROUTER else node
        _check_cert_pair(d / "router" / f"{cfg}.crt", d / "router" / f"{cfg}.key", d / "tls" / "ca.crt")
    return Bundle(node, role, tls, tuple(found))


def _check_cert_pair(cert_path: Path, key_path: Path, ca_path: Path) -> None:
    """The certificate is the key's and the CA signed it."""
    from cryptography import x509
    from cryptography.exceptions import InvalidSignature
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ec

    try:
        cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
        ca = x509.load_pem_x509_certificate(ca_path.read_bytes())
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{cert_path}: unreadable certificate or key: {exc}") from None
    if cert.public_key().public_numbers() != key.public_key().public_numbers():  # type: ignore[union-attr]
        raise ConfigError(f"{cert_path}: not the certificate of {key_path.name}")
    ca_key = ca.public_key()
    try:
        assert isinstance(ca_key, ec.EllipticCurvePublicKey)
        ca_key.verify(cert.signature, cert.tbs_certificate_bytes, ec.ECDSA(cert.signature_hash_algorithm))  # type: ignore[arg-type]
    except (InvalidSignature, AssertionError):
        raise ConfigError(f"{cert_path}: not signed by the fleet CA in {ca_path}") from None
