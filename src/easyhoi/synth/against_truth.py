"""How a reconstruction of a rendered scene compares with the scene it was rendered from.

``easyhoi example`` reconstructs a synthetic photo as it would a real one, so the product's
own answer can be checked against the truth a real photo lacks: the perception's masks
(IoU with the rendered visible and complete silhouettes) and the hand in the photo (mean pixel
distance of the detector's 21 keypoints and of the result's hand, reprojected through its
camera, to the rendered keypoints).
"""

from __future__ import annotations

import numpy as np

from easyhoi.geometry.masks import mask_iou
from easyhoi.optim.hand_change import reprojected_keypoints

__all__ = ["against_truth", "truth_line"]


def against_truth(scene, inp, result, hand_model) -> dict:
    """Masks and 2D keypoints of a reconstruction against its scene's truth.

    Args:
        scene: :class:`easyhoi.synth.scene.SynthScene` the photo was rendered from.
        inp: HOIInput the perception made of the photo (same pixel grid as the scene).
        result: HOIResult of the optimizer.
        hand_model: The hand model ``result.hand_params`` belong to.

    Returns:
        ``hand_mask_iou``, ``object_mask_iou`` (visible), ``amodal_mask_iou``, and where the
        input carries the detector's keypoints ``detector_px``; ``result_px`` (mean distances to
        the rendered keypoints, pixels).
    """
    truth_amodal = np.asarray(scene.object_amodal, bool) | np.asarray(scene.object_mask, bool)
    out = {
        "hand_mask_iou": mask_iou(inp.hand_mask, scene.hand_mask),
        "object_mask_iou": mask_iou(inp.object_mask, scene.object_mask),
        "amodal_mask_iou": mask_iou(inp.amodal_mask, truth_amodal),
    }
    gt = np.asarray(scene.keypoints_2d, np.float64)
    det = inp.meta.get("keypoints2d") if isinstance(inp.meta, dict) else None
    if det is not None and np.shape(det) == (21, 2):
        out["detector_px"] = float(np.linalg.norm(np.asarray(det, np.float64) - gt, axis=1).mean())
    uv = reprojected_keypoints(hand_model, result.hand_params, result.camera, result.metric_scale)
    out["result_px"] = float(np.linalg.norm(uv - gt, axis=1).mean())
    return out


def truth_line(measured: dict) -> str:
    """One line for the terminal: what the truth says of the reconstruction."""
    obj, amodal = measured["object_mask_iou"], measured["amodal_mask_iou"]
    parts = [
        f"hand mask IoU {measured['hand_mask_iou']:.2f}",
        f"object mask IoU {obj:.2f} (complete {amodal:.2f})",
    ]
    kp = f"hand keypoints {measured['result_px']:.1f} px off"
    if "detector_px" in measured:
        kp += f" (the detector's {measured['detector_px']:.1f} px)"
    return "against the scene's truth: " + ", ".join(parts + [kp])
