"""The point picker: `chainspace pick` writes a standalone page; a real browser clicks on it and the key
frames it produces hold the clicked pixels, whatever the CSS scaling of the frame.

The browser test needs headless Chromium and chromedriver (Debian packages ``chromium`` and
``chromium-driver``) and selenium; without them it is skipped and says why.
"""

from __future__ import annotations

import base64
import json
import os
import re
import shutil

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from chainspace import VideoError, write_picker
from chainspace.cli import app
from chainspace.video.keyframes import load_keyframes

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or (
    "/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else None)
CHROMEDRIVER = shutil.which("chromedriver") or (
    "/usr/bin/chromedriver" if os.path.exists("/usr/bin/chromedriver") else None)
SIZE = (1200, 900)  # wider than the page leaves it: "fit" shows it scaled down


@pytest.fixture
def frames(tmp_path, rng):
    d = tmp_path / "frames"
    d.mkdir()
    for k in range(3):
        cv2.imwrite(str(d / f"img{k}.jpg"), rng.integers(0, 255, (SIZE[1], SIZE[0], 3), dtype=np.uint8))
    return d


def _data(page: str) -> dict:
    return json.loads(re.search(r"const DATA = (\{.*?\});\n", page, re.S).group(1))


def test_the_page_embeds_the_frames_and_the_names(frames, tmp_path):
    out = write_picker(frames, tmp_path / "pick.html", [2, 0], names=["base", "elbow", "tip"])
    data = _data(out.read_text())
    assert [f["index"] for f in data["frames"]] == [0, 2] and data["names"] == ["base", "elbow", "tip"]
    jpeg = np.frombuffer(base64.b64decode(data["frames"][1]["jpeg"]), np.uint8)
    assert cv2.imdecode(jpeg, cv2.IMREAD_COLOR).shape == (SIZE[1], SIZE[0], 3)
    with pytest.raises(Exception, match="already exists"):
        write_picker(frames, out, [0])
    with pytest.raises(VideoError, match="frame 7 is out of range"):
        write_picker(frames, tmp_path / "other.html", [7])


def test_cli_pick_with_a_chain(frames, tmp_path):
    out = tmp_path / "p.html"
    res = CliRunner().invoke(app, ["pick", str(frames), "--frame", "1", "--chain", "coco17", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert _data(out.read_text())["names"][:2] == ["nose", "left_eye"]


def _driver(tmp_path):
    if CHROMIUM is None or CHROMEDRIVER is None:
        pytest.skip("headless Chromium or chromedriver not found (Debian packages chromium and chromium-driver)")
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=900,700",
                "--force-device-scale-factor=1", f"--user-data-dir={tmp_path / 'profile'}"):
        options.add_argument(arg)
    try:
        return webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))
    except Exception as exc:  # a browser that cannot start here is an environment problem
        pytest.skip(f"Chromium did not start under chromedriver: {str(exc).splitlines()[0]}")


@pytest.mark.browser
def test_clicks_in_a_browser_give_the_clicked_pixels(frames, tmp_path):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    page = write_picker(frames, tmp_path / "pick.html", [0], names=["base", "elbow", "tip", "tool"])
    driver = _driver(tmp_path)
    try:
        driver.get(page.resolve().as_uri())
        img = driver.find_element(By.ID, "image")
        rect = driver.execute_script("const r = arguments[0].getBoundingClientRect();"
                                     "return [r.left, r.top, r.width, r.height];", img)
        scale = rect[2] / SIZE[0]
        assert scale < 0.7, "the frame should be shown scaled down"

        def click(vx: int, vy: int) -> list[float]:
            """Click at viewport point (vx, vy) px; return the image pixel the page should record."""
            actions = ActionChains(driver)
            actions.w3c_actions.pointer_action.move_to_location(vx, vy).click()
            actions.perform()
            return [(vx - rect[0]) / scale - 0.5, (vy - rect[1]) / scale - 0.5]

        def current() -> str:
            return driver.find_element(By.CSS_SELECTOR, "li.current").text

        assert current() == "base"
        expected = {"base": click(int(rect[0]) + 40, int(rect[1]) + 30)}
        assert current() == "elbow"
        click(int(rect[0]) + 100, int(rect[1]) + 200)
        driver.find_element(By.ID, "undo").click()  # the elbow was misplaced
        assert current() == "elbow"
        expected["elbow"] = click(int(rect[0]) + 151, int(rect[1]) + 97)
        driver.find_element(By.ID, "skip").click()  # the tip is not visible
        # zoomed to 200 %: another CSS scale, the same image pixels
        Select(driver.find_element(By.ID, "zoom")).select_by_value("2")
        rect = driver.execute_script("const r = arguments[0].getBoundingClientRect();"
                                     "return [r.left, r.top, r.width, r.height];", img)
        scale = rect[2] / SIZE[0]
        assert scale == pytest.approx(2.0)
        expected["tool"] = click(int(rect[0]) + 301, int(rect[1]) + 211)
        keyframes = json.loads(driver.find_element(By.ID, "json").get_attribute("value"))
    finally:
        driver.quit()
    assert list(keyframes) == ["0"] and list(keyframes["0"]) == ["base", "elbow", "tool"]
    for name, xy in expected.items():
        np.testing.assert_allclose(keyframes["0"][name], xy, atol=0.006)  # rounded to 0.01 px
    # what the page writes is what `chainspace track` reads
    assert load_keyframes(keyframes, image_size=SIZE)[0]["base"] == tuple(keyframes["0"]["base"])
