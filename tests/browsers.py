"""Headless Chromium for the browser tests: Debian's chromium driven by selenium through
the system chromedriver (never Selenium Manager, which would reach for the network), with
software WebGL2 (ANGLE on SwiftShader)."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

CHROMIUM, CHROMEDRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")
HAVE_CHROMIUM = CHROMIUM.exists() and CHROMEDRIVER.exists()
NO_CHROMIUM = ("needs Debian's chromium and chromium-driver (apt-get install chromium "
               "chromium-driver; .ci/run installs them)")


def start_browser(script_timeout_s: float, size: tuple[int, int] | None = None):
    """Headless chromium through the system chromedriver; (driver, profile folder)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    profile = tempfile.mkdtemp(prefix="lodsprite-chromium-")
    args = ["--headless=new", "--no-sandbox", "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run",
            f"--user-data-dir={profile}"]
    if size is not None:
        args.append(f"--window-size={size[0]},{size[1]}")
    for arg in args:
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})  # console, for failures
    driver = webdriver.Chrome(service=Service(executable_path=str(CHROMEDRIVER)),
                              options=options)
    driver.set_script_timeout(script_timeout_s)
    return driver, profile


def quit_browser(driver, profile: str) -> None:
    """Quit ``driver`` and remove its profile folder."""
    driver.quit()
    shutil.rmtree(profile, ignore_errors=True)
