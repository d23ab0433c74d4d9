"""TLS files for Mosquitto's TLS listener (``edge-ips broker-config --tls``), made with ``cryptography``.

A private CA signs one server certificate (for the names the clients use to reach the broker) and one client
certificate (for the edge and the operators' laptops). The listener requires a client certificate, so a rover's
login, which a rover cannot use over TLS anyway, is no key to it. The CA's private key is never written: to add a
name or replace a certificate, run ``broker-config --tls --force`` again. Private keys are 0600 from their first
byte (:func:`edge.private_files.write_private`).
"""

from __future__ import annotations

import datetime as dt
import ipaddress
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from edge.errors import BrokerError
from edge.private_files import write_private

VALID_DAYS = 3650
TLS_FILES = ("ca.crt", "server.crt", "server.key", "client.crt", "client.key")


@dataclass(frozen=True)
class TlsPaths:
    ca_cert: Path
    server_cert: Path
    server_key: Path
    client_cert: Path
    client_key: Path


def _name_entry(name: str) -> object:
    from cryptography import x509

    try:
        return x509.IPAddress(ipaddress.ip_address(name))
    except ValueError:
        return x509.DNSName(name)


def write_tls_files(out_dir: Path, names: Sequence[str], *, valid_days: int = VALID_DAYS) -> TlsPaths:
    """The CA certificate, a server certificate and key for ``names`` (host names or addresses), a client one."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    if not names:
        raise BrokerError("--tls needs at least one name the clients use to reach the broker (--tls-name)")
    now = dt.datetime.now(dt.UTC)
    until = now + dt.timedelta(days=valid_days)

    def subject(common_name: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = subject("edge-ips broker CA")
    ca = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(until)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=False,
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
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False)
        .sign(ca_key, hashes.SHA256())
    )

    def issue(common_name: str, usage: x509.ObjectIdentifier, alt: list[object] | None) -> tuple[bytes, bytes]:
        key = ec.generate_private_key(ec.SECP256R1())
        builder = (
            x509.CertificateBuilder()
            .subject_name(subject(common_name))
            .issuer_name(ca_name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now)
            .not_valid_after(until)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([usage]), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
        )
        if alt:
            builder = builder.add_extension(x509.SubjectAlternativeName(alt), critical=False)  # type: ignore[arg-type]
        cert = builder.sign(ca_key, hashes.SHA256())
        key_pem = key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
        return cert.public_bytes(serialization.Encoding.PEM), key_pem

    server_cert, server_key = issue(names[0], ExtendedKeyUsageOID.SERVER_AUTH, [_name_entry(n) for n in names])
    client_cert, client_key = issue("edge-ips client", ExtendedKeyUsageOID.CLIENT_AUTH, None)
    paths = TlsPaths(*(out_dir / name for name in TLS_FILES))
    write_private(paths.ca_cert, ca.public_bytes(serialization.Encoding.PEM), mode=0o644)
    write_private(paths.server_cert, server_cert, mode=0o644)
    write_private(paths.server_key, server_key)
    write_private(paths.client_cert, client_cert, mode=0o644)
    write_private(paths.client_key, client_key)
    return paths


def tls_listener_lines(
    port: int, bind: str, where: Path, *, clientid_from_username: bool = False, max_connections: int | None = None
) -> list[str]:
    """Mosquitto lines of a TLS listener that only clients holding a certificate signed by ``where/ca.crt`` reach
    (:func:`write_tls_files` wrote the files into ``where``); ``clientid_from_username``: a client's id is its
    user name there; ``max_connections``: sockets it keeps open at most (silent ones included)."""
    return [
        f"listener {port} {bind}",
        *([f"max_connections {max_connections}"] if max_connections is not None else []),
        *(["use_username_as_clientid true"] if clientid_from_username else []),
        f"cafile {where / 'ca.crt'}",
        f"certfile {where / 'server.crt'}",
        f"keyfile {where / 'server.key'}",
        "require_certificate true",
        "tls_version tlsv1.2",
        "",
    ]
