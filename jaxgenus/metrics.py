"""Evaluation metrics for reconstructions: `jaxgenus.metrics`.

The evaluation protocol that combines them is described in docs/metrics.md.
"""

from jaxgenus.geometry import Betti, HandlePlacement, betti_numbers, handle_placement, voxelize
from jaxgenus.geometry import (
    ChamferResult,
    ICPResult,
    Normalization,
    chamfer_distance,
    hausdorff_distance,
    icp_align,
    normalize_to_unit_sphere,
    reprojection_psnr,
    Reprojection,
    volume_iou,
)

__all__ = [
    "Betti",
    "ChamferResult",
    "HandlePlacement",
    "ICPResult",
    "Normalization",
    "betti_numbers",
    "chamfer_distance",
    "handle_placement",
    "hausdorff_distance",
    "icp_align",
    "normalize_to_unit_sphere",
    "Reprojection",
    "reprojection_psnr",
    "volume_iou",
    "voxelize",
]
