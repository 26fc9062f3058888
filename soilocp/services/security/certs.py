"""Development certificates for the secure fleet: a CA, one certificate per vehicle (CN = the
vehicle id), one for the fleet router and one per fleet tool (dashboard, fleet CLI, recorder).

Made with the ``cryptography`` library (ECDSA P-256, SHA-256), in the shape Zenoh's TLS transport
(rustls / webpki) accepts: a CA with ``basicConstraints CA:TRUE`` and ``keyCertSign``; leaves with
``CA:FALSE``, both extended key usages (a vehicle router is a TLS client of the fleet router, the
fleet router a server), and the subject alternative names a client checks the server against.
The common name is what the fleet router's access control matches (``cert_common_names``).

Layout of DIR: ``ca.pem`` + ``ca.key`` (the development CA; keep ``ca.key`` off the vehicles),
``<name>.pem`` + ``<name>.key`` per certificate.  Private keys are written with mode 0600.
A real deployment uses its own CA instead (docs/deploy.md): only the file names matter.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
from pathlib import Path
from typing import Iterable, Optional

from soilocp.schemas import keys

#: Certificates that are not vehicles; a vehicle may not take one of these names.
FLEET_ROUTER = "fleet-router"
DEFAULT_TOOLS = ("dashboard",)
DEFAULT_FLEET_HOSTS = ("fleet-router", "localhost", "127.0.0.1")


def _x509():
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    return x509, hashes, serialization, ec, ExtendedKeyUsageOID, NameOID


def _write_key(path: Path, key) -> None:
    _, _, serialization, *_ = _x509()
    data = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(path, 0o600)


def _write_cert(path: Path, cert) -> None:
    _, _, serialization, *_ = _x509()
    path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def _san(host: str):
    x509 = _x509()[0]
    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def make_ca(directory: Path, *, days: int = 3650, common_name: str = "soilocp development CA") -> None:
    """Write ``ca.pem`` and ``ca.key`` into ``directory``."""
    x509, hashes, _, ec, _, NameOID = _x509()
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name),
                      x509.NameAttribute(NameOID.ORGANIZATION_NAME, "soilocp")])
    now = dt.datetime.now(dt.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False,
                                         data_encipherment=False, key_agreement=False, encipher_only=False,
                                         decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    directory.mkdir(parents=True, exist_ok=True)
    _write_key(directory / "ca.key", key)
    _write_cert(directory / "ca.pem", cert)


def issue(directory: Path, common_name: str, *, hosts: Iterable[str] = (), days: int = 825) -> Path:
    """Sign ``<common_name>.pem`` / ``.key`` with the CA in ``directory``; returns the certificate path.

    ``hosts`` (DNS names or IP addresses) go into the subject alternative names: the names under
    which clients reach this certificate's holder when it listens (the fleet router).  The common
    name is always one of them, so every certificate is also a valid server certificate for it.
    """
    x509, hashes, serialization, ec, EKU, NameOID = _x509()
    check_name(common_name)
    try:
        ca_key = serialization.load_pem_private_key((directory / "ca.key").read_bytes(), password=None)
        ca_cert = x509.load_pem_x509_certificate((directory / "ca.pem").read_bytes())
    except FileNotFoundError as exc:
        raise ValueError(f"{directory}: no development CA (ca.pem, ca.key): run `soilocp certs init` first "
                         f"({exc.filename} missing)") from None
    key = ec.generate_private_key(ec.SECP256R1())
    now = dt.datetime.now(dt.timezone.utc)
    not_after = min(now + dt.timedelta(days=days), ca_cert.not_valid_after_utc)
    names = list(dict.fromkeys([common_name, *hosts]))
    cert = (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name),
                                     x509.NameAttribute(NameOID.ORGANIZATION_NAME, "soilocp")]))
            .issuer_name(ca_cert.subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(not_after)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_encipherment=False, key_cert_sign=False,
                                         crl_sign=False, content_commitment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False),
                           critical=True)
            .add_extension(x509.ExtendedKeyUsage([EKU.SERVER_AUTH, EKU.CLIENT_AUTH]), critical=False)
            .add_extension(x509.SubjectAlternativeName([_san(h) for h in names]), critical=False)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    _write_key(directory / f"{common_name}.key", key)
    path = directory / f"{common_name}.pem"
    _write_cert(path, cert)
    return path


def check_name(name: str) -> str:
    """A certificate name is a file name and an ACL subject: the vehicle-id alphabet."""
    try:
        return keys.check_vehicle_id(name)
    except ValueError:
        raise ValueError(f"certificate name {name!r} is invalid: it must match [A-Za-z0-9_-]{{1,64}}") from None


def init_fleet(directory: Path, vehicles: Iterable[str], *, fleet_hosts: Iterable[str] = DEFAULT_FLEET_HOSTS,
               tools: Iterable[str] = DEFAULT_TOOLS, days: int = 825, force: bool = False) -> list[Path]:
    """A development CA and the certificates of a fleet; returns the files written."""
    vehicles, tools = list(vehicles), list(tools)
    for name in (*vehicles, *tools):
        check_name(name)
    clash = sorted(set(vehicles) & ({FLEET_ROUTER} | set(tools)))
    if clash:
        raise ValueError(f"vehicle id(s) {clash} are also the name of the fleet router or a fleet tool: "
                         "the access control could not tell them apart")
    if not vehicles:
        raise ValueError("at least one vehicle is needed (--vehicle ID)")
    if (directory / "ca.key").exists() and not force:
        raise ValueError(f"{directory}/ca.key exists: a new CA would invalidate every certificate it signed "
                         "(add certificates with `soilocp certs issue`, or pass --force)")
    make_ca(directory, days=max(days, 3650))
    issue(directory, FLEET_ROUTER, hosts=fleet_hosts, days=days)
    for name in (*tools, *vehicles):
        issue(directory, name, days=days)
    return sorted(directory.iterdir())


def describe(path: Path) -> dict[str, Optional[str]]:
    """Common name, issuer, SANs and expiry of a certificate file (for `soilocp certs show`)."""
    x509, *_ , NameOID = _x509()
    cert = x509.load_pem_x509_certificate(path.read_bytes())
    cn = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        sans = ", ".join(str(v) for v in san.get_values_for_type(x509.DNSName)) or ""
        ips = ", ".join(str(v) for v in san.get_values_for_type(x509.IPAddress))
        sans = ", ".join(s for s in (sans, ips) if s)
    except x509.ExtensionNotFound:
        sans = ""
    return {"file": path.name, "cn": cn[0].value if cn else None, "issuer": cert.issuer.rfc4514_string(),
            "sans": sans, "not_after": cert.not_valid_after_utc.isoformat()}
