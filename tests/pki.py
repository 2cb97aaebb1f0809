"""A certificate authority for tests, made by the fleet example's own script.

``Pki(folder).certificate("drive1")`` is a certificate with common name
``drive1`` (also valid as a server for localhost and 127.0.0.1) signed by the
test CA; ``ca="other"`` signs it with a second, unrelated CA. Both come from
``config/fleet/make-certs.sh``, the script the README's fleet set-up uses.
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MAKE_CERTS = REPO / "config" / "fleet" / "make-certs.sh"
OPENSSL = shutil.which("openssl")


def make_certs(folder: Path, ca: str, *names: str) -> None:
    """Run ``make-certs.sh folder ca names...``."""
    subprocess.run(
        ["sh", str(MAKE_CERTS), str(folder), ca, *names], check=True, capture_output=True,
        timeout=120,
    )  # fmt: skip


@dataclass(frozen=True)
class Certificate:
    certificate: Path
    private_key: Path


class Pki:
    def __init__(self, folder: Path) -> None:
        self.folder = folder
        make_certs(folder / "ca", "ca")
        self.root_ca = folder / "ca" / "ca.pem"

    def certificate(self, common_name: str, ca: str = "ca") -> Certificate:
        """A certificate (and key) for ``common_name`` signed by ``ca`` ("ca" or "other")."""
        where = self.folder / ca
        made = Certificate(where / f"{common_name}.pem", where / f"{common_name}.key")
        if not made.certificate.exists():
            make_certs(where, ca, common_name)
        return made
