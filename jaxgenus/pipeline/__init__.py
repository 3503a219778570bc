"""`reconstruct` and its stages: options, setup, start (with hidden handles), optimize/remesh
cycles, the verdict and the typed run record; built-in scenes. Depends on every layer below.
"""

from jaxgenus.pipeline._handles import (
    HandleCandidate,
    HoleTests,
    handle_candidates,
    hole_tests,
    normal_image_loss,
    open_handles,
)
from jaxgenus.pipeline._history import (
    CycleRecord,
    GenusEstimate,
    GenusEvidence,
    HandleRecord,
    History,
    Reconstruction,
)
from jaxgenus.pipeline._options import ENTRIES, ReconstructOptions
from jaxgenus.pipeline._reconstruct import genus_estimate, reconstruct
from jaxgenus.pipeline._scenes import SCENES, builtin_scene, render_targets
from jaxgenus.pipeline._setup import TEXTURE_SETTINGS

__all__ = [
    "CycleRecord",
    "ENTRIES",
    "GenusEstimate",
    "GenusEvidence",
    "HandleCandidate",
    "HandleRecord",
    "HoleTests",
    "History",
    "ReconstructOptions",
    "Reconstruction",
    "SCENES",
    "TEXTURE_SETTINGS",
    "builtin_scene",
    "genus_estimate",
    "handle_candidates",
    "hole_tests",
    "normal_image_loss",
    "open_handles",
    "reconstruct",
    "render_targets",
]
