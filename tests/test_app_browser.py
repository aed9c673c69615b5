"""The web demo in headless Chromium: upload, Run, overlay, metrics, GLB download, errors, and
click-to-prompt (a click on the photo adds a point, Show mask previews the mask, Run uses it).

Uses the driver and the stand-in reconstruction of ``scripts/app_screenshot.py``; the server
runs on 127.0.0.1 at a free port in a background thread. Slow (a browser start and a page
load, about 20 s); skipped only when gradio, selenium or the system Chromium is missing.
"""

from __future__ import annotations

import importlib.util
import io
import shutil
import time
import urllib.request
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from easyhoi.perception.prompts import Prompts
from tests.test_app import load_screenshot_script, photo

pytestmark = pytest.mark.slow

standin = load_screenshot_script()


def _missing() -> str | None:
    if importlib.util.find_spec("gradio") is None:
        return "gradio not installed (pip install 'easyhoi[demo]')"
    if importlib.util.find_spec("selenium") is None:
        return "selenium not installed (pip install selenium)"
    for exe in (standin.CHROMIUM, standin.CHROMEDRIVER):
        if not Path(exe).is_file() and not shutil.which(Path(exe).name):
            return f"{exe} not installed (apt-get install chromium chromium-driver)"
    return None


if _missing():
    pytest.skip(_missing(), allow_module_level=True)


#: prompts each reconstruction of the served page got (None: no click)
PROMPTS_SEEN: list = []


def slowed_standin(image_path, out_dir, config, *, progress=None, **kw):
    """The stand-in, with 0.1 s per progress report so that the page can show them."""

    def slow(*args):
        time.sleep(0.1)
        progress(*args)

    PROMPTS_SEEN.append(kw.get("prompts"))
    return standin.standin_reconstruct(image_path, out_dir, config, progress=slow, **kw)


@pytest.fixture(scope="module")
def server():
    app, url = standin.start_demo(slowed_standin, segment_fn=standin.standin_segment)
    yield url
    app.close()


@pytest.fixture(scope="module")
def driver(tmp_path_factory):
    d = standin.make_driver(tmp_path_factory.mktemp("chromium-profile"))
    yield d
    d.quit()


def _get(url: str) -> bytes:
    return urllib.request.urlopen(url, timeout=30).read()


def test_upload_run_shows_overlay_metrics_and_serves_the_glb(server, driver, tmp_path):
    src = photo(tmp_path / "browser photo.png", size=(320, 240))
    shown = standin.run_flow(driver, server, src, timeout=90)
    shot = tmp_path / "app.png"
    driver.save_screenshot(str(shot))
    assert shown["error_text"] == ""
    # progress fed from the reconstruction's callbacks reached the page
    assert {"optimizing: camera", "optimizing: contact", "optimizing: refine"} & set(
        shown["progress_seen"]
    ), shown["progress_seen"]
    # the overlay shown is the reconstruction's overlay: the photo size, hand drawn over it
    overlay = Image.open(io.BytesIO(_get(shown["overlay_src"]))).convert("RGB")
    assert overlay.size == (320, 240)
    diff = np.abs(np.asarray(overlay, int) - np.asarray(Image.open(src).convert("RGB"), int))
    assert 0.02 < (diff.sum(-1) > 30).mean() < 0.9
    # metrics table as text
    text = shown["metrics_text"]
    assert "penetration depth" in text and "0.21 cm" in text and "in contact" in text
    assert "hand mask IoU" in text and "seed" in text
    # downloads: a zip of the result folder and a GLB served over HTTP
    names = [u.rsplit("/", 1)[-1] for u in shown["download_urls"]]
    assert names == ["browser_photo-easyhoi.zip", "scene.glb", "report.html"]
    glb = _get(shown["download_urls"][1])
    assert glb[:4] == b"glTF" and int.from_bytes(glb[8:12], "little") == len(glb)
    with zipfile.ZipFile(io.BytesIO(_get(shown["download_urls"][0]))) as zf:
        assert zf.read("browser_photo/scene.glb") == glb
        assert Image.open(io.BytesIO(zf.read("browser_photo/overlay.png"))).size == (320, 240)
    # the 3D view drew its canvas; the screenshot is the full page, not a blank window
    assert shown["model3d_canvas"]
    img = np.asarray(Image.open(shot).convert("RGB"))
    assert img.shape[0] > 1000 and img.shape[1] > 1000 and img.std() > 20


def test_corrupt_upload_shows_a_readable_error(server, driver, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import WebDriverWait

    bad = tmp_path / "broken.png"
    full = photo(tmp_path / "full.png", size=(400, 300)).read_bytes()
    bad.write_bytes(full[: len(full) // 2])
    driver.get(server)
    wait = WebDriverWait(driver, 60)
    upload = wait.until(
        ec.presence_of_element_located((By.CSS_SELECTOR, "#photo input[type=file]"))
    )
    upload.send_keys(str(bad))
    error = wait.until(ec.visibility_of_element_located((By.CSS_SELECTOR, "#error")))
    wait.until(lambda d: error.text.strip())
    assert error.text.startswith("The photo cannot be used:")
    assert "'broken.png'" in error.text and "corrupt or truncated" in error.text
    driver.find_element(By.CSS_SELECTOR, "#run").click()
    wait.until(lambda d: "cannot be used" in d.find_element(By.CSS_SELECTOR, "#error").text)
    driver.save_screenshot(str(tmp_path / "error.png"))
    body = driver.find_element(By.TAG_NAME, "body").text
    assert "Traceback" not in body and "/tmp/" not in body
    assert not driver.find_elements(By.CSS_SELECTOR, "#overlay img[src]")


def test_the_page_contacts_no_other_host(server, driver):
    # every request of every page this browser loaded (the other tests' flows too)
    driver.get(server)
    time.sleep(2)
    urls = standin.requested_urls(driver)
    assert any(u.startswith(server) for u in urls)
    assert standin.foreign_urls(urls) == []


def _click_on_image(driver, img, fx: float, fy: float) -> tuple[float, float]:
    """Click at the fractions (fx, fy) of the shown image; returns the natural pixel clicked."""
    from selenium.webdriver.common.action_chains import ActionChains

    rect = driver.execute_script(
        "const r = arguments[0].getBoundingClientRect();"
        "return [r.width, r.height, arguments[0].naturalWidth, arguments[0].naturalHeight];",
        img,
    )
    w, h, nw, nh = rect
    # the picture is fitted into the element ("object-fit: contain"): scaled, centred
    scale = min(w / nw, h / nh)
    ox, oy = (w - nw * scale) / 2, (h - nh * scale) / 2
    dx = round(ox + fx * nw * scale - w / 2)  # offsets from the element's centre
    dy = round(oy + fy * nh * scale - h / 2)
    ActionChains(driver).move_to_element_with_offset(img, dx, dy).click().perform()
    return (w / 2 + dx - ox) / scale, (h / 2 + dy - oy) / scale


def test_click_on_the_photo_adds_a_point_previews_the_mask_and_runs_with_it(server, driver,
                                                                           tmp_path):  # fmt: skip
    import re

    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import WebDriverWait

    src = photo(tmp_path / "click.png", size=(640, 480))  # shown as a 512x384 thumbnail
    wait = WebDriverWait(driver, 60)
    driver.get(server)
    upload = wait.until(
        ec.presence_of_element_located((By.CSS_SELECTOR, "#photo input[type=file]"))
    )
    upload.send_keys(str(src))
    img = wait.until(ec.visibility_of_element_located((By.CSS_SELECTOR, "#preview img")))
    first_src = img.get_attribute("src")
    nx, ny = _click_on_image(driver, img, 0.3, 0.6)

    def text(css):
        return driver.find_element(By.CSS_SELECTOR, css).text

    wait.until(lambda d: "object point: (" in text("#prompt_text"))
    x, y = (float(v) for v in re.search(r"object point: \((\d+), (\d+)\)",
                                         text("#prompt_text")).groups())  # fmt: skip
    # thumbnail pixel -> photo pixel: x 640/512, y 480/384 (1.25 both)
    assert abs(x - (int(nx) + 0.5) * 1.25) <= 1.5 and abs(y - (int(ny) + 0.5) * 1.25) <= 1.5
    # the point is drawn on the photo shown: a green disc at the clicked pixel
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR, "#preview img").get_attribute("src")
               != first_src)  # fmt: skip
    shown = driver.find_element(By.CSS_SELECTOR, "#preview img").get_attribute("src")
    drawn = np.asarray(Image.open(io.BytesIO(_get(shown))).convert("RGB"))
    assert drawn.shape == (384, 512, 3)
    # (the page may get the picture lossily encoded: a few levels off)
    assert np.abs(drawn[int(ny), int(nx)].astype(int) - (40, 220, 90)).max() <= 4

    # Show mask: the stand-in's disc around the point, tinted green on the thumbnail
    driver.find_element(By.CSS_SELECTOR, "#show_mask").click()
    mask_img = wait.until(
        ec.presence_of_element_located((By.CSS_SELECTOR, "#mask_preview img[src]"))
    )
    wait.until(lambda d: "Object mask:" in text("#mask_text"))
    share = float(re.search(r"Object mask: ([\d.]+)%", text("#mask_text")).group(1))
    assert share == pytest.approx(100 * np.pi * 60**2 / (640 * 480), abs=0.3)  # r = 480/8
    masked = np.asarray(Image.open(io.BytesIO(_get(mask_img.get_attribute("src")))).convert("RGB"))
    near = masked[int(ny), int(nx) + 30]  # 30 px < 48 px radius on the thumbnail
    assert near[1] > near[0] + 40 and near[1] > near[2] + 40

    # the hand mode sets the hand point
    driver.find_element(By.XPATH, "//*[@id='click_mode']//label[contains(., 'hand point')]").click()
    img = driver.find_element(By.CSS_SELECTOR, "#preview img")
    _click_on_image(driver, img, 0.8, 0.2)
    wait.until(lambda d: "hand point: (" in text("#prompt_text"))
    assert "object point: (" in text("#prompt_text")
    # the background mode adds a point that is not the object
    driver.find_element(
        By.XPATH, "//*[@id='click_mode']//label[contains(., 'background point')]"
    ).click()
    img = driver.find_element(By.CSS_SELECTOR, "#preview img")
    _click_on_image(driver, img, 0.1, 0.9)
    wait.until(lambda d: "not the object: (" in text("#prompt_text"))

    # Run: the reconstruction gets the points; the pointed object is not a low-confidence one
    PROMPTS_SEEN.clear()
    driver.find_element(By.CSS_SELECTOR, "#run").click()
    WebDriverWait(driver, 90).until(
        ec.presence_of_element_located((By.CSS_SELECTOR, "#overlay img[src]"))
    )
    (prompts,) = PROMPTS_SEEN
    assert np.allclose(prompts.object_points, [(x, y)], atol=0.5)  # the text shows them rounded
    assert prompts.hand_point is not None and prompts.hand_point[0] > 400
    ((bx, by),) = prompts.background_points
    assert bx < 200 and by > 300
    assert not any(e.is_displayed() for e in driver.find_elements(By.CSS_SELECTOR, "#warnings"))

    # Clear points: back to none; a run without points warns about the object mask
    driver.find_element(By.CSS_SELECTOR, "#clear_points").click()
    wait.until(lambda d: "Click on the held object" in text("#prompt_text"))
    assert text("#mask_text") == "" and not driver.find_elements(
        By.CSS_SELECTOR, "#mask_preview img[src]"
    )
    driver.find_element(By.CSS_SELECTOR, "#run").click()
    warn = WebDriverWait(driver, 90).until(
        ec.visibility_of_element_located((By.CSS_SELECTOR, "#warnings"))
    )
    assert "Low confidence in the object mask" in warn.text
    assert "click on the held object in the photo" in warn.text
    assert PROMPTS_SEEN[-1] is None

    # Object region: another of the automatic path's regions, without coordinates
    from selenium.webdriver.common.keys import Keys

    box = driver.find_element(By.CSS_SELECTOR, "#object_region input")
    box.click()
    box.send_keys(Keys.CONTROL, "a")
    box.send_keys("3", Keys.ENTER)  # the menu filters to the entry "3", Enter takes it
    wait.until(lambda d: "object region 3" in text("#prompt_text"))
    driver.find_element(By.CSS_SELECTOR, "#run").click()
    wait.until(lambda d: len(PROMPTS_SEEN) == 3)
    assert PROMPTS_SEEN[-1] == Prompts(object_choice=3)
    # the run over (its progress gone from the overlay): the page ignores Run while one runs
    wait.until(lambda d: not d.find_elements(By.CSS_SELECTOR, "#overlay .progress-text"))

    # Object point: its regions replace the automatic path's, so the menu is back at region 1;
    # a region picked then is one of the point's
    driver.find_element(
        By.XPATH, "//*[@id='click_mode']//label[contains(., 'object point')]"
    ).click()
    _click_on_image(driver, driver.find_element(By.CSS_SELECTOR, "#preview img"), 0.5, 0.5)
    wait.until(lambda d: "object point: (" in text("#prompt_text"))
    region = driver.find_element(By.CSS_SELECTOR, "#object_region input")
    wait.until(lambda d: region.get_attribute("value") == "1 (automatic)")
    region.click()
    region.send_keys(Keys.CONTROL, "a")
    region.send_keys("2", Keys.ENTER)
    wait.until(lambda d: "object region 2" in text("#prompt_text"))
    driver.find_element(By.CSS_SELECTOR, "#run").click()
    wait.until(lambda d: len(PROMPTS_SEEN) == 4)
    assert len(PROMPTS_SEEN[-1].object_points) == 1 and PROMPTS_SEEN[-1].object_choice == 2
    wait.until(lambda d: not d.find_elements(By.CSS_SELECTOR, "#overlay .progress-text"))
    driver.find_element(By.CSS_SELECTOR, "#clear_points").click()
    wait.until(lambda d: "Click on the held object" in text("#prompt_text"))
    region.click()
    region.send_keys(Keys.CONTROL, "a")
    region.send_keys("3", Keys.ENTER)
    wait.until(lambda d: "object region 3" in text("#prompt_text"))

    # Object box: two clicks at opposite corners; the box replaces the chosen region
    driver.find_element(
        By.XPATH, "//*[@id='click_mode']//label[contains(., 'object box corner')]"
    ).click()
    img = driver.find_element(By.CSS_SELECTOR, "#preview img")
    before = img.get_attribute("src")
    ax, ay = _click_on_image(driver, img, 0.7, 0.7)
    wait.until(lambda d: "box corner" in text("#prompt_text"))
    # the corner drawn: the shown picture is replaced before the next click lands on it
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR, "#preview img").get_attribute("src")
               != before)  # fmt: skip
    bx, by = _click_on_image(driver, driver.find_element(By.CSS_SELECTOR, "#preview img"),
                             0.2, 0.3)  # fmt: skip
    wait.until(lambda d: "object box: (" in text("#prompt_text"))
    driver.find_element(By.CSS_SELECTOR, "#run").click()
    wait.until(lambda d: len(PROMPTS_SEEN) == 5)
    box = PROMPTS_SEEN[-1].object_box
    expect = [(int(bx) + 0.5) * 1.25, (int(by) + 0.5) * 1.25, (int(ax) + 0.5) * 1.25,
              (int(ay) + 0.5) * 1.25]  # fmt: skip
    assert np.allclose(box, expect, atol=1.5) and PROMPTS_SEEN[-1].object_choice is None
    driver.save_screenshot(str(tmp_path / "page.png"))


def test_an_example_photo_fills_the_preview_and_runs(driver, tmp_path_factory):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import WebDriverWait

    from easyhoi.app_request import synthetic_examples

    (example,) = synthetic_examples(tmp_path_factory.mktemp("examples"), seeds=(1,))
    app, url = standin.start_demo(slowed_standin, examples=[example])
    try:
        wait = WebDriverWait(driver, 60)
        driver.get(url)
        button = wait.until(ec.element_to_be_clickable((By.CSS_SELECTOR, "button.gallery-item")))
        assert button.text == "synthetic-1.png"
        button.click()
        img = wait.until(ec.visibility_of_element_located((By.CSS_SELECTOR, "#preview img")))
        shown = np.asarray(Image.open(io.BytesIO(_get(img.get_attribute("src")))).convert("RGB"))
        photo_rgb = np.asarray(Image.open(example).convert("RGB"))
        assert shown.shape == photo_rgb.shape  # 256 px: shown as it is
        assert np.abs(shown.astype(int) - photo_rgb).mean() < 3  # (lossy on the page)
        PROMPTS_SEEN.clear()
        driver.find_element(By.CSS_SELECTOR, "#run").click()
        WebDriverWait(driver, 90).until(
            ec.presence_of_element_located((By.CSS_SELECTOR, "#overlay img[src]"))
        )
        assert PROMPTS_SEEN == [None]
        assert not any(e.is_displayed() and e.text for e in
                       driver.find_elements(By.CSS_SELECTOR, "#error"))  # fmt: skip
    finally:
        app.close()
