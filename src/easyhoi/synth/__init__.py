"""Synthetic hand-object scenes with exact ground truth, and perturbation models.

* :mod:`~easyhoi.synth.objects`: procedural and scanned watertight objects (metres).
* :mod:`~easyhoi.synth.grasp`: grasp synthesis by optimization with the hand model.
* :mod:`~easyhoi.synth.scene`: camera, GT masks / depth / keypoints, :class:`SynthScene`.
* :mod:`~easyhoi.synth.photo`: shaded RGB photos.
* :mod:`~easyhoi.synth.perturb`: error models of the large models and :class:`HOIInput` building.
"""

from easyhoi.synth.grasp import GRASP_TYPES, Grasp, synthesize_grasp
from easyhoi.synth.objects import OBJECT_KINDS, SynthObject, list_objects, make_object
from easyhoi.synth.perturb import PERTURBATION_LEVELS, Perturbation, get_perturbation
from easyhoi.synth.scene import SynthScene, make_scene

__all__ = [
    "GRASP_TYPES",
    "OBJECT_KINDS",
    "PERTURBATION_LEVELS",
    "Grasp",
    "Perturbation",
    "SynthScene",
    "SynthObject",
    "get_perturbation",
    "list_objects",
    "make_object",
    "make_scene",
    "synthesize_grasp",
]
