"""Screenshot of the web demo after one reconstruction, for the docs.

Starts the demo (:mod:`easyhoi.app`) on 127.0.0.1 at a free port, drives headless Chromium
(selenium + the system ``chromium`` / ``chromedriver``): uploads a photo, presses Run, waits for
the overlay, the metrics and the downloads, and saves a screenshot::

    python scripts/app_screenshot.py --out docs/img/demo.png --image photo.jpg
    python scripts/app_screenshot.py --out /tmp/demo.png --stand-in   # no optimizer needed

``--stand-in`` replaces the reconstruction by :func:`standin_reconstruct`, a small function that
poses the built-in hand over the photo (real overlay PNG, real GLB, fixed metrics) so that the
page can be shown and tested without running the optimizer. The browser is kept to 127.0.0.1
(every other host name resolves to nothing) and every request it makes is recorded.

Needs: ``pip install 'easyhoi[demo]' selenium`` and ``apt-get install chromium chromium-driver``.
This file is also the driver of ``tests/test_app_browser.py``.
"""

from __future__ import annotations

import argparse
import json
import re
import socket
import sys
import tempfile
import time
from pathlib import Path
from urllib.parse import urlparse

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--disable-dev-shm-usage", "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1",
)  # fmt: skip
SHARED_PHOTO = Path(__file__).resolve().parents[2] / "shared" / "data" / "images" / "hort-can.png"


# ----------------------------------------------------------------------------------------------
# stand-in reconstruction
# ----------------------------------------------------------------------------------------------

STANDIN_PLAUSIBILITY = {
    "penetration_depth_cm": 0.21,
    "intersection_volume_cm3": 0.75,
    "in_contact": True,
    "contact_distance_cm": -0.08,
}


def standin_reconstruct(image_path, out_dir, config=None, *, seed=0, progress=None, say=None,
                        provided=None, prompts=None):  # fmt: skip
    """Write a small but real result folder for ``image_path`` (no optimization).

    The result folder ``out_dir`` gets ``overlay.png`` (the built-in hand in a grasp pose drawn
    over the photo), ``scene.glb`` (that hand and a box, metres), ``result.json`` (plausibility:
    :data:`STANDIN_PLAUSIBILITY` plus ``hand_mask_iou`` = the hand's share of the overlay's
    pixels, a camera facing the hand, and ``meta``: the ``prompts`` and a perception report
    whose object mask has low confidence unless an object point was given) and
    ``report.html``. Calls ``say`` once and ``progress`` for three stages.
    """
    import numpy as np
    import trimesh
    from PIL import Image, ImageDraw

    from easyhoi.hand import load_hand_model
    from easyhoi.hand.regions import grasp_pose
    from easyhoi.io.image import load_image
    from easyhoi.pipeline import Reconstruction
    from easyhoi.structures import HandParams

    t0 = time.perf_counter()
    photo = load_image(image_path)
    if say is not None:
        say("stand-in: posing the built-in hand")
    model = load_hand_model("open")
    p = HandParams.zeros(1)
    hand = model(HandParams(p.global_orient, p.transl, grasp_pose(model).float(), None))
    hand_mesh = hand.to_trimesh()
    box = trimesh.creation.box(extents=(0.07, 0.04, 0.06))
    box.apply_translation(hand_mesh.bounds.mean(axis=0) + np.array([0.0, -0.035, 0.0]))
    for stage in ("camera", "contact", "refine"):
        for it in range(11):
            if progress is not None:
                progress(stage, it, 10, {"total": 1.0 / (1.0 + it + seed)})

    # overlay: hand triangles projected orthographically into the middle of the photo
    img = Image.fromarray(photo.rgb).convert("RGBA")
    w, h = img.size
    v = np.asarray(hand_mesh.vertices)[:, :2]
    lo, hi = v.min(0), v.max(0)
    s = 0.6 * min(w, h) / float(max(hi - lo))
    uv = (v - (lo + hi) / 2) * s * np.array([1.0, -1.0]) + np.array([w / 2, h / 2])
    layer = Image.new("RGBA", img.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(layer)
    for f in np.asarray(hand_mesh.faces):
        draw.polygon([tuple(uv[i]) for i in f], fill=(60, 140, 255, 150))
    covered = float((np.asarray(layer)[..., 3] > 0).mean())
    overlay = Image.alpha_composite(img, layer).convert("RGB")

    folder = Path(out_dir)  # the result folder itself (see easyhoi.pipeline.reconstruct_photo)
    folder.mkdir(parents=True, exist_ok=True)
    overlay.save(folder / "overlay.png")
    scene = trimesh.Scene({"hand": hand_mesh, "object": box})
    (folder / "scene.glb").write_bytes(scene.export(file_type="glb"))
    plaus = dict(STANDIN_PLAUSIBILITY, hand_mask_iou=round(covered, 4))
    # a camera 0.4 m in front of the hand on +z looking back along -z (image up = +y), the
    # view the overlay's orthographic drawing mimics
    centre = (lo + hi) / 2
    cam = {"K": [[s * 0.4, 0, w / 2], [0, s * 0.4, h / 2], [0, 0, 1]],
           "R": [[1, 0, 0], [0, -1, 0], [0, 0, -1]],
           "t": [-float(centre[0]), float(centre[1]), float(hand_mesh.bounds.mean(0)[2]) + 0.4],
           "width": w, "height": h}  # fmt: skip
    pointed = prompts is not None and bool(prompts.object_points)
    confidence = (
        {"score": 0.9, "low": False, "reasons": []}
        if pointed
        else {"score": 0.3, "low": True, "reasons": ["stand-in: nobody pointed at the object"]}
    )
    meta = {"prompts": None if prompts is None else prompts.to_dict(),
            "perception": {"hands_found": 1, "side": "right", "hand_index": 0,
                           "confidence": {"object": confidence}}}  # fmt: skip
    doc = {"plausibility": plaus, "seed": seed, "camera": cam, "meta": meta}
    (folder / "result.json").write_text(json.dumps(doc))
    (folder / "report.html").write_text("<!doctype html><title>stand-in</title><p>stand-in</p>")
    files = [folder / n for n in ("overlay.png", "scene.glb", "result.json", "report.html")]
    return Reconstruction(None, None, {}, files, time.perf_counter() - t0)


def standin_segment(rgb, config, prompts):
    """Masks for the demo's "Show mask" without a hand detector: discs around the points.

    The object mask is a disc of radius 1/8 of the photo's shorter side around each object
    point; the hand mask a disc twice as large around the hand point (or the photo's centre).
    Without an object point there is no object (``NoObjectError``).
    """
    import numpy as np

    from easyhoi.errors import NoObjectError

    h, w = rgb.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    r = min(h, w) / 8

    def disc(x, y, radius):
        return (xx - x) ** 2 + (yy - y) ** 2 <= radius**2

    if prompts is None or not prompts.object_points:
        raise NoObjectError("stand-in: click on the object first")
    obj = np.zeros((h, w), bool)
    for x, y in prompts.object_points:
        obj |= disc(x, y, r)
    hx, hy = prompts.hand_point if prompts.hand_point is not None else (w / 2, h / 2)
    hand = disc(hx, hy, 2 * r) & ~obj
    return hand, obj, {"hands_found": 1, "hand_index": 0, "side": "right"}


# ----------------------------------------------------------------------------------------------
# server and browser
# ----------------------------------------------------------------------------------------------


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_demo(reconstruct_fn=None, preset: str = "fast", port: int | None = None,
               segment_fn=None, examples=()):  # fmt: skip
    """Serve the demo in a background thread; returns ``(app, url)``. Stop with ``app.close()``.

    ``examples``: example photos offered on the page (none by default: rendering the synthetic
    ones takes seconds).
    """
    from easyhoi.app import launch

    port = port or free_port()
    app = launch("127.0.0.1", port, preset=preset, reconstruct_fn=reconstruct_fn, block=False,
                 quiet=True, examples=list(examples), segment_fn=segment_fn)  # fmt: skip
    return app, f"http://127.0.0.1:{port}/"


def make_driver(user_data_dir: str | Path, width: int = 1400, height: int = 1500):
    """Headless Chromium through the system chromedriver (selenium never downloads a driver)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in CHROMIUM_FLAGS:
        opts.add_argument(flag)
    opts.add_argument(f"--user-data-dir={user_data_dir}")
    opts.add_argument(f"--window-size={width},{height}")
    opts.set_capability("goog:loggingPrefs", {"performance": "ALL"})
    return webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)


def requested_urls(driver) -> list[str]:
    """Every URL the page requested so far (from the performance log; drains it)."""
    urls = []
    for entry in driver.get_log("performance"):
        msg = json.loads(entry["message"])["message"]
        if msg.get("method") in ("Network.requestWillBeSent", "Network.webSocketCreated"):
            url = msg["params"].get("request", {}).get("url") or msg["params"].get("url", "")
            urls.append(url)
    return urls


def foreign_urls(urls) -> list[str]:
    """The network URLs among ``urls`` whose host is not 127.0.0.1."""
    out = []
    for u in urls:
        p = urlparse(u)
        if p.scheme in ("http", "https", "ws", "wss") and p.hostname != "127.0.0.1":
            out.append(u)
    return out


def run_flow(driver, url: str, image: str | Path, timeout: float = 120.0) -> dict:
    """Upload ``image``, press Run, wait for the results; returns what the page shows.

    Returns a dict with ``overlay_src``, ``metrics_text``, ``error_text``, ``download_urls``,
    ``model3d_canvas`` (whether the 3D view drew a canvas) and ``progress_seen`` (the
    "optimizing: <stage>" progress texts seen while waiting).
    """
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import WebDriverWait

    wait = WebDriverWait(driver, timeout)
    driver.get(url)
    upload = wait.until(
        ec.presence_of_element_located((By.CSS_SELECTOR, "#photo input[type=file]"))
    )
    upload.send_keys(str(Path(image).resolve()))
    wait.until(ec.presence_of_element_located((By.CSS_SELECTOR, "#preview img")))
    driver.find_element(By.CSS_SELECTOR, "#run").click()

    seen = []

    def done(d):
        text = d.find_element(By.TAG_NAME, "body").text
        seen.extend(m for m in re.findall(r"optimizing: \w+", text) if m not in seen)
        err = d.find_elements(By.CSS_SELECTOR, "#error")
        if err and err[0].is_displayed() and err[0].text.strip():
            return "error"
        ok = d.find_elements(By.CSS_SELECTOR, "#overlay img[src]")
        links = d.find_elements(By.CSS_SELECTOR, "#downloads a[href]")
        return "ok" if ok and links else False

    WebDriverWait(driver, timeout, poll_frequency=0.2).until(done)
    time.sleep(1.5)  # let the 3D view draw before a screenshot
    overlay = driver.find_elements(By.CSS_SELECTOR, "#overlay img[src]")
    error = driver.find_elements(By.CSS_SELECTOR, "#error")
    return {
        "overlay_src": overlay[0].get_attribute("src") if overlay else None,
        "metrics_text": driver.find_element(By.CSS_SELECTOR, "#metrics").text,
        "error_text": error[0].text if error and error[0].is_displayed() else "",
        "download_urls": [a.get_attribute("href") for a in
                          driver.find_elements(By.CSS_SELECTOR, "#downloads a[href]")],
        "model3d_canvas": bool(driver.find_elements(By.CSS_SELECTOR, "#model3d canvas")),
        "progress_seen": seen,
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="PNG file to write")
    ap.add_argument(
        "--image",
        default=str(SHARED_PHOTO) if SHARED_PHOTO.is_file() else None,
        help="photo to upload (default: the shared hort-can.png when present)",
    )
    ap.add_argument("--preset", default="fast", help="preset (default fast)")
    ap.add_argument(
        "--stand-in",
        action="store_true",
        help="use the stand-in reconstruction instead of the real pipeline",
    )
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds to wait for a result")
    args = ap.parse_args(argv)  # fmt: skip
    if not args.image:
        ap.error("--image is required (no shared test photo found)")
    app, url = start_demo(standin_reconstruct if args.stand_in else None, args.preset)
    try:
        with tempfile.TemporaryDirectory(prefix="easyhoi-chromium-") as profile:
            driver = make_driver(profile)
            try:
                shown = run_flow(driver, url, args.image, args.timeout)
                Path(args.out).parent.mkdir(parents=True, exist_ok=True)
                driver.save_screenshot(str(args.out))
                foreign = foreign_urls(requested_urls(driver))
            finally:
                driver.quit()
    finally:
        app.close()
    sys.stdout.write(json.dumps({"screenshot": str(args.out), **shown}, indent=1) + "\n")
    if foreign:
        sys.stderr.write(f"the page requested other hosts: {foreign}\n")
    return 0 if not shown["error_text"] and not foreign else 1


if __name__ == "__main__":
    sys.exit(main())
