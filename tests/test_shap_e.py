"""Shap-E object backend with a tiny random-weight pipeline built offline."""

from __future__ import annotations

import numpy as np
import pytest

from easyhoi.errors import InvalidInputError


@pytest.fixture(scope="module")
def shap_e_dir(tmp_path_factory):
    dif = pytest.importorskip("diffusers", reason="diffusers not installed (extra 'diffusion')")
    tf = pytest.importorskip("transformers")
    import torch
    from diffusers.pipelines.shap_e import ShapERenderer

    d = 16
    torch.manual_seed(0)
    prior = dif.PriorTransformer(
        num_attention_heads=2, attention_head_dim=16, embedding_dim=d, num_embeddings=32,
        embedding_proj_dim=d, time_embed_dim=64, num_layers=1, clip_embed_dim=2 * d,
        additional_embeddings=0, time_embed_act_fn="gelu", norm_in_type="layer",
        embedding_proj_norm_type="layer", encoder_hid_proj_type=None, added_emb_type=None,
    )  # fmt: skip
    renderer = ShapERenderer(param_shapes=((8, 93), (8, 8), (8, 8), (8, 8)), d_latent=d,
                             d_hidden=8, n_output=12, background=(0.1, 0.1, 0.1))  # fmt: skip
    encoder = tf.CLIPVisionModel(tf.CLIPVisionConfig(
        hidden_size=d, image_size=32, projection_dim=d, intermediate_size=24,
        num_attention_heads=2, num_channels=3, num_hidden_layers=2, patch_size=4,
    ))  # fmt: skip
    processor = tf.CLIPImageProcessor(crop_size=32, do_center_crop=True, do_normalize=True,
                                      do_resize=True, size=32, resample=3)  # fmt: skip
    scheduler = dif.HeunDiscreteScheduler(
        beta_schedule="exp", num_train_timesteps=1024, prediction_type="sample",
        use_karras_sigmas=True, clip_sample=True, clip_sample_range=1.0,
    )  # fmt: skip
    pipe = dif.ShapEImg2ImgPipeline(prior=prior, image_encoder=encoder, image_processor=processor,
                                    shap_e_renderer=renderer, scheduler=scheduler)  # fmt: skip
    folder = tmp_path_factory.mktemp("shap_e")
    pipe.save_pretrained(folder)
    return folder


def test_shap_e_backend_places_a_closed_mesh(shap_e_dir):
    from easyhoi.perception.base import create

    rec = create("object", "shap-e", model_dir=shap_e_dir, steps=2, grid=24)
    img = np.full((120, 160, 3), 200, np.uint8)
    m = np.zeros((120, 160), bool)
    m[30:90, 50:130] = True
    img[m] = (180, 40, 30)
    mesh = rec.reconstruct(img, m)
    md = mesh.metadata["easyhoi"]
    assert md["method"] == "shap-e"
    assert mesh.is_watertight and mesh.volume > 0
    assert mesh.extents.max() == pytest.approx(1.0)
    # placed like the offline mesh: its outline's box is the mask's box
    uv = mesh.vertices[:, :2] * md["pixels_per_unit"] + np.asarray(md["center_px"])
    lo, hi = uv.min(0), uv.max(0)
    np.testing.assert_allclose(np.sqrt(np.prod(hi - lo)), np.sqrt(80 * 60), rtol=1e-6)
    np.testing.assert_allclose((lo + hi) / 2, [90, 60], atol=1e-6)
    again = rec.reconstruct(img, m)
    np.testing.assert_array_equal(again.vertices, mesh.vertices)


def test_shap_e_backend_needs_a_folder(tmp_path):
    pytest.importorskip("diffusers")
    from easyhoi.perception.adapters.shap_e import ShapEObjectReconstructor

    with pytest.raises(InvalidInputError, match="not found"):
        ShapEObjectReconstructor(model_dir=tmp_path / "missing")
    with pytest.raises(InvalidInputError, match="model_index.json"):
        ShapEObjectReconstructor(model_dir=tmp_path)


def test_shap_e_backend_names_its_flag():
    from easyhoi.config import PerceptionConfig
    from easyhoi.perception import chain

    with pytest.raises(InvalidInputError, match="--shape-dir"):
        chain._backend(PerceptionConfig(object="shap-e"), "object", "shap-e")


def test_shape_dir_flag_selects_the_backend(tmp_path):
    from easyhoi.cli import _config_from_args, build_parser

    args = build_parser().parse_args(
        ["reconstruct", "photo.jpg", "--out", str(tmp_path / "o"), "--shape-dir", str(tmp_path)]
    )
    cfg = _config_from_args(args)
    assert cfg.perception.object == "shap-e" and cfg.perception.shape_dir == str(tmp_path)
