"""The objective and its optimizer: loss terms (image, carving, containment), the image pyramid,
large-steps solves, uniform Adam, and `optimize_block`. Depends on `geometry` and `rendering`.
"""

from jaxgenus.optim._intrinsic import (EDGE_LOG_RATIO, RATIO_BAND, RATIO_OFFSET, RATIO_SCALE, albedo_edges,
                                      shading_ratio_cost)
from jaxgenus.optim._adam import GradientTransformation, UniformAdamState, uniform_adam
from jaxgenus.optim._carving import carving_term
from jaxgenus.optim._compilations import count_compilations
from jaxgenus.optim._consistency import (ROBUST_SPREAD, STEREO_SCALE, consistency_windows, photo_consistency, robust_cost,
                                         stereo_depth_cost, view_neighbours)
from jaxgenus.optim._containment import containment_penalty, outside_distance
from jaxgenus.optim._largesteps import (
    Factor,
    SolveInfo,
    factor_capacity,
    from_differential,
    lambda_from_alpha,
    largesteps_factor,
    largesteps_solve,
    to_differential,
)
from jaxgenus.optim._loss import LossWeights, image_loss, objective, render_channels
from jaxgenus.optim._optimize import (
    Appearance,
    OptimizeOptions,
    OptimizerState,
    block_factor,
    init_optimizer_state,
    optimize_block,
    optimize_steps,
)
from jaxgenus.optim._record import RECORD_KEYS, StepRecord
from jaxgenus.optim._devices import (device_mesh, gathered_views, held_views, place, place_held, spread_views,
                                     summed_over_processes, views_layout)
from jaxgenus.optim._pyramid import pyramid_level, resolution_factors, scaled_cameras, step_views

__all__ = [
    "Appearance",
    "EDGE_LOG_RATIO",
    "RATIO_BAND",
    "RATIO_OFFSET",
    "RATIO_SCALE",
    "albedo_edges",
    "shading_ratio_cost",
    "GradientTransformation",
    "LossWeights",
    "OptimizeOptions",
    "OptimizerState",
    "RECORD_KEYS",
    "Factor",
    "SolveInfo",
    "StepRecord",
    "UniformAdamState",
    "carving_term",
    "consistency_windows",
    "ROBUST_SPREAD",
    "photo_consistency",
    "robust_cost",
    "view_neighbours",
    "stereo_depth_cost",
    "STEREO_SCALE",
    "containment_penalty",
    "count_compilations",
    "factor_capacity",
    "from_differential",
    "image_loss",
    "init_optimizer_state",
    "lambda_from_alpha",
    "largesteps_factor",
    "largesteps_solve",
    "objective",
    "optimize_block",
    "optimize_steps",
    "block_factor",
    "step_views",
    "device_mesh",
    "gathered_views",
    "held_views",
    "place",
    "place_held",
    "spread_views",
    "summed_over_processes",
    "views_layout",
    "outside_distance",
    "pyramid_level",
    "render_channels",
    "resolution_factors",
    "scaled_cameras",
    "to_differential",
    "uniform_adam",
]
