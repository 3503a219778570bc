"""Which camera goes with which image: `pair_images`, by name or by order.

Names are compared without folders and without an image extension
(`_normalize_name`), so the names of `load_images` (file stems) meet the file
names of camera files (`"./train/r_12"`, `"images/frame_001.png"`).
"""

from __future__ import annotations

import os
import re

import numpy as np
from jaxtyping import Int

from jaxgenus.capture._images import IMAGE_EXTENSIONS, few

__all__ = ["pair_images"]

_NAME_EXTENSIONS = IMAGE_EXTENSIONS + (".exr", ".hdr", ".gif", ".npy")


def _normalize_name(name) -> str:
    """Basename without folders and without an image extension (case-sensitive)."""
    base = os.fspath(name).replace("\\", "/").rstrip("/").rsplit("/", 1)[-1]
    root, ext = os.path.splitext(base)
    return root if ext.lower() in _NAME_EXTENSIONS and root else base


def _names(arg, count, what: str) -> tuple[list[str] | None, int]:
    """(names or None, count) of a list of names, a count, a list of None, or None with `count`."""
    if arg is None and count is not None:
        arg = count
    if isinstance(arg, (int, np.integer)) and not isinstance(arg, bool) and arg >= 0:
        return None, int(arg)
    if arg is None or isinstance(arg, (str, bytes, os.PathLike, int, np.integer)):
        raise ValueError(f"{what}: give a list of names, or the number of items when they have none; got {arg!r}")
    items = list(arg)
    missing = [x is None for x in items]
    if count is not None and count != len(items):
        raise ValueError(f"{what}: {len(items)} names for {count} items")
    if all(missing):
        return None, len(items)
    if any(missing):
        raise ValueError(f"{what}: item {missing.index(True)} has no name while others have; name all or none")
    return [str(x) if isinstance(x, np.str_) else os.fspath(x) for x in items], len(items)


def _natural(name: str) -> list:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def pair_images(image_names, camera_names, *, n_images: int | None = None, n_cameras: int | None = None
                ) -> tuple[Int[np.ndarray, " N"], str]:
    """Which camera goes with which image: `(order, description)`.

    `image_names` are the images' names (e.g. `LoadedImages.names`), `camera_names` the cameras' (file
    names as in a `transforms.json`: `"./train/r_12"`, `"images/frame_001.png"`); where a side has no
    names, pass None (or a list of None) and its count as `n_images` / `n_cameras`, or the count in
    place of the names (the counts, when given with names, must agree with them):
    `pair_images(loaded.names, cam_names, n_images=len(loaded.images), n_cameras=len(cams))` works in
    every case. `order[i]` is the camera of image `i`, so
    `cams[order]` lines the cameras up with the images.

    When both sides have names they are compared without folders and without an image extension,
    case-sensitively (`images/frame_001.png` and `./frame_001` both match the image `frame_001.png`).
    Every image must find exactly one camera; cameras without an image are allowed: they are left out
    of `cams[order]` and the description lists them. When one side or neither has names, image `i`
    pairs with camera `i` (`load_images` reads folders in sorted file-name order), the counts must
    match, and the description says so.
    """
    imgs, n_img = _names(image_names, n_images, "image_names")
    cams, n_cam = _names(camera_names, n_cameras, "camera_names")
    if imgs is not None and cams is not None:
        keys = []
        for what, names in (("image_names", imgs), ("camera_names", cams)):
            keys.append([_normalize_name(x) for x in names])
            for i, k in enumerate(keys[-1]):
                if k in keys[-1][:i]:
                    j = keys[-1].index(k)
                    raise ValueError(f"{what}: {names[j]!r} and {names[i]!r} are both {k!r} without folders and extension")
        index = {k: j for j, k in enumerate(keys[1])}
        lost = [n for n, k in zip(imgs, keys[0]) if k not in index]
        spare = [n for n, k in zip(cams, keys[1]) if k not in set(keys[0])]
        if lost:
            raise ValueError(
                f"pair_images: {len(lost)} of {n_img} images have no camera of the same name ({few(lost)}); "
                f"{len(spare)} of {n_cam} cameras have no image" + (f" ({few(spare)})" if spare else "")
                + "; names are compared without folders and extension"
            )
        order = np.array([index[k] for k in keys[0]], np.int64)
        desc = f"{n_img} images paired with cameras by name" + (", in the same order" if np.array_equal(order, np.arange(n_img)) else "")
        return order, desc + (f"; {len(spare)} of {n_cam} cameras have no image and are left out ({few(spare, 3)})" if spare else "")
    if n_img != n_cam:
        side = "neither images nor cameras" if imgs is None and cams is None else "only the images" if cams is None else "only the cameras"
        raise ValueError(f"pair_images: {n_img} images but {n_cam} cameras; {side} have names, so they pair by order and counts must match")
    order = np.arange(n_img, dtype=np.int64)
    if imgs is None:
        side = "neither images nor cameras have" if cams is None else "the images have no"
        return order, f"{side} names: paired by order, image i with camera i ({n_img} pairs)"
    desc = f"the cameras have no names: paired by order, image i with camera i ({n_img} pairs"
    desc += f", images {imgs[0]} ... {imgs[-1]})" if imgs else ")"
    if imgs == sorted(imgs) and imgs != sorted(imgs, key=_natural):
        desc += "; note: the images are in string order (10 before 2), check that the cameras follow it"
    return order, desc
