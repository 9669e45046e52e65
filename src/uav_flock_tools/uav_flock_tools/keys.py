"""A run's keys for TLS between hosts (`uav-flock keys`, docs/multihost.md): a certificate authority made for
the run, and per host a certificate it signed, for mutual verification on the DDS transport.

The CA's private key signs the hosts' certificates and is then dropped, never written: a host that joins
later needs keys made anew for all (`--replace`). What a host holds, DIR/<host>/, is the CA's certificate
(ca.pem), its own (cert.pem) and its private key (key.pem, readable by its owner only).
"""
from __future__ import annotations

import datetime
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

CA_FILE, CERT_FILE, KEY_FILE = 'ca.pem', 'cert.pem', 'key.pem'
FILES = (CA_FILE, CERT_FILE, KEY_FILE)
DAYS = 30                  # a run's keys are valid this long by default
HOST = re.compile(r'^[A-Za-z0-9]([A-Za-z0-9.-]{0,62})$')  # a DNS label or dotted name, no path separators
CURVE = ec.SECP256R1()     # P-256: what every TLS stack verifies, and quick to sign


class KeysError(ValueError):
    """Keys that cannot be made or used: the message is one line that names the folder or file."""


@dataclass(frozen=True)
class HostKeys:
    """A host's folder, checked: where it is, the host its certificate names, and the CA's fingerprint."""

    folder: Path
    host: str
    ca_fingerprint: str


def hosts_of(text: str) -> list[str]:
    """`--hosts a,b,c` as names, each a host name that can also be a folder name, none twice."""
    hosts = [h.strip() for h in text.split(',') if h.strip()]
    if not hosts:
        raise KeysError('--hosts: name at least one host, e.g. --hosts world,field1')
    bad = [h for h in hosts if not HOST.match(h)]
    if bad:
        raise KeysError(f'--hosts: {bad[0]!r} is not a host name (letters, digits, dots and dashes)')
    twice = sorted({h for h in hosts if hosts.count(h) > 1})
    if twice:
        raise KeysError(f'--hosts: {twice[0]} is named twice')
    return hosts


def fingerprint(cert: x509.Certificate) -> str:
    return cert.fingerprint(hashes.SHA256()).hex(':').upper()


def _name(common: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, 'uav-flock run'),
                      x509.NameAttribute(NameOID.COMMON_NAME, common)])


def make_ca(now: datetime.datetime, days: int) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    key = ec.generate_private_key(CURVE)
    name = _name('uav-flock run CA')
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False, key_encipherment=False,
                                         data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                         crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    return cert, key


def issue(ca: x509.Certificate, ca_key: ec.EllipticCurvePrivateKey, host: str, not_before: datetime.datetime,
          not_after: datetime.datetime) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    """A host's certificate, for both ends of a TLS connection (each host dials and is dialled)."""
    key = ec.generate_private_key(CURVE)
    cert = (x509.CertificateBuilder().subject_name(_name(host)).issuer_name(ca.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(not_before).not_valid_after(not_after)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName([x509.DNSName(host)]), critical=False)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    return cert, key


def _pem(cert: x509.Certificate) -> bytes:
    return cert.public_bytes(serialization.Encoding.PEM)


def _write(path: Path, data: bytes, mode: int) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    with os.fdopen(fd, 'wb') as f:
        f.write(data)
    os.chmod(path, mode)  # whatever the umask made of it


def _ours(folder: Path) -> bool:
    """A folder this command wrote: exactly a host's three files."""
    return folder.is_dir() and sorted(p.name for p in folder.iterdir()) == sorted(FILES)


def make(out: Path, hosts: Sequence[str], replace: bool = False, days: int = DAYS,
         now: Optional[datetime.datetime] = None) -> x509.Certificate:
    """Write the run's keys into out/<host>/ for every host; returns the CA's certificate.

    Refuses a folder that already holds keys unless `replace`, which removes the host folders this command
    wrote there before (and nothing else: a folder holding anything but keys stops it)."""
    if days < 1:
        raise KeysError(f'--days: {days}: keys must be valid for a day at least')
    now = now or datetime.datetime.now(datetime.timezone.utc)
    if out.exists() and not out.is_dir():
        raise KeysError(f'--out: {out} is a file')
    present = sorted(out.iterdir()) if out.is_dir() else []
    if present and not replace:
        raise KeysError(f'--out: {out} already holds keys or other files; pass --replace to make new keys there')
    foreign = [p for p in present if not _ours(p)]
    if foreign:
        raise KeysError(f'--out: {foreign[0]} is not a host folder made by `uav-flock keys`; not replacing it')
    for p in present:
        shutil.rmtree(p)
    ca, ca_key = make_ca(now, days)
    out.mkdir(parents=True, exist_ok=True)
    for host in hosts:
        cert, key = issue(ca, ca_key, host, ca.not_valid_before_utc, ca.not_valid_after_utc)
        folder = out / host
        folder.mkdir(mode=0o700)
        os.chmod(folder, 0o700)
        _write(folder / CA_FILE, _pem(ca), 0o644)
        _write(folder / CERT_FILE, _pem(cert), 0o644)
        _write(folder / KEY_FILE, key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                                    serialization.NoEncryption()), 0o600)
    return ca


def check(folder: Path, host: Optional[str] = None, now: Optional[datetime.datetime] = None) -> HostKeys:
    """A host's folder as `--secure` takes it: every file there and readable, the certificate signed by the
    CA, valid now, for `host` when given, and the key its own. Raises KeysError naming what is wrong."""
    now = now or datetime.datetime.now(datetime.timezone.utc)
    if not folder.is_dir():
        raise KeysError(f'--secure: {folder}: no such folder (make one with `uav-flock keys`)')
    raw = {}
    for name in FILES:
        try:
            raw[name] = (folder / name).read_bytes()
        except OSError as exc:
            raise KeysError(f'--secure: {folder / name}: {exc.strerror or exc}') from None
    try:
        ca = x509.load_pem_x509_certificate(raw[CA_FILE])
        cert = x509.load_pem_x509_certificate(raw[CERT_FILE])
    except ValueError:
        raise KeysError(f'--secure: {folder}: {CA_FILE} or {CERT_FILE} is not a PEM certificate') from None
    try:
        key = serialization.load_pem_private_key(raw[KEY_FILE], password=None)
    except (ValueError, TypeError):
        raise KeysError(f'--secure: {folder / KEY_FILE}: not an unencrypted PEM private key') from None
    try:
        cert.verify_directly_issued_by(ca)
    except (ValueError, TypeError, InvalidSignature):
        raise KeysError(f'--secure: {folder / CERT_FILE}: not signed by the CA in {CA_FILE}') from None
    for what, c in (('CA certificate', ca), ('certificate', cert)):
        if now < c.not_valid_before_utc:
            raise KeysError(f'--secure: {folder}: the {what} is valid only from {c.not_valid_before_utc:%Y-%m-%d %H:%M} UTC')
        if now > c.not_valid_after_utc:
            raise KeysError(f'--secure: {folder}: the {what} expired on {c.not_valid_after_utc:%Y-%m-%d %H:%M} UTC')
    names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value.get_values_for_type(x509.DNSName)
    if host is not None and host not in names:
        raise KeysError(f'--secure: {folder / CERT_FILE}: a certificate for {", ".join(names)}, not for {host}')
    if key.public_key().public_bytes(serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo) != \
            cert.public_key().public_bytes(serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo):
        raise KeysError(f'--secure: {folder / KEY_FILE}: not the key of {CERT_FILE}')
    return HostKeys(folder, names[0], fingerprint(ca))
