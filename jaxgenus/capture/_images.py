"""Reading target images as users have them: image files, arrays and masks.

`load_images` turns arrays, folders of PNG masks, RGBA renders and JPEG photos
with mask folders into the `(N, H, W, C)` float32 stacks in [0, 1] (row 0 at the
top) that `reconstruct` takes, and says what kind of targets they are
(`jaxgenus.capture._targets.infer_targets`); `jaxgenus.capture._pairing.pair_images` says
which camera goes with which image.
"""

from __future__ import annotations

import concurrent.futures
import glob
import os
from typing import NamedTuple, Sequence

import numpy as np
from jaxtyping import Float

from jaxgenus.capture._mask_pixels import grey_mask, is_grey, luminance, mask_like
from jaxgenus.capture._targets import TARGET_KINDS as TARGETS, inferred_targets, unit_float as _float

__all__ = ["BACKGROUND_THRESHOLD", "IMAGE_EXTENSIONS", "LoadedImages", "few", "load_images"]

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")
BACKGROUND_THRESHOLD = 0.1  # max channel distance to the background colour above which a pixel is foreground
_GREY_FRACTION = 0.3  # a "mask" with more grey (0.1 < m < 0.9) pixels than this is a photo
_MASK_SUFFIXES = ("_mask", "-mask", ".mask")
_HOW_TO_MASK = "masks (masks=DIR, CLI --masks DIR) or background='black'|'white' (CLI --masks white|black)"


class LoadedImages(NamedTuple):
    """What `load_images` read.

    Attributes:
        images: `(N, H, W, 4)` float32 RGBA in [0, 1] (A = mask), or `(N, H, W, 1)`
            silhouettes when `targets == "silhouette"`; uint8 (value / 255) when read with
            `dtype=np.uint8`.
        names: the images' file stems in reading order, or None for an array.
        targets: `"silhouette"`, `"normals"` (RGB = (n + 1) / 2 world normals) or `"photo"`.
        source: one line saying what was read and how the targets were chosen.
        views: the indices (in reading order) of the images read when `load_images` was
            asked for some (`views=`; `names` still lists all), else None.
        count: how many images the source holds (all of them, also when only some were read).
    """

    images: Float[np.ndarray, "N H W C"]
    names: list[str] | None
    targets: str
    source: str
    views: np.ndarray | None = None
    count: int | None = None


class _Picture(NamedTuple):
    path: str
    pixels: np.ndarray  # (H, W, C) as read (`_checked`: uint8, uint16, bool or float32), C in {1, 2 (LA), 3, 4}
    format: str  # "PNG", "JPEG", ...
    label: bool  # a palette of colours (a label map such as DAVIS's)
    rotated: bool  # an EXIF orientation was applied


def few(items, k=5) -> str:
    """The first `k` of `items` joined by commas, and how many more there are."""
    items = list(items)
    return ", ".join(items[:k]) + (f", ... ({len(items) - k} more)" if len(items) > k else "")


def _stem(path: str) -> str:
    return os.path.splitext(os.path.basename(path))[0]


def _checked(arr: np.ndarray, what: str) -> np.ndarray:
    """`arr` as read (uint8, uint16, bool, or float checked in [0, 1] and kept as float32); not copied
    where it is one of those already: the float32 copy is made per picture where it is used (`_float`)."""
    if arr.dtype in (np.uint8, np.uint16, np.bool_):
        return arr
    if np.issubdtype(arr.dtype, np.floating):
        out = np.asarray(arr, np.float32)
        if out.size and not (np.isfinite(out).all() and out.min() >= 0.0 and out.max() <= 1.0):
            raise ValueError(f"{what}: float values must lie in [0, 1], got [{np.nanmin(out):.4g}, {np.nanmax(out):.4g}]")
        return out
    raise ValueError(f"{what}: dtype {arr.dtype} is not supported (use uint8, uint16, bool or float in [0, 1])")


def _put(out: np.ndarray, values) -> None:
    """Values in [0, 1] written into `out`: as they are (float32), or as 8-bit pixels (uint8, rounded)."""
    if out.dtype == np.uint8:
        np.rint(np.asarray(values, np.float32) * np.float32(255.0), out=out, casting="unsafe")
    else:
        out[...] = values


def _scale(arr: np.ndarray, what: str) -> np.ndarray:
    """`arr` checked and scaled to [0, 1] (`_checked`, `_float`); always a new float32 array."""
    out = _float(_checked(arr, what))
    return out.copy() if np.may_share_memory(out, arr) else out


def _read(path: str, what: str) -> _Picture:
    from PIL import Image, ImageOps, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            fmt, label = im.format or "image", False
            rotated = fmt == "JPEG" and im.getexif().get(0x0112, 1) != 1
            im = ImageOps.exif_transpose(im) if fmt == "JPEG" else im
            im.load()
            if im.mode == "1":
                px = np.asarray(im, dtype=bool)
            elif im.mode in ("L", "LA", "RGB", "RGBA") or im.mode.startswith("I;16"):
                px = np.asarray(im)
                opaque = im.mode == "RGB" or (im.mode == "RGBA" and px.size > 0 and px[..., 3].min() == 255)
                if opaque and mask_like(px, fmt):  # a 0/255 mask saved as RGB(A)
                    px = grey_mask(px)
            elif im.mode == "I":  # 16-bit PNGs in older Pillow; other 32-bit data must fit 16 bits
                px = np.asarray(im)
                if px.size and (px.min() < 0 or px.max() > 65535):
                    raise ValueError(f"{what}: {path}: 32-bit integer pixels outside [0, 65535]")
                px = px.astype(np.uint16)
            elif im.mode == "F":
                px = np.asarray(im, dtype=np.float32)
            elif im.mode == "P" and "transparency" not in im.info:
                px = np.asarray(im.convert("RGB"))
                px, label = (px[..., :1], False) if is_grey(px) else (px, True)
            else:  # P with transparency, PA, CMYK, YCbCr, LAB, RGBX, RGBa, La, ...
                px = np.asarray(im.convert("RGBA" if im.mode.endswith(("A", "a")) or im.mode == "P" else "RGB"))
    except (OSError, UnidentifiedImageError, SyntaxError) as err:
        raise ValueError(f"{what}: cannot read {path} as an image ({err})") from None
    return _Picture(path, _checked(px if px.ndim == 3 else px[..., None], f"{what}: {path}"), fmt, label, rotated)


def _read_all(paths: list[str], what: str) -> list[_Picture]:
    """`_read` of every path in order, a thread per core (Pillow decodes without the GIL)."""
    with concurrent.futures.ThreadPoolExecutor(max(1, min(len(paths), os.cpu_count() or 1))) as pool:
        return list(pool.map(lambda p: _read(p, what), paths))


def _list_files(arg, what: str) -> list[str]:
    """The image files of a folder (sorted), a glob (sorted), one file or a list (as given)."""
    if isinstance(arg, (str, os.PathLike)):
        s = os.fspath(arg)
        if os.path.isdir(s) or any(c in s for c in "*?["):  # glob skips names starting with "."
            pattern = os.path.join(glob.escape(s), "*") if os.path.isdir(s) else s
            files = sorted(f for f in glob.glob(pattern) if f.lower().endswith(IMAGE_EXTENSIONS) and os.path.isfile(f))
            if not files:
                raise ValueError(f"{what}: {s} holds no image files ({' '.join(IMAGE_EXTENSIONS)})")
            return files
        if os.path.isfile(s):
            return [s]
        raise ValueError(f"{what}: no such file or folder: {s}")
    if isinstance(arg, Sequence) and not isinstance(arg, (str, bytes)):
        files = [os.fspath(f) for f in arg]
        for f in files:
            if not os.path.isfile(f):
                raise ValueError(f"{what}: no such file: {f}")
        if not files:
            raise ValueError(f"{what}: the list of files is empty")
        return files
    raise ValueError(f"{what}: expected a .npy file, an array, a folder, a glob pattern or a list of files, got {type(arg).__name__}")


def _check_size(pics: list[_Picture], size: tuple[int, int], than: str, what: str) -> None:
    for p in pics:
        if p.pixels.shape[:2] != size:
            (hh, ww), (h, w) = p.pixels.shape[:2], size
            raise ValueError(f"{what}: {p.path} is {ww}x{hh} but {than} is {w}x{h}; all images must share one size")


def _describe(pics: list[_Picture], noun: str) -> str:
    rot = sum(p.rotated for p in pics)
    return f"{len(pics)} {'/'.join(sorted({p.format for p in pics}))} {noun}" + (f" (EXIF orientation applied to {rot})" if rot else "")


def _is_array(x) -> bool:
    return isinstance(x, np.ndarray) or (isinstance(x, (str, os.PathLike)) and os.fspath(x).lower().endswith(".npy"))


def _chosen(views, n: int) -> np.ndarray | None:
    """`load_images`' `views` (a sequence, or a function of the image count) as checked indices."""
    if views is None:
        return None
    idx = np.asarray(views(n) if callable(views) else views)
    if idx.ndim != 1 or not len(idx) or not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"views: expected a non-empty list of image indices, got {idx.tolist()!r:.80}")
    if idx.min() < 0 or idx.max() >= n or np.any(np.diff(idx) <= 0):
        raise ValueError(f"views: expected increasing indices into the {n} images, got {idx.tolist()[:10]}")
    return idx.astype(np.int64)


def _array(arr, what: str, views=None) -> tuple[np.ndarray, str, np.ndarray | None, int]:
    """A `.npy` / array as a new float32 `(N, H, W, C)` array (only the chosen `views`), its
    description, the chosen indices and the count of all."""
    label = "an array" if isinstance(arr, np.ndarray) else os.fspath(arr)
    if not isinstance(arr, np.ndarray):
        if not os.path.isfile(label):
            raise ValueError(f"{what}: no such file: {label}")
        try:
            arr = np.load(label, allow_pickle=False, mmap_mode="r")
        except (OSError, ValueError) as err:
            raise ValueError(f"{what}: cannot read {label} as a .npy array ({err})") from None
    desc = f"{arr.dtype} array {tuple(arr.shape)} from {os.path.basename(label)}"
    arr = arr[..., None] if arr.ndim == 3 else arr
    if arr.ndim != 4 or arr.shape[-1] not in (1, 3, 4) or 0 in arr.shape:
        raise ValueError(f"{what}: expected an array of shape (N, H, W), (N, H, W, 1), (N, H, W, 3) or (N, H, W, 4), got {arr.shape}")
    chosen = _chosen(views, len(arr))
    return _scale(np.asarray(arr if chosen is None else arr[chosen]), f"{what}: {label}"), desc, chosen, len(arr)


def _mask(pic: _Picture, what: str, check_grey: bool = True) -> np.ndarray:
    """`(H, W)` mask of a mask file: luminance (times alpha), see `load_images`."""
    px, c = _float(pic.pixels), pic.pixels.shape[-1]
    if pic.label:
        m = (px.max(-1) > 0).astype(np.float32)
    elif c in (1, 3):
        m = px[..., 0] if c == 1 else luminance(px)
    else:
        lum, alpha = (px[..., 0] if c == 2 else luminance(px[..., :3])), px[..., -1]
        inside = alpha > 0
        if alpha.min() >= 1.0:
            m = lum
        elif inside.any() and lum[inside].min() == lum[inside].max():  # one colour on a transparent background
            m = alpha
        else:
            m = lum * alpha
    grey = float(np.mean((m > 0.1) & (m < 0.9)))
    if check_grey and grey > _GREY_FRACTION:
        raise ValueError(f"{what}: {pic.path} has {grey:.0%} grey pixels: a grayscale photo, not a mask; give {_HOW_TO_MASK}")
    if pic.format == "JPEG":  # a lossy mask: its ringing edges are not coverage
        m = m >= 0.5
    return np.ascontiguousarray(m, np.float32)


def _mask_keys(path: str) -> list[str]:
    """Photo stems a mask file may belong to, best first: a.png, a_mask.png, a.jpg.png -> 'a'."""
    base = _stem(path)
    keys = [base] + [base[: -len(s)] for s in _MASK_SUFFIXES if base.endswith(s) and len(base) > len(s)]
    root, ext = os.path.splitext(base)
    return keys + ([root] if ext.lower() in IMAGE_EXTENSIONS and root else [])


def _numbers(stems) -> dict[int, int]:
    """`{number: index}` of the stems that are all digits, when no two of them are the same number."""
    nums = [(int(s), i) for i, s in enumerate(stems) if s.isdigit()]
    return dict(nums) if len({n for n, _ in nums}) == len(nums) else {}


def _pair_masks(photos: list[str], masks: list[str]) -> tuple[list[int], list[str], bool]:
    """For each photo the index of its mask (by file stem, or by number when the stems are numbers
    of other widths: `000012.png` takes `012.png`), the names of the masks left over, and whether
    any pair was made by number."""
    stems = {_stem(p): i for i, p in enumerate(photos)}
    numbers = _numbers(list(stems))
    found: dict[int, list[int]] = {}
    by_number = False
    for j, m in enumerate(masks):
        keys = _mask_keys(m)
        key = next((k for k in keys if k in stems), None)
        if key is not None:
            found.setdefault(stems[key], []).append(j)
            continue
        num = next((int(k) for k in keys if k.isdigit() and int(k) in numbers), None)
        if num is not None:
            found.setdefault(numbers[num], []).append(j)
            by_number = True
    missing = [os.path.basename(photos[i]) for i in range(len(photos)) if i not in found]
    used = {j for js in found.values() for j in js}
    extra = [os.path.basename(m) for j, m in enumerate(masks) if j not in used]
    if missing:
        raise ValueError(
            f"masks: {len(missing)} of {len(photos)} photos have no mask ({few(missing)}); masks pair by file stem "
            f"(photo a.jpg takes a.png, a_mask.png or a.jpg.png; 000012.jpg takes 012.png); {len(extra)} of "
            f"{len(masks)} masks have no photo"
            + (f" ({few(extra)})" if extra else "")
        )
    for i, js in sorted(found.items()):
        if len(js) > 1:
            both = ", ".join(os.path.basename(masks[j]) for j in js)
            raise ValueError(f"masks: photo {os.path.basename(photos[i])} has several masks ({both})")
    return [found[i][0] for i in range(len(photos))], extra, by_number


def _load_masks(masks, photos: list[str] | None, n: int, size: tuple[int, int],
                views: np.ndarray | None = None, into: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """`(N, H, W)` masks for N photos: paired by stem when the photos are files, else by order;
    only those of the photos `views` (indices) when given; written into `into` when given."""
    if _is_array(masks):
        arr, _, _, _ = _array(masks, "masks", views)
        if views is not None:
            n = len(views)
        if arr.shape[-1] != 1 or arr.shape[:3] != (n,) + size:
            raise ValueError(f"masks: expected an array of shape ({n}, {size[0]}, {size[1]}[, 1]) for the images, got {arr.shape}")
        if into is not None:
            _put(into, arr[..., 0])
        return arr[..., 0] if into is None else into, f"{n} masks from an array, paired by order"
    files = _list_files(masks, "masks")
    if photos is None and len(files) != n:
        raise ValueError(f"masks: {len(files)} mask files for an array of {n} images (they pair by sorted order)")
    index, extra, by_number = (list(range(n)), [], False) if photos is None else _pair_masks(photos, files)
    pics = _read_all([files[index[i]] for i in (range(len(index)) if views is None else views)], "masks")
    _check_size(pics, size, "its image", "masks")
    how = "paired by order" if photos is None else "paired by number" if by_number else "paired by name"
    note = f"; {len(extra)} masks without photos ignored ({few(extra, 3)})" if extra else ""
    out = np.empty((len(pics),) + tuple(size), np.float32) if into is None else into
    for i, p in enumerate(pics):
        _put(out[i], _mask(p, "masks"))
    return out, _describe(pics, f"mask files {how}{note}")


def load_images(path, *, masks=None, background: str | None = None, targets: str | None = None,
                background_threshold: float = BACKGROUND_THRESHOLD, views=None, dtype=np.float32) -> LoadedImages:
    """Read target images the way users have them.

    Args:
        path: a `.npy` file or an array: `(N, H, W)` / `(N, H, W, 1)` silhouettes, `(N, H, W, 4)` RGBA,
            `(N, H, W, 3)` (needs `masks` or `background`); uint8 / 255, uint16 / 65535, bool -> {0, 1},
            floats kept (must lie in [0, 1]). Or image files (PNG, JPEG, TIFF, BMP, WebP): a folder
            (sorted file-name order, plain string order as `sorted()` gives; names starting with "."
            skipped), a glob pattern (sorted), one file or a list (order kept); all of one size. JPEGs
            are turned upright with `PIL.ImageOps.exif_transpose` (cameras store portrait shots
            sideways with an EXIF orientation tag); other formats are used as stored. 16-bit RGB PNGs
            are read at Pillow's 8-bit precision, 16-bit grey ones exactly.
            * RGBA images: alpha is the mask (a stack opaque everywhere has none).
            * Single-channel images (modes `1`, `L`, `I;16`, `I`, `F`, a palette of greys, `LA`) are
              silhouette masks: the luminance in [0, 1] (16-bit / 65535: 32768 -> 0.50000763); for
              `LA` luminance times alpha, or alpha when the luminance is constant where alpha > 0 (one
              colour on a transparent background). A mask with over 30 % grey pixels (0.1 < m < 0.9)
              is refused as a grayscale photo.
            * Photos (RGB; grayscale ones too when `masks` or `background` is given) need `masks` or
              `background`; without either they are refused.
        masks: a folder, glob or list of mask files, paired to photo files by file stem (photo `a.jpg`
            takes `a.png`, `a_mask.png`, `a-mask.png`, `a.mask.png` or `a.jpg.png`; every photo needs
            exactly one; masks without a photo are ignored and listed in `source`), or to an array of
            images by sorted order; or a `.npy` / array `(N, H, W[, 1])`. Mask files may be
            single-channel as above, RGB (luminance), RGBA (as `LA`) or a palette of colours (a label
            map: every non-black pixel is foreground). They replace any alpha the photos have.
        background: `"black"` or `"white"`: a hard mask where the largest channel distance to that colour
            exceeds `background_threshold` (default `BACKGROUND_THRESHOLD` = 0.1, about 26 / 255: above JPEG and sensor noise, so the
            object must differ from the background by more than that in some channel); no cleanup.
        targets: `"silhouette"`, `"normals"` or `"photo"`, checked against what was read (normals and
            photos need RGB); None infers it (`infer_targets`). `"silhouette"` keeps only the mask: images
            are then `(N, H, W, 1)`.
        views: read only these images (increasing indices in reading order, or a function of the
            image count giving them, e.g. `lambda n: jaxgenus.optim.held_views(n)` for the views
            this process renders when processes share a capture) and their masks; None: all.
        dtype: `np.float32` (default), or `np.uint8`: the images as 8-bit pixels (value / 255, as
            `reconstruct` reads them), a quarter of the memory; exact for 8-bit files and binary masks,
            rounded to 1/255 otherwise (16-bit files, soft masks of products, float arrays).

    Returns:
        `LoadedImages(images, names, targets, source)`; nothing passed in is modified or aliased.
        Raises `ValueError` with a one-line message naming the argument or the file.
    """
    if not (isinstance(background_threshold, (int, float)) and 0.0 < background_threshold < 1.0):
        raise ValueError(f"background_threshold must be in (0, 1), got {background_threshold!r}")
    if targets is not None and targets not in TARGETS:
        raise ValueError(f"targets must be one of {', '.join(repr(t) for t in TARGETS)} or None, got {targets!r}")
    if background is not None and background not in ("black", "white"):
        raise ValueError(f"background must be 'black' or 'white', got {background!r}")
    if masks is not None and background is not None:
        raise ValueError("masks and background: give one way of finding the masks, not both")
    derive = masks is not None or background is not None
    if dtype not in (np.float32, np.uint8, "float32", "uint8") and not (isinstance(dtype, np.dtype) and dtype.name in ("float32", "uint8")):
        raise ValueError(f"dtype must be np.float32 or np.uint8, got {dtype!r}")

    if _is_array(path):
        arr, source, chosen, n_all = _array(path, "images", views)
        names = files = None
        first = "the array" if isinstance(path, np.ndarray) else os.fspath(path)
        pics = [_Picture(first, a, "array", False, False) for a in arr]
        if arr.shape[-1] == 1 and derive:
            raise ValueError(f"{'masks' if masks is not None else 'background'}: the images ({first}) are silhouettes already")
    else:
        files = _list_files(path, "images")
        names = [_stem(f) for f in files]
        for i, s in enumerate(names):
            if s in names[:i]:
                raise ValueError(f"images: {files[names.index(s)]} and {files[i]} have the same name {s!r}; names must be unique")
        chosen, n_all = _chosen(views, len(files)), len(files)
        pics = _read_all(files if chosen is None else [files[i] for i in chosen], "images")
        first, source = pics[0].path, ""
        _check_size(pics[1:], pics[0].pixels.shape[:2], first, "images")

    grey = [p.pixels.shape[-1] in (1, 2) for p in pics]
    if any(grey) and not derive:
        odd = next((p for p, g in zip(pics, grey) if not g), None)
        if odd is not None:
            raise ValueError(f"images: {odd.path} is a colour image but {first} is a grayscale mask; all images must be of one kind")
        images = np.empty((len(pics),) + pics[0].pixels.shape[:2] + (1,), dtype)
        for view, p in zip(images, pics):
            _put(view[..., 0], _mask(p, "images", check_grey=files is not None))
        source = _describe(pics, "grayscale mask files, silhouettes") if files else source + ", silhouettes"
    else:
        images = np.empty((len(pics),) + pics[0].pixels.shape[:2] + (4,), dtype)  # filled view by view
        for i, (p, g) in enumerate(zip(pics, grey)):
            _put(images[i, ..., :3], _float(p.pixels[..., :1] if g else p.pixels[..., :3]))
        has_alpha = any(p.pixels.shape[-1] in (2, 4) and _float(p.pixels[..., -1]).min() < 1.0 for p in pics)
        if files:
            noun = ("grayscale photos" if all(grey) else "photos") if derive else "RGBA files" if has_alpha else "RGB files"
            source = _describe(pics, noun)
        if masks is not None:
            _, how = _load_masks(masks, files, n_all, images.shape[1:3], chosen, into=images[..., 3])
            source += f" + {how}" + (", replacing their alpha" if has_alpha else "")
        elif background is not None:
            if has_alpha:
                raise ValueError(f"background: the images ({first}) have alpha masks already; background is for photos without one")
            for view in images:
                _put(view[..., 3], np.abs(_float(view[..., :3]) - (0.0 if background == "black" else 1.0)).max(-1)
                     > background_threshold)
            source += f", masks where max |RGB - {background}| > {background_threshold}"
        elif has_alpha:
            odd = next((p for p in pics if p.pixels.shape[-1] not in (2, 4)), None)
            if odd is not None:
                raise ValueError(f"images: {odd.path} has no alpha channel but {first} has one; all images must be of one kind")
            for view, p in zip(images, pics):
                _put(view[..., 3], _float(p.pixels[..., -1]))
            source += ", alpha = mask"
        else:
            raise ValueError(f"images: {first} has no mask (RGB without alpha, or alpha opaque everywhere); give {_HOW_TO_MASK}")

    if targets is None:
        targets, why = inferred_targets(images)
        note = f"targets {targets}: {why}"
    elif images.shape[-1] == 1 and targets != "silhouette":
        raise ValueError(f"targets={targets!r} needs RGB images, but {first} holds silhouette masks")
    else:
        note = f"targets {targets} (given)"
        if targets == "silhouette" and images.shape[-1] == 4:
            images, note = np.ascontiguousarray(images[..., 3:]), note + ", RGB dropped"
    if chosen is not None:
        note += f"; {len(chosen)} of {n_all} views read here"
    return LoadedImages(images, names, targets, f"{source}; {note}", chosen, n_all)

