"""Configuration: a tree of frozen dataclasses with named presets.

Every weight, threshold, learning rate and schedule of the optimizer lives here (never inline in
the code). The tree::

    EasyHOIConfig
      optim: OptimConfig
        camera: CameraStageConfig     stage 1, camera setup
        contact: ContactStageConfig   stage 2, HOI contact alignment
        refine: RefineStageConfig     stage 3, hand parameter refinement
      perception: PerceptionConfig    backend names per role

Each field carries an attribute docstring (the string literal under it); :func:`field_docs`
reads them, so a CLI can show them as ``--help``. Presets: ``PRESETS["paper"]`` (the paper's
schedule) and ``PRESETS["fast"]`` (the default, for a CPU). Change values with
:func:`with_overrides` (dotted paths, type-checked) and persist with :func:`to_dict` /
:func:`from_dict` (JSON-ready).
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import json
import math
import textwrap
import types
import typing
from dataclasses import dataclass, field, fields, is_dataclass, replace
from functools import cache
from typing import Any

from easyhoi.device import check_device_name
from easyhoi.errors import InvalidInputError
from easyhoi.shape_families import OBJECT_SHAPES

__all__ = [
    "CameraStageConfig",
    "ContactStageConfig",
    "EasyHOIConfig",
    "MAX_SEED",
    "OptimConfig",
    "PRESETS",
    "PerceptionConfig",
    "RefineStageConfig",
    "field_docs",
    "from_dict",
    "get_preset",
    "parse_overrides",
    "to_dict",
    "with_overrides",
]


#: Largest accepted seed (numpy's seed range; OpenCV's backends get the seed modulo 2**31).
MAX_SEED = 2**32 - 1


def _finite(obj) -> None:
    """Every float of a config dataclass (tuples included) is finite."""
    for f in fields(obj):
        v = getattr(obj, f.name)
        values = v if isinstance(v, tuple) else (v,)
        for x in values:
            if isinstance(x, float) and not math.isfinite(x):
                raise InvalidInputError(
                    f"{type(obj).__name__}.{f.name} must be a finite number, got {v!r}"
                )


def _positive(obj, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        if not v > 0:
            raise InvalidInputError(f"{type(obj).__name__}.{n} must be > 0, got {v!r}")


def _non_negative(obj, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        if v < 0:
            raise InvalidInputError(f"{type(obj).__name__}.{n} must be >= 0, got {v!r}")


def _check_schedule(obj) -> None:
    s = obj.resolution_schedule
    if len(s) == 0 or any(not 0 < f <= 1 for f in s) or list(s) != sorted(s):
        raise InvalidInputError(
            f"{type(obj).__name__}.resolution_schedule must be non-empty increasing fractions in "
            f"(0, 1], got {s!r}"
        )


@dataclass(frozen=True)
class CameraStageConfig:
    """Stage 1: fit the object camera so the rendered object silhouette matches M^_o."""

    lr: float = 1e-2
    """Adam learning rate for the camera parameters."""
    max_iters: int = 1000
    """Iteration cap over all resolution phases together (split evenly between them)."""
    stop_loss: float = 0.1
    """Stop once the soft IoU loss (without the Sinkhorn term) is below this value; a start whose
    sharp silhouette already has IoU >= 1 - stop_loss with M^_o runs no iteration."""
    patience: int = 0
    """Early stopping: stop after this many iterations without the total loss improving by
    min_delta (0 = off, the paper)."""
    min_delta: float = 1e-4
    """Smallest decrease of the total loss that counts as an improvement for patience."""
    resolution_schedule: tuple[float, ...] = (1.0,)
    """Coarse-to-fine render sizes as fractions of optim.render_size, increasing; each phase
    gets an equal share of max_iters."""
    iou_weight: float = 1.0
    """Weight of the soft IoU loss between the rendered silhouette and the amodal mask."""
    use_sinkhorn: bool = True
    """Add the Sinkhorn (optimal-transport) mask term, which has gradients without overlap."""
    sinkhorn_weight: float = 1.0
    """Weight of the Sinkhorn mask term."""
    sinkhorn_grid: int = 32
    """Cells per side of the coarse grid the Sinkhorn term works on. Cost grows as grid^4
    (forward + backward on one CPU core: about 0.06 s at 16, 1.5 s at 32 per call)."""
    sinkhorn_blur: float = 0.05
    """Entropic blur of the Sinkhorn term, in image-normalised units (long side = 1)."""
    sinkhorn_scaling: float = 0.8
    """epsilon-scaling ratio of the Sinkhorn solver, in (0, 1)."""
    init_fov_deg: float = 30.0
    """Initial vertical field of view in degrees (InstantMesh's rendering setup)."""
    init_distance: float = 4.5
    """Initial camera distance from the object centre, in object units (InstantMesh)."""
    init_from_masks: bool = False
    """Initialise the camera translation so that the object's projected box matches the amodal
    mask's box (False: centred object at init_distance, as the reference implementation)."""
    init_rotations: str = "yaw"
    """Rotations tried by init_from_masks: "yaw" (4 yaws of a mesh that faces the camera, as the
    silhouette reconstructor outputs) or "cube" (the 24 axis-aligned rotations: a mesh in any
    frame, e.g. a scan)."""
    optimise_focal: bool = True
    """Optimise fx and fy together with the 6-DoF pose (8 DoF); False keeps the focal fixed."""
    square_pixels: bool = False
    """One focal length for both image axes (fx = fy, 7 DoF): every photo's camera has square
    pixels, and a stretched camera (fx != fy) distorts the hand's projection in a way no rigid
    hand follows. False = the reference implementation's separate fx, fy (8 DoF)."""

    def __post_init__(self):
        _finite(self)
        _positive(self, "lr", "sinkhorn_grid", "sinkhorn_blur", "init_fov_deg", "init_distance")
        _non_negative(self, "max_iters", "stop_loss", "patience", "min_delta")
        _non_negative(self, "iou_weight", "sinkhorn_weight")
        _check_schedule(self)
        if not 0 < self.sinkhorn_scaling < 1:
            raise InvalidInputError(
                f"CameraStageConfig.sinkhorn_scaling must be in (0, 1), got {self.sinkhorn_scaling}"
            )
        if self.init_rotations not in ("yaw", "cube"):
            raise InvalidInputError(
                f'CameraStageConfig.init_rotations must be "yaw" or "cube", '
                f"got {self.init_rotations!r}"
            )
        if not self.init_fov_deg < 180:
            raise InvalidInputError(f"init_fov_deg must be < 180, got {self.init_fov_deg}")


@dataclass(frozen=True)
class ContactStageConfig:
    """Stage 2: align the hand's global pose (and scale) to the hand mask and the contacts."""

    lr: float = 1e-2
    """Adam learning rate for the hand's global rotation, translation and log-scale."""
    max_iters: int = 1000
    """Iteration cap of the mask-constrained optimisation."""
    stop_loss: float = 0.1
    """Stop once the hand-mask soft IoU loss is below this value and every registration in
    register_at has run (or could not run because the cap came first)."""
    patience: int = 0
    """Early stopping patience in iterations (0 = off), counted after the last registration."""
    min_delta: float = 1e-4
    """Smallest decrease of the loss that counts as an improvement for patience."""
    resolution_schedule: tuple[float, ...] = (1.0,)
    """Coarse-to-fine render sizes as fractions of optim.render_size, increasing."""
    register_at: tuple[int, ...] = (100, 200)
    """Iterations at which contact-based registration (depth peeling + ICP) runs."""
    peel_layers: int = 4
    """Depth-peeling layers used to collect every ray hit through a contact pixel."""
    palmar_only: bool = True
    """Keep only hand hits on palmar faces (the dorsal faces of the template are excluded)."""
    icp_iters: int = 30
    """Maximum iterations of the translation-only ICP between hand and object contact points."""
    icp_tolerance: float = 1e-7
    """ICP stops when the translation update is shorter than this (object units)."""
    icp_trim_fraction: float = 0.0
    """Fraction of the farthest correspondences dropped in each ICP iteration (0 = plain ICP)."""
    optimise_scale: bool = True
    """Optimise the hand's uniform scale (the object frame has no metric scale)."""
    rotation_prior_weight: float = 0.0
    """Weight of ||r||^2, r (radians, axis-angle) the hand's rotation away from the estimator's
    rotation relative to the camera; keeps that rotation while the mask term moves the hand
    (0 = off: rotation driven by the mask alone, the paper)."""
    scan_tie_margin: float = 0.0
    """Depth scan (scan_scale): depths scoring within this of the best count as ties and the
    one nearest the current depth wins (0 = the best score)."""
    scan_band: float = 0.0
    """Depth scan touching term: 0 = the closest hand vertex's distance to the surface; > 0 =
    the mean over the contact-zone vertices of min(|d|, scan_band) / scan_band, plus the closest
    one's distance beyond the band (in bands) when none lies in it (d in normalised object
    units: the grasp's contact zones on the surface)."""

    depth_only_registration: bool = False
    """Apply only the depth part of each registration's translation (as a change of the metric
    scale); False = the paper's full translation."""
    initial_competes: bool = False
    """The state the stage starts from competes for the best state (False = the paper's: only
    states from the first registration on)."""
    rescan_range: float = 2.0
    """The depth scans at the registrations try metric scales from 1 / rescan_range to
    rescan_range times the current one (41 log-spaced factors; 2 = the placement's own scan)."""
    rescan_tie_margin: float = 0.0
    """Tie margin of the depth scans at the registrations (as scan_tie_margin, which the
    placement's scan keeps): a re-scan moves the depth only for a score this much better."""
    score_band: bool = False
    """The best-state score measures touching with the depth scan's contact-band term (the
    contact zones on the surface, scan_band) instead of the closest vertex's distance to it;
    used only when scan_band > 0."""
    keypoint_weight: float = 0.0
    """Weight of the robust 2D keypoint term (optim.hand_terms.keypoint_loss) in the mask fit:
    the rigid hand's reprojected keypoints against the detector's (HOIInput.meta["keypoints2d"]),
    so that a hand mask that is wrong in places cannot drag the hand off where the detector
    saw it; 0 = off (the paper: the mask alone)."""
    keypoint_drift_weight: float = 0.0
    """Weight of the whole-hand drift term (optim.hand_terms.keypoint_drift_loss) in the mask
    fit; used only with keypoint_weight > 0."""
    keypoint_sigma: float = 0.1
    """Geman-McClure scale of the stage's keypoint terms, as a fraction of the hand's size in
    the photo."""

    def __post_init__(self):
        _finite(self)
        _positive(self, "lr", "peel_layers", "keypoint_sigma")
        _non_negative(self, "keypoint_weight", "keypoint_drift_weight")
        _non_negative(self, "max_iters", "stop_loss", "patience", "min_delta", "icp_iters")
        _non_negative(self, "icp_tolerance", "rotation_prior_weight", "scan_tie_margin")
        _non_negative(self, "scan_band", "rescan_tie_margin")
        if not self.rescan_range > 1.0:
            raise InvalidInputError(
                f"ContactStageConfig.rescan_range must be > 1, got {self.rescan_range}"
            )
        _check_schedule(self)
        if any(r < 0 for r in self.register_at) or list(self.register_at) != sorted(
            set(self.register_at)
        ):
            raise InvalidInputError(
                f"ContactStageConfig.register_at must be strictly increasing iterations >= 0, "
                f"got {self.register_at!r}"
            )
        if not 0 <= self.icp_trim_fraction < 1:
            raise InvalidInputError(
                f"ContactStageConfig.icp_trim_fraction must be in [0, 1), "
                f"got {self.icp_trim_fraction}"
            )


@dataclass(frozen=True)
class RefineStageConfig:
    """Stage 3: refine the hand's global pose and articulation with the combined loss."""

    lr_global: float = 1e-4
    """Adam learning rate of the global pose phi: rotation (radians) and translation, the latter
    in normalised object units (the object's largest side = 1, as the SDF), like stages 1-2."""
    lr_transl: float | None = None
    """Separate learning rate of the translation (normalised object units); None = lr_global."""
    lr_pose: float = 1e-2
    """Adam learning rate of the articulation theta."""
    max_iters: int = 1000
    """Iteration cap (the paper does not state one; the cap of the other stages)."""
    patience: int = 0
    """Early stopping patience in iterations (0 = off)."""
    min_delta: float = 1e-5
    """Smallest decrease of the loss that counts as an improvement for patience."""
    resolution_schedule: tuple[float, ...] = (1.0,)
    """Coarse-to-fine render sizes as fractions of optim.render_size, increasing."""
    hand_mask_weight: float = 5.0
    """Weight of the soft IoU loss between the rendered hand and M_h (0 disables the term)."""
    penetration_weight: float = 10.0
    """Weight of the penetration loss (1/N) sum max(0, -d(v)) (0 disables it)."""
    contact_weight: float = 5.0
    """Weight of the contact loss, sum over the contact-zone vertices C of max(0, d(v)) times
    contact_reference_count / |C| (0 disables it)."""
    contact_reference_count: float | None = 115.0
    """The contact sum is rescaled to this many vertices (K / |C|): 115 = MANO's contact zones,
    so the paper's weights keep their balance against the mean penetration for any hand mesh
    (OpenHand: |C| = 285); None = the raw sum."""
    reg_weight: float = 0.1
    """Weight of the pose regulariser ||theta - theta_0||_1 (0 disables it)."""
    sdf_resolution: int = 64
    """Cells per side of the object SDF grid queried by trilinear interpolation."""
    penetration_threshold: float = -5e-3
    """A vertex counts as penetrating when its SDF is below this (normalised object units)."""
    pad_tolerance_m: float = 0.0
    """Depth in metres to which the contact-zone vertices (finger pads and palm) may lie inside
    the object before they count as penetrating (the deeper of this and
    ``penetration_threshold``): skin pressed on an object flattens by a millimetre or two.
    0: the same threshold for every vertex, the paper."""
    contact_max_distance: float | None = None
    """Attract contact vertices only closer than this (normalised object units); None = all,
    the paper."""
    opposition_max_distance: float | None = None
    """Attraction radius of the thumb's and index finger's contact vertices (normalised object
    units), the digits that close a grasp from opposite sides; the other contact vertices keep
    contact_max_distance. None = contact_max_distance for all. Used only when
    contact_max_distance is set."""
    optimise_global: bool = True
    """Optimise the global pose phi."""
    optimise_pose: bool = True
    """Optimise the articulation theta."""
    keypoint_weight: float = 0.0
    """Weight of the robust 2D keypoint term against the detector's keypoints
    (HOIInput.meta["keypoints2d"]); 0 = off (the paper has no such term)."""
    keypoint_sigma: float = 0.05
    """Geman-McClure scale of the keypoint term, as a fraction of the hand's size in the photo."""
    keypoint_drift_weight: float = 0.0
    """Weight of the non-saturating term on the mean keypoint residual (the whole hand moved
    off the detector's keypoints; optim.hand_terms.keypoint_drift_loss); used only with
    keypoint_weight > 0. 0 = off."""
    rigid_first: bool = False
    """In the first phase of the schedule only the global pose moves (the fingers keep the
    estimator's articulation); False = the paper's joint optimisation."""
    push_out_steps: int = 0
    """Before the gradient steps, move the penetrating hand rigidly out of the object in up to
    this many steps, along the camera rays (optim.refine.push_out; 0 = off, the paper)."""
    push_out_scale: bool = False
    """The push-out along the camera ray changes the metric scale (the hand's depth relative to
    the object, its projection kept exactly) instead of translating the hand along the ray
    through its centroid (which also changes its apparent size). Used with a camera only."""
    prior_weight: float = 0.0
    """Weight of the anatomical pose prior (joint limits, hinges, finger coupling); 0: off."""
    close_gap: bool = False
    """After the gradient steps, a hand that does not touch the object is moved along the camera
    rays (a change of the metric scale that keeps its projection) to where its nearest vertex
    touches the surface (optim.close_gap.close_gap); when no such move reaches it (the hand lies
    beside the object in the photo), the object is moved onto the hand by at most a finger's
    width, the camera with the hand so that the hand keeps its projection
    (optim.close_gap.meet). Needs a camera. False: the paper."""

    def __post_init__(self):
        _finite(self)
        _positive(self, "lr_global", "lr_pose", "sdf_resolution", "keypoint_sigma")
        _non_negative(self, "keypoint_weight", "prior_weight", "push_out_steps", "pad_tolerance_m")
        _non_negative(self, "keypoint_drift_weight")
        if self.lr_transl is not None and not self.lr_transl > 0:
            raise InvalidInputError(
                f"RefineStageConfig.lr_transl must be > 0 or None, got {self.lr_transl}"
            )
        _non_negative(self, "max_iters", "patience", "min_delta")
        _non_negative(
            self, "hand_mask_weight", "penetration_weight", "contact_weight", "reg_weight"
        )
        _check_schedule(self)
        if self.penetration_threshold > 0:
            raise InvalidInputError(
                f"RefineStageConfig.penetration_threshold must be <= 0, "
                f"got {self.penetration_threshold}"
            )
        if self.contact_reference_count is not None and not self.contact_reference_count > 0:
            raise InvalidInputError(
                f"RefineStageConfig.contact_reference_count must be > 0 or None, "
                f"got {self.contact_reference_count}"
            )
        if self.contact_max_distance is not None and not self.contact_max_distance > 0:
            raise InvalidInputError(
                f"RefineStageConfig.contact_max_distance must be > 0 or None, "
                f"got {self.contact_max_distance}"
            )
        if self.opposition_max_distance is not None and not self.opposition_max_distance > 0:
            raise InvalidInputError(
                f"RefineStageConfig.opposition_max_distance must be > 0 or None, "
                f"got {self.opposition_max_distance}"
            )


_DTYPES = ("float32", "float64")


@dataclass(frozen=True)
class OptimConfig:
    """The three-stage optimizer: which stages run, shared settings, and each stage."""

    camera: CameraStageConfig = field(default_factory=CameraStageConfig)
    """Stage 1, camera setup."""
    contact: ContactStageConfig = field(default_factory=ContactStageConfig)
    """Stage 2, HOI contact alignment."""
    refine: RefineStageConfig = field(default_factory=RefineStageConfig)
    """Stage 3, hand parameter refinement."""
    run_camera: bool = True
    """Run stage 1 (False: keep the initial camera; for ablations)."""
    run_contact: bool = True
    """Run stage 2 (False: keep the initial hand pose; for ablations)."""
    run_refine: bool = True
    """Run stage 3 (False: stop after contact alignment; for ablations)."""
    render_size: int = 256
    """Long side in pixels of the final-resolution renders; masks are resampled to it."""
    seed: int = 0
    """Seed of every random choice of the optimizer (same input + seed -> same output)."""
    dtype: str = "float32"
    """Floating-point type of the optimisation: "float32" or "float64"."""
    history_every: int = 1
    """Record the losses in the stage history every this many iterations (the last always)."""

    def __post_init__(self):
        _finite(self)
        _positive(self, "render_size", "history_every")
        if not 0 <= self.seed <= MAX_SEED:
            raise InvalidInputError(
                f"OptimConfig.seed must be in [0, {MAX_SEED}], got {self.seed!r}"
            )
        if self.dtype not in _DTYPES:
            raise InvalidInputError(
                f"OptimConfig.dtype must be one of {_DTYPES}, got {self.dtype!r}"
            )

    @property
    def torch_dtype(self):
        """The torch dtype named by ``dtype``."""
        import torch

        return getattr(torch, self.dtype)


@dataclass(frozen=True)
class PerceptionConfig:
    """Backend names per perception role (see easyhoi.perception.base.available)."""

    hand: str = "mediapipe"
    """Hand estimator: keypoints and hand parameters from the photo."""
    segmenter: str = "classical"
    """Hand / held-object segmenter giving M_h and M_o."""
    inpainter: str = "opencv"
    """Inpainter removing the hand from the photo."""
    amodal: str = "classical"
    """Amodal segmenter giving the complete object mask M^_o."""
    object: str = "silhouette"
    """Object reconstructor giving the object mesh."""
    sam_dir: str | None = None
    """Local folder of a SAM model (transformers format) for the "sam" amodal backend and the
    "grounded-sam" segmenter."""
    detector_dir: str | None = None
    """Local folder of an OWLv2 or Grounding DINO detector (transformers) for the
    "grounded-sam" segmenter."""
    depth_dir: str | None = None
    """Local folder of a depth-estimation model (transformers) for the "depth" object backend."""
    diffusion_dir: str | None = None
    """Local folder of a diffusers inpainting pipeline for the "diffusion" inpainter."""
    shape_dir: str | None = None
    """Local folder of a diffusers Shap-E image-to-3D pipeline for the "shap-e" object backend."""
    object_shape: str = "auto"
    """Shape family of the "silhouette" object backend: "auto" fits every family and keeps the
    best; a family name (:data:`OBJECT_SHAPES`) fits that one alone, for a user who knows the
    object's kind (a cup is a "revolution", a mug "handled", a phone a "cuboid" or a "slab")."""

    def __post_init__(self):
        if self.object_shape not in ("auto", *OBJECT_SHAPES):
            raise InvalidInputError(
                f"object_shape must be 'auto' or one of {OBJECT_SHAPES}, got {self.object_shape!r}"
            )


_HAND_MODELS = ("open", "mano")


@dataclass(frozen=True)
class EasyHOIConfig:
    """Everything a reconstruction needs to know besides its inputs."""

    optim: OptimConfig = field(default_factory=OptimConfig)
    """The three-stage optimizer."""
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    """Perception backends by role."""
    hand_model: str = "open"
    """Hand model: "open" (built in) or "mano" (needs the user's MANO_RIGHT.pkl in mano_dir)."""
    mano_dir: str | None = None
    """Folder holding MANO_RIGHT.pkl (and MANO_LEFT.pkl); used when hand_model is "mano"."""
    full_size_pictures: bool = False
    """Result pictures at the photo's full size; by default they are drawn at the size they are
    shown (overlay at most 1024 px, figure panels at their size in the figure), which is several
    times cheaper."""
    name: str = "custom"
    """Name of the preset this configuration came from (provenance only)."""
    device: str = "auto"
    """Where tensors and large models run: "cpu", "cuda" (or "cuda:N"), or "auto" (cuda when
    torch sees a GPU, else cpu); resolved once by :func:`easyhoi.settings.resolve_run`."""

    def __post_init__(self):
        _finite(self)
        if self.hand_model not in _HAND_MODELS:
            raise InvalidInputError(
                f"hand_model must be one of {_HAND_MODELS}, got {self.hand_model!r}"
            )
        check_device_name(self.device)


# ----------------------------------------------------------------------------------------------
# presets
# ----------------------------------------------------------------------------------------------

#: The paper's settings (docs/method.md section 2.3): 1000-iteration caps without early stopping,
#: registration at iterations 100 and 200, the paper's loss weights and learning rates, 256 px
#: renders, a 32 x 32 Sinkhorn grid and a 64^3 SDF.
_PAPER = EasyHOIConfig(
    optim=OptimConfig(
        camera=CameraStageConfig(),
        contact=ContactStageConfig(),
        refine=RefineStageConfig(),
        render_size=256,
    ),
    name="paper",
)

#: The default: the same three stages at a cost a CPU can afford, and the weights that work with
#: the shorter schedule. docs/benchmark.md measures it against "paper" on synthetic scenes.
_FAST = EasyHOIConfig(
    optim=OptimConfig(
        camera=CameraStageConfig(
            # coarse-to-fine at 64 then 128 px, stopping once the silhouette fits: the camera
            # converges in tens of iterations, not a thousand
            max_iters=150,
            stop_loss=0.05,
            patience=20,
            resolution_schedule=(0.5, 1.0),
            # the Sinkhorn term costs grid^4; a 16 x 16 grid still pulls non-overlapping masks
            # together, which is all the term is for
            sinkhorn_grid=16,
            # start from the camera whose projected object box matches the amodal mask's box,
            # trying all 24 axis-aligned rotations: an image-to-3D model or a scan may put the
            # object in any canonical frame, and a bad start rotation is a local minimum
            init_from_masks=True,
            init_rotations="cube",
            # a photo's pixels are square: one focal for both axes (a stretched camera distorts
            # the hand's projection, which no rigid hand follows)
            square_pixels=True,
        ),
        contact=ContactStageConfig(
            max_iters=150,
            patience=20,
            resolution_schedule=(0.5, 1.0),
            # the paper's 100 / 200 scaled to the shorter stage
            register_at=(20, 60),
            icp_iters=20,
            # the hand estimator's rotation is better than what the hand mask alone implies (a
            # silhouette is nearly symmetric under rotation): keep it unless the mask insists
            rotation_prior_weight=100.0,
            # place the hand at the depth where its contact zones lie on the object's surface,
            # not where a single vertex first touches it: a grasp touches with pads and palm
            scan_band=0.02,
            # the placement scanned depths from 1/2 to 2 times its first guess; the scans at the
            # registrations only adjust that depth to the moves of the mask fit (a second wide
            # scan jumped to another touching depth, e.g. the palm instead of the pinch)
            rescan_range=1.15,
            # ... and only where the score says so: the band term is read from the 48^3 SDF
            # grid, whose cells (about 0.026 of the object's size) are wider than the 0.02 band,
            # and the estimator's articulation leaves most contact-zone vertices outside the
            # band, so across the re-scan's range it drifts by a few hundredths; a re-scan that
            # followed that drift walked to the end of its range
            rescan_tie_margin=0.05,
            # a registration moves the hand only along the camera rays: the photo fixes where
            # the hand is in the image, so the in-plane part of the ICP (biased where the two
            # surfaces differ in shape) would only pull the hand off its silhouette
            depth_only_registration=True,
            # the start (already placed at the scanned depth) competes for the best state, so
            # the stage never ends worse by its own score than it began
            initial_competes=True,
            # the best state is judged by the scan's own touching term (contact zones on the
            # surface), not by the closest vertex: with the estimator's articulation, the rigid
            # hand whose deepest vertex just touches is a hand backed off the object, which
            # then holds nothing
            score_band=True,
            # the detector's keypoints hold the rigid hand where the photo shows it, with the
            # same balance against the mask as in the refinement (8 : 1 and 4 : 1): a hand mask
            # that takes in a sleeve or loses a finger to the object otherwise drags the hand
            # across the photo (docs/benchmark.md, "Keypoints in the mask fit")
            keypoint_weight=8.0,
            keypoint_drift_weight=4.0,
        ),
        refine=RefineStageConfig(
            max_iters=100,
            patience=15,
            resolution_schedule=(0.5, 1.0),
            sdf_resolution=48,
            # translation steps of 1e-3 of the object's size (about 0.1 mm for a 10 cm object)
            lr_transl=1e-3,
            # smaller articulation steps than the paper's: fingers pushed out of the object do
            # not drift away from the estimator's pose within the short schedule
            lr_pose=3e-3,
            # Penetration dominates: with the paper's balance (10 x the mean over all vertices
            # against 5 x the contact sum) the pull of the fingers that do not touch the object
            # outweighs the push of the ones inside it, and the hand sinks into the object. Here
            # a penetrating vertex costs about 10 and a contact vertex outside the object
            # attracts with weight 1 x 115 / |C|, only within 5 % of the object's size, so only
            # fingers that nearly touch are pulled in. Not stiffer: a grasp holds by pressing on
            # the object, and a stiffer penetration term leaves the fingers resting on it.
            penetration_weight=2000.0,
            contact_weight=1.0,
            contact_max_distance=0.05,
            # the thumb and index finger close a grasp from opposite sides; their pads are pulled
            # in from 10 % of the object's size, since an estimator's fingertips often end 5-15
            # mm off the surface
            opposition_max_distance=0.1,
            penetration_threshold=-0.002,
            # ... except the finger pads and the palm, which may lie 2 mm inside: skin pressed
            # on an object flattens by a millimetre or two, and a grasp holds by pressing (the
            # ground-truth grasps sit about 2 mm inside their objects); pushed out to the
            # surface, a hand rests on its object and lets it fall (docs/benchmark.md)
            pad_tolerance_m=0.002,
            # the photo's evidence: the detector's 2D keypoints (robust, a tenth of the hand's
            # size as the Geman-McClure scale) and a pose prior, so that contact and penetration
            # cannot bend fingers where the photo or anatomy says no; at 40 they move the
            # fingers where the photo leaves them free (docs/benchmark.md, "Why the fast
            # preset is what it is")
            keypoint_weight=40.0,
            keypoint_sigma=0.1,
            # ... and the hand as a whole may not leave them (penetration pushing the hand
            # across the photo: the robust term is flat once every joint is off)
            keypoint_drift_weight=20.0,
            prior_weight=10.0,
            reg_weight=2.0,
            # penetration is first resolved by moving the hand as a whole
            push_out_steps=5,
            # ... along the camera rays, as a change of the metric scale: the hand keeps its
            # projection exactly, only its depth relative to the object gives
            push_out_scale=True,
            rigid_first=True,
            # ... and a hand the steps leave beside the object is brought back onto it along the
            # camera rays, the one direction the photo does not fix
            close_gap=True,
        ),
        # half the paper's render size: every render costs in proportion to its pixels
        render_size=128,
    ),
    name="fast",
)

#: Named presets: "paper" (the paper's settings) and "fast" (the default).
PRESETS: dict[str, EasyHOIConfig] = {"paper": _PAPER, "fast": _FAST}

DEFAULT_PRESET = "fast"


def get_preset(name: str = DEFAULT_PRESET) -> EasyHOIConfig:
    """The preset called ``name`` (frozen, safe to share); InvalidInputError lists the names."""
    if name not in PRESETS:
        raise InvalidInputError(
            f"unknown configuration preset {name!r}; available: {', '.join(sorted(PRESETS))}"
        )
    return PRESETS[name]


# ----------------------------------------------------------------------------------------------
# introspection, overrides, serialisation
# ----------------------------------------------------------------------------------------------


@cache
def _hints(cls) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _is_optional(tp) -> tuple[bool, Any]:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return True, args[0]
    return False, tp


def _coerce(value: Any, tp, path: str) -> Any:
    """Check ``value`` against the annotation ``tp``; return it normalised (lists -> tuples)."""
    optional, base = _is_optional(tp)
    if value is None:
        if optional:
            return None
        raise InvalidInputError(f"config field {path!r} may not be None")
    bad = InvalidInputError(
        f"config field {path!r} expects {getattr(tp, '__name__', str(tp))}, "
        f"got {type(value).__name__} {value!r}"
    )
    if base is bool:
        if not isinstance(value, bool):
            raise bad
        return value
    if base is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad
        return value
    if base is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise bad
        return float(value)
    if base is str:
        if not isinstance(value, str):
            raise bad
        return value
    if typing.get_origin(base) is tuple:
        if not isinstance(value, list | tuple):
            raise bad
        (elem,) = [a for a in typing.get_args(base) if a is not Ellipsis]
        return tuple(_coerce(v, elem, f"{path}[{i}]") for i, v in enumerate(value))
    if is_dataclass(base):
        if isinstance(value, base):
            return value
        if isinstance(value, dict):
            return _from_dict(base, value, path)
        raise bad
    raise bad  # pragma: no cover - every field type is handled above


def _walk(cfg, parts: list[str], path: str):
    obj = cfg
    for p in parts:
        if not is_dataclass(obj) or p not in {f.name for f in fields(obj)}:
            names = ", ".join(f.name for f in fields(obj)) if is_dataclass(obj) else "none"
            raise InvalidInputError(f"unknown config field {path!r} (at {p!r}; fields: {names})")
        obj = getattr(obj, p)
    return obj


def with_overrides(cfg, overrides: dict[str, Any]):
    """A copy of ``cfg`` with dotted-path fields replaced, type-checked.

    Args:
        cfg: a config dataclass (usually :class:`EasyHOIConfig`)
        overrides (dict): ``{"optim.refine.max_iters": 50, "optim.camera.use_sinkhorn": False,
            ...}``. ints are accepted for float fields, lists for tuple fields; the value checks of
            each dataclass run again on the new values.

    Raises:
        InvalidInputError: Unknown path, wrong type, or a value outside its allowed range.
    """
    for path, value in overrides.items():
        parts = path.split(".")
        parent = _walk(cfg, parts[:-1], path)
        leaf = parts[-1]
        if not is_dataclass(parent) or leaf not in {f.name for f in fields(parent)}:
            names = ", ".join(f.name for f in fields(parent)) if is_dataclass(parent) else "none"
            raise InvalidInputError(f"unknown config field {path!r} (fields here: {names})")
        new = _coerce(value, _hints(type(parent))[leaf], path)
        try:
            cfg = _set(cfg, parts, new)
        except InvalidInputError as exc:  # the value check of the dataclass: name the key
            raise InvalidInputError(f"{path}={value!r} refused: {exc}") from None
    return cfg


def _set(obj, parts: list[str], value):
    if len(parts) == 1:
        return replace(obj, **{parts[0]: value})
    child = getattr(obj, parts[0])
    return replace(obj, **{parts[0]: _set(child, parts[1:], value)})


def parse_overrides(items: list[str], cfg=None) -> dict[str, Any]:
    """Parse CLI-style ``"path=value"`` strings into a dict for :func:`with_overrides`.

    Values are read as JSON (``50``, ``1e-3``, ``true``, ``null``, ``[20, 60]``); a value that
    is not valid JSON is taken as a string (``optim.dtype=float64``).
    """
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise InvalidInputError(f"override {item!r} must look like path=value")
        key, raw = item.split("=", 1)
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        out[key.strip()] = value
    if cfg is not None:
        with_overrides(cfg, out)  # validate now, with the offending item named
    return out


def to_dict(cfg) -> dict[str, Any]:
    """JSON-ready nested dict of a config (tuples become lists)."""
    out = {}
    for f in fields(cfg):
        v = getattr(cfg, f.name)
        if is_dataclass(v):
            v = to_dict(v)
        elif isinstance(v, tuple):
            v = list(v)
        out[f.name] = v
    return out


def _from_dict(cls, data: dict, path: str):
    if not isinstance(data, dict):
        raise InvalidInputError(f"config section {path or cls.__name__!r} must be a mapping")
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise InvalidInputError(
            f"unknown config field(s) {unknown} in {path or cls.__name__}; "
            f"fields: {', '.join(sorted(known))}"
        )
    hints = _hints(cls)
    kw = {k: _coerce(v, hints[k], f"{path}.{k}" if path else k) for k, v in data.items()}
    return cls(**kw)


def from_dict(data: dict, cls=EasyHOIConfig):
    """Rebuild a config from :func:`to_dict` output; missing fields take their defaults."""
    return _from_dict(cls, data, "")


@cache
def field_docs(cls) -> dict[str, str]:
    """Attribute docstrings of a config dataclass: ``{field name: text}`` (for CLI help)."""
    if not dataclasses.is_dataclass(cls):
        raise InvalidInputError(f"{cls!r} is not a config dataclass")
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body  # type: ignore[attr-defined]
    docs: dict[str, str] = {}
    for node, nxt in zip(body, body[1:], strict=False):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(nxt, ast.Expr)
            and isinstance(nxt.value, ast.Constant)
            and isinstance(nxt.value.value, str)
        ):
            docs[node.target.id] = " ".join(nxt.value.value.split())
    return docs
