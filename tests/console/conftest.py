"""Fixtures of the console tests: a small simulated plant, a console server process
(``heliocal console --simulate``) and a headless Chromium driven by Selenium.

Selenium uses the system chromedriver (Debian ``chromium-driver``, /usr/bin/chromedriver)
through an explicit Service, with Selenium Manager told to stay offline: nothing is downloaded.
"""

from __future__ import annotations

import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import yaml

from tests.conftest import scaled_s

REPO = Path(__file__).resolve().parents[2]
IDS = ["H02", "H08", "H14"]  # serial bus 1, serial bus 2, Modbus TCP
SPEEDUP = "50"  # plant clock of the simulated plant, x real time


def small_config_file(path: Path, **calibration) -> Path:
    """The demo plant with a 256x192 camera (quick to render), ``calibration`` keys overridden."""
    data = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    data["camera"]["width_px"], data["camera"]["height_px"] = 256, 192
    reg = data["camera"].get("registration")
    if reg:  # the same lens on a 4x binned sensor: a quarter of the focal length in pixels
        reg["focal_px"] = reg["focal_px"] * 256 / 1024
    data["calibration"].update(calibration)
    path.write_text(yaml.safe_dump(data))
    return path


class ConsoleProcess:
    """``heliocal console`` in a subprocess; ``url`` once it listens."""

    def __init__(self, args: list[str]) -> None:
        self.p = subprocess.Popen([sys.executable, "-m", "controller.cli", "console", *args], cwd=REPO,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines: queue.Queue[str] = queue.Queue()
        self.stderr: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()
        self.url = self._wait_url(scaled_s(60.0))

    def _read(self) -> None:
        for line in self.p.stderr:
            self.stderr.append(line)
            self.lines.put(line)

    def _wait_url(self, seconds: float) -> str:
        while True:
            try:
                line = self.lines.get(timeout=seconds)
            except queue.Empty:
                self.stop()
                raise AssertionError("the console did not start: " + "".join(self.stderr)) from None
            m = re.search(r"(http://\S+?)/? \(", line)
            if m:
                return m.group(1)

    def stop(self) -> int:
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGINT)
            try:
                self.p.wait(scaled_s(30.0))
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait()
        return self.p.returncode


@pytest.fixture(scope="module")
def console_server(tmp_path_factory):
    """A console on a 3-heliostat simulated plant (module-wide: the browser tests share it)."""
    tmp = tmp_path_factory.mktemp("console")
    cfg = small_config_file(tmp / "small.yaml")
    proc = ConsoleProcess(["--config", str(cfg), "--db", str(tmp / "c.db"), "--simulate", "--heliostats",
                           ",".join(IDS), "--port", "0", "--clock-speedup", SPEEDUP,
                           "--run-dir", str(tmp / "run")])
    proc.db, proc.config = tmp / "c.db", cfg
    yield proc
    proc.stop()


def chrome(width: int = 1024, height: int = 900):
    """Headless Chromium through the system chromedriver (no downloads), or None when either is
    not installed."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_path = shutil.which("chromedriver") or "/usr/bin/chromedriver"
    if chromium is None or not Path(driver_path).is_file():
        return None
    os.environ["SE_OFFLINE"] = "true"  # Selenium Manager must not fetch anything
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    opts = Options()
    opts.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                f"--window-size={width},{height}", "--hide-scrollbars", "--no-first-run",
                "--disable-extensions"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(executable_path=driver_path), options=opts)
    driver.set_page_load_timeout(scaled_s(30.0))
    return driver


@pytest.fixture(scope="module")
def browser():
    """Headless Chromium, 1024 px wide."""
    driver = chrome()
    if driver is None:
        pytest.skip("chromium / chromedriver not installed (apt-get install chromium chromium-driver); "
                    "the browser tests need them")
    yield driver
    driver.quit()
