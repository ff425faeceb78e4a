"""The certificates of a legws deployment: a private CA and one identity per role.

zenoh's TLS (rustls/webpki) checks the *extended key usage*: a certificate marked for
client authentication only cannot serve a TLS connection, and one marked for server
authentication only cannot authenticate a client. So the roles get exactly what they do:

========  ============================  =================================================
role      usage                         why
========  ============================  =================================================
daemon    server (and client)           it listens for every other party; it may dial a
                                        bridge that listens
operator  client                        steers and commands
observer  client                        watches status and events, may stop
safety    client                        a stop button or a safety monitor: may stop only
bridge    client                        the robot-side bridge dials the daemon
========  ============================  =================================================

Only the daemon's certificate names hosts (``subjectAltName``): the names and addresses
clients dial. No other key can impersonate the daemon, because no other certificate is
valid for a server.

Keys are EC P-256 (PKCS#8 PEM, mode 0600); the CA is constrained to sign end-entity
certificates only (``pathlen:0``).
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from legws_daemon.errors import InputError

Role = Literal["daemon", "operator", "observer", "safety", "bridge"]
#: Every role of a deployment, the daemon first.
ROLES: tuple[Role, ...] = ("daemon", "operator", "observer", "safety", "bridge")
#: Default validity of the certificates, days.
DAYS = 825
ORGANISATION = "legws"


def common_name(role: Role) -> str:
    """The certificate common name of a role (what zenoh's ACL subjects match)."""
    return f"legws-{role}"


def usages(role: Role) -> tuple[x509.ObjectIdentifier, ...]:
    """The extended key usages of a role's certificate."""
    if role == "daemon":
        return (ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH)
    return (ExtendedKeyUsageOID.CLIENT_AUTH,)


def host_name(host: str) -> x509.GeneralName:
    """A subjectAltName entry: an IP address, or a DNS name (checked)."""
    try:
        return x509.IPAddress(ipaddress.ip_address(host.strip("[]")))
    except ValueError:
        pass
    labels = host.split(".")
    if (
        not host
        or len(host) > 253
        or not all(
            label and len(label) <= 63 and label.replace("-", "").isalnum() and label[0] != "-"
            for label in labels
        )
    ):
        raise InputError(f"'{host}' is neither an IP address nor a DNS name", field="--host")
    return x509.DNSName(host)


@dataclass(frozen=True)
class Identity:
    """One party's key and certificate, as PEM."""

    role: Role
    key_pem: bytes
    cert_pem: bytes

    @property
    def certificate(self) -> x509.Certificate:
        return x509.load_pem_x509_certificate(self.cert_pem)


def _key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def _name(cn: str) -> x509.Name:
    return x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, ORGANISATION),
            x509.NameAttribute(NameOID.COMMON_NAME, cn),
        ]
    )


def _key_usage(*, ca: bool) -> x509.KeyUsage:
    """A CA signs certificates (and revocation lists); an end entity signs handshakes."""
    return x509.KeyUsage(
        digital_signature=not ca,
        content_commitment=False,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        key_cert_sign=ca,
        crl_sign=ca,
        encipher_only=False,
        decipher_only=False,
    )


@dataclass(frozen=True)
class Authority:
    """The deployment's private CA."""

    key: ec.EllipticCurvePrivateKey
    certificate: x509.Certificate

    @classmethod
    def create(cls, days: int = DAYS) -> Authority:
        key = _key()
        now = dt.datetime.now(dt.UTC)
        name = _name(f"{ORGANISATION}-ca")
        cert = (
            x509.CertificateBuilder()
            .subject_name(name)
            .issuer_name(name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(_key_usage(ca=True), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), False)
            .sign(key, hashes.SHA256())
        )
        return cls(key, cert)

    @property
    def cert_pem(self) -> bytes:
        return self.certificate.public_bytes(serialization.Encoding.PEM)

    @property
    def key_pem(self) -> bytes:
        return _key_pem(self.key)

    def issue(self, role: Role, hosts: tuple[str, ...] = (), days: int = DAYS) -> Identity:
        """A key and a certificate for ``role``; ``hosts`` (the daemon's only) go into its
        subjectAltName next to ``localhost`` and ``127.0.0.1``."""
        if hosts and role != "daemon":
            raise InputError("only the daemon's certificate names hosts", field="hosts")
        key = _key()
        now = dt.datetime.now(dt.UTC)
        builder = (
            x509.CertificateBuilder()
            .subject_name(_name(common_name(role)))
            .issuer_name(self.certificate.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(_key_usage(ca=False), critical=True)
            .add_extension(x509.ExtendedKeyUsage(list(usages(role))), critical=False)
            .add_extension(
                x509.AuthorityKeyIdentifier.from_issuer_public_key(self.key.public_key()), False
            )
        )
        if role == "daemon":
            names = [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
            for host in hosts:
                entry = host_name(host)
                if entry not in names:
                    names.append(entry)
            builder = builder.add_extension(x509.SubjectAlternativeName(names), critical=False)
        cert = builder.sign(self.key, hashes.SHA256())
        return Identity(role, _key_pem(key), cert.public_bytes(serialization.Encoding.PEM))


def write_new(path: Path, data: bytes, mode: int) -> None:
    """Write a new file with ``mode`` (0o600 for a key, 0o644 for a certificate); never
    overwrites (``O_EXCL``), so the mode is the file's from its first byte."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
