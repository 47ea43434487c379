"""A headless Chromium for the viewer's browser tests: Debian's ``chromium`` and ``chromium-driver`` driven by
selenium, WebGL in software (SwiftShader). ``.ci/run`` installs the two packages when they are missing; on a
machine without them the tests that need a browser are skipped, saying which binary is missing."""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

CHROMIUM, CHROMEDRIVER = "chromium", "chromedriver"
#: Flags of a headless Chromium on a closed network: software WebGL, no sandbox (root in CI), no calls home.
FLAGS = (
    "--headless=new",
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-dev-shm-usage",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)


def chromium(width: int = 800, height: int = 600):
    """A selenium WebDriver of a headless Chromium with a ``width`` x ``height`` window; skips the test when
    Chromium or chromedriver is not installed."""
    binaries = {name: shutil.which(name) for name in (CHROMIUM, CHROMEDRIVER)}
    missing = [name for name, path in binaries.items() if path is None]
    if missing:
        pytest.skip(f"{' and '.join(missing)} not installed (apt-get install chromium chromium-driver)")
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    options.binary_location = binaries[CHROMIUM]
    for flag in (*FLAGS, f"--window-size={width},{height}"):
        options.add_argument(flag)
    return webdriver.Chrome(service=Service(binaries[CHROMEDRIVER]), options=options)


def screenshot(driver, path: Path) -> np.ndarray:
    """The page as (H, W, 3) uint8, also saved to ``path``."""
    from PIL import Image

    driver.save_screenshot(str(path))
    return np.asarray(Image.open(path).convert("RGB"))


def wait_for(condition: Callable[[], object], timeout: float, what: str, every: float = 0.2):
    """``condition()``'s first truthy value within ``timeout`` seconds, else an AssertionError naming
    ``what``."""
    end = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > end:
            raise AssertionError(f"{what}: not within {timeout:g} s")
        time.sleep(every)
