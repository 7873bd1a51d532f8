"""Mutual TLS for the fleet: a fleet CA, a certificate per node and per router (``fleet init --tls``).

Every Zenoh hop can then be TLS with client certificates: the router accepts only clients whose
certificate the fleet CA signed, and its access control matches each client by its certificate's
common name (the node's name) *and* its username, so a stolen router password is no longer enough
to speak on a node's keys, and neither is another node's certificate.

Files (all PEM; private keys mode 0600):

* ``tls/ca.crt`` — the fleet CA, public (every node and router trusts it);
* ``tls/ca.key`` — its private key: needed only to issue certificates; keep it off the nodes;
* ``tls/<node>.crt`` and ``secrets/<node>.tls.key`` — a node's client certificate (CN = its name);
* ``router/router.crt`` and ``router/router.key`` — the router's server (and router-to-router
  client) certificate, CN ``router``, valid for the names and addresses in ``router_hosts``.

Keys are ECDSA P-256 (PKCS#8), made with ``cryptography``'s x509 builder.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from zdrone.core.errors import ConfigError
from zdrone.core.fleet import Fleet

VALID_DAYS = 3650
ROUTER_NAME = "router"
DEFAULT_ROUTER_HOSTS = ("127.0.0.1", "localhost")


@dataclass(frozen=True, slots=True)
class TlsFiles:
    """Where one endpoint's TLS material is."""

    ca: Path
    cert: Path
    key: Path

    def check(self) -> "TlsFiles":
        for p in (self.ca, self.cert, self.key):
            if not p.is_file():
                raise ConfigError(f"{p}: missing (run 'zdrone fleet init --tls')")
        return self


def node_files(fleet_dir: str | Path, name: str) -> TlsFiles:
    d = Path(fleet_dir)
    return TlsFiles(d / "tls" / "ca.crt", d / "tls" / f"{name}.crt", d / "secrets" / f"{name}.tls.key")


def router_files(fleet_dir: str | Path) -> TlsFiles:
    d = Path(fleet_dir)
    return TlsFiles(d / "tls" / "ca.crt", d / "router" / "router.crt", d / "router" / "router.key")


def _key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _pem_key(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())


def _write(path: Path, data: bytes, private: bool) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if private:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(path, 0o600)
    else:
        path.write_bytes(data)


def _name(cn: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "zdrone fleet"),
                      x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def make_ca(now: datetime.datetime | None = None) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    now = now or datetime.datetime.now(datetime.timezone.utc)
    key = _key()
    cert = (x509.CertificateBuilder().subject_name(_name("zdrone fleet CA")).issuer_name(_name("zdrone fleet CA"))
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True, content_commitment=False,
                                         key_encipherment=False, data_encipherment=False, key_agreement=False,
                                         encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    return cert, key


def issue(ca: x509.Certificate, ca_key: ec.EllipticCurvePrivateKey, cn: str, hosts: tuple[str, ...] = (),
          now: datetime.datetime | None = None) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    """A certificate for ``cn`` signed by the CA: a client certificate, and a server one for ``hosts``."""
    now = now or datetime.datetime.now(datetime.timezone.utc)
    key = _key()
    sans: list[x509.GeneralName] = []
    for h in hosts:
        try:
            sans.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            sans.append(x509.DNSName(h))
    usages = [ExtendedKeyUsageOID.CLIENT_AUTH] + ([ExtendedKeyUsageOID.SERVER_AUTH] if hosts else [])
    b = (x509.CertificateBuilder().subject_name(_name(cn)).issuer_name(ca.subject).public_key(key.public_key())
         .serial_number(x509.random_serial_number())
         .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
         .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
         .add_extension(x509.ExtendedKeyUsage(usages), critical=False)
         .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False))
    if sans:
        b = b.add_extension(x509.SubjectAlternativeName(sans), critical=False)
    else:  # rustls wants a subject alternative name on every end-entity certificate
        b = b.add_extension(x509.SubjectAlternativeName([x509.DNSName(cn)]), critical=False)
    return b.sign(ca_key, hashes.SHA256()), key


def init_tls(fleet_dir: str | Path, fleet: Fleet, router_hosts: tuple[str, ...] = DEFAULT_ROUTER_HOSTS,
             sites: list[str] | tuple[str, ...] = ()) -> None:
    """Write the fleet CA and a certificate for every node, for the router and for each site's
    router (``router/<site>.crt``, CN ``router-<site>``)."""
    d = Path(fleet_dir)
    ca, ca_key = make_ca()
    _write(d / "tls" / "ca.crt", ca.public_bytes(serialization.Encoding.PEM), private=False)
    _write(d / "tls" / "ca.key", _pem_key(ca_key), private=True)
    for name in fleet.nodes:
        cert, key = issue(ca, ca_key, name)
        files = node_files(d, name)
        _write(files.cert, cert.public_bytes(serialization.Encoding.PEM), private=False)
        _write(files.key, _pem_key(key), private=True)
    cert, key = issue(ca, ca_key, ROUTER_NAME, router_hosts)
    files = router_files(d)
    _write(files.cert, cert.public_bytes(serialization.Encoding.PEM), private=False)
    _write(files.key, _pem_key(key), private=True)
    for site in sites:
        cert, key = issue(ca, ca_key, f"router-{site}", router_hosts)
        _write(d / "router" / f"{site}.crt", cert.public_bytes(serialization.Encoding.PEM), private=False)
        _write(d / "router" / f"{site}.key", _pem_key(key), private=True)
