"""Photo and mask loading: formats by content, EXIF, pixel formats, sizes, bad files."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from easyhoi.errors import InvalidInputError
from easyhoi.io.image import load_image, load_mask


def gradient(h=60, w=80):
    yy, xx = np.mgrid[0:h, 0:w]
    return np.stack([xx * 3 % 256, yy * 4 % 256, (xx + yy) % 256], -1).astype(np.uint8)


def test_png_roundtrip_is_exact(tmp_path):
    a = gradient()
    Image.fromarray(a).save(tmp_path / "a.png")
    img = load_image(tmp_path / "a.png")
    assert img.rgb.dtype == np.uint8 and img.rgb.shape == (60, 80, 3)
    assert np.array_equal(img.rgb, a)
    assert img.scale == 1.0 and img.original_size == (80, 60) and img.source_format == "PNG"


def test_webp_named_jpg_is_decoded_by_content(tmp_path):
    a = gradient()
    Image.fromarray(a).save(tmp_path / "photo.jpg", format="WEBP", lossless=True)
    img = load_image(tmp_path / "photo.jpg")
    assert img.source_format == "WEBP"
    assert np.array_equal(img.rgb, a)


def test_exif_orientation_is_applied(tmp_path):
    a = np.zeros((40, 60, 3), np.uint8)
    a[:, :30] = 255  # left half white
    exif = Image.Exif()
    exif[0x0112] = 6  # rotate 90 degrees clockwise to display
    Image.fromarray(a).save(tmp_path / "r.jpg", exif=exif, quality=95)
    img = load_image(tmp_path / "r.jpg")
    assert img.rgb.shape == (60, 40, 3)
    assert img.original_size == (40, 60)
    # the white left half ends up at the top after a clockwise rotation
    assert img.rgb[:25].mean() > 240 and img.rgb[35:].mean() < 15


def test_grayscale_rgba_and_16bit(tmp_path):
    g = (np.arange(64 * 64).reshape(64, 64) % 256).astype(np.uint8)
    Image.fromarray(g, mode="L").save(tmp_path / "g.png")
    rgb = load_image(tmp_path / "g.png").rgb
    assert rgb.shape == (64, 64, 3) and np.array_equal(rgb[..., 1], g)

    rgba = np.zeros((40, 40, 4), np.uint8)
    rgba[..., 0] = 200
    rgba[:, 20:, 3] = 255  # right half opaque red, left half fully transparent
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "a.png")
    out = load_image(tmp_path / "a.png").rgb
    assert np.array_equal(out[0, 0], [255, 255, 255])
    assert np.array_equal(out[0, 39], [200, 0, 0])

    s = np.full((40, 40), 65535, np.uint16)
    s[:, :20] = 32768
    Image.fromarray(s).save(tmp_path / "s.png")
    out = load_image(tmp_path / "s.png").rgb
    assert out.dtype == np.uint8
    assert out[0, 39, 0] == 255 and abs(int(out[0, 0, 0]) - 128) <= 1


def test_large_photo_is_downscaled_and_tiny_refused(tmp_path):
    Image.fromarray(np.zeros((100, 2000, 3), np.uint8)).save(tmp_path / "big.png")
    img = load_image(tmp_path / "big.png", max_side=1000)
    assert img.rgb.shape == (50, 1000, 3) and img.scale == pytest.approx(0.5)
    assert load_image(tmp_path / "big.png", max_side=None).rgb.shape == (100, 2000, 3)
    Image.fromarray(np.zeros((20, 300, 3), np.uint8)).save(tmp_path / "tiny.png")
    with pytest.raises(InvalidInputError, match="at least 32"):
        load_image(tmp_path / "tiny.png")


def test_bad_files_raise_named_errors(tmp_path):
    with pytest.raises(InvalidInputError, match="not found"):
        load_image(tmp_path / "missing.jpg")
    (tmp_path / "empty.jpg").write_bytes(b"")
    with pytest.raises(InvalidInputError, match="empty"):
        load_image(tmp_path / "empty.jpg")
    (tmp_path / "notes.png").write_text("this is not an image\n" * 10)
    with pytest.raises(InvalidInputError, match="not an image"):
        load_image(tmp_path / "notes.png")
    Image.fromarray(gradient(200, 200)).save(tmp_path / "full.jpg", quality=90)
    data = (tmp_path / "full.jpg").read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) // 3])
    with pytest.raises(InvalidInputError, match="corrupt|truncated"):
        load_image(tmp_path / "cut.jpg")
    with pytest.raises(InvalidInputError, match="not a file"):
        load_image(tmp_path)


@pytest.mark.parametrize("encoding", ["0_255", "0_1", "inverted", "rgb"])
def test_mask_polarity(tmp_path, encoding):
    gt = np.zeros((48, 64), bool)
    gt[10:30, 20:40] = True
    if encoding == "0_255":
        arr = gt.astype(np.uint8) * 255
    elif encoding == "0_1":
        arr = gt.astype(np.uint8)
    elif encoding == "inverted":
        arr = (~gt).astype(np.uint8) * 255
    else:
        arr = np.zeros((48, 64, 3), np.uint8)
        arr[gt] = (0, 255, 0)
    Image.fromarray(arr).save(tmp_path / "m.png")
    m = load_mask(tmp_path / "m.png", size=(64, 48))
    assert m.dtype == bool and np.array_equal(m, gt)


def test_mask_touching_the_border_keeps_polarity(tmp_path):
    gt = np.zeros((40, 40), bool)
    gt[25:, 10:30] = True  # an arm entering from the bottom edge, 20 of 156 border pixels
    Image.fromarray(gt.astype(np.uint8) * 255).save(tmp_path / "m.png")
    assert np.array_equal(load_mask(tmp_path / "m.png"), gt)


def test_mask_size_mismatch_message(tmp_path):
    Image.fromarray(np.zeros((480, 640), np.uint8)).save(tmp_path / "m.png")
    with pytest.raises(InvalidInputError, match="mask is 480x640 but the image is 720x1280"):
        load_mask(tmp_path / "m.png", size=(1280, 720))


def test_real_webp_photo_named_jpg(shared_data):
    img = load_image(shared_data / "images" / "easyhoi-coffee-2.jpg")
    assert img.source_format == "WEBP"
    assert img.original_size == (4242, 4242)
    assert img.rgb.shape == (1600, 1600, 3)
    assert img.scale == pytest.approx(1600 / 4242)


def _reference_load(path, max_side=1600):
    """The definition: orientation applied, converted to an RGB array, then downscaled."""
    from PIL import ImageOps

    from easyhoi.io.image import _to_rgb

    img = ImageOps.exif_transpose(Image.open(path))
    rgb = _to_rgb(img)
    h, w = rgb.shape[:2]
    if max(h, w) > max_side:
        s = max_side / float(max(h, w))
        size = (max(1, round(w * s)), max(1, round(h * s)))
        rgb = np.asarray(Image.fromarray(rgb).resize(size, Image.Resampling.BOX))
    return rgb


@pytest.mark.parametrize("mode", ["RGB", "RGBA", "L"])
def test_downscaled_photo_equals_the_array_path(tmp_path, mode):
    rng = np.random.default_rng(5)
    h, w = 700, 530
    a = rng.integers(0, 256, (h, w, {"RGB": 3, "RGBA": 4, "L": 1}[mode]), dtype=np.uint8)
    img = Image.fromarray(a[..., 0] if mode == "L" else a, mode)
    exif = Image.Exif()
    exif[0x0112] = 6  # rotated: the stored picture is turned by 90 degrees
    path = tmp_path / f"p_{mode}.{'jpg' if mode == 'RGB' else 'png'}"
    img.save(path, exif=exif) if mode == "RGB" else img.save(path)
    got = load_image(path, max_side=400)
    want = _reference_load(path, max_side=400)
    assert got.rgb.shape == want.shape and got.rgb.shape[2] == 3
    assert max(got.rgb.shape[:2]) == 400
    np.testing.assert_array_equal(got.rgb, want)
    if mode == "RGB":
        assert got.rgb.shape[:2] == (303, 400)  # turned upright: wider than high
