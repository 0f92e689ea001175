"""The console in a real browser (headless Chromium) against the simulated plant: click through
commissioning, watch a 3-heliostat campaign to its end, then a planned night, and read it on
the Reports page (the night's morning report) and a heliostat's page (its nights side by side,
the beam image with that measurement's aim point)."""

from __future__ import annotations

import time
import urllib.request

import cv2
import numpy as np
import pytest
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

from controller.config import load_config
from controller.geometry.target_frame import TargetFrame
from controller.storage.db import CampaignStore
from controller.storage.trends import heliostat_trends
from tests.conftest import scaled_s

# The tests share one console and follow on from each other (commissioning, night 0, night 1):
# one worker runs them, in order.
pytestmark = pytest.mark.xdist_group("console-browser")


def _text(driver, css: str) -> str:
    """Text of the element (read in one script call: the live page re-renders under us)."""
    return driver.execute_script(f"const e = document.querySelector({css!r}); return e ? e.innerText : ''")


def _texts(driver, css: str) -> list[str]:
    return driver.execute_script(f"return [...document.querySelectorAll({css!r})].map((e) => e.innerText)")


def _wait(driver, seconds: float, cond, what: str):
    return WebDriverWait(driver, scaled_s(seconds), poll_frequency=0.05).until(
        lambda d: cond(d), message=f"waited {scaled_s(seconds):g} s for {what}")


def _click_step(driver, step: str, seconds: float = 30.0) -> str:
    """Click a commissioning step and wait for its result line (✔ …) or an error message."""
    res = f"#res-{step}"
    driver.execute_script(f"document.querySelector('{res}').textContent = ''")
    driver.find_element(By.ID, f"step-{step}").click()
    failed = "document.getElementById('msg').classList.contains('err')"
    _wait(driver, seconds, lambda d: _text(d, res) or d.execute_script(f"return {failed}"),
          f"the result of {step}")
    assert _text(driver, res).startswith("✔"), _text(driver, "#msg")
    return _text(driver, res)


def test_commissioning_click_through(console_server, browser):
    d = browser
    d.get(f"{console_server.url}/commission/H02")
    _wait(d, 20, lambda d: _text(d, "#live") == "live" and d.find_elements(By.ID, "az-steps"),
          "the live page")
    assert _text(d, "#az-steps") == "500"  # the simulated plant starts at stow

    assert "firmware sim-" in _click_step(d, "connect")
    assert "refused before sending" in _click_step(d, "limits")

    # Jog: the drive status on the page follows the drive (server-sent events).
    jog = d.find_element(By.ID, "jog-n")
    jog.clear()
    jog.send_keys("300")
    d.find_element(By.CSS_SELECTOR, "button[data-j='1,0']").click()
    _wait(d, 20, lambda d: _text(d, "#az-steps") == "800", "azimuth 800 steps on the page")
    assert _text(d, "#el-steps") == "500"

    # An out-of-range move: refused by the controller, shown, nothing moved.
    d.find_element(By.ID, "move-az").send_keys("999999")
    d.find_element(By.ID, "move-el").send_keys("600")
    d.find_element(By.ID, "move-go").click()
    _wait(d, 10, lambda d: "soft limits" in _text(d, "#msg"), "the refusal")
    msg = d.find_element(By.ID, "msg")
    assert "err" in msg.get_attribute("class") and "nothing was sent" in msg.text
    time.sleep(0.3)  # a status change would arrive within the poll period; none must come
    assert (_text(d, "#az-steps"), _text(d, "#el-steps")) == ("800", "500")

    _click_step(d, "aim")
    capture = _click_step(d, "capture")
    assert "centroid x" in capture
    x, y = (float(v) for v in capture.split("centroid x ")[1].split(" px")[0].split(" y "))
    # The page shows the beam image with the centroid drawn (red cross) where the result says.
    shown = ("const i = document.getElementById('beam'); "
             "return i.complete && i.naturalWidth > 0 && i.style.display !== 'none'")
    _wait(d, 10, lambda d: d.execute_script(shown), "the beam image")
    src = d.find_element(By.ID, "beam").get_attribute("src")
    png = cv2.imdecode(np.frombuffer(urllib.request.urlopen(src).read(), np.uint8), cv2.IMREAD_COLOR)
    k = png.shape[1] // 256  # the image is scaled up from the 256-px camera
    cx, cy = int((x + 0.5) * k), int((y + 0.5) * k)
    patch = png[cy - 8:cy + 9, cx - 8:cx + 9].astype(int)
    red = (patch[..., 2] > 200) & (patch[..., 1] < 60) & (patch[..., 0] < 60)
    assert red.sum() >= 10, "no red centroid mark at the centroid"
    assert "Δaz" in _click_step(d, "correct")
    assert "saved" in _click_step(d, "record")
    _click_step(d, "park")


def test_campaign_to_completion(console_server, browser):
    d = browser
    d.get(f"{console_server.url}/campaign")
    _wait(d, 20, lambda d: _text(d, "#live") == "live" and d.find_element(By.ID, "start").is_enabled(),
          "the campaign page")
    d.find_element(By.ID, "name").send_keys("browser-night")
    d.find_element(By.ID, "start").click()
    seen: set[str] = set()
    deadline = time.monotonic() + scaled_s(60.0)
    while time.monotonic() < deadline:
        seen.update(_texts(d, "#queue tbody td:nth-child(3)"))
        if _text(d, "#camp-status") not in ("running", "idle", ""):
            break
        time.sleep(0.05)
    assert _text(d, "#camp-status") == "finished", _text(d, "#prog")
    assert _text(d, "#camp-done") == "3 / 3"
    results = _texts(d, "#queue td.result")
    assert results == ["calibrated"] * 3
    assert seen & {"slewing", "capturing", "settling", "verifying"}, f"no live state shown, saw {seen}"
    assert _text(d, "#holder") == "nobody"
    assert "ok" in _text(d, "#safety")


def test_a_planned_night_on_the_reports_and_heliostat_pages(console_server, browser):
    d = browser
    d.get(f"{console_server.url}/campaign")
    _wait(d, 20, lambda d: _text(d, "#live") == "live" and d.find_element(By.ID, "night-start").is_enabled(),
          "the campaign page")
    d.find_element(By.ID, "night-start").click()
    _wait(d, 180, lambda d: _text(d, "#night-status") in ("finished", "partial"), "the end of the night")

    # Reports: the nights, the latest shown first with its morning report and trend.
    d.get(f"{console_server.url}/reports")
    _wait(d, 20, lambda d: len(_texts(d, "#nights tbody tr")) == 2, "the two nights")
    row = _texts(d, "#nights tbody tr")[0].split("\t")
    assert row[0] == "1" and row[2] == "planned"
    measured, planned = (int(v) for v in row[5].split(" / "))
    assert 0 < measured <= planned
    loaded = ("const f = document.getElementById('report').contentDocument; "
              "return f && f.readyState === 'complete' && [...f.images].length > 0 && "
              "[...f.images].every((i) => i.complete && i.naturalWidth > 0)")
    _wait(d, 60, lambda d: d.execute_script(loaded), "the night's report with its figures")
    d.switch_to.frame("report")
    assert d.find_element(By.TAG_NAME, "h1").text.startswith("Morning report: night 1")
    shown = {i.get_attribute("src").rsplit("/", 1)[-1] for i in d.find_elements(By.TAG_NAME, "img")}
    assert {"passes.png", "field_map.png", "trend.png"} <= shown
    d.switch_to.default_content()

    # A heliostat's page: its nights, as the database has them, and the chart of them.
    with CampaignStore(console_server.db, readonly=True) as store:
        trends = heliostat_trends(store, ["H02", "H08", "H14"])
        last = {}
        for hid in trends:
            ms = [m for m in store.measurements(heliostat_id=hid) if len(store.images(m.id)) >= 2]
            last[hid] = (ms[-1], store.campaign(ms[-1].campaign_id).target)
    d.get(f"{console_server.url}/heliostat/H02")
    _wait(d, 20, lambda d: len(_texts(d, "#nights tbody tr")) == len(trends["H02"]), "the nights' table")
    cells = [r.split("\t") for r in _texts(d, "#nights tbody tr")]
    assert [c[0].split(" · ")[0] for c in cells] == ["0", "1"]
    assert [c[3] for c in cells] == [f"{p['first_look_error_mrad']:.3f}" for p in trends["H02"]]
    assert cells[1][4] == f"{trends['H02'][1]['predicted_rms_mrad']:.3f}"
    points = d.execute_script(
        "return [...document.querySelectorAll('#trend polyline')].map((p) => p.points.length)")
    assert points == [2, 1]  # first looks on nights 0 and 1; a prediction from night 1 on

    # The beam image marks the aim point of its measurement, not the target centre: the
    # heliostat whose last stored measurement aimed farthest from the centre.
    cfg = load_config(console_server.config)
    far = max(last, key=lambda h: np.linalg.norm(np.subtract(last[h][0].aim_enu,
                                                             cfg.target(last[h][1]).center_enu_m)))
    m, tid = last[far]
    cam = cfg.camera_of(tid)
    frame = TargetFrame.from_config(cfg.target(tid), (cam.height_px, cam.width_px))
    # The pixel whose centre is the aim point (TargetFrame.pixel_to_enu is linear in x and y).
    o = frame.pixel_to_enu(0, 0)
    ex, ey = frame.pixel_to_enu(1, 0) - o, frame.pixel_to_enu(0, 1) - o
    d_aim = np.asarray(m.aim_enu) - o
    ax, ay = d_aim @ ex / (ex @ ex), d_aim @ ey / (ey @ ey)
    off = np.hypot(ax - (frame.shape[1] - 1) / 2, ay - (frame.shape[0] - 1) / 2)
    assert off > 10, "no measurement aimed off the centre"
    url = f"{console_server.url}/api/heliostats/{far}/image.png"
    png = cv2.imdecode(np.frombuffer(urllib.request.urlopen(url).read(), np.uint8), cv2.IMREAD_COLOR)
    k = png.shape[1] / frame.shape[1]
    cyan = (png[..., 0] > 200) & (png[..., 1] > 200) & (png[..., 2] < 80)
    ys, xs = np.nonzero(cyan)
    assert len(xs) > 50, "no cyan aim mark"
    assert abs(xs.mean() - (ax + 0.5) * k) < 3 and abs(ys.mean() - (ay + 0.5) * k) < 3
