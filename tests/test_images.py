"""Reading images as users have them (jaxgenus.capture._images): formats, masks, targets; pairing (jaxgenus.capture._pairing)."""

import os
import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from jaxgenus.capture._images import BACKGROUND_THRESHOLD, load_images
from jaxgenus.capture._targets import infer_targets
from jaxgenus.capture._pairing import pair_images

RNG = np.random.default_rng(0)


def u8(x):
    return np.round(np.clip(x, 0.0, 1.0) * 255).astype(np.uint8)


def write_png16(path, arr, color_type):
    """A 16-bit PNG (color type 0 grey, 2 RGB, 6 RGBA) written by hand: Pillow cannot write 16-bit RGB."""
    h, w = arr.shape[:2]
    raw = b"".join(b"\0" + arr[i].astype(">u2").tobytes() for i in range(h))

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    header = struct.pack(">IIBBBBB", w, h, 16, color_type, 0, 0, 0)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def disc(h=24, w=32, cy=12.0, cx=15.0, r=8.0):
    yy, xx = np.mgrid[:h, :w]
    return ((yy - cy) ** 2 + (xx - cx) ** 2 <= r * r)


def sphere_normals(h, w, rotation, r=None, supersample=3):
    """RGBA of a sphere's normal field (n rotated to world by `rotation`), anti-aliased like render_targets."""
    s = supersample
    r = r or 0.4 * min(h, w)
    yy, xx = np.mgrid[: h * s, : w * s]
    x = ((xx + 0.5) / s - w / 2) / r
    y = ((yy + 0.5) / s - h / 2) / r
    cover = x * x + y * y <= 1.0
    z = -np.sqrt(np.clip(1.0 - x * x - y * y, 0.0, None))  # facing an OpenCV camera looking along +z
    n = np.stack([x, y, z], -1) @ rotation.T * cover[..., None]
    a = cover.reshape(h, s, w, s).mean((1, 3))
    nm = n.reshape(h, s, w, s, 3).mean((1, 3))
    rgb = np.where(a[..., None] > 0, (nm / np.maximum(a, 1e-9)[..., None] + 1) / 2, 0.0)
    return np.concatenate([rgb, a[..., None]], -1).astype(np.float32)


def random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


def shaded_photo(h, w, albedo, light, ambient=0.05):
    """RGBA of a Lambert-shaded sphere with per-pixel albedo (h, w, 3), mask in A."""
    rot = np.eye(3)
    nm = sphere_normals(h, w, rot, supersample=1)
    n = nm[..., :3] * 2 - 1
    shade = np.clip(n @ (light / np.linalg.norm(light)), 0.0, None)[..., None]
    rgb = np.clip(albedo * (ambient + (1 - ambient) * shade), 0, 1) * (nm[..., 3:] > 0)
    return np.concatenate([rgb, nm[..., 3:]], -1).astype(np.float32)


# ---------------------------------------------------------------- RGBA and masks


def test_rgba_png_folder_reads_alpha_as_mask_in_sorted_order(tmp_path):
    frames = {name: RNG.integers(0, 256, (6, 5, 4), dtype=np.uint8) for name in ("b", "c", "a")}
    for name, f in frames.items():
        f[0, 0, 3] = 0  # some transparency
        Image.fromarray(f, "RGBA").save(tmp_path / f"{name}.png")
    out = load_images(tmp_path)
    assert out.names == ["a", "b", "c"]
    assert out.images.dtype == np.float32 and out.images.shape == (3, 6, 5, 4)
    expect = np.stack([frames[k] for k in "abc"]).astype(np.float64) / 255
    np.testing.assert_array_equal(out.images, expect.astype(np.float32))
    assert "RGBA" in out.source and "alpha = mask" in out.source
    assert out.targets == "photo"  # random colours are no normal map


def mask_folder(tmp_path, name, images):
    d = tmp_path / name
    d.mkdir()
    for i, im in enumerate(images):
        im.save(d / f"m{i}.png")
    return d


def test_mask_modes_read_exactly(tmp_path):
    m = disc()
    grey8 = np.where(m, 255, 0).astype(np.uint8)
    grey8[0, :4] = [0, 1, 128, 254]
    cases = {
        "L": (Image.fromarray(grey8), grey8 / 255),
        "1": (Image.fromarray(m), m.astype(np.float64)),
        "I16": (Image.fromarray(np.where(m, 32768, 0).astype(np.uint16)), np.where(m, 32768 / 65535, 0.0)),
        "P": (Image.fromarray(grey8).convert("P"), grey8 / 255),
    }
    for key, (im, expect) in cases.items():
        out = load_images(mask_folder(tmp_path, key, [im, im]))
        assert out.targets == "silhouette" and out.images.shape == (2, 24, 32, 1), key
        assert out.names is not None and out.images.dtype == np.float32
        np.testing.assert_array_equal(out.images[0, ..., 0], expect.astype(np.float32), err_msg=key)
    assert Image.open(tmp_path / "I16" / "m0.png").mode.startswith("I")  # really a 16-bit file
    val = load_images(tmp_path / "I16").images[0, 12, 15, 0]
    assert val == np.float32(32768 / 65535) and abs(val - 0.50000763) < 1e-8


def test_32bit_int_and_float_tiff_masks(tmp_path):
    m = disc()
    Image.fromarray(np.where(m, 65535, 0).astype(np.int32)).save(tmp_path / "a.tif")
    assert Image.open(tmp_path / "a.tif").mode == "I"
    np.testing.assert_array_equal(load_images(tmp_path / "a.tif").images[0, ..., 0], m.astype(np.float32))
    Image.fromarray(np.where(m, 0.75, 0.0).astype(np.float32)).save(tmp_path / "b.tif")
    assert Image.open(tmp_path / "b.tif").mode == "F"
    np.testing.assert_array_equal(load_images(tmp_path / "b.tif").images[0, ..., 0], np.where(m, 0.75, 0).astype(np.float32))
    Image.fromarray(np.where(m, 70000, 0).astype(np.int32)).save(tmp_path / "c.tif")
    with pytest.raises(ValueError, match=r"c\.tif.*outside \[0, 65535\]"):
        load_images(tmp_path / "c.tif")


def test_la_masks(tmp_path):
    m = disc()
    alpha = np.where(m, 255, 0).astype(np.uint8)
    lum = np.full_like(alpha, 0)  # a black shape on a transparent background: alpha is the mask
    la_const = Image.merge("LA", [Image.fromarray(lum), Image.fromarray(alpha)])
    lum2 = np.full_like(alpha, 255)
    lum2[12, :] = 0  # a black stripe through the opaque shape: luminance times alpha
    la_prod = Image.merge("LA", [Image.fromarray(lum2), Image.fromarray(alpha)])
    opaque = Image.merge("LA", [Image.fromarray(lum2), Image.fromarray(np.full_like(alpha, 255))])
    out = load_images(mask_folder(tmp_path, "la", [la_const, la_prod, opaque])).images[..., 0]
    np.testing.assert_array_equal(out[0], m.astype(np.float32))
    np.testing.assert_array_equal(out[1], (lum2 / 255 * m).astype(np.float32))
    np.testing.assert_array_equal(out[2], (lum2 / 255).astype(np.float32))


def test_grayscale_masks_never_become_alpha_one(tmp_path):
    """The old bug: .convert("RGBA") of an L mask gave alpha = 1 everywhere."""
    m = disc()
    d = mask_folder(tmp_path, "masks", [Image.fromarray(np.where(m, 255, 0).astype(np.uint8))] * 3)
    out = load_images(d)
    assert out.images.shape[-1] == 1
    assert out.images.min() == 0.0 and out.images.mean() < 0.5
    np.testing.assert_array_equal(out.images[1, ..., 0], m.astype(np.float32))


def test_masks_saved_in_colour_with_stray_pixels_read_as_masks(tmp_path):
    """Masks saved as RGB at a photo's size with stray coloured pixels (DTU's have a few) beside grayscale
    masks read as silhouettes wherever the strays lie. DTU scan37's mask 020 (a public copy) has 0.4 %
    of them, but over 1 % of a sample of a sample of its pixels (every 49th row and column): the folder
    was refused as mixing colour and grayscale. Here 0.4 % scattered and a row of them on that grid."""
    rng = np.random.default_rng(5)
    m = np.zeros((1200, 1600), np.uint8)
    m[300:900, 400:1200] = 255
    rgb = np.repeat(m[..., None], 3, axis=-1)
    stray = rng.random(m.shape) < 0.004
    stray[0, ::49] = True
    rgb[stray] = (200, 180, 40)
    d = mask_folder(tmp_path, "masks", [Image.fromarray(m), Image.fromarray(rgb)])
    out = load_images(d, dtype=np.uint8)
    assert out.images.shape == (2, 1200, 1600, 1)
    assert np.mean(out.images[1, ..., 0] == out.images[0, ..., 0]) > 0.99


def test_palette_label_masks_and_grey_photo_refused(tmp_path):
    m = disc()
    label = Image.fromarray(m.astype(np.uint8), "L").convert("P")
    label.putpalette([0, 0, 0, 128, 0, 0] + [0] * 762)  # DAVIS-style: index 1 is dark red
    photo = RNG.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    Image.fromarray(photo).save(tmp_path / "a.png")
    (tmp_path / "m").mkdir()
    label.save(tmp_path / "m" / "a.png")
    out = load_images(tmp_path / "a.png", masks=tmp_path / "m")
    np.testing.assert_array_equal(out.images[0, ..., 3], m.astype(np.float32))
    np.testing.assert_array_equal(out.images[0, ..., :3], (photo / 255).astype(np.float32))
    grey_photo = (np.mgrid[:24, :32][1] * 8).astype(np.uint8)  # a smooth grey ramp, no mask
    d = mask_folder(tmp_path, "g", [Image.fromarray(grey_photo)])
    with pytest.raises(ValueError, match=r"m0\.png.*grayscale photo.*masks"):
        load_images(d)


# ---------------------------------------------------------------- photos


def test_jpeg_photos_paired_with_masks_by_stem(tmp_path):
    photos, masks = tmp_path / "photos", tmp_path / "masks"
    photos.mkdir()
    masks.mkdir()
    names = ["IMG_001", "IMG_002", "IMG_003"]
    mask_files = ["IMG_001.png", "IMG_002_mask.png", "IMG_003.jpg.png"]
    shapes = [disc(cx=8.0), disc(cx=15.0), disc(cx=22.0)]  # distinct, so a mix-up shows
    for n, mf, m in zip(names, mask_files, shapes):
        Image.fromarray(RNG.integers(0, 256, (24, 32, 3), dtype=np.uint8)).save(photos / f"{n}.jpg", quality=95)
        Image.fromarray(np.where(m, 255, 0).astype(np.uint8)).save(masks / mf)
    Image.fromarray(np.zeros((24, 32), np.uint8)).save(masks / "IMG_999.png")  # a mask without a photo
    out = load_images(photos, masks=masks)
    assert out.names == names and out.images.shape == (3, 24, 32, 4)
    for i, n in enumerate(names):
        rgb = np.asarray(Image.open(photos / f"{n}.jpg").convert("RGB")) / 255
        np.testing.assert_array_equal(out.images[i, ..., :3], rgb.astype(np.float32))
        np.testing.assert_array_equal(out.images[i, ..., 3], shapes[i].astype(np.float32))
    assert "JPEG photos" in out.source and "paired by name" in out.source and "IMG_999" in out.source
    assert out.targets == "photo"
    # masks as a list of files, in another order: same pairing
    listed = load_images(photos, masks=[masks / f for f in reversed(mask_files)])
    np.testing.assert_array_equal(listed.images, out.images)



def test_some_views_read_with_their_own_masks(tmp_path):
    """`views=` reads only the chosen photos and their masks (as a process sharing a capture does):
    the same rows as a full read; `names` and `count` still cover all; bad indices are refused."""
    photos, masks = tmp_path / "photos", tmp_path / "masks"
    photos.mkdir()
    masks.mkdir()
    for i in range(5):
        Image.fromarray(RNG.integers(0, 256, (24, 32, 3), dtype=np.uint8)).save(photos / f"{i:03d}.png")
        Image.fromarray(np.where(disc(cx=6.0 + 4 * i), 255, 0).astype(np.uint8)).save(masks / f"{i:03d}.png")
    every = load_images(photos, masks=masks)
    assert every.views is None and every.count == 5
    for views in ([1, 3], lambda n: np.arange(n)[n // 2:]):
        some = load_images(photos, masks=masks, views=views)
        chosen = [1, 3] if isinstance(views, list) else [2, 3, 4]
        np.testing.assert_array_equal(some.images, every.images[chosen])
        assert some.names == every.names and some.count == 5 and some.views.tolist() == chosen
        assert f"{len(chosen)} of 5 views read here" in some.source
    arr = np.stack([disc(cx=6.0 + 4 * i) for i in range(5)]).astype(np.float32)
    np.save(tmp_path / "masks.npy", arr)
    some = load_images(tmp_path / "masks.npy", views=[0, 4])
    np.testing.assert_array_equal(some.images[..., 0], arr[[0, 4]])
    assert some.count == 5 and some.names is None
    for bad in ([3, 1], [5], [], [0.5]):
        with pytest.raises(ValueError, match="^views: "):
            load_images(photos, masks=masks, views=bad)


def test_unpaired_photo_is_an_error_naming_it(tmp_path):
    (tmp_path / "m").mkdir()
    for n in ("a", "b", "c"):
        Image.fromarray(RNG.integers(0, 256, (8, 8, 3), dtype=np.uint8)).save(tmp_path / f"{n}.jpg")
    for n in ("a", "c_mask", "x"):
        Image.fromarray(np.full((8, 8), 255, np.uint8)).save(tmp_path / "m" / f"{n}.png")
    with pytest.raises(ValueError, match=r"masks: 1 of 3 photos have no mask \(b\.jpg\).*x\.png") as err:
        load_images(tmp_path, masks=tmp_path / "m")
    assert "\n" not in str(err.value)
    Image.fromarray(np.full((8, 8), 255, np.uint8)).save(tmp_path / "m" / "b.png")
    Image.fromarray(np.full((8, 8), 255, np.uint8)).save(tmp_path / "m" / "b_mask.png")
    with pytest.raises(ValueError, match=r"b\.jpg has several masks"):
        load_images(tmp_path, masks=tmp_path / "m")


def test_rgb_photo_without_mask_is_refused(tmp_path):
    Image.fromarray(RNG.integers(0, 256, (8, 8, 3), dtype=np.uint8)).save(tmp_path / "shot.jpg")
    with pytest.raises(ValueError) as err:
        load_images(tmp_path)
    msg = str(err.value)
    assert "shot.jpg" in msg and "masks" in msg and "--masks" in msg and "background" in msg and "\n" not in msg
    # an RGBA stack opaque everywhere carries no mask either
    opaque = np.full((8, 8, 4), 255, np.uint8)
    opaque[..., :3] = RNG.integers(0, 256, (8, 8, 3))
    Image.fromarray(opaque, "RGBA").save(tmp_path / "p.png")
    with pytest.raises(ValueError, match="p.png has no mask"):
        load_images(tmp_path / "p.png")


@pytest.mark.parametrize("background", ["white", "black"])
def test_background_threshold(tmp_path, background):
    bg = 1.0 if background == "white" else 0.0
    sign = -1.0 if background == "white" else 1.0
    rgb = np.full((24, 32, 3), bg) + sign * RNG.uniform(0, 0.06, (24, 32, 3))  # sensor / JPEG-like noise
    m = disc()
    rgb[m] = 0.5
    rgb[2:5, 2:5] = bg + sign * np.array([0.02, 0.16, 0.02])  # one channel 0.16 away: foreground
    rgb[8:10, 28:31] = bg + sign * 0.08  # all channels 0.08 away: background
    Image.fromarray(u8(rgb)).save(tmp_path / "a.png")
    out = load_images(tmp_path, background=background)
    expect = m.copy()
    expect[2:5, 2:5] = True
    np.testing.assert_array_equal(out.images[0, ..., 3], expect.astype(np.float32))
    np.testing.assert_array_equal(out.images[0, ..., :3], (u8(rgb) / 255).astype(np.float32))
    assert f"> {BACKGROUND_THRESHOLD}" in out.source and background in out.source
    with pytest.raises(ValueError, match="background must be"):
        load_images(tmp_path, background="green")
    with pytest.raises(ValueError, match="not both"):
        load_images(tmp_path, background=background, masks=tmp_path)


def test_16bit_photos_and_masks(tmp_path):
    rgb16 = RNG.integers(0, 65536, (6, 7, 3)).astype(np.uint16)
    write_png16(tmp_path / "a.png", rgb16, 2)
    (tmp_path / "m").mkdir()
    mask16 = np.zeros((6, 7), np.uint16)
    mask16[1:4, 2:6] = 65535
    mask16[0, 0] = 32768
    write_png16(tmp_path / "m" / "a_mask.png", mask16, 0)
    out = load_images(tmp_path / "a.png", masks=tmp_path / "m")
    assert np.abs(out.images[0, ..., :3] - rgb16 / 65535).max() <= 1 / 255 + 1e-6
    np.testing.assert_array_equal(out.images[0, ..., 3], (mask16 / 65535).astype(np.float32))


def test_exif_orientation_applied_to_jpeg(tmp_path):
    im = Image.fromarray(RNG.integers(0, 256, (10, 20, 3), dtype=np.uint8))
    exif = Image.Exif()
    exif[0x0112] = 6  # stored sideways: display rotated 90 degrees clockwise
    im.save(tmp_path / "portrait.jpg", exif=exif)
    (tmp_path / "m").mkdir()
    Image.fromarray(np.full((20, 10), 255, np.uint8)).save(tmp_path / "m" / "portrait.png")
    out = load_images(tmp_path / "portrait.jpg", masks=tmp_path / "m")
    assert out.images.shape == (1, 20, 10, 4) and "EXIF" in out.source
    stored = np.asarray(Image.open(tmp_path / "portrait.jpg").convert("RGB")) / 255
    np.testing.assert_allclose(out.images[0, ..., :3], np.rot90(stored, -1), atol=1e-6)


def test_mixed_sizes_and_kinds(tmp_path):
    Image.fromarray(np.zeros((8, 8), np.uint8)).save(tmp_path / "a.png")
    Image.fromarray(np.zeros((8, 8), np.uint8)).save(tmp_path / "b.png")
    Image.fromarray(np.zeros((8, 9), np.uint8)).save(tmp_path / "c.png")
    with pytest.raises(ValueError, match=r"c\.png is 9x8 but .*a\.png is 8x8"):
        load_images(tmp_path)
    os.remove(tmp_path / "c.png")
    Image.fromarray(np.zeros((8, 8, 4), np.uint8), "RGBA").save(tmp_path / "c.png")
    with pytest.raises(ValueError, match=r"c\.png is a colour image"):
        load_images(tmp_path)
    with pytest.raises(ValueError, match="no such file or folder"):
        load_images(tmp_path / "nothing")
    with pytest.raises(ValueError, match="same name"):
        (tmp_path / "sub").mkdir()
        Image.fromarray(np.zeros((8, 8), np.uint8)).save(tmp_path / "sub" / "a.png")
        load_images([tmp_path / "a.png", tmp_path / "sub" / "a.png"])


def test_glob_and_list_inputs_not_modified(tmp_path):
    for n in ("x2", "x1", "y"):
        Image.fromarray(np.where(disc(8, 8, 4, 4, 3), 255, 0).astype(np.uint8)).save(tmp_path / f"{n}.png")
    (tmp_path / "._x3.png").write_bytes(b"AppleDouble resource fork, not a PNG")
    (tmp_path / "cameras.json").write_text("{}")
    assert load_images(tmp_path).names == ["x1", "x2", "y"]
    assert load_images(str(tmp_path / "x*.png")).names == ["x1", "x2"]
    files = [tmp_path / "y.png", tmp_path / "x1.png"]
    before = list(files)
    assert load_images(files).names == ["y", "x1"]  # a list keeps its order
    assert files == before


# ---------------------------------------------------------------- arrays


@pytest.mark.parametrize(
    "dtype,scale", [(np.uint8, 255), (np.uint16, 65535), (np.float32, 1), (np.float64, 1), (np.bool_, 1)]
)
def test_npy_dtypes_and_shapes(tmp_path, dtype, scale):
    base = RNG.uniform(0, 1, (2, 5, 6, 4))
    base[..., 3] = disc(5, 6, 2, 3, 2)
    arr = (base > 0.5) if dtype == np.bool_ else (np.round(base * scale) if scale > 1 else base).astype(dtype)
    expect = arr.astype(np.float64) / (scale if dtype != np.bool_ else 1)
    np.save(tmp_path / "t.npy", arr)
    out = load_images(tmp_path / "t.npy")
    assert out.names is None and out.images.shape == (2, 5, 6, 4)
    np.testing.assert_array_equal(out.images, expect.astype(np.float32))
    sil = load_images(arr[..., 3])  # (N, H, W) in memory
    assert sil.images.shape == (2, 5, 6, 1) and sil.targets == "silhouette"
    np.testing.assert_array_equal(sil.images[..., 0], expect[..., 3].astype(np.float32))
    assert not np.shares_memory(sil.images, arr) and not np.shares_memory(out.images, arr)
    assert load_images(arr[..., 3:]).images.shape == (2, 5, 6, 1)


def test_npy_refusals_and_not_modified(tmp_path):
    rgb = RNG.uniform(0, 1, (2, 5, 6, 3)).astype(np.float32)
    keep = rgb.copy()
    with pytest.raises(ValueError, match="has no mask.*masks.*background"):
        load_images(rgb)
    with pytest.raises(ValueError, match=r"float values must lie in \[0, 1\]"):
        load_images(rgb * 2)
    with pytest.raises(ValueError, match="dtype int32"):
        load_images((rgb * 255).astype(np.int32))
    with pytest.raises(ValueError, match="shape"):
        load_images(rgb[..., :2])
    masks = np.zeros((2, 5, 6), np.uint8)
    masks[:, 1:4, 2:5] = 255
    out = load_images(rgb, masks=masks)
    np.testing.assert_array_equal(out.images[..., :3], rgb)
    np.testing.assert_array_equal(out.images[..., 3], masks / 255)
    out.images[...] = 0.0  # the result shares no memory with the input
    np.testing.assert_array_equal(rgb, keep)
    np.testing.assert_array_equal(masks[:, 2, 3], [255, 255])
    # masks from files pair with an array by order
    (tmp_path / "m").mkdir()
    for i in range(2):
        Image.fromarray(masks[i] // (i + 1)).save(tmp_path / "m" / f"{i}.png")
    out = load_images(rgb, masks=tmp_path / "m")
    np.testing.assert_array_equal(out.images[1, ..., 3], (masks[1] // 2 / 255).astype(np.float32))
    with pytest.raises(ValueError, match="silhouettes already"):
        load_images(masks, masks=masks)


# ---------------------------------------------------------------- targets


def test_normal_maps_inferred_as_normals(tmp_path):
    rng = np.random.default_rng(1)
    views = np.stack([sphere_normals(48, 64, random_rotation(rng)) for _ in range(4)])
    assert infer_targets(views) == "normals"
    assert infer_targets(sphere_normals(48, 64, np.eye(3))[None]) == "normals"  # one view
    for i, v in enumerate(views):  # through 8-bit PNG
        Image.fromarray(u8(v), "RGBA").save(tmp_path / f"n{i}.png")
    out = load_images(tmp_path)
    assert out.targets == "normals" and "unit normals" in out.source


def test_photos_never_inferred_as_normals():
    h, w = 48, 64
    lights = [np.array(v, float) for v in ([0, 0, -1], [1, -1, -1], [-1, 0.5, -0.3], [0.2, 1, -0.5])]
    for grey in (0.5, 0.8, 1.0):  # plaster: constant albedo times Lambert shading
        plaster = np.stack([shaded_photo(h, w, np.full((h, w, 3), grey), light) for light in lights])
        assert infer_targets(plaster) == "photo", grey
    # a flat-lit grey whose ||2 rgb - 1|| is exactly 1: only the direction test can tell
    flat = sphere_normals(h, w, np.eye(3))
    flat[..., :3] = np.where(flat[..., 3:] > 0, 0.5 + 0.5 / np.sqrt(3), 0.0)
    assert infer_targets(flat[None]) == "photo"
    rng = np.random.default_rng(2)
    texture = np.kron(rng.uniform(0.1, 1.0, (h // 8, w // 8, 3)), np.ones((8, 8, 1)))
    textured = np.stack([shaded_photo(h, w, texture, light) for light in lights])
    assert infer_targets(textured) == "photo"
    pastel = sphere_normals(h, w, np.eye(3))  # a photo of a pastel object: some pixels near the sphere
    pastel[..., :3] = np.clip(pastel[..., :3] * rng.uniform(0.6, 1.1, (h, w, 1)), 0, 1)
    assert infer_targets(pastel[None]) == "photo"
    short = sphere_normals(h, w, np.eye(3))  # every ||2 rgb - 1|| = 0.9: within 0.15 but the median is off
    short[..., :3] = np.where(short[..., 3:] > 0, (0.9 * (2 * short[..., :3] - 1) + 1) / 2, 0.0)
    assert infer_targets(short[None]) == "photo"
    assert infer_targets(np.zeros((1, 4, 4))) == "silhouette"


def test_targets_argument(tmp_path):
    normals = np.stack([sphere_normals(16, 16, np.eye(3))] * 2)
    assert load_images(normals).targets == "normals"
    given = load_images(normals, targets="photo")
    assert given.targets == "photo" and "given" in given.source
    sil = load_images(normals, targets="silhouette")
    assert sil.images.shape == (2, 16, 16, 1)
    np.testing.assert_array_equal(sil.images[..., 0], normals[..., 3])
    with pytest.raises(ValueError, match="targets='normals' needs RGB"):
        load_images(normals[..., 3], targets="normals")
    with pytest.raises(ValueError, match="targets must be one of"):
        load_images(normals, targets="depth")


# ---------------------------------------------------------------- pairing


def test_pair_by_name_with_shuffled_camera_names():
    images = ["frame_000", "frame_001", "frame_002", "r_12"]
    cameras = ["./r_12", "images/frame_002.png", "extra/frame_009.jpg", "frame_000.JPG", "C:\\shots\\frame_001"]
    order, desc = pair_images(images, cameras)
    assert order.tolist() == [3, 4, 1, 0]
    assert "by name" in desc and "1 of 5 cameras have no image" in desc and "frame_009" in desc
    order, desc = pair_images(images, ["frame_000", "frame_001.png", "frame_002", "r_12"])
    assert order.tolist() == [0, 1, 2, 3] and "same order" in desc


def test_pair_order_applies_to_cameras():
    from jaxgenus.geometry._cameras import sphere_cameras

    cams = sphere_cameras(3, resolution=8)
    order, _ = pair_images(["b", "c", "a"], ["a.png", "b.png", "c.png"])
    picked = cams[order]
    np.testing.assert_array_equal(np.asarray(picked.translation), np.asarray(cams.translation)[[1, 2, 0]])


def test_pair_by_order_and_errors():
    order, desc = pair_images(3, [None, None, None])
    assert order.tolist() == [0, 1, 2] and "neither" in desc and "order" in desc
    order, desc = pair_images(["a", "b"], 2)
    assert order.tolist() == [0, 1] and "cameras have no names" in desc and "order" in desc
    _, desc = pair_images(["f_1", "f_10", "f_2"], 3)
    assert "string order" in desc
    order, desc = pair_images(2, ["x", "y"])
    assert "images have no names" in desc and "order" in desc
    with pytest.raises(ValueError, match="3 images but 4 cameras"):
        pair_images(3, 4)
    with pytest.raises(ValueError, match="2 images but 3 cameras"):
        pair_images(["a", "b"], 3)
    names = [f"v{i}" for i in range(8)]
    with pytest.raises(ValueError) as err:
        pair_images(names, ["w0", "v1"])
    msg = str(err.value)
    assert "7 of 8 images have no camera" in msg and "v0" in msg and "(2 more)" in msg
    assert "1 of 2 cameras have no image (w0)" in msg and "\n" not in msg
    with pytest.raises(ValueError, match="both 'a' without folders"):
        pair_images(["a"], ["x/a.png", "y/a.jpg"])
    with pytest.raises(ValueError, match="image_names"):
        pair_images(None, 3)
    with pytest.raises(ValueError, match="name all or none"):
        pair_images(["a", None], 2)
    order, desc = pair_images(None, None, n_images=2, n_cameras=2)  # as LoadedImages.names / load_cameras give
    assert order.tolist() == [0, 1] and "neither" in desc
    order, _ = pair_images(["a", "b"], ["b", "a"], n_images=2, n_cameras=2)
    assert order.tolist() == [1, 0]
    with pytest.raises(ValueError, match="camera_names: 2 names for 3 items"):
        pair_images(["a", "b"], ["b", "a"], n_cameras=3)
    cams = ["b", "a"]
    pair_images(["a", "b"], cams)
    assert cams == ["b", "a"]


def _traced_peak(fn):
    """`(result, peak bytes)` of `fn()` as tracemalloc counts them (numpy reports its arrays' memory)."""
    import tracemalloc

    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        out = fn()
        return out, tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def test_photos_load_and_check_without_copies_of_the_whole_stack(tmp_path):
    """Reading photos with masks and checking them as targets hold about one float32 RGBA stack at a
    time: photos and masks are kept as read (uint8) and written into the result view by view, and
    the premultiplied targets are written view by view with their alpha a view of them. Before, on
    this test 4.3x and 2.8x the stack; on a DTU capture (41 photos of 1600x1200, 1.26 GB as float32)
    3.8 GB reading and 4.9 GB checked."""
    import jaxgenus as jg
    from jaxgenus.capture._targets import check_targets

    n, h, w = 6, 96, 128
    for i in range(n):
        Image.fromarray(u8(RNG.random((h, w, 3)))).save(tmp_path / f"{i:03d}.png")
        Image.fromarray(u8(disc(h, w, 48.0, 64.0, 30.0 + i))).save(tmp_path / f"{i:03d}_mask.png")
    stack = n * h * w * 4 * 4  # bytes of one float32 RGBA stack
    photos = sorted(str(p) for p in tmp_path.glob("*.png") if "mask" not in p.name)
    # targets given: telling photos from normal maps reads at most a million pixels, a fixed cost
    loaded, peak = _traced_peak(lambda: load_images(photos, masks=str(tmp_path / "*_mask.png"), targets="photo"))
    assert loaded.images.shape == (n, h, w, 4) and loaded.targets == "photo"
    assert peak < 1.7 * stack, peak / stack  # the stack, the files as read (uint8), a view converted
    first = np.asarray(Image.open(photos[0]), np.float32) / 255.0
    assert np.array_equal(loaded.images[0, ..., :3], first)  # the same values as before, exactly
    cams = jg.sphere_cameras(n, resolution=(h, w))
    targets, peak = _traced_peak(lambda: check_targets(loaded.images, cams, "photo"))
    assert targets.kind == "photo" and peak < 1.3 * stack, peak / stack
    a = loaded.images[..., 3:]
    assert np.array_equal(targets.fit, np.concatenate([loaded.images[..., :3] * a, a], -1))
    assert np.array_equal(targets.alpha, loaded.images[..., 3]) and np.shares_memory(targets.alpha, targets.fit)


def test_photos_as_8bit_pixels_give_the_same_targets(tmp_path):
    """`dtype=np.uint8` keeps 8-bit photos and masks as their pixels (a quarter of the float32 stack):
    the same values / 255 as the float32 reading, to the bit, and `check_targets` reads uint8 stacks
    as value / 255, so both give the same `Targets`. A 0/1 uint8 stack reads as empty silhouettes,
    said with how uint8 is read; other dtypes are refused."""
    import jaxgenus as jg
    from jaxgenus.capture._targets import check_targets

    n, h, w = 3, 24, 32
    for i in range(n):
        Image.fromarray(u8(RNG.random((h, w, 3)))).save(tmp_path / f"{i}.jpg", quality=90)
        Image.fromarray(u8(disc(h, w, r=6.0 + i))).save(tmp_path / f"{i}_mask.png")
    photos = sorted(str(p) for p in tmp_path.glob("*.jpg"))
    masks = str(tmp_path / "*_mask.png")
    cams = jg.sphere_cameras(n, resolution=(h, w))
    for kw in (dict(masks=masks), dict(background="black"), dict(masks=masks, targets="silhouette")):
        full, small = load_images(photos, **kw), load_images(photos, dtype=np.uint8, **kw)
        assert small.images.dtype == np.uint8 and small.images.nbytes * 4 == full.images.nbytes
        assert small.targets == full.targets and small.source == full.source
        assert np.array_equal(small.images / np.float32(255.0), full.images), kw
        a, b = check_targets(full.images, cams), check_targets(small.images, cams)
        assert a.kind == b.kind and np.array_equal(a.fit, b.fit) and np.array_equal(a.alpha, b.alpha)
    binary = (full.images > 0.5).astype(np.uint8)
    with pytest.raises(ValueError, match=r"empty silhouettes .*uint8 images are read as value / 255"):
        check_targets(binary, cams)
    with pytest.raises(ValueError, match="dtype must be np.float32 or np.uint8"):
        load_images(photos, masks=masks, dtype=np.float64)
