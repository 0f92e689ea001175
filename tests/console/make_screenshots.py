"""Screenshots of every console page for docs/console.md (docs/img/console-*.png, 1024 px wide).

Run from the repository: ``python -m tests.console.make_screenshots [--out docs/img]``. Starts
``heliocal console --simulate`` on the demo plant (all its heliostats on the map, full-size
camera), clicks through commissioning of one heliostat in headless Chromium, runs a 6-heliostat
campaign and then a planned night of them from the campaign page and photographs each page.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import urllib.request
from pathlib import Path

import cv2

from tests.console.conftest import REPO, ConsoleProcess, chrome

CAMPAIGN = ["H02", "H05", "H08", "H11", "H14", "H17"]


def shoot(driver, path: Path, settle_s: float = 0.6) -> None:
    """The whole page, 1024 px wide, as a compact PNG."""
    time.sleep(settle_s)
    driver.execute_script("document.activeElement.blur(); window.scrollTo(0, 0);")
    height = driver.execute_script("return Math.ceil(document.documentElement.scrollHeight)")
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", {
        "width": 1024, "height": max(600, min(int(height), 2400)), "deviceScaleFactor": 1, "mobile": False})
    time.sleep(0.3)
    driver.save_screenshot(str(path))
    driver.execute_cdp_cmd("Emulation.clearDeviceMetricsOverride", {})
    img = cv2.imread(str(path))
    cv2.imwrite(str(path), img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"{path}: {img.shape[1]}x{img.shape[0]} px, {path.stat().st_size // 1024} KiB")


def wait_text(driver, css: str, ok, seconds: float) -> str:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        t = driver.execute_script(f"const e = document.querySelector({css!r}); return e ? e.innerText : ''")
        if ok(t):
            return t
        time.sleep(0.1)
    raise RuntimeError(f"{css}: still {t!r} after {seconds} s")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(REPO / "docs" / "img"), help="output folder (default docs/img)")
    ap.add_argument("--reports", default=None, help="folder of confusion reports to show on the reports page")
    args = ap.parse_args()
    out = Path(args.out)
    driver = chrome(1024, 800)
    if driver is None:
        raise SystemExit("chromium / chromedriver not installed")
    with tempfile.TemporaryDirectory() as tmp:
        extra = ["--reports", args.reports] if args.reports else []
        proc = ConsoleProcess(["--config", "configs/demo.yaml", "--db", f"{tmp}/c.db",
                               "--simulate", "--port", "0", "--clock-speedup", "50",
                               "--run-dir", f"{tmp}/run", *extra])
        try:
            u = proc.url
            d = driver
            d.get(f"{u}/commission/H05")
            wait_text(d, "#live", lambda t: t == "live", 30)
            for step in ("connect", "limits", "aim", "capture", "correct", "verify"):
                d.find_element("id", f"step-{step}").click()
                wait_text(d, f"#res-{step}", bool, 60)
            d.find_element("id", "move-az").send_keys("999999")
            d.find_element("id", "move-el").send_keys("30000")
            d.find_element("id", "move-go").click()
            wait_text(d, "#msg", lambda t: "soft limits" in t, 10)
            shoot(d, out / "console-commission.png", 1.5)
            d.find_element("id", "step-park").click()
            wait_text(d, "#res-park", bool, 60)

            d.get(f"{u}/campaign")
            wait_text(d, "#live", lambda t: t == "live", 30)
            d.execute_script("document.querySelectorAll('.hs').forEach((c) => { c.checked = "
                             f"{json.dumps(CAMPAIGN)}.includes(c.value); }})")
            d.find_element("id", "name").send_keys("demo-night")
            d.find_element("id", "start").click()
            wait_text(d, "#camp-done", lambda t: t.startswith("2 /"), 120)
            shoot(d, out / "console-campaign.png", 0.0)
            wait_text(d, "#camp-status", lambda t: t not in ("running", ""), 240)
            d.find_element("id", "night-start").click()
            wait_text(d, "#night-status", lambda t: t in ("finished", "partial"), 900)

            d.get(f"{u}/field")
            wait_text(d, "#live", lambda t: t == "live", 30)
            d.execute_script("const m = document.getElementById('mode'); m.value = 'error'; m.onchange();")
            shoot(d, out / "console-field.png", 1.5)
            d.get(f"{u}/heliostat/H08")
            wait_text(d, "#live", lambda t: t == "live", 30)
            shoot(d, out / "console-heliostat.png", 2.0)
            d.get(f"{u}/reports")
            wait_text(d, "#nights tbody", lambda t: "planned" in t, 30)
            shoot(d, out / "console-reports.png", 6.0)
            with urllib.request.urlopen(f"{u}/api/campaign") as r:
                print(json.dumps(json.loads(r.read())["outcome"]))
        finally:
            driver.quit()
            proc.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
