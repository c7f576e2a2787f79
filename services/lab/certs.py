"""A small certificate authority for a lab's Zenoh TLS links (``wart certs``).

One CA per lab signs a certificate for each host's router and for each kind of
process on each host. The certificate's common name (CN) is the identity the
routers' access-control rules match (``cert_common_names``), so it says what
the process is: ``router.B``, ``engine.B``, ``registry.A``, ``student``. Every
certificate carries the host's names and addresses as subject alternative
names (routers check them when they connect to each other) and both the
server and client extended key usages (a router listens and connects).

Keys are ECDSA P-256 in PKCS#8 PEM (what rustls, inside Zenoh, reads), written
with mode 0600; certificates are PEM, 0644. Rotation is re-issuing: see
docs/DEPLOY.md.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

CA_CERT = "ca.pem"
CA_KEY = "ca.key"
CA_DAYS = 3650
LEAF_DAYS = 397  # about a year and a month: a yearly rotation with slack

# A common name is what ACL rules match: keep it to one simple token.
_CN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}$")


class CertError(ValueError):
    """A certificate cannot be made or read; the message says why."""


@dataclass(frozen=True)
class Issued:
    name: str  # the common name
    cert: Path
    key: Path
    not_after: dt.datetime


def check_common_name(name: str) -> str:
    if not _CN.match(name):
        raise CertError(
            f"certificate name {name!r} is not valid: use 1 to 64 letters, digits, '_', '-' "
            "or '.', starting with a letter or digit"
        )
    return name


def _write_private(path: Path, data: bytes) -> None:
    """Write a key so that it is never readable by others, even for an instant."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.write(fd, data)
    finally:
        os.close(fd)
    os.chmod(tmp, 0o600)
    os.replace(tmp, path)


def _write_public(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    os.chmod(tmp, 0o644)
    os.replace(tmp, path)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def _now() -> dt.datetime:
    return dt.datetime.now(dt.UTC)


def init_ca(directory: Path, name: str = "wart lab CA", *, force: bool = False) -> Issued:
    """Create the lab's CA in ``directory`` (refuses to overwrite one unless ``force``)."""
    cert_path, key_path = directory / CA_CERT, directory / CA_KEY
    if key_path.exists() and not force:
        raise CertError(
            f"a CA already exists in {directory}; re-issuing it invalidates every certificate "
            "(use --force to do so on purpose)"
        )
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    now = _now()
    not_after = now + dt.timedelta(days=CA_DAYS)
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(not_after)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    _write_private(key_path, _key_pem(key))
    _write_public(cert_path, cert.public_bytes(serialization.Encoding.PEM))
    return Issued(name, cert_path, key_path, not_after)


def load_ca(directory: Path) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    cert_path, key_path = directory / CA_CERT, directory / CA_KEY
    if not cert_path.is_file() or not key_path.is_file():
        raise CertError(f"no CA in {directory}: run `wart certs init --dir {directory}` first")
    cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
    key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    if not isinstance(key, ec.EllipticCurvePrivateKey):
        raise CertError(f"{key_path} is not an EC private key")
    return cert, key


def _san(names: Sequence[str]) -> list[x509.GeneralName]:
    out: list[x509.GeneralName] = []
    seen: set[str] = set()
    for raw in names:
        name = raw.strip()
        if not name or name in seen:
            continue
        seen.add(name)
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(name)))
        except ValueError:
            if not re.match(r"^[A-Za-z0-9*][A-Za-z0-9.\-]*$", name):
                raise CertError(f"{name!r} is neither an IP address nor a DNS name") from None
            out.append(x509.DNSName(name))
    return out


def issue(
    directory: Path,
    name: str,
    *,
    alt_names: Sequence[str] = (),
    days: int = LEAF_DAYS,
    out_dir: Path | None = None,
) -> Issued:
    """Issue (or re-issue: a rotation) the certificate ``name`` signed by the CA in ``directory``.

    Writes ``<out_dir>/<name>.pem`` and ``<name>.key`` (out_dir defaults to
    ``directory``). ``alt_names`` are the DNS names and IP addresses it answers
    to; ``localhost`` and 127.0.0.1 are always added, for local clients.
    """
    check_common_name(name)
    if not 1 <= days <= CA_DAYS:
        raise CertError(f"validity of {days} days is out of range (1 to {CA_DAYS})")
    ca_cert, ca_key = load_ca(directory)
    key = ec.generate_private_key(ec.SECP256R1())
    now = _now()
    not_after = min(now + dt.timedelta(days=days), ca_cert.not_valid_after_utc)
    sans = _san([*alt_names, "localhost", "127.0.0.1"])
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(not_after)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.SubjectAlternativeName(sans), critical=False)
        .add_extension(
            x509.ExtendedKeyUsage(
                [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
            ),
            critical=False,
        )
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False
        )
        .sign(ca_key, hashes.SHA256())
    )
    target = out_dir or directory
    cert_path, key_path = target / f"{name}.pem", target / f"{name}.key"
    _write_private(key_path, _key_pem(key))
    _write_public(cert_path, cert.public_bytes(serialization.Encoding.PEM))
    return Issued(name, cert_path, key_path, not_after)


@dataclass(frozen=True)
class CertInfo:
    path: Path
    common_name: str
    not_after: dt.datetime
    alt_names: tuple[str, ...]
    issuer: str

    def days_left(self) -> float:
        return (self.not_after - _now()).total_seconds() / 86400.0


def inspect(path: Path) -> CertInfo:
    try:
        cert = x509.load_pem_x509_certificate(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise CertError(f"cannot read the certificate {path}: {exc}") from None
    cns = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        alts = tuple(str(v) for v in san.get_values_for_type(x509.DNSName)) + tuple(
            str(v) for v in san.get_values_for_type(x509.IPAddress)
        )
    except x509.ExtensionNotFound:
        alts = ()
    return CertInfo(
        path=path,
        common_name=str(cns[0].value) if cns else "",
        not_after=cert.not_valid_after_utc,
        alt_names=alts,
        issuer=cert.issuer.rfc4514_string(),
    )
