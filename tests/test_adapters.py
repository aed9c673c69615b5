"""Large-model adapters with tiny randomly initialised models saved to a temporary folder."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

from easyhoi.errors import InvalidInputError, MissingDependencyError
from easyhoi.perception.adapters import resolve_model_dir
from easyhoi.perception.adapters.depth import DepthObjectReconstructor, relief_mesh
from easyhoi.perception.adapters.diffusion import DiffusionInpainter
from easyhoi.perception.adapters.grounded_sam import (
    GroundedSamSegmenter,
    box_distance,
    choose_box,
    grasp_centre,
)
from easyhoi.perception.adapters.sam import SamAmodalSegmenter, prompts_from_mask


def disk_mask(shape=(60, 80), center=(40, 30), radius=20) -> np.ndarray:
    m = np.zeros(shape, np.uint8)
    cv2.circle(m, center, radius, 1, -1)
    return m.astype(bool)


def photo(shape=(60, 80), seed=0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (*shape, 3), dtype=np.uint8)


# ----------------------------------------------------------------------------------------------
# no dependency needed
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "cls, module, extra",
    [
        (SamAmodalSegmenter, "transformers", "sam"),
        (DepthObjectReconstructor, "transformers", "depth"),
        (DiffusionInpainter, "diffusers", "diffusion"),
        (GroundedSamSegmenter, "transformers", "sam"),
    ],
)
def test_missing_dependency_names_the_extra(monkeypatch, tmp_path, cls, module, extra):
    monkeypatch.setitem(sys.modules, module, None)  # makes the import fail
    folders = {"model_dir": tmp_path}
    if cls is GroundedSamSegmenter:
        folders = {"detector_dir": tmp_path, "sam_dir": tmp_path}
    with pytest.raises(MissingDependencyError, match=rf"easyhoi\[{extra}\]"):
        cls(**folders)


def test_importing_adapters_imports_no_heavy_dependency():
    code = (
        "import sys, easyhoi.perception.adapters.sam, easyhoi.perception.adapters.depth, "
        "easyhoi.perception.adapters.diffusion, easyhoi.perception.adapters.grounded_sam; "
        "print(sorted(m for m in ('transformers', 'diffusers') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_resolve_model_dir(tmp_path):
    with pytest.raises(InvalidInputError, match="not found"):
        resolve_model_dir(tmp_path / "nope", "SAM")
    with pytest.raises(InvalidInputError, match="model_dir"):
        resolve_model_dir(None, "SAM")
    with pytest.raises(InvalidInputError, match="config.json"):
        resolve_model_dir(tmp_path, "SAM", marker="config.json")
    (tmp_path / "config.json").write_text("{}")
    assert resolve_model_dir(tmp_path, "SAM", marker="config.json") == tmp_path


def test_prompts_from_mask_one_point_per_part():
    m = np.zeros((50, 100), bool)
    m[10:40, 5:40] = True
    m[10:40, 60:95] = True  # the hand splits the object in two
    pts, box = prompts_from_mask(m, margin=0.1)
    assert pts.shape == (2, 2)
    for u, v in pts:
        assert m[int(v), int(u)]
    assert {int(u) < 50 for u, _ in pts} == {True, False}
    assert box == pytest.approx((0.0, 7.0, 100.0, 43.0))


def test_relief_mesh_sphere_front_gives_sphere():
    m = disk_mask((120, 120), (60, 60), 40)
    v, u = np.mgrid[0:120, 0:120] + 0.5
    r = np.sqrt(m.sum() / np.pi)
    rho2 = (u - 60.5) ** 2 + (v - 60.5) ** 2
    front = -np.sqrt(np.maximum(r**2 - rho2, 0))  # depth: the centre is closest
    mesh = relief_mesh(m, front, kind="depth", depth_scale=1.0)
    assert mesh.is_watertight and mesh.volume > 0
    s = mesh.metadata["easyhoi"]["pixels_per_unit"]
    assert mesh.volume * s**3 == pytest.approx(4 / 3 * np.pi * r**3, rel=0.06)
    assert mesh.extents * s == pytest.approx([2 * r, 2 * r, 2 * r], rel=0.05)
    # the same surface given as disparity (closer = larger) is the same mesh
    again = relief_mesh(m, -front, kind="disparity", depth_scale=1.0)
    np.testing.assert_allclose(again.vertices, mesh.vertices, atol=1e-9)


def test_relief_mesh_tilted_front_shears_the_solid():
    m = disk_mask((100, 100), (50, 50), 30)
    v, u = np.mgrid[0:100, 0:100] + 0.5
    flat = relief_mesh(m, np.zeros((100, 100)), kind="depth")
    tilt = relief_mesh(m, (u - 50.0) * 0.5, kind="depth", depth_scale=1.0)
    assert tilt.is_watertight and flat.is_watertight
    # z spans [F, F + 2h] with F = x / 2: from -r/2 (left rim) to max(x/2 + 2 sqrt(r^2 - x^2))
    r = np.sqrt(m.sum() / np.pi)
    x = np.linspace(-r, r, 10001)
    expected = (0.5 * x + 2 * np.sqrt(r**2 - x**2)).max() + 0.5 * r
    s_t, s_f = (mesh.metadata["easyhoi"]["pixels_per_unit"] for mesh in (tilt, flat))
    assert tilt.extents[2] * s_t == pytest.approx(expected, rel=0.03)
    assert flat.extents[2] * s_f == pytest.approx(2 * r, rel=0.03)
    nearest = tilt.vertices[np.argmin(tilt.vertices[:, 2])]
    assert nearest[0] < -0.3  # the left rim is closest to the camera
    with pytest.raises(InvalidInputError):
        relief_mesh(m, np.zeros((10, 10)))
    with pytest.raises(InvalidInputError):
        relief_mesh(m, np.zeros((100, 100)), kind="height")


# ----------------------------------------------------------------------------------------------
# tiny models (transformers / diffusers)
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sam_dir(tmp_path_factory):
    pytest.importorskip("transformers", reason="transformers not installed (extra 'sam')")
    from easyhoi.testing.tiny_models import write_tiny_sam

    return write_tiny_sam(tmp_path_factory.mktemp("sam"))


def test_sam_adapter_mask_matches_image(sam_dir):
    from easyhoi.perception.base import create

    seg = create("amodal", "sam", model_dir=sam_dir)
    img, vis = photo(), disk_mask()
    pts, box = prompts_from_mask(vis)
    mask = seg.segment(img, pts, box, vis)
    assert mask.shape == (60, 80) and mask.dtype == bool
    assert seg.last_scores.shape == (3,)
    again = seg.segment(img, None, None, vis)  # prompts derived from the visible mask
    np.testing.assert_array_equal(mask, again)
    with pytest.raises(InvalidInputError, match="box"):
        seg.segment(img, pts, (10, 10, 5, 20), vis)
    # a box alone, points alone, neither
    assert seg.predict(img, None, box).shape == (60, 80)
    assert seg.predict(img, pts, None).dtype == bool
    with pytest.raises(InvalidInputError, match="point prompts, a box, or both"):
        seg.predict(img, np.zeros((0, 2)), None)
    with pytest.raises(InvalidInputError, match="image"):
        seg.segment(img, pts, box, vis[:10])


def test_sam_adapter_missing_folder(sam_dir, tmp_path):
    with pytest.raises(InvalidInputError, match="not found"):
        SamAmodalSegmenter(model_dir=tmp_path / "missing")


@pytest.fixture(scope="module")
def depth_dir(tmp_path_factory):
    pytest.importorskip("transformers", reason="transformers not installed (extra 'depth')")
    from easyhoi.testing.tiny_models import write_tiny_depth

    return write_tiny_depth(tmp_path_factory.mktemp("dpt"))


def test_depth_adapter_closed_mesh(depth_dir):
    from easyhoi.perception.base import create

    rec = create("object", "depth", model_dir=depth_dir)
    img, m = photo(), disk_mask()
    pred = rec.predict(img)
    assert pred.shape == (60, 80) and np.isfinite(pred).all()
    mesh = rec.reconstruct(img, m)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert mesh.metadata["easyhoi"]["method"] == "depth"
    assert mesh.extents.max() == pytest.approx(1.0)
    with pytest.raises(InvalidInputError):
        rec.reconstruct(img, m[:, :10])
    with pytest.raises(InvalidInputError, match="not found"):
        DepthObjectReconstructor(model_dir=depth_dir / "missing")


@pytest.fixture(scope="module")
def inpaint_dir(tmp_path_factory):
    pytest.importorskip("transformers", reason="transformers not installed (extra 'diffusion')")
    pytest.importorskip("diffusers", reason="diffusers not installed ('diffusion')")
    from easyhoi.testing.tiny_models import write_tiny_inpainter

    return write_tiny_inpainter(tmp_path_factory.mktemp("inpaint"))


def test_diffusion_inpainter_fills_only_the_mask(inpaint_dir):
    from easyhoi.perception.base import create

    inp = create("inpainter", "diffusion", model_dir=inpaint_dir, steps=2, resolution=32)
    assert inp.size_multiple == 4  # VAE factor 2 x one UNet down-sampling
    assert inp.working_size(80, 60) == (32, 24)
    img, m = photo(), disk_mask(radius=12)
    out = inp.inpaint(img, m)
    assert out.shape == img.shape and out.dtype == np.uint8
    np.testing.assert_array_equal(out[~m], img[~m])
    assert (out[m] != img[m]).any()
    np.testing.assert_array_equal(out, inp.inpaint(img, m))  # seeded
    np.testing.assert_array_equal(inp.inpaint(img, np.zeros_like(m)), img)
    with pytest.raises(InvalidInputError):
        inp.inpaint(img.astype(np.float32), m)
    with pytest.raises(InvalidInputError, match="model_index.json"):
        DiffusionInpainter(model_dir=inpaint_dir / "unet", steps=1)


# ----------------------------------------------------------------------------------------------
# grounded-sam: OWLv2 detector + SAM
# ----------------------------------------------------------------------------------------------


def hand_keypoints(u0=10.0, v0=30.0, size=20.0) -> np.ndarray:
    """21 keypoints: wrist at the bottom, five fingers fanned out upwards, in a size^2 box."""
    k = np.zeros((21, 2))
    k[0] = (u0 + size / 2, v0 + size)
    for f in range(5):
        for j in range(4):
            k[1 + 4 * f + j] = (u0 + size * f / 4, v0 + size * (0.75 - 0.25 * j))
    return k


def test_mask_confidences_name_the_weak_cues():
    from easyhoi.perception.adapters.grounded_sam import mask_confidences

    conf = mask_confidences(0.9, 0.3, 0.05)
    assert conf["hand"].score == 0.9 and conf["hand"].reasons == () and not conf["hand"].low
    assert conf["object"].low and conf["object"].reasons == (
        "SAM predicts an IoU of 0.30",
        "the detector found the object box with score 0.05 only",
    )
    assert set(mask_confidences(1.2, None)) == {"hand"}
    assert mask_confidences(1.2, None)["hand"].score == 1.0


def test_choose_box_prefers_the_box_at_the_grasp_over_a_higher_score_far_away():
    k = hand_keypoints()  # grasp centre: mean of bases and tips
    g = grasp_centre(k)
    # bases of fingers 1-4 at x = 15..30, y = 45; the five tips at x = 10..30, y = 30
    np.testing.assert_allclose(g, [(15 + 20 + 25 + 30 + 10 + 15 + 20 + 25 + 30) / 9,
                                   (4 * 45 + 5 * 30) / 9])  # fmt: skip
    assert box_distance(g, (0, 0, 100, 100)) == 0.0
    assert box_distance((0.0, 0.0), (3, 4, 10, 10)) == 5.0
    near = (15, 25, 40, 45)  # contains the grasp centre
    far = (60, 5, 79, 20)  # 20+ px away, one hand size
    boxes = np.array([far, near], float)
    # rank = score * exp(-d / hand size): far 0.9 * exp(-d/20) against near 0.5
    d = box_distance(g, far)
    assert 0.9 * np.exp(-d / 20) < 0.5
    assert choose_box(boxes, np.array([0.9, 0.5]), k, (80, 60)) == 1
    assert choose_box(boxes, np.array([0.9, 0.5 * np.exp(-d / 20) * 0.9 / 0.5 * 0.99]), k,
                      (80, 60)) == 0  # fmt: skip
    # the whole photo is the scene, not a held object; nothing left -> None
    assert choose_box(np.array([[0, 0, 80, 60]], float), np.array([0.99]), k, (80, 60)) is None
    assert choose_box(np.zeros((0, 4)), np.zeros(0), k, (80, 60)) is None


@pytest.fixture(scope="module")
def owl_dir(tmp_path_factory):
    tf = pytest.importorskip("transformers", reason="transformers not installed (extra 'sam')")
    import torch

    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1}
    for c in "abcdefghijklmnopqrstuvwxyz":
        vocab[c] = len(vocab)
        vocab[c + "</w>"] = len(vocab)
    tok = tf.CLIPTokenizer(vocab=vocab, merges=[])
    tc = tf.Owlv2TextConfig(
        vocab_size=len(vocab), hidden_size=16, intermediate_size=32, num_hidden_layers=1,
        num_attention_heads=2, max_position_embeddings=64, bos_token_id=0, eos_token_id=1,
        pad_token_id=1,
    )  # fmt: skip
    vc = tf.Owlv2VisionConfig(hidden_size=16, intermediate_size=32, num_hidden_layers=1,
                              num_attention_heads=2, image_size=32, patch_size=8)  # fmt: skip
    cfg = tf.Owlv2Config(text_config=tc.to_dict(), vision_config=vc.to_dict(), projection_dim=16)
    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("owlv2")
    model = tf.Owlv2ForObjectDetection(cfg)
    with torch.no_grad():  # random heads saturate: boxes of zero size, scores of 0
        for layer in (model.box_head.dense2, model.class_head.logit_shift,
                      model.class_head.logit_scale):  # fmt: skip
            layer.weight.mul_(0.01)
            layer.bias.zero_()
    model.save_pretrained(folder)
    ip = tf.Owlv2ImageProcessorPil(size={"height": 32, "width": 32})
    tf.Owlv2Processor(image_processor=ip, tokenizer=tok).save_pretrained(folder)
    return folder


def test_grounded_sam_segments_hand_and_object(owl_dir, sam_dir):
    from easyhoi.perception.base import HandDetection, create
    from easyhoi.perception.prompts import Prompts

    seg = create("segmenter", "grounded-sam", detector_dir=owl_dir, sam_dir=sam_dir,
                 min_score=0.0)  # fmt: skip
    img = photo()
    hand = HandDetection(hand_keypoints(), None, "right", 0.9)
    out = seg.segment(img, hand)
    for m in (out.hand_mask, out.object_mask):
        assert m.shape == (60, 80) and m.dtype == bool
    assert not (out.hand_mask & out.object_mask).any()
    boxes, scores = seg.last_detections
    assert boxes.shape == (16, 4) and scores.shape == (16,)  # (32 / 8)^2 patches, all kept
    assert np.all(np.diff(scores) <= 0) and np.all((0 <= scores) & (scores <= 1))
    assert np.all(boxes[:, [0, 2]] <= 80) and np.all(boxes[:, [1, 3]] <= 60) and np.all(boxes >= 0)
    assert out.meta["source"] == "detector" and out.has_object == bool(out.object_mask.any())
    assert out.meta["object_box"] == pytest.approx(
        boxes[choose_box(boxes, scores, hand.keypoints2d, (80, 60))].tolist()
    )
    assert seg.segment(img, hand).object_mask.tolist() == out.object_mask.tolist()  # same again
    # confidence: SAM's predicted IoU of each mask
    assert out.confidence["hand"].score == pytest.approx(np.clip(out.meta["hand_sam_iou"], 0, 1))
    assert out.confidence["object"].score == pytest.approx(
        np.clip(out.meta["object_sam_iou"], 0, 1)
    )
    # prompts replace the detector: a box, or points alone
    seg.last_detections = None
    boxed = seg.segment(img, hand, prompts=Prompts(object_box=(40.0, 10.0, 75.0, 50.0)))
    assert seg.last_detections is None and boxed.meta["source"] == "prompts"
    assert boxed.meta["object_box"] == [40.0, 10.0, 75.0, 50.0]
    pointed = seg.segment(img, hand, prompts=Prompts(object_points=((60.0, 30.0),)))
    assert seg.last_detections is None and pointed.meta["object_box"] is None
    assert pointed.object_mask.shape == (60, 80)
    # background points go to SAM as negative points (label 0), after the positive ones
    calls, real = [], seg.sam.processor

    class Spy:
        def __call__(self, *a, **kw):
            calls.append(kw)
            return real(*a, **kw)

        def __getattr__(self, name):
            return getattr(real, name)

    seg.sam.processor = Spy()
    negative = Prompts(object_points=((60.0, 30.0),), background_points=((10.0, 50.0),))
    assert seg.segment(img, hand, prompts=negative).object_mask.shape == (60, 80)
    assert calls[-1]["input_points"] == [[[[60.0, 30.0], [10.0, 50.0]]]]
    assert calls[-1]["input_labels"] == [[[1, 0]]]
    seg.sam.processor = real
    with pytest.raises(InvalidInputError, match="21 hand keypoints"):
        seg.segment(img, HandDetection(np.zeros((0, 2)), None, "right", 1.0))


@pytest.fixture(scope="module")
def dino_dir(tmp_path_factory):
    tf = pytest.importorskip("transformers", reason="transformers not installed (extra 'sam')")
    import torch

    folder = tmp_path_factory.mktemp("grounding-dino")
    words = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]", ".", "an", "object", "held", "by", "a",
             "hand"]  # fmt: skip
    (folder / "vocab.txt").write_text("\n".join(words) + "\n")
    tok = tf.BertTokenizer(vocab_file=str(folder / "vocab.txt"))
    backbone = tf.SwinConfig(
        window_size=7, embed_dim=8, depths=[1, 1, 1, 1], num_heads=[1, 1, 1, 1], image_size=64,
        out_features=["stage2", "stage3", "stage4"], out_indices=[2, 3, 4],
    )  # fmt: skip
    text = {"hidden_size": 8, "num_hidden_layers": 1, "num_attention_heads": 2,
            "intermediate_size": 8, "max_position_embeddings": 32, "model_type": "bert",
            "vocab_size": len(words)}  # fmt: skip
    cfg = tf.GroundingDinoConfig(
        backbone_config=backbone, text_config=text, d_model=32, encoder_layers=1,
        decoder_layers=2, encoder_attention_heads=2, decoder_attention_heads=2,
        encoder_ffn_dim=16, decoder_ffn_dim=16, num_queries=5, num_feature_levels=4,
        encoder_n_points=2, decoder_n_points=2, max_text_len=32,
    )  # fmt: skip
    torch.manual_seed(0)
    tf.GroundingDinoForObjectDetection(cfg).save_pretrained(folder)
    ip = tf.GroundingDinoImageProcessor(size={"shortest_edge": 64, "longest_edge": 96})
    tf.GroundingDinoProcessor(image_processor=ip, tokenizer=tok).save_pretrained(folder)
    return folder


def test_grounded_sam_reads_grounding_dino(dino_dir, sam_dir):
    from easyhoi.perception.base import HandDetection

    seg = GroundedSamSegmenter(detector_dir=dino_dir, sam_dir=sam_dir, min_score=0.0)
    assert seg.kind == "grounding-dino"
    img = photo()
    boxes, scores = seg.detect(img)
    assert boxes.shape == (5, 4) and scores.shape == (5,)  # one per query
    assert np.all((0 <= scores) & (scores <= 1)) and np.all(np.diff(scores) <= 0)
    assert np.all(boxes[:, [0, 2]] <= 80) and np.all(boxes[:, [1, 3]] <= 60)
    out = seg.segment(img, HandDetection(hand_keypoints(), None, "right", 0.9))
    assert out.hand_mask.shape == out.object_mask.shape == (60, 80)
    assert out.object_mask.dtype == bool and not (out.hand_mask & out.object_mask).any()


def test_grounded_sam_box_pixels_follow_grounding_dino_fractions(dino_dir, sam_dir):
    import torch

    seg = GroundedSamSegmenter(detector_dir=dino_dir, sam_dir=sam_dir, min_score=0.3)

    class Fixed(torch.nn.Module):
        def forward(self, **inputs):
            inf = float("-inf")
            logits = torch.tensor([[[1.0, 3.0, inf], [0.0, -1.0, inf]]])  # best token per box
            boxes = torch.tensor([[[0.5, 0.5, 0.5, 0.5], [0.25, 0.25, 0.1, 0.2]]])
            return type("Out", (), {"logits": logits, "pred_boxes": boxes})()

    seg.detector = Fixed()
    boxes, scores = seg.detect(photo((60, 80)))
    np.testing.assert_allclose(scores, [1 / (1 + np.exp(-3)), 0.5])
    # fractions of the 80x60 photo: (40, 30, 40, 30) -> (20, 15, 60, 45); (20, 15, 8, 12)
    np.testing.assert_allclose(boxes, [[20, 15, 60, 45], [16, 9, 24, 21]])


def test_grounded_sam_box_pixels_follow_owlv2_square_padding(owl_dir, sam_dir):
    import torch

    seg = GroundedSamSegmenter(detector_dir=owl_dir, sam_dir=sam_dir, min_score=0.3)

    class Fixed(torch.nn.Module):
        def forward(self, **inputs):
            logits = torch.tensor([[[2.0], [-2.0], [0.0]]])  # sigmoid: 0.88, 0.12, 0.5
            boxes = torch.tensor([[[0.5, 0.25, 0.5, 0.25], [0.1, 0.1, 0.1, 0.1],
                                   [0.9, 0.9, 0.4, 0.4]]])  # fmt: skip
            return type("Out", (), {"logits": logits, "pred_boxes": boxes})()

    seg.detector = Fixed()
    boxes, scores = seg.detect(photo((60, 80)))  # padded to an 80x80 square
    np.testing.assert_allclose(scores, [1 / (1 + np.exp(-2)), 0.5])
    # (cx, cy, w, h) * 80 = (40, 20, 40, 20) -> (20, 10, 60, 30); the second clipped to 80x60
    np.testing.assert_allclose(boxes, [[20, 10, 60, 30], [56, 56, 80, 60]])


def test_grounded_sam_folders_are_checked(owl_dir, sam_dir, tmp_path):
    with pytest.raises(InvalidInputError, match="detector model folder not found"):
        GroundedSamSegmenter(detector_dir=tmp_path / "missing", sam_dir=sam_dir)
    with pytest.raises(InvalidInputError, match="SAM adapter needs model_dir"):
        GroundedSamSegmenter(detector_dir=owl_dir, sam_dir=None)
    refused = "holds a 'sam' model; the grounded-sam segmenter reads owlv2, grounding-dino"
    with pytest.raises(InvalidInputError, match=refused):
        GroundedSamSegmenter(detector_dir=sam_dir, sam_dir=sam_dir)


def test_grounded_sam_needs_both_folders_in_the_chain(tmp_path, capsys):
    from easyhoi.cli import main

    img = tmp_path / "p.png"
    cv2.imwrite(str(img), photo((64, 64)))
    rc = main(["reconstruct", str(img), "--out", str(tmp_path / "o"), "--segmenter",
               "grounded-sam", "--sam-dir", str(tmp_path)])  # fmt: skip
    assert rc == 2
    err = capsys.readouterr().err
    assert "segmenter backend 'grounded-sam' needs a local model folder: pass --detector-dir" in err
    rc = main(["reconstruct", str(img), "--out", str(tmp_path / "o"), "--detector-dir",
               str(tmp_path / "nope")])  # fmt: skip
    assert rc == 2 and "needs a local model folder: pass --sam-dir" in capsys.readouterr().err
