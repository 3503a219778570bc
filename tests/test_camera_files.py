"""Camera files of other tools (`load_cameras`), checked against hand-made projections.

Every test writes its file into tmp_path from known cameras: an object of about
0.1 m seen from about 0.5 m, rotated cameras, non-square pixels and off-centre
principal points. The expected pixels are computed here in each format's own
convention (written out separately from the library), then compared with
`jg.project` of the loaded cameras.
"""

import json
import math
import struct

import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

import jaxgenus as jg
from jaxgenus.capture._camera_files import load_cameras

H, W = 480, 640
TOL_PX = 0.01

# A 0.1 m cube's corners and two inner points (metres).
POINTS = np.array(
    [[sx * 0.05, sy * 0.05, sz * 0.05] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    + [[0.0, 0.0, 0.0], [0.02, -0.03, 0.04]]
)
EYES = np.array([[0.5, 0.1, 0.05], [-0.2, 0.45, 0.15], [0.05, -0.35, 0.38], [-0.3, -0.3, -0.25]])
TARGETS = np.array([[0.01, -0.02, 0.005], [0.0, 0.01, -0.01], [-0.015, 0.0, 0.02], [0.02, 0.02, 0.0]])
ROLLS = [0.3, -1.1, 2.0, 0.7]
# (fx, fy, cx, cy), cx/cy in the convention of whichever format uses them.
INTRINSICS = [(800.0, 760.0, 300.3, 250.7), (640.0, 640.0, 331.2, 228.9), (910.0, 870.5, 318.0, 245.5),
              (700.0, 715.0, 290.6, 262.4)]


def world_to_camera(eye, target, roll):
    """OpenCV-axes world-to-camera (R, t): looks from `eye` at `target`, rolled about the view axis."""
    z = (target - eye) / np.linalg.norm(target - eye)
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = math.cos(roll), math.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    R = np.stack([x, y, z])
    return R, -R @ eye


POSES = [world_to_camera(e, t, r) for e, t, r in zip(EYES, TARGETS, ROLLS)]


def expected_centre_half(R, t, fx, fy, cx, cy):
    """Pinhole projection where the top-left pixel centre is (0.5, 0.5) (COLMAP, NeRF): no shift."""
    xc = POINTS @ R.T + t
    assert np.all(xc[:, 2] > 0.1)
    return np.stack([fx * xc[:, 0] / xc[:, 2] + cx, fy * xc[:, 1] / xc[:, 2] + cy], axis=-1)


def expected_opencv(P):
    """`P = K [R | t]` (3x4) with pixel centres at integers (OpenCV), moved to jaxgenus's (+0.5)."""
    h = np.c_[POINTS, np.ones(len(POINTS))] @ P.T
    return h[:, :2] / h[:, 2:3] + 0.5


def k_matrix(fx, fy, cx, cy, skew=0.0):
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def check_projection(cams, expected):
    """Max |project - expected| over cameras and points; fails above TOL_PX."""
    got = np.asarray(jg.project(cams, jnp.asarray(POINTS, jnp.float32)))
    expected = np.asarray(expected)
    assert got.shape == expected.shape
    err = float(np.max(np.abs(got - expected)))
    assert err <= TOL_PX, f"max projection error {err:.4g} px"
    return err


def raises_naming(path, match=None):
    """pytest.raises(ValueError) whose one-line message names `path` (and matches `match`)."""

    class _Check:
        def __enter__(self):
            self.ctx = pytest.raises(ValueError, match=match)
            self.info = self.ctx.__enter__()
            return self.info

        def __exit__(self, *exc):
            out = self.ctx.__exit__(*exc)
            msg = str(self.info.value)
            assert str(path) in msg, msg
            assert "\n" not in msg, msg
            return out

    return _Check()


# ---------------------------------------------------------------------- OpenCV JSON


def write_opencv_json(path, cams, height=H, width=W):
    path.write_text(json.dumps({"height": height, "width": width, "cameras": cams}))
    return path


def opencv_cameras(names=True):
    cams = []
    for i, ((R, t), (fx, fy, cx, cy)) in enumerate(zip(POSES, INTRINSICS)):
        c = {"K": k_matrix(fx, fy, cx, cy).tolist(), "R": R.tolist(), "t": t.tolist()}
        if names:
            c["name"] = f"view_{i}.png"
        cams.append(c)
    return cams


def test_opencv_json(tmp_path):
    path = write_opencv_json(tmp_path / "cams.json", opencv_cameras())
    cams, names = load_cameras(path)
    assert (cams.height, cams.width) == (H, W) and len(cams) == 4
    assert names == [f"view_{i}.png" for i in range(4)]
    expected = [expected_opencv(k_matrix(*k) @ np.c_[R, t]) for (R, t), k in zip(POSES, INTRINSICS)]
    check_projection(cams, expected)


def test_opencv_json_names_optional_and_column_t(tmp_path):
    spec = opencv_cameras()
    del spec[2]["name"]
    spec[1]["t"] = [[v] for v in spec[1]["t"]]
    cams, names = load_cameras(write_opencv_json(tmp_path / "cams.json", spec))
    assert names is None
    expected = [expected_opencv(k_matrix(*k) @ np.c_[R, t]) for (R, t), k in zip(POSES, INTRINSICS)]
    check_projection(cams, expected)


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda c: c[1].update(R=(1.01 * np.array(c[1]["R"])).tolist()), "rotation"),
        (lambda c: c[2].update(R=(np.diag([1, 1, -1]) @ np.array(c[2]["R"])).tolist()), "det = -1"),
        (lambda c: c[0].update(K=k_matrix(-800, 760, 300, 250).tolist()), "focal"),
        (lambda c: c[3].update(t=[0.1, float("nan"), 0.5]), "non-finite"),
        (lambda c: c[1].update(K=k_matrix(640, 640, 331, 228, skew=3.0).tolist()), "skew"),
        (lambda c: c[1].pop("K"), "missing 'K'"),
    ],
)
def test_opencv_json_refusals(tmp_path, edit, match):
    spec = opencv_cameras()
    edit(spec)
    path = write_opencv_json(tmp_path / "cams.json", spec)
    with raises_naming(path, match) as info:
        load_cameras(path)
    assert "camera" in str(info.value)


def test_opencv_json_small_skew_dropped_and_empty_refused(tmp_path):
    spec = opencv_cameras()
    spec[0]["K"] = k_matrix(*INTRINSICS[0], skew=0.01).tolist()  # moves pixels by < 0.01 px
    cams, _ = load_cameras(write_opencv_json(tmp_path / "a.json", spec))
    check_projection(cams[0], [expected_opencv(k_matrix(*INTRINSICS[0]) @ np.c_[POSES[0]])])
    empty = write_opencv_json(tmp_path / "b.json", [])
    with raises_naming(empty, "no cameras"):
        load_cameras(empty)


def test_image_size_must_match_file(tmp_path):
    path = write_opencv_json(tmp_path / "cams.json", opencv_cameras())
    cams, _ = load_cameras(path, image_size=(H, W))
    assert (cams.height, cams.width) == (H, W)
    with raises_naming(path, "image_size"):
        load_cameras(path, image_size=(W, H))
    with pytest.raises(ValueError, match="image_size"):
        load_cameras(path, image_size=(0, 3))


# --------------------------------------------------------------------------- COLMAP

# (camera_id, model, width, height, params): cameras 1-3 are used; 9 is unused and
# has distortion and another size, which must not matter.
COLMAP_CAMERAS = [
    (1, "PINHOLE", W, H, INTRINSICS[0]),
    (2, "SIMPLE_PINHOLE", W, H, (INTRINSICS[1][0], INTRINSICS[1][2], INTRINSICS[1][3])),
    (3, "OPENCV", W, H, INTRINSICS[2] + (0.0, 0.0, 0.0, 0.0)),
    (9, "SIMPLE_RADIAL", 100, 80, (90.0, 50.0, 40.0, 0.2)),
]
COLMAP_MODEL_IDS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "OPENCV": 4, "OPENCV_FISHEYE": 5}
# (image_id, name, camera_id, pose index, intrinsics index): ids and names out of order.
COLMAP_IMAGES = [(7, "c.png", 1, 0, 0), (3, "a.png", 2, 1, 1), (12, "d.png", 3, 2, 2), (5, "b.png", 1, 3, 0)]


def colmap_quaternion(R, flip=False):
    x, y, z, w = Rotation.from_matrix(R).as_quat()  # scipy: scalar last, Hamilton
    q = np.array([w, x, y, z])
    return -q if flip else q  # q and -q are the same rotation


def colmap_image_records(images=COLMAP_IMAGES):
    out = []
    for image_id, name, camera_id, pose, _ in images:
        R, t = POSES[pose]
        out.append((image_id, colmap_quaternion(R, flip=image_id == 12), t, camera_id, name))
    return out


def write_colmap_text(folder, cameras, images):
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    lines += [f"{cid} {model} {w} {h} " + " ".join(f"{p:.17g}" for p in params) for cid, model, w, h, params in cameras]
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME"]
    for k, (iid, q, t, cid, name) in enumerate(images):
        lines.append(f"{iid} " + " ".join(f"{v:.17g}" for v in (*q, *t)) + f" {cid} {name}")
        lines.append("" if k % 2 else "101.5 202.25 -1 55.0 66.0 42")  # POINTS2D, sometimes empty
    (folder / "images.txt").write_text("\n".join(lines) + "\n")


def write_colmap_binary(folder, cameras, images):
    """COLMAP's documented binary layout, little-endian."""
    folder.mkdir(parents=True, exist_ok=True)
    data = struct.pack("<Q", len(cameras))
    for cid, model, w, h, params in cameras:
        data += struct.pack("<iiQQ", cid, COLMAP_MODEL_IDS[model], w, h)
        data += struct.pack(f"<{len(params)}d", *params)
    (folder / "cameras.bin").write_bytes(data)
    data = struct.pack("<Q", len(images))
    for k, (iid, q, t, cid, name) in enumerate(images):
        data += struct.pack("<i", iid) + struct.pack("<4d", *q) + struct.pack("<3d", *t)
        data += struct.pack("<i", cid) + name.encode() + b"\0"
        points = [] if k % 2 else [(101.5, 202.25, -1), (55.0, 66.0, 42)]
        data += struct.pack("<Q", len(points))
        for x, y, pid in points:
            data += struct.pack("<ddq", x, y, pid)
    (folder / "images.bin").write_bytes(data)


WRITERS = {"text": (write_colmap_text, ".txt"), "binary": (write_colmap_binary, ".bin")}


def colmap_expected():
    """Images sorted by name, each with its camera's pinhole (COLMAP convention = no shift)."""
    rows = sorted(COLMAP_IMAGES, key=lambda r: r[1])
    return [r[1] for r in rows], [expected_centre_half(*POSES[r[3]], *INTRINSICS[r[4]]) for r in rows]


@pytest.mark.parametrize("fmt", ["text", "binary"])
@pytest.mark.parametrize("where", ["project", "sparse", "sparse/0", "file"])
def test_colmap(tmp_path, fmt, where):
    write, ext = WRITERS[fmt]
    model = tmp_path / "project" / "sparse" / "0"
    write(model, COLMAP_CAMERAS, colmap_image_records())
    path = {"project": tmp_path / "project", "sparse": tmp_path / "project" / "sparse", "sparse/0": model,
            "file": model / f"images{ext}"}[where]
    cams, names = load_cameras(path)
    want_names, expected = colmap_expected()
    assert names == want_names == ["a.png", "b.png", "c.png", "d.png"]
    assert (cams.height, cams.width) == (H, W)
    check_projection(cams, expected)


def test_colmap_prefers_binary_like_colmap(tmp_path):
    write_colmap_binary(tmp_path, COLMAP_CAMERAS, colmap_image_records())
    moved = [(1, "PINHOLE", W, H, (800.0, 760.0, 310.3, 250.7))] + COLMAP_CAMERAS[1:]
    write_colmap_text(tmp_path, moved, colmap_image_records())
    cams, _ = load_cameras(tmp_path)
    check_projection(cams, colmap_expected()[1])
    cams_txt, _ = load_cameras(tmp_path / "cameras.txt")
    np.testing.assert_allclose(np.asarray(cams_txt.principal_point)[1], [310.3, 250.7], rtol=1e-6)


@pytest.mark.parametrize("fmt", ["text", "binary"])
@pytest.mark.parametrize(
    "camera, match",
    [
        ((1, "SIMPLE_RADIAL", W, H, (800.0, 300.0, 250.0, 0.01)), "camera 1 \\(SIMPLE_RADIAL\\).*image_undistorter"),
        ((1, "OPENCV", W, H, (800.0, 760.0, 300.0, 250.0, 0.0, 0.0, 1e-3, 0.0)), "camera 1 \\(OPENCV\\).*distortion"),
        ((1, "OPENCV_FISHEYE", W, H, (800.0, 760.0, 300.0, 250.0, 0.0, 0.0, 0.0, 0.0)), "fisheye.*image_undistorter"),
        ((1, "PINHOLE", 800, 600, INTRINSICS[0]), "different sizes"),
        ((1, "PINHOLE", W, H, (800.0, -760.0, 300.0, 250.0)), "focal"),
    ],
)
def test_colmap_refusals(tmp_path, fmt, camera, match):
    write, ext = WRITERS[fmt]
    write(tmp_path, [camera] + COLMAP_CAMERAS[1:], colmap_image_records())
    with raises_naming(tmp_path / f"cameras{ext}", match):
        load_cameras(tmp_path)


@pytest.mark.parametrize("fmt", ["text", "binary"])
def test_colmap_image_size_and_empty(tmp_path, fmt):
    write, ext = WRITERS[fmt]
    write(tmp_path / "m", COLMAP_CAMERAS, colmap_image_records())
    assert len(load_cameras(tmp_path / "m", image_size=(H, W))[0]) == 4
    with raises_naming(tmp_path / "m" / f"cameras{ext}", "image_size"):
        load_cameras(tmp_path / "m", image_size=(H + 1, W))
    write(tmp_path / "e", COLMAP_CAMERAS, [])
    with raises_naming(tmp_path / "e" / f"images{ext}", "no registered images"):
        load_cameras(tmp_path / "e")


def test_colmap_bad_quaternion_and_missing_camera(tmp_path):
    recs = colmap_image_records()
    recs[1] = (recs[1][0], 1.1 * recs[1][1], *recs[1][2:])
    write_colmap_text(tmp_path / "q", COLMAP_CAMERAS, recs)
    with raises_naming(tmp_path / "q" / "images.txt", "image 'a.png'.*quaternion"):
        load_cameras(tmp_path / "q")
    recs = colmap_image_records()
    recs[0] = (*recs[0][:3], 4, recs[0][4])
    write_colmap_binary(tmp_path / "c", COLMAP_CAMERAS, recs)
    with raises_naming(tmp_path / "c" / "images.bin", "CAMERA_ID 4"):
        load_cameras(tmp_path / "c")


def test_colmap_truncated_binary(tmp_path):
    write_colmap_binary(tmp_path, COLMAP_CAMERAS, colmap_image_records())
    data = (tmp_path / "images.bin").read_bytes()
    (tmp_path / "images.bin").write_bytes(data[:-10])
    with raises_naming(tmp_path / "images.bin", "truncated"):
        load_cameras(tmp_path)


# ------------------------------------------------------------------ transforms.json


def opengl_camera_to_world(R, t):
    """NeRF's transform_matrix: camera-to-world with OpenGL camera axes (x right, y up, looking along -z)."""
    centre = -R.T @ t
    axes_cv = R.T  # columns: the camera's x (right), y (down), z (forward) in world coordinates
    axes_gl = np.stack([axes_cv[:, 0], -axes_cv[:, 1], -axes_cv[:, 2]], axis=1)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = axes_gl, centre
    return m


def expected_nerf(c2w, fx, fy, cx, cy):
    """Invert the camera-to-world, then OpenGL camera axes -> pixels (centre of top-left pixel at 0.5)."""
    w2c = np.linalg.inv(c2w)
    p = (np.c_[POINTS, np.ones(len(POINTS))] @ w2c.T)[:, :3]
    depth = -p[:, 2]  # the camera looks along -z
    assert np.all(depth > 0.1)
    u = fx * p[:, 0] / depth + cx  # +x is right in the image
    v = fy * (-p[:, 1]) / depth + cy  # +y is up, image rows go down
    return np.stack([u, v], axis=-1)


def test_transforms_nerfstudio_style(tmp_path):
    fx, fy, cx, cy = INTRINSICS[0]
    frames = [{"file_path": f"images/frame_{i:05d}.png", "transform_matrix": opengl_camera_to_world(*POSES[i]).tolist()}
              for i in range(4)]
    frames[2].update(fl_x=INTRINSICS[2][0], fl_y=INTRINSICS[2][1], cx=INTRINSICS[2][2], cy=INTRINSICS[2][3])
    spec = {"camera_model": "OPENCV", "w": W, "h": H, "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy,
            "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "frames": frames}
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps(spec))
    cams, names = load_cameras(path)
    assert names == [f["file_path"] for f in frames]
    assert (cams.height, cams.width) == (H, W)
    intr = [INTRINSICS[0], INTRINSICS[0], INTRINSICS[2], INTRINSICS[0]]
    check_projection(cams, [expected_nerf(np.array(f["transform_matrix"]), *k) for f, k in zip(frames, intr)])
    # the folder finds the same file
    cams2, _ = load_cameras(tmp_path)
    np.testing.assert_array_equal(np.asarray(cams2.rotation), np.asarray(cams.rotation))


def blender_spec(angle_x=0.69, angle_y=None):
    frames = [{"file_path": f"./train/r_{i}", "rotation": 0.0,
               "transform_matrix": opengl_camera_to_world(*POSES[i]).tolist()} for i in range(4)]
    spec = {"camera_angle_x": angle_x, "frames": frames}
    if angle_y is not None:
        spec["camera_angle_y"] = angle_y
    return spec


def test_transforms_blender_size_from_images(tmp_path):
    h, w = 60, 80
    (tmp_path / "train").mkdir()
    for i in range(4):
        Image.new("RGBA", (w, h)).save(tmp_path / "train" / f"r_{i}.png")
    path = tmp_path / "transforms_train.json"
    path.write_text(json.dumps(blender_spec()))
    cams, names = load_cameras(path)
    assert (cams.height, cams.width) == (h, w)
    assert names == [f"./train/r_{i}" for i in range(4)]
    f = 0.5 * w / math.tan(0.5 * 0.69)
    check_projection(cams, [expected_nerf(opengl_camera_to_world(R, t), f, f, w / 2, h / 2) for R, t in POSES])


def test_transforms_blender_image_size_argument(tmp_path):
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps(blender_spec(angle_y=0.6)))
    with raises_naming(path, "image_size"):
        load_cameras(path)  # no w/h, no images
    cams, _ = load_cameras(path, image_size=(H, W))
    fx, fy = 0.5 * W / math.tan(0.5 * 0.69), 0.5 * H / math.tan(0.5 * 0.6)
    check_projection(cams, [expected_nerf(opengl_camera_to_world(R, t), fx, fy, W / 2, H / 2) for R, t in POSES])


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda s: s.update(k1=0.01), "frame 0.*distortion.*k1"),
        (lambda s: s["frames"][1].update(p2=-0.002), "frame 1.*distortion.*p2"),
        (lambda s: s.update(camera_model="OPENCV_FISHEYE"), "camera_model"),
        (lambda s: s["frames"][3].update(w=W // 2, h=H // 2), "different image sizes"),
        (lambda s: s["frames"][2]["transform_matrix"][0].__setitem__(0, 1.5), "frame 2.*rotation"),
        (lambda s: s.update(fl_x=-500.0), "focal"),
    ],
)
def test_transforms_refusals(tmp_path, edit, match):
    spec = {"w": W, "h": H, "fl_x": 800.0, "fl_y": 760.0, "cx": 300.0, "cy": 250.0,
            "frames": [{"file_path": f"{i}.png", "transform_matrix": opengl_camera_to_world(*POSES[i]).tolist()}
                       for i in range(4)]}
    edit(spec)
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps(spec))
    with raises_naming(path, match):
        load_cameras(path)


# ------------------------------------------------------------------------ IDR / NeuS

IDR_SCALES = [2.5, -0.7, 1.0, -3.0]  # P is defined up to scale, sign included


def idr_world_mats():
    mats = []
    for (R, t), k, s in zip(POSES, INTRINSICS, IDR_SCALES):
        P = np.eye(4)
        P[:3] = s * (k_matrix(*k) @ np.c_[R, t])
        mats.append(P)
    return mats


def write_idr(path, mats):
    scale = np.diag([0.3, 0.3, 0.3, 1.0])
    scale[:3, 3] = [0.01, -0.02, 0.03]
    arrays = {}
    for i, m in enumerate(mats):
        arrays[f"world_mat_{i}"] = m
        arrays[f"scale_mat_{i}"] = scale
        arrays[f"camera_mat_{i}"] = np.eye(4)
    np.savez(path, **arrays)
    return path


def test_idr_npz(tmp_path):
    mats = idr_world_mats()
    path = write_idr(tmp_path / "cameras.npz", mats)
    cams, names = load_cameras(path, image_size=(H, W))
    assert names is None and (cams.height, cams.width) == (H, W)
    check_projection(cams, [expected_opencv(m[:3]) for m in mats])  # world_mat frame; scale_mat ignored
    assert np.allclose(np.linalg.det(np.asarray(cams.rotation, np.float64)), 1.0, atol=1e-5)


def test_idr_npz_size_from_image_folder_and_required(tmp_path):
    path = write_idr(tmp_path / "cameras_sphere.npz", idr_world_mats())
    with raises_naming(path, "image_size"):
        load_cameras(path)
    (tmp_path / "image").mkdir()
    Image.new("RGB", (W, H)).save(tmp_path / "image" / "000000.png")
    cams, _ = load_cameras(tmp_path)  # the folder finds cameras_sphere.npz
    assert (cams.height, cams.width) == (H, W)


def test_idr_region_is_the_unit_sphere_of_scale_mat(tmp_path):
    path = write_idr(tmp_path / "cameras.npz", idr_world_mats())
    centre, radius = jg.load_region(path)  # write_idr: x_world = 0.3 x + (0.01, -0.02, 0.03)
    np.testing.assert_allclose(centre, [0.01, -0.02, 0.03])
    assert radius == pytest.approx(0.3)
    scale = np.diag([0.2, 0.5, 0.3, 1.0])  # an ellipsoid: the sphere holding it
    np.savez(tmp_path / "b.npz", world_mat_0=idr_world_mats()[0], scale_mat_0=scale)
    assert jg.load_region(tmp_path / "b.npz")[1] == pytest.approx(0.5)
    np.savez(tmp_path / "c.npz", world_mat_0=idr_world_mats()[0])
    assert jg.load_region(tmp_path / "c.npz") is None  # no scale_mat: no region
    assert jg.load_region(write_par(tmp_path / "x_par.txt", par_rows())) is None  # the format has none
    for name, bad, match in (("d.npz", np.diag([0.0, 0.3, 0.3, 1.0]), "scale_mat_0.*singular"),
                             ("e.npz", np.full((4, 4), np.nan), "scale_mat_0.*non-finite")):
        np.savez(tmp_path / name, world_mat_0=idr_world_mats()[0], scale_mat_0=bad)
        with raises_naming(tmp_path / name, match):
            jg.load_region(tmp_path / name)
    np.savez(tmp_path / "f.npz", world_mat_0=idr_world_mats()[0], world_mat_1=idr_world_mats()[1],
             scale_mat_0=np.eye(4), scale_mat_1=2 * np.eye(4))
    with raises_naming(tmp_path / "f.npz", "differ"):
        jg.load_region(tmp_path / "f.npz")


def test_idr_npz_skew_refused(tmp_path):
    mats = idr_world_mats()
    R, t = POSES[1]
    mats[1][:3] = k_matrix(*INTRINSICS[1], skew=4.0) @ np.c_[R, t]
    path = write_idr(tmp_path / "cameras.npz", mats)
    with raises_naming(path, "world_mat_1.*skew"):
        load_cameras(path, image_size=(H, W))


# ------------------------------------------------------------------------ Middlebury


def write_par(path, rows, count=None):
    lines = [str(len(rows) if count is None else count)]
    for name, K, R, t in rows:
        lines.append(name + " " + " ".join(f"{v:.17g}" for v in (*K.ravel(), *R.ravel(), *t)))
    path.write_text("\n".join(lines) + "\n")
    return path


def par_rows():
    return [(f"temple{i + 1:04d}.png", k_matrix(*k), R, t) for i, ((R, t), k) in enumerate(zip(POSES, INTRINSICS))]


def test_middlebury_par(tmp_path):
    rows = par_rows()
    path = write_par(tmp_path / "temple_par.txt", rows)
    for name, *_ in rows[:1]:
        Image.new("RGB", (W, H)).save(tmp_path / name)
    cams, names = load_cameras(path)
    assert names == [r[0] for r in rows] and (cams.height, cams.width) == (H, W)
    check_projection(cams, [expected_opencv(K @ np.c_[R, t]) for _, K, R, t in rows])
    folder = tmp_path / "capture"  # a capture folder: the images in image/ beside the file
    (folder / "image").mkdir(parents=True)
    Image.new("RGB", (W, H)).save(folder / "image" / rows[0][0])
    cams, _ = load_cameras(write_par(folder / "temple_par.txt", rows))
    assert (cams.height, cams.width) == (H, W)


def test_middlebury_par_refusals(tmp_path):
    rows = par_rows()
    path = write_par(tmp_path / "dino_par.txt", rows)
    with raises_naming(path, "image_size"):
        load_cameras(path)  # no images beside it
    assert len(load_cameras(path, image_size=(H, W))[0]) == 4
    bad = list(rows)
    bad[2] = (bad[2][0], bad[2][1], bad[2][2] * 0.98, bad[2][3])
    path = write_par(tmp_path / "bad_par.txt", bad)
    with raises_naming(path, "image 'temple0003.png'.*rotation"):
        load_cameras(path, image_size=(H, W))
    path = write_par(tmp_path / "count_par.txt", rows, count=5)
    with raises_naming(path, "says 5 images"):
        load_cameras(path, image_size=(H, W))


# ---------------------------------------------------------------------- detection


def test_unknown_formats(tmp_path):
    for name, content in [("cams.yaml", "a: 1\n"), ("notes.txt", "hello\nworld\n"), ("x.json", '{"a": 1}')]:
        path = tmp_path / name
        path.write_text(content)
        with raises_naming(path, "cannot tell the camera format"):
            load_cameras(path)
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with raises_naming(tmp_path / "other.npz", "cannot tell the camera format"):
        load_cameras(tmp_path / "other.npz")
    empty = tmp_path / "empty"
    empty.mkdir()
    with raises_naming(empty, "cannot tell the camera format"):
        load_cameras(empty)
    with pytest.raises(FileNotFoundError):
        load_cameras(tmp_path / "missing.json")


def test_folder_with_several_camera_files_is_ambiguous(tmp_path):
    write_idr(tmp_path / "cameras.npz", idr_world_mats())
    (tmp_path / "transforms.json").write_text(json.dumps(blender_spec()))
    with raises_naming(tmp_path, "several camera files"):
        load_cameras(tmp_path)
