"""Tiny random-weight large models, written to a folder in the format their adapters load.

Used by the adapter tests and ``benchmarks/bench_gpu.py``: the adapters' real code paths run
offline on models of a few thousand parameters (nothing is downloaded). Each writer seeds torch
so the same folder content comes out every time.
"""

from __future__ import annotations

import json
from pathlib import Path


def write_tiny_sam(folder: Path, seed: int = 0) -> Path:
    """A SAM model + processor (64 px input) in ``folder``; returns ``folder``."""
    import torch
    import transformers as tf
    from transformers.models.sam import configuration_sam as cs

    vc = cs.SamVisionConfig(
        hidden_size=32, num_hidden_layers=2, num_attention_heads=2, mlp_dim=64,
        output_channels=16, image_size=64, patch_size=8, global_attn_indexes=[1],
        window_size=4, num_pos_feats=8,
    )  # fmt: skip
    pc = cs.SamPromptEncoderConfig(hidden_size=16, image_size=64, patch_size=8)
    mc = cs.SamMaskDecoderConfig(
        hidden_size=16, num_hidden_layers=2, num_attention_heads=2, mlp_dim=32,
        iou_head_hidden_dim=16,
    )  # fmt: skip
    cfg = tf.SamConfig(
        vision_config=vc.to_dict(),
        prompt_encoder_config=pc.to_dict(),
        mask_decoder_config=mc.to_dict(),
    )
    torch.manual_seed(seed)
    tf.SamModel(cfg).save_pretrained(folder)
    ip = tf.SamImageProcessor(size={"longest_edge": 64}, pad_size={"height": 64, "width": 64})
    tf.SamProcessor(image_processor=ip).save_pretrained(folder)
    return Path(folder)


def write_tiny_depth(folder: Path, seed: int = 0) -> Path:
    """A DPT depth model + processor (32 px input) in ``folder``; returns ``folder``."""
    import torch
    import transformers as tf

    cfg = tf.DPTConfig(
        hidden_size=32, num_hidden_layers=4, num_attention_heads=2, intermediate_size=37,
        image_size=32, patch_size=8, backbone_out_indices=[0, 1, 2, 3],
        neck_hidden_sizes=[8, 16, 16, 32], fusion_hidden_size=16,
        reassemble_factors=[4, 2, 1, 0.5],
    )  # fmt: skip
    torch.manual_seed(seed)
    tf.DPTForDepthEstimation(cfg).save_pretrained(folder)
    tf.DPTImageProcessor(size={"height": 32, "width": 32}, keep_aspect_ratio=False).save_pretrained(
        folder
    )
    return Path(folder)


def tiny_clip_tokenizer(folder: Path):
    """A CLIP tokenizer over lower-case letters and the comma; returns (tokenizer, vocab size)."""
    from transformers import CLIPTokenizer

    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1}
    for suffix in ("", "</w>"):
        for c in "abcdefghijklmnopqrstuvwxyz,":
            vocab[c + suffix] = len(vocab)
    (folder / "vocab.json").write_text(json.dumps(vocab))
    (folder / "merges.txt").write_text("#version: 0.2\n")
    tok = CLIPTokenizer(
        vocab_file=str(folder / "vocab.json"),
        merges_file=str(folder / "merges.txt"),
        model_max_length=16,
    )
    return tok, len(vocab)


def write_tiny_inpainter(folder: Path, seed: int = 0) -> Path:
    """A Stable-Diffusion inpainting pipeline in ``folder / "pipe"``; returns that folder."""
    import diffusers
    import torch
    from transformers import CLIPTextConfig, CLIPTextModel

    tokdir = Path(folder) / "tokenizer-src"
    tokdir.mkdir(parents=True, exist_ok=True)
    tok, n_vocab = tiny_clip_tokenizer(tokdir)
    torch.manual_seed(seed)
    unet = diffusers.UNet2DConditionModel(
        block_out_channels=(8, 16), layers_per_block=1, sample_size=16, in_channels=9,
        out_channels=4, down_block_types=("DownBlock2D", "CrossAttnDownBlock2D"),
        up_block_types=("CrossAttnUpBlock2D", "UpBlock2D"), cross_attention_dim=16,
        attention_head_dim=4, norm_num_groups=4,
    )  # fmt: skip
    vae = diffusers.AutoencoderKL(
        block_out_channels=[8, 16], in_channels=3, out_channels=3, latent_channels=4,
        down_block_types=["DownEncoderBlock2D"] * 2, up_block_types=["UpDecoderBlock2D"] * 2,
        norm_num_groups=4, sample_size=32,
    )  # fmt: skip
    text = CLIPTextModel(
        CLIPTextConfig(
            bos_token_id=0, eos_token_id=1, pad_token_id=1, hidden_size=16,
            intermediate_size=32, num_attention_heads=2, num_hidden_layers=2,
            vocab_size=n_vocab, max_position_embeddings=16,
        )
    )  # fmt: skip
    pipe = diffusers.StableDiffusionInpaintPipeline(
        unet=unet, vae=vae, text_encoder=text, tokenizer=tok,
        scheduler=diffusers.DDIMScheduler(steps_offset=1), safety_checker=None,
        feature_extractor=None, requires_safety_checker=False,
    )  # fmt: skip
    out = Path(folder) / "pipe"
    pipe.save_pretrained(out)
    return out
