"""Inputs as users have them: images and masks, camera files (OpenCV, COLMAP, NeRF, IDR/NeuS,
Middlebury), pairing of images with cameras, validated targets, the visual hull and the canonical
frame. Depends on `geometry` only.
"""

from jaxgenus.capture._camera_files import load_cameras, load_region
from jaxgenus.capture._frame import SceneFrame, pixel_footprint, scene_frame
from jaxgenus.capture._hull import HullOccupancy, check_region, cut_views, hull_occupancy, hull_thickness, largest_component, region_misses, visual_hull, visual_hull_bounds
from jaxgenus.capture._images import LoadedImages, load_images
from jaxgenus.capture._pairing import pair_images
from jaxgenus.capture._stereo import StereoDepths, carved_occupancy, consistent_depths, stereo_depths
from jaxgenus.capture._targets import TARGET_KINDS, Targets, check_targets, unit_float

__all__ = [
    "LoadedImages",
    "StereoDepths",
    "carved_occupancy",
    "consistent_depths",
    "stereo_depths",
    "TARGET_KINDS",
    "SceneFrame",
    "Targets",
    "check_targets",
    "check_region",
    "cut_views",
    "HullOccupancy",
    "hull_occupancy",
    "hull_thickness",
    "largest_component",
    "load_cameras",
    "load_region",
    "load_images",
    "pair_images",
    "pixel_footprint",
    "region_misses",
    "scene_frame",
    "visual_hull",
    "visual_hull_bounds",
    "unit_float",
]
