"""The soft rasterizer: per-face set-up (projection, facing), the JAX splat and its native CPU kernel,
raster plans, `render`, and Lambertian shading of photos. Depends on `geometry` only.
"""

from jaxgenus.rendering._plan import RasterPlan, plan_render, static_plan
from jaxgenus.rendering._render import CHANNEL_SIZES, SHADINGS, RenderInfo, RenderSettings, render
from jaxgenus.rendering._shading import (
    LIGHTING_SHAPE,
    LIGHTING_SHAPES,
    directional_lighting,
    face_colors,
    irradiance,
    lighting_model,
    render_photo,
    shading_colors,
    vertex_colors,
)

__all__ = [
    "CHANNEL_SIZES",
    "LIGHTING_SHAPE",
    "LIGHTING_SHAPES",
    "RasterPlan",
    "RenderInfo",
    "RenderSettings",
    "SHADINGS",
    "directional_lighting",
    "face_colors",
    "irradiance",
    "lighting_model",
    "plan_render",
    "render",
    "render_photo",
    "shading_colors",
    "static_plan",
    "vertex_colors",
]
