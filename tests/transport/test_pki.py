"""The deployment's certificates: usages per role, host names, the CA's constraints."""

from __future__ import annotations

import ipaddress

import pytest
from cryptography import x509
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from legws_daemon.errors import InputError
from legws_daemon.transport.pki import ROLES, Authority, common_name, host_name


@pytest.fixture(scope="module")
def ca() -> Authority:
    return Authority.create(days=30)


def _eku(cert: x509.Certificate) -> set[x509.ObjectIdentifier]:
    return set(cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value)


def test_only_the_daemon_may_serve(ca: Authority) -> None:
    for role in ROLES:
        cert = ca.issue(role).certificate
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == (
            common_name(role)
        )
        usages = _eku(cert)
        assert ExtendedKeyUsageOID.CLIENT_AUTH in usages
        assert (ExtendedKeyUsageOID.SERVER_AUTH in usages) == (role == "daemon")
        has_names = True
        try:
            cert.extensions.get_extension_for_class(x509.SubjectAlternativeName)
        except x509.ExtensionNotFound:
            has_names = False
        assert has_names == (role == "daemon")
        assert cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca is False
        cert.verify_directly_issued_by(ca.certificate)  # signed by the CA


def test_the_daemon_names_its_hosts(ca: Authority) -> None:
    cert = ca.issue("daemon", ("robot-pc.local", "192.168.1.10", "fe80::1")).certificate
    names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert names.get_values_for_type(x509.DNSName) == ["localhost", "robot-pc.local"]
    assert names.get_values_for_type(x509.IPAddress) == [
        ipaddress.ip_address(a) for a in ("127.0.0.1", "192.168.1.10", "fe80::1")
    ]
    with pytest.raises(InputError, match="only the daemon"):
        ca.issue("bridge", ("robot-pc.local",))


def test_the_ca_signs_end_entities_only(ca: Authority) -> None:
    constraints = ca.certificate.extensions.get_extension_for_class(x509.BasicConstraints)
    assert (constraints.critical, constraints.value.ca, constraints.value.path_length) == (
        True,
        True,
        0,
    )
    assert isinstance(ca.key, ec.EllipticCurvePrivateKey) and ca.key.curve.name == "secp256r1"


@pytest.mark.parametrize("bad", ["", "-bad.example", "under_score", "a" * 64 + ".com", "a b"])
def test_bad_host_names_are_one_line(bad: str) -> None:
    with pytest.raises(InputError, match="neither an IP address nor a DNS name"):
        host_name(bad)
