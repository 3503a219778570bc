"""`reconstruct` and its stages: options, start mesh, hidden handles, optimize/remesh cycles, the verdict
and the typed run history; built-in scenes. Depends on every layer below.
"""

from jaxgenus.pipeline._handles import HandleCandidate, handle_candidates, normal_image_loss, open_handles
from jaxgenus.pipeline._history import CycleRecord, History
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.pipeline._reconstruct import Reconstruction, reconstruct
from jaxgenus.pipeline._scenes import SCENES, builtin_scene, render_targets

__all__ = [
    "CycleRecord",
    "HandleCandidate",
    "History",
    "ReconstructOptions",
    "Reconstruction",
    "SCENES",
    "builtin_scene",
    "handle_candidates",
    "normal_image_loss",
    "open_handles",
    "reconstruct",
    "render_targets",
]
