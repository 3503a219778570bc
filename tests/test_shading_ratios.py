"""Shading ratios (jaxgenus.optim._intrinsic): an albedo-free shading term for photos, checked on
photos ray cast by trimesh (smooth normals, one lamp) with 3D colour cells the mesh's albedo cannot hold."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgenus as jg
from jaxgenus.optim import shading_ratio_cost
from _meshes import torus, torus_trimesh
from _raycast import cell_albedo, raycast_lambert

LIGHT = np.array([0.4, 0.8, 0.45]) / np.linalg.norm([0.4, 0.8, 0.45])
AMBIENT = 0.25


#: A high-frequency albedo: 3D cells of 0.25 (about 11 px here) with hashed colours in [0.1, 0.9].
cells = cell_albedo(0.25)


@pytest.fixture(scope="module")
def scene():
    tm = torus_trimesh(1.0, 0.35, 64, 32)
    cams = jg.sphere_cameras(8, radius=3.0, fov_deg=40.0, resolution=96)
    out = {}
    for name, albedo in (("cells", cells), ("constant", (0.6, 0.5, 0.4))):
        photos = np.asarray(raycast_lambert(cams, tm, light_direction=LIGHT, ambient=AMBIENT, albedo=albedo), np.float32)
        photos[..., :3] *= photos[..., 3:4]  # premultiplied, as the pipeline fits them
        out[name] = jnp.asarray(photos)
    lighting, _ = jg.rendering.directional_lighting(LIGHT, AMBIENT, model="directional")
    return cams, out, jnp.asarray(lighting, jnp.float32)


def _cost(mesh, cams, photos, lighting, shading="smooth"):
    e = jnp.maximum(jg.rendering.irradiance(jg.geometry.vertex_normals(mesh) if shading == "smooth" else jg.geometry.face_normals(mesh), lighting), 0)
    kw = {"vertex_colors": e} if shading == "smooth" else {"face_colors": e}
    img = jg.render(mesh, cams, channels=("alpha", "color"), **kw)
    return shading_ratio_cost(img[..., 0], img[..., 1:4], photos)


def _per_pair(mesh, cams, photos, lighting):
    cost, count = _cost(mesh, cams, photos, lighting)
    return float(cost) / max(float(count), 1.0)


def test_lowest_at_the_true_surface_whatever_the_albedo(scene):
    cams, photos, lighting = scene
    # per pair: a thinner tube has fewer pixels inside (the term sums over pixels; the silhouette holds it)
    costs = {name: {s: _per_pair(torus(1.0, 0.35 * s, 64, 32), cams, photos[name], lighting)
                    for s in (0.8, 0.9, 1.0, 1.1, 1.25)} for name in ("cells", "constant")}
    c = costs["constant"]
    assert c[1.0] < 0.6 * min(c[0.9], c[1.1]) and c[1.0] < 0.3 * min(c[0.8], c[1.25]), c
    # the pairs across a cell edge cost a bounded amount wherever the surface is: the slope is the rest's
    c = costs["cells"]
    assert c[1.0] < min(c[0.9], c[1.1]) and c[1.0] < min(c[0.8], c[1.25]) / 1.05, c
    truth = torus(1.0, 0.35, 64, 32)
    cost, count = _cost(truth, cams, photos["constant"], lighting)
    assert float(count) > 100000
    # the flat-shaded irradiance steps at mesh edges where the ray-cast photo ramps: it fits worse
    assert float(cost) < 0.2 * float(_cost(truth, cams, photos["constant"], lighting, "flat")[0])


def test_gradient_matches_finite_differences_float64(scene):
    cams, photos, lighting = scene
    with jax.enable_x64(True):
        mesh = torus(1.0, 0.33, 32, 16, dtype=np.float64)
        cams64 = jg.sphere_cameras(3, radius=3.0, fov_deg=40.0, resolution=48)
        tm = torus_trimesh(1.0, 0.35, 32, 16)
        target = raycast_lambert(cams64, tm, light_direction=LIGHT, ambient=AMBIENT, albedo=cells)
        target = jnp.asarray(np.concatenate([target[..., :3] * target[..., 3:], target[..., 3:]], -1), jnp.float64)
        lt = jnp.asarray(lighting, jnp.float64)

        @jax.jit  # one program each for the value and the gradient, not an op-by-op trace
        def f(x):
            m = jg.Mesh(x, mesh.faces, mesh.n_vertices, mesh.n_faces)
            return _cost(m, cams64, target, lt)[0]

        g = jax.jit(jax.grad(f))(mesh.vertices)
        assert float(jnp.linalg.norm(g)) > 0
        rng = np.random.default_rng(0)
        for _ in range(3):
            d = jnp.asarray(rng.normal(size=mesh.vertices.shape)) * mesh.vertex_mask[:, None]
            eps = 1e-6
            fd = float((f(mesh.vertices + eps * d) - f(mesh.vertices - eps * d)) / (2 * eps))
            an = float(jnp.sum(g * d))
            assert abs(fd - an) <= 0.03 * abs(an) + 1e-9, (fd, an)


def test_nothing_to_compare_gives_zero_not_nan(scene):
    cams, photos, lighting = scene
    mesh = torus(1.0, 0.35, 64, 32)
    dark = photos["cells"].at[..., :3].set(0.0)  # under the dark floor everywhere
    empty = jnp.zeros_like(photos["cells"])  # no mask
    for target in (dark, empty):
        cost, count = _cost(mesh, cams, target, lighting)
        assert float(cost) == 0.0 and float(count) == 0.0
        g = jax.grad(lambda x: _cost(jg.Mesh(x, mesh.faces, mesh.n_vertices, mesh.n_faces), cams, target,
                                     lighting)[0])(mesh.vertices)
        assert bool(jnp.all(jnp.isfinite(g)))
    with pytest.raises(ValueError, match="offset"):
        shading_ratio_cost(jnp.ones((1, 4, 4)), jnp.ones((1, 4, 4, 3)), jnp.ones((1, 4, 4, 4)), offset=0)


def test_the_objective_counts_pairs_near_albedo_edges_only(scene):
    """Where the albedo is smooth the photometric term sees the shading itself: no ratio there."""
    cams, photos, lighting = scene
    mesh = torus(1.0, 0.33, 64, 32)
    albedo = jnp.full((mesh.vertex_capacity, 3), 0.5, jnp.float32)
    w = jg.LossWeights(shading_ratio=1.0, photo=0.0, alpha=0.0, inversion=0.0, albedo_smoothness=0.0)
    terms = {name: jg.optim.objective(mesh, cams, photos[name], mesh.vertices, weights=w, appearance=(albedo, lighting))[1]
             for name in ("cells", "constant")}
    # a constant albedo marks few pixels (inner contours, where the torus hides itself)
    assert float(terms["constant"]["shading_ratio"]) < 0.1 * float(terms["cells"]["shading_ratio"]), terms
    near = jg.optim.albedo_edges(photos["cells"], band=jg.optim.RATIO_BAND)
    full, n_all = _cost(mesh, cams, photos["cells"], lighting)
    e = jnp.maximum(jg.rendering.irradiance(jg.geometry.vertex_normals(mesh), lighting), 0)
    img = jg.render(mesh, cams, channels=("alpha", "color"), vertex_colors=e)
    part, n_near = shading_ratio_cost(img[..., 0], img[..., 1:4], photos["cells"], where=near)
    assert float(terms["cells"]["shading_ratio"]) == pytest.approx(float(part), rel=1e-5)
    assert 0 < float(n_near) < float(n_all)


def test_fine_textures_turn_the_term_on(scene):
    """`reconstruct` gives photos whose albedo edges cover FINE_TEXTURE of the masks the term
    (`ReconstructOptions.fine_texture`); a constant albedo's few edges (inner contours) do not."""
    from jaxgenus.pipeline._setup import FINE_TEXTURE, texture_share

    _, photos, _ = scene
    assert texture_share(photos["cells"]) >= FINE_TEXTURE  # 11-px cells: 34 % of the pixels on a jump
    assert texture_share(photos["constant"]) < 0.1 * FINE_TEXTURE


def test_fine_textures_weigh_the_silhouettes_more(scene):
    """For photos of a fine texture the fit takes `TEXTURE_SETTINGS`: it raises the silhouette weight,
    lowers the photometric weight, turns shading ratios on, compares them unblurred, weighs the stereo
    depths more, closes with two
    polish cycles, runs five cycles and remeshes curvature-adaptively, each only where the caller did
    not name the setting (a default named holds too); smooth photos keep all, and so do cells the
    finest level fitted blurs (the share is measured on the images the fit sees)."""
    from jaxgenus.optim import pyramid_level
    from jaxgenus.pipeline._setup import FINE_TEXTURE, TEXTURE_SETTINGS, fine_texture, texture_share

    cams, photos, _ = scene
    base, polish, adaptive, cycles, stereo = jg.ReconstructOptions(), [], [], [], []

    def weights(name, options, factor=1):
        lines, level = [], photos[name] if isinstance(name, str) else name
        level = level if factor == 1 else pyramid_level(level, factor)
        fitted = fine_texture(options, "photo", level, lines.append)
        w = fitted.optimize.weights
        polish.append(fitted.polish_cycles)
        adaptive.append(fitted.remesh_options.adaptive)
        cycles.append(fitted.n_cycles)
        stereo.append(w.stereo)
        return w.alpha, w.shading_ratio, w.consistency_blur, w.photo, lines

    alpha, ratio, blur, photo, said = weights("cells", base)
    t = TEXTURE_SETTINGS
    assert (alpha, ratio, blur, photo) == (t["alpha"], t["shading_ratio"], t["consistency_blur"], t["photo"]) == (4.0, 6.0, 0.0, 1.0)
    assert len(said) == 1 and all(s in said[0] for s in ("alpha=4.0", "shading_ratio=6.0", "consistency_blur=0.0",
                                                         "photo=1.0", "polish_cycles=2", "stereo=16.0",
                                                         "adaptive=True", "n_cycles=5")), said
    assert polish[-1] == t["polish_cycles"] == 2 and base.polish_cycles == 0
    assert adaptive[-1] and not base.remesh_options.adaptive
    assert cycles[-1] == t["n_cycles"] == 5 and base.n_cycles == 4
    assert stereo[-1] == t["stereo"] == 16.0 and base.optimize.weights.stereo == 1.0
    # photos that resolve 4x the budget's faces or more (a DTU-class capture) keep the cycles as set
    detailed = fine_texture(base, "photo", photos["cells"], print, 4 * base.face_budget)
    assert detailed.n_cycles == 4 and detailed.polish_cycles == t["polish_cycles"]
    assert fine_texture(base, "photo", photos["cells"], print, 4 * base.face_budget - 1).n_cycles == 5
    kept = base.updated(alpha=2.0, shading_ratio=1.5, consistency_blur=0.5, photo=3.0, polish_cycles=1, adaptive=True)
    kept = kept.updated(n_cycles=3)
    kept = kept.updated(stereo=2.0)
    assert weights("cells", kept) == (2.0, 1.5, 0.5, 3.0, []) and polish[-1] == 1 and cycles[-1] == 3  # the caller's
    assert stereo[-1] == 2.0
    defaults = base.updated(alpha=1.0, shading_ratio=0.0, consistency_blur=1.0, photo=6.0, polish_cycles=0,
                            adaptive=False, n_cycles=4, stereo=1.0)  # the defaults, named: held
    assert weights("cells", defaults) == (1.0, 0.0, 1.0, 6.0, []) and polish[-1] == 0 and not adaptive[-1]
    assert cycles[-1] == 4
    off = base.updated(fine_texture=False)
    assert weights("cells", off) == (1.0, 0.0, 1.0, 6.0, []) and polish[-1] == 0 and not adaptive[-1]
    assert cycles[-1] == 4
    assert weights("cells", base.updated(consistency=0.0))[2] == 1.0 and polish[-1] == 0  # no term: no polish
    assert weights("cells", base.replaced(stereo=0.0))[0] == 4.0 and stereo[-1] == 0.0  # off stays off
    assert weights("constant", base) == (1.0, 0.0, 1.0, 6.0, []) and polish[-1] == 0 and not adaptive[-1]
    assert cycles[-1] == 4
    # the same cells at 4x the size (44 px): few pixels on an edge; fitted at 1/4 they are fine again
    big = jnp.repeat(jnp.repeat(photos["cells"], 4, axis=1), 4, axis=2)
    assert texture_share(big) < 0.5 * FINE_TEXTURE
    assert weights(big, base)[:4] == (1.0, 0.0, 1.0, 6.0) and weights(big, base, factor=4)[:4] == (4.0, 6.0, 0.0, 1.0)
    assert fine_texture(base, "normals", photos["cells"], print) is base


def test_fine_textures_get_the_face_budget_their_photos_resolve(scene):
    """Photos of a fine texture that resolve fewer faces than `max_faces` (edges of 4 px on the visual
    hull) fit with that many, to no less than `TEXTURE_FACES` of the budget (said); smooth photos,
    and a budget given by name, keep it."""
    from jaxgenus.pipeline._setup import prepare

    cams, photos, _ = scene
    base, said = jg.ReconstructOptions(initial_faces=500).replaced(max_faces=30000), []
    fitted = prepare(photos["cells"], cams, 1, "photo", base, said.append)
    assert 0 < fitted.resolved < 30000, fitted.resolved
    budget = fitted.options.face_budget
    assert budget == max(20000, fitted.resolved // 1000 * 1000) < 30000 and base.face_budget == 30000
    assert any(line.startswith(f"face budget: {budget} faces (photos of a fine texture") for line in said), said
    assert prepare(photos["constant"], cams, 1, "photo", base, print).options.face_budget == 30000
    assert prepare(photos["cells"], cams, 1, "photo", base.updated(max_faces=30000), print).options.face_budget == 30000


def test_stereo_carves_only_photos_of_a_fine_texture(scene):
    """Plane-sweep stereo carves the start only from photos of a fine texture (smooth shading can make two
    views agree on a wrong depth); the stereo depth term stays on for both."""
    from jaxgenus.pipeline._setup import prepare

    cams, photos, _ = scene
    for name, carves in (("cells", True), ("constant", False)):
        lines = []
        setup = prepare(photos[name], cams, 1, "photo", jg.ReconstructOptions(fine_below=0.0), lines.append)
        setup.hulls.occupancy(48)  # the carving runs when a hull is first built
        said = [x for x in lines if x.startswith("stereo")]
        assert len(said) == 1 and ("no carving" not in said[0]) == carves, said
        assert setup.stereo is not None


def test_the_polish_smooths_by_its_own_lambda():
    """The polish cycles run with `POLISH_LAMBDA` (less smoothing than the cycles' `lambda_`, which
    keep theirs), `POLISH_AVERAGE` and the cycles' silhouette weight."""
    from types import SimpleNamespace

    from jaxgenus.pipeline._cycles import POLISH_AVERAGE, POLISH_LAMBDA, _polish_options

    level = SimpleNamespace(valid=None, crop=0)
    base = jg.ReconstructOptions()
    assert base.optimize.lambda_ == 19.0 and POLISH_LAMBDA == 5.0 and POLISH_AVERAGE == 0.99
    polished = _polish_options(base.updated(alpha=4.0), level, None)
    assert polished.lambda_ == 5.0 and polished.weights.alpha == 4.0  # the cycles' silhouette weight
    opts = base.updated(lambda_=30.0)
    polished = _polish_options(opts, level, None)
    assert polished.lambda_ == 5.0 and opts.optimize.lambda_ == 30.0
    assert polished.weights.photo == 0.0 and polished.average == 0.99


def test_the_plan_takes_the_fine_texture_settings_once(scene):
    """The fine-texture settings are chosen once, by the plan, from the photos of the finest level it
    fits (`planned`): the plan names the choice and its settings, and the options the fits run are the
    plan's; smooth photos plan the defaults."""
    from jaxgenus.pipeline._schedule import planned
    from jaxgenus.pipeline._setup import TEXTURE_SETTINGS, prepare

    cams, photos, _ = scene
    lines = []
    setup = planned(prepare(photos["cells"], cams, 1, "photo", jg.ReconstructOptions(), print), True, lines.append)
    plan = setup.plan
    assert lines[0].startswith("plan: 24 views") or lines[0].startswith(f"plan: {len(cams)} views"), lines
    assert all(line.startswith("plan: ") for line in lines)
    assert any(c.startswith("fine texture:") for c in plan.choices), plan.choices
    assert plan.scene["texture_share"] >= 0.3 and plan.scene["targets"] == "photo"
    assert setup.options.optimize.weights.shading_ratio == TEXTURE_SETTINGS["shading_ratio"]
    assert plan.settings["shading_ratio"] == TEXTURE_SETTINGS["shading_ratio"] and "normal" not in plan.settings
    assert plan.settings["n_cycles"] == setup.options.n_cycles == len(plan.factors)
    smooth = planned(prepare(photos["constant"], cams, 1, "photo", jg.ReconstructOptions(), print), True, print)
    assert not any(c.startswith("fine texture:") for c in smooth.plan.choices)
    assert "shading_ratio" not in smooth.plan.settings and smooth.options.n_cycles == 4
