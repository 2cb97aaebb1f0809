"""Headless Chromium for the tests that open a report page (skipped where it is missing)."""

from __future__ import annotations

import shutil
from pathlib import Path

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
MISSING = "chromium not installed (apt-get install chromium)"


def headless(profile: Path) -> list[str]:
    """The command line of a headless Chromium that fetches nothing on its own."""
    assert CHROMIUM is not None, MISSING
    return [
        CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
        "--no-first-run", "--disable-background-networking", "--disable-component-update",
        "--disable-sync", f"--user-data-dir={profile}",
    ]  # fmt: skip
