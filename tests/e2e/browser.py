"""A real headless Chromium for the studio's tests (Debian's ``chromium`` driven by Playwright
for Python through ``executable_path``; never a downloaded browser).

``browser`` (module-scoped) skips with the reason when Chromium or Playwright is missing,
except under BONEFIT_TEST_REQUIRE_SERVICES=1 (CI), where it fails. ``BONEFIT_TEST_CHROMIUM``
overrides the binary.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from typing import TYPE_CHECKING

import pytest

from tests.e2e.services import unavailable

if TYPE_CHECKING:
    from playwright.sync_api import Browser

CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]


def find_chromium() -> str | None:
    """The Chromium binary: BONEFIT_TEST_CHROMIUM, or ``chromium`` on PATH."""
    override = os.environ.get("BONEFIT_TEST_CHROMIUM")
    if override:
        return override if os.path.isfile(override) else None
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    """A headless Chromium."""
    binary = find_chromium()
    if binary is None:
        unavailable("no Chromium (apt-get install chromium)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        unavailable("Playwright for Python is not installed (pip install playwright)")
    with sync_playwright() as playwright:
        chromium = playwright.chromium.launch(executable_path=binary, args=CHROMIUM_ARGS)
        try:
            yield chromium
        finally:
            chromium.close()
