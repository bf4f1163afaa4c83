"""Throw-away PKI for the secured-profile tests, generated at run time with the `openssl` CLI.

`make_pki(directory)` writes two certificate authorities into `directory`:

* the deployment CA (`ca.pem`), which signs one leaf certificate per role: `router` (with
  subjectAltName DNS:localhost and IP:127.0.0.1 so clients can verify it by name), `camera`,
  `perception` and `consumer`, plus `stranger`, a valid certificate whose name no access
  control rule mentions;
* a rogue CA (`rogue-ca.pem`), unknown to the deployment, which signs the `rogue` leaf: it claims
  CN=camera and carries the router's subjectAltNames, so it can impersonate either.

Files are `<name>.pem` (certificate) and `<name>.key` (private key), the names the configs in
config/secure/ use under `certs/`. The CN of every leaf is its name (except `rogue`), which is
what the router's access control matches on. Keys are ECDSA P-256 in PKCS#8 PEM; certificates
are valid for one day.
"""

from __future__ import annotations

import secrets
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

ROLES: tuple[str, ...] = ("router", "camera", "perception", "consumer")
"""Leaf certificates signed by the deployment CA; the CN of each is its role name."""

STRANGER = "stranger"
"""Leaf signed by the deployment CA whose CN (stranger) the access control does not list."""

ROGUE = "rogue"
"""Leaf signed by the rogue CA, claiming CN=camera."""

ROGUE_COMMON_NAME = "camera"

_VALID_DAYS = "1"


class CertificateError(RuntimeError):
    """The test PKI could not be generated (openssl missing or failing)."""


@dataclass(frozen=True)
class KeyPair:
    """PEM paths of one leaf: its certificate and its private key."""

    cert: Path
    key: Path


@dataclass(frozen=True)
class Pki:
    """Paths of the generated PKI."""

    ca: Path
    """Deployment CA certificate: the router and the clients trust it."""
    rogue_ca: Path
    """CA certificate of the rogue chain (trusted by nobody in the deployment)."""
    leaves: dict[str, KeyPair]
    """Leaves by name: every entry of `ROLES`, `STRANGER` and `ROGUE`."""

    def __getitem__(self, name: str) -> KeyPair:
        return self.leaves[name]


def _openssl() -> str:
    exe = shutil.which("openssl")
    if exe is None:
        raise CertificateError(
            "the openssl command-line tool is required to generate test certificates"
        )
    return exe


def _run(*args: str) -> None:
    try:
        subprocess.run([_openssl(), *args], check=True, capture_output=True, text=True)
    except subprocess.CalledProcessError as err:
        raise CertificateError(f"openssl {args[0]} failed: {err.stderr.strip()}") from err


def _serial() -> str:
    return "0x" + secrets.token_hex(16)


def _new_key(path: Path) -> None:
    _run("genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256", "-out", str(path))


def _make_ca(directory: Path, name: str, common_name: str) -> KeyPair:
    key = directory / f"{name}.key"
    cert = directory / f"{name}.pem"
    _new_key(key)
    ext = directory / f"{name}.ext"
    ext.write_text(
        "[v3_ca]\n"
        "basicConstraints = critical, CA:TRUE\n"
        "keyUsage = critical, keyCertSign, cRLSign\n"
        "subjectKeyIdentifier = hash\n",
        encoding="utf-8",
    )
    _run(
        "req", "-x509", "-new", "-key", str(key), "-subj", f"/CN={common_name}",
        "-days", _VALID_DAYS, "-set_serial", _serial(),
        "-config", str(ext), "-extensions", "v3_ca", "-out", str(cert),
    )  # fmt: skip
    return KeyPair(cert=cert, key=key)


def _make_leaf(
    directory: Path, name: str, ca: KeyPair, *, server: bool, common_name: str | None = None
) -> KeyPair:
    key = directory / f"{name}.key"
    csr = directory / f"{name}.csr"
    cert = directory / f"{name}.pem"
    ext = directory / f"{name}.ext"
    _new_key(key)
    _run("req", "-new", "-key", str(key), "-subj", f"/CN={common_name or name}", "-out", str(csr))
    lines = [
        "basicConstraints = critical, CA:FALSE",
        "keyUsage = critical, digitalSignature",
        # A router both accepts (server) and may open (client) TLS links.
        "extendedKeyUsage = " + ("serverAuth, clientAuth" if server else "clientAuth"),
        "subjectKeyIdentifier = hash",
        "authorityKeyIdentifier = keyid",
    ]
    if server:
        lines.append("subjectAltName = DNS:localhost, IP:127.0.0.1")
    ext.write_text("\n".join(lines) + "\n", encoding="utf-8")
    _run(
        "x509", "-req", "-in", str(csr), "-CA", str(ca.cert), "-CAkey", str(ca.key),
        "-set_serial", _serial(), "-days", _VALID_DAYS, "-extfile", str(ext), "-out", str(cert),
    )  # fmt: skip
    return KeyPair(cert=cert, key=key)


def make_pki(directory: Path) -> Pki:
    """Generate the deployment CA, one leaf per role, and a rogue CA with its leaf."""
    directory.mkdir(parents=True, exist_ok=True)
    ca = _make_ca(directory, "ca", "zenoh-perception test CA")
    rogue_ca = _make_ca(directory, "rogue-ca", "rogue CA")
    leaves = {role: _make_leaf(directory, role, ca, server=role == "router") for role in ROLES}
    leaves[STRANGER] = _make_leaf(directory, STRANGER, ca, server=False)
    leaves[ROGUE] = _make_leaf(
        directory, ROGUE, rogue_ca, server=True, common_name=ROGUE_COMMON_NAME
    )
    return Pki(ca=ca.cert, rogue_ca=rogue_ca.cert, leaves=leaves)
