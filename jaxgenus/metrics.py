"""Evaluation metrics for reconstructions: `jaxgenus.metrics`.

The evaluation protocol that combines them is described in docs/metrics.md.
"""

from jaxgenus import _betti, _metrics
from jaxgenus._betti import Betti, HandlePlacement, betti_numbers, handle_placement, voxelize
from jaxgenus._metrics import (
    ChamferResult,
    ICPResult,
    Normalization,
    chamfer_distance,
    hausdorff_distance,
    icp_align,
    normalize_to_unit_sphere,
    volume_iou,
)

__all__ = list(_metrics.__all__) + list(_betti.__all__)
