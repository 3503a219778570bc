"""`ReconstructOptions`: every setting of `reconstruct`, validated, with its presets.

The options compose: the optimizer's settings are an `OptimizeOptions` (which holds the
`LossWeights` and the `RenderSettings`), the remesher's a `RemeshOptions`; this class
adds only what the pipeline itself decides (schedule, start, resolution, verdict, refits).
`updated(name=value, ...)` changes any of them by its own name.
"""

from __future__ import annotations

import dataclasses
import math

from jaxgenus.geometry import settings_repr, RemeshOptions
from jaxgenus.optim import LossWeights, OptimizeOptions, resolution_factors
from jaxgenus.rendering import RenderSettings

__all__ = ["ReconstructOptions"]


#: A setting given by name (`ReconstructOptions.holding`) holds: these automatic choices, which would
#: change it during a run, are then off (the fine-texture rules of `pipeline._setup.fine_texture`,
#: the photos' detail budget; `stereo=0` also turns off the stereo carving of the start).
HELD_BY = {
    "n_cycles": {"texture_cycles": 0},
    "shading_ratio": {"texture_ratio": 0.0},
    "polish_cycles": {"texture_polish": 0},
    "alpha": {"texture_alpha": 0.0},
    "photo": {"texture_photo": 0.0},
    "consistency_blur": {"texture_blur": LossWeights().consistency_blur},
    "adaptive": {"texture_adaptive": False},
    "max_faces": {"detail_faces": 0, "texture_faces": 1.0},
    "stereo": {"stereo_carve": 0.0},
}


def _positive_int(name, v, minimum=1):
    if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
        raise ValueError(f"options.{name} must be an int >= {minimum}, got {v!r}")


def _number(name, v, lo, hi, *, open_lo=False):
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    ok = ok and (v > lo if open_lo else v >= lo) and v <= hi
    if not ok:
        raise ValueError(f"options.{name} must be a number in {'(' if open_lo else '['}{lo}, {hi}], got {v!r}")


def _choice(name, v, allowed):
    if v not in allowed:
        raise ValueError(f"options.{name} must be one of {', '.join(map(repr, allowed))}, got {v!r}")


@dataclasses.dataclass(frozen=True, repr=False)
class ReconstructOptions:
    """Settings of `reconstruct` (immutable). Edge lengths are in pixels (see below).

    Attributes:
        n_cycles: optimize/remesh cycles; the last one is not followed by a remesh.
        steps_per_cycle: optimizer steps per cycle.
        lr_decay: the step is `optimize.learning_rate * lr_decay ** cycle` (coarse to fine;
            no recompile).
        optimize: `OptimizeOptions` of every optimizer block: step size, smoothing
            (`lambda_`), uniform Adam's quantile, iterate averaging, views per step,
            `LossWeights`, `RenderSettings` (`sigma`, `gamma`; None: the renderer's defaults),
            albedo and lighting steps of photo fits, and `crop` (the native cycles of the
            resolution schedule fit random `crop x crop` windows centred in the
            silhouettes; 0: whole images).
        remesh: `RemeshOptions` of the remeshes between cycles (`adaptive`, `iterations`,
            `max_faces`: the face budget, which picks the run's capacity bucket; the remeshes
            between cycles may use that bucket whole); None keeps the connectivity (Nicolet's
            baseline; the budget is then `initial_faces`). `target_edge_length` is set by the
            schedule below.
        initial_faces: face count of the starting primitive.
        initial_edge_length, final_edge_length: remesh targets of the first and the last
            remesh (geometric in between: coarse to fine), in pixels: one pixel is the
            median over the cameras of the world-space footprint of a pixel at the
            visual hull's centre, so the mesh is as fine as the images resolve.
        start: `"auto"` (the silhouettes' visual hull when its largest component has the
            requested genus at one of `hull_resolutions`, possibly after closing
            thin spurious tunnels; when it has fewer handles, the missing ones are
            added as small tunnels under its surface; else the genus-g primitive),
            `"primitive"` (always the genus-g primitive) or `"sphere"` (genus 0).
        hull_resolutions: grid sizes tried, in order, for the visual-hull start.
        fine_below: thin-structure switch: when the silhouettes' visual hull (grid
            `hull_resolutions[0]`, largest piece) is thinner than this many pixels of the
            level the first cycles fit, as `2 * volume / area` (a slab's thickness, a
            tube's radius), `reconstruct` runs with `self.fine()` instead
            (`history["fine"]`, `Reconstruction.options`). 0 turns it off.
        min_view_iou: the verdict's threshold: a run whose silhouette IoU (result against
            target, both at alpha 0.5) is under this in any view is not ok.
        outlier_gap: the verdict's test of views that disagree with the rest: a view
            whose IoU is this far under the median of the views makes the run not ok.
        max_photo_error: photo targets: the verdict fails when the median over the views
            of the mean absolute RGB error (result rendered with its albedo and
            lighting, against the photos) is above this.
        downsample: fit copies of the images area-averaged over `downsample x downsample`
            blocks, with the cameras scaled to match (1: the images as they are): speed over
            detail; the verdict then judges those copies.
        coarse_resolution, native_cycles: the resolution schedule for images of any
            size. When the images' longer side is at least 1.5 x `coarse_resolution`,
            all but the last `native_cycles` cycles fit copies area-averaged by a power
            of two to about `coarse_resolution` pixels (edge lengths in those pixels),
            and the last ones fit the images at their own resolution.
            `coarse_resolution = 0` fits every cycle at full size.
        devices: the devices (of the default backend; every process's when processes were joined by
            `jax.distributed`) the views are split over: None (the default) all of them, 1 one. With several, each device renders and differentiates its own
            views every step (`jaxgenus.optim._devices`), the mesh and optimizer state replicated
            (`history["devices"]`). At most one device per view.
        one_jit: run all cycles (optimizer blocks and FFI remeshes) as one jit-compiled
            `lax.scan` with one rasterizer plan sized for the final face count, instead of
            one compiled block per cycle driven from Python. One compilation per run;
            `callback` is then called after the run, once per cycle.
        lighting: photo targets: the lighting model, `"sh"` (spherical harmonics of
            order <= 4: any smooth distant light) or `"directional"` (one lamp plus
            ambient, exact); `jaxgenus.irradiance`, docs/photometric.md.
        hidden_handles: handles the visual hull lacks (holes no silhouette shows):
            `"images"` (normal targets) first fits the hull's genus, then opens holes
            where that fit's normals disagree with the targets and the image loss drops
            (`jaxgenus.open_handles`), drilling only what the images do not show; `"drill"`
            drills them all as small tunnels at spread-out sites.
        refits: fits after the first, each started from the previous result (remeshed to
            the first edge length, the optimizer and its step size reset) with the same
            settings; None (the default): `refit_count`, up to two for normal maps
            fitted through the resolution schedule, else none; the second only when the
            first lowered the mean normal error by 3 % or more. A refit that fits the
            images worse than its start is dropped (a warning says so). Refits carve
            concavities that few cameras see (docs/reconstruction.md).
        refit_carve: `LossWeights.carve` in refits of normal maps (when
            `optimize.weights.carve` is 0): the visible surface moves away from the camera
            where its normal is more than 37 degrees from the image's
            (`jaxgenus.carving_term`). A carving refit that fits the images worse is
            dropped and the next refit runs without carving. 0 turns it off.
        detail_faces: photo targets fitted with photo-consistency: when the photos resolve 4 x
            `max_faces` or more (faces with edges of 4 px on the visual hull), the face budget
            rises towards that, to at most this many (time and memory grow with it). 0, or any
            value not above `max_faces`, holds the budget at `max_faces`.
        texture_ratio: photo targets whose albedo edges (`jaxgenus.optim.albedo_edges`) cover
            `FINE_TEXTURE` (30 %) of the masks or more in the finest images a fit sees (a texture
            finer than the mesh's albedo holds) are fitted with `LossWeights.shading_ratio` at this
            weight when it is 0. 0: never.
        texture_alpha: the silhouette weight (`LossWeights.alpha`) for photos of such a fine texture,
            when it is at its default (1): where shading cannot explain the photos, the outline the
            masks give weighs more. 0: never.
        texture_blur: `LossWeights.consistency_blur` for photos of such a fine texture, when it is at
            its default (1): compared unblurred (0), as a blur in each photo's own pixels biases NCC
            where two views foreshorten the texture differently. 1: blurred as other photos.
        texture_photo: the photometric weight (`LossWeights.photo`) for photos of such a fine texture,
            when it is at its default (6): a per-vertex albedo cannot hold the texture, and
            photo-consistency does better with less shading. 0: never.
        stereo_carve: photo targets on one device: the visual hull loses the space that plane-sweep
            stereo (`jaxgenus.capture.stereo_depths`) shows to be empty, in front of depths two views
            agree on, by `stereo_carve` grid cells or more, so the start has the concavities no
            silhouette shows. Only for photos of a fine texture at the stereo size. 0: off.
        polish_cycles: photo targets fitted with photo-consistency (one device): after the cycles,
            this many more cycles at the finest level, without remeshing, on the silhouettes
            (`polish_alpha`) and colour photo-consistency only, with fresh moments and iterate
            averaging (`polish_average`). 0 (default): none, but see `texture_polish`.
        texture_polish: `polish_cycles` for photos of such a fine texture, when it is 0. 0: never.
        texture_adaptive: photos of such a fine texture are remeshed curvature-adaptively
            (`RemeshOptions.adaptive`) when it is off. False: as set.
        texture_faces: photos of such a fine texture (at full size) that resolve fewer faces than
            `max_faces` get a budget lowered to that count, to no less than this share of
            `max_faces`. 1: `max_faces` as set.
        texture_cycles: `n_cycles` for photos of such a fine texture, when it is at its default (4),
            where the photos resolve fewer than 4 x the faces of the budget. 0, or any value not above
            `n_cycles`: as set.
        polish_lambda: the large-steps `lambda_` of the polish cycles (less smoothing than the
            cycles' `optimize.lambda_`, so photo-consistency can sharpen creases).
        polish_alpha: the polish's silhouette weight; None: the cycles'.
        polish_average: the polish's iterate averaging (`OptimizeOptions.average`: about the last
            `1 / (1 - polish_average)` steps of each polish cycle).
        subdivide: a result whose median edge is longer than `SUBDIVIDE_EDGE_PX` (2) pixels at the
            images' own size goes through one `phong_subdivision` (4x the faces, the albedo carried):
            flat faces are chords that cut under curved parts by about k h^2 / 8, and the new
            vertices sit on the smooth surface through the fitted ones. A finer result is kept as
            fitted (the images hold no finer detail). The verdict judges the mesh returned. False:
            never (`nicolet()` sets it).
        fill_unseen: photo targets: before the subdivision, the vertices no camera sees (though
            some holds them in frame) move onto the membrane the seen surface spans around them
            (`jaxgenus.geometry.fill_unseen`). False: off.
        fit_outline: when the finest level fitted is coarser than the images, the result's outline
            moves onto the masks at their own size (`jaxgenus.geometry.fit_outline`). False: off.
        fit_photo_depth: photo targets, when the finest level fitted is coarser than the images:
            after the outline, the surface moves along its normals to where the photos at their
            own size agree (`jaxgenus.geometry.fit_photo_depth`); the outline stays. False: off.
        depth_edge_px: before the outline and the sweep, more Phong subdivisions while the median
            edge at the images' own size is longer than this many pixels (at most 2^20 faces): the
            sweep measures a vertex's depth from a 13-pixel square. 0: no more subdivision.

    What each default bought is in docs/results.md.
    """

    def __repr__(self) -> str:
        return settings_repr(self)


    n_cycles: int = 4
    steps_per_cycle: int = 150
    lr_decay: float = 0.5
    optimize: OptimizeOptions = OptimizeOptions()
    remesh: RemeshOptions | None = RemeshOptions(iterations=3, max_faces=12000)
    initial_faces: int = 2000
    initial_edge_length: float = 2.0
    final_edge_length: float = 1.4
    start: str = "auto"
    hull_resolutions: tuple[int, ...] = (64, 48, 80)
    fine_below: float = 3.0
    min_view_iou: float = 0.8
    outlier_gap: float = 0.15
    max_photo_error: float = 0.1
    downsample: int = 1
    coarse_resolution: int = 128
    native_cycles: int = 1
    devices: int | None = None
    one_jit: bool = False
    lighting: str = "sh"
    hidden_handles: str = "images"
    refits: int | None = None
    refit_carve: float = 1.0
    detail_faces: int = 40000
    texture_ratio: float = 6.0
    texture_alpha: float = 4.0
    texture_blur: float = 0.0
    texture_photo: float = 1.0
    stereo_carve: float = 2.0
    polish_cycles: int = 0
    texture_polish: int = 2
    texture_adaptive: bool = True
    texture_faces: float = 2.0 / 3.0
    texture_cycles: int = 5
    polish_lambda: float = 5.0
    polish_alpha: float | None = None
    polish_average: float = 0.99
    subdivide: bool = True
    fill_unseen: bool = True
    fit_outline: bool = True
    fit_photo_depth: bool = True
    depth_edge_px: float = 8.0

    def __post_init__(self):
        for name in ("n_cycles", "steps_per_cycle", "initial_faces", "downsample"):
            _positive_int(name, getattr(self, name))
        for name in ("coarse_resolution", "native_cycles", "detail_faces", "polish_cycles",
                     "texture_polish", "texture_cycles"):
            _positive_int(name, getattr(self, name), 0)
        if self.refits is not None:
            _positive_int("refits", self.refits, 0)
        if self.devices is not None:
            _positive_int("devices", self.devices)
        _number("lr_decay", self.lr_decay, 0.0, 1.0, open_lo=True)
        for name in ("initial_edge_length", "final_edge_length"):
            _number(name, getattr(self, name), 0.0, math.inf, open_lo=True)
        for name in ("refit_carve", "fine_below", "texture_ratio", "texture_alpha", "texture_photo", "stereo_carve",
                     "polish_lambda", "depth_edge_px"):
            _number(name, getattr(self, name), 0.0, math.inf)
        if self.polish_alpha is not None:
            _number("polish_alpha", self.polish_alpha, 0.0, math.inf)
        _number("polish_average", self.polish_average, 0.0, 0.999)
        for name in ("min_view_iou", "outlier_gap", "max_photo_error", "texture_blur", "texture_faces"):
            _number(name, getattr(self, name), 0.0, 1.0)
        for name in ("subdivide", "fill_unseen", "fit_outline", "fit_photo_depth"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"options.{name} must be True or False, got {getattr(self, name)!r}")
        if not isinstance(self.texture_adaptive, bool):
            raise ValueError(f"options.texture_adaptive must be True or False, got {self.texture_adaptive!r}")
        _choice("hidden_handles", self.hidden_handles, ("images", "drill"))
        _choice("lighting", self.lighting, ("sh", "directional"))
        _choice("start", self.start, ("auto", "primitive", "sphere"))
        if not all(isinstance(r, int) and r >= 8 for r in self.hull_resolutions):
            raise ValueError(f"options.hull_resolutions must be ints >= 8, got {self.hull_resolutions!r}")
        if not isinstance(self.optimize, OptimizeOptions):
            raise ValueError(f"options.optimize must be an OptimizeOptions, got {type(self.optimize).__name__}")
        if self.remesh is not None:
            if not isinstance(self.remesh, RemeshOptions):
                raise ValueError(f"options.remesh must be a RemeshOptions or None, got {type(self.remesh).__name__}")
            if self.remesh.max_faces is None:
                raise ValueError("options.remesh.max_faces must be set: it is the run's face budget")
        if self.face_budget < self.initial_faces:
            raise ValueError("options.remesh.max_faces must be >= options.initial_faces")

    @property
    def face_budget(self) -> int:
        """Faces the run may reach (`remesh.max_faces`; `initial_faces` without remeshing)."""
        return self.initial_faces if self.remesh is None else int(self.remesh.max_faces)

    @property
    def render(self) -> RenderSettings:
        """The renderer's settings of the fits and the verdict (`optimize.render`, or the defaults)."""
        return self.optimize.render if self.optimize.render is not None else RenderSettings()

    def updated(self, **settings) -> "ReconstructOptions":
        """A copy with settings changed by their own names, wherever they live: a field of
        this class, of `optimize`, of its `weights` (`LossWeights`) or `render`
        (`RenderSettings`), or of `remesh` (no name repeats across them), e.g.
        `ReconstructOptions().updated(learning_rate=0.05, sigma=0.03, adaptive=True, max_faces=30000)`."""
        own = {f.name for f in dataclasses.fields(self)}
        parts = {"optimize": OptimizeOptions, "weights": LossWeights, "render": RenderSettings, "remesh": RemeshOptions}
        changes = {"": {}, **{k: {} for k in parts}}
        for name, value in settings.items():
            where = "" if name in own else next((k for k, cls in parts.items()
                                                  if name in {f.name for f in dataclasses.fields(cls)}), None)
            if where is None:
                raise ValueError(f"options: no setting named {name!r}")
            changes[where][name] = value
        out = dict(changes[""])
        opt = out.get("optimize", self.optimize)
        if changes["weights"]:
            changes["optimize"]["weights"] = dataclasses.replace(opt.weights, **changes["weights"])
        if changes["render"]:
            base = opt.render if opt.render is not None else RenderSettings()
            changes["optimize"]["render"] = dataclasses.replace(base, **changes["render"])
        if changes["optimize"]:
            out["optimize"] = dataclasses.replace(opt, **changes["optimize"])
        if changes["remesh"]:
            base = out.get("remesh", self.remesh)
            if base is None:
                raise ValueError(f"options: {sorted(changes['remesh'])} set on a run without remeshing (remesh=None)")
            out["remesh"] = dataclasses.replace(base, **changes["remesh"])
        return dataclasses.replace(self, **out)

    def holding(self, **settings) -> "ReconstructOptions":
        """`updated(**settings)` with each setting named held as given: the automatic choices that
        would change it later in a run are off (`HELD_BY`: `n_cycles=4` stays 4 for photos of a fine
        texture, `max_faces` is not raised for detailed photos, `stereo=0` also skips the stereo
        carving of the start). What the command line's `--option` and `--max-faces` apply."""
        change = dict(settings)
        for name, value in settings.items():
            for rule, off in HELD_BY.get(name, {}).items():
                if rule not in settings and (name != "stereo" or not value):
                    change[rule] = off
        if isinstance(settings.get("max_faces"), int) and "initial_faces" not in settings:
            change["initial_faces"] = min(self.initial_faces, int(settings["max_faces"]))
        if self.remesh is None:  # no remeshing (nicolet()): the start's faces are the budget
            change.pop("max_faces", None)
        return self.updated(**change)

    @classmethod
    def nicolet(cls, **settings) -> "ReconstructOptions":
        """Nicolet et al. 2021: sphere start, no remeshing, same renderer, their uniform Adam (the max),
        the result as fitted (no `subdivide`)."""
        return cls(start="sphere", remesh=None, subdivide=False).updated(adam_quantile=1.0, **settings)

    def fine(self) -> "ReconstructOptions":
        """A copy set up for thin structures a few pixels wide (e.g. sheets 2 px thick).

        `reconstruct` switches to it by itself when the visual hull is thinner than
        `fine_below` pixels. Sharper edges (`sigma` 0.03 px: the outward tails of the
        contour faces at the default 0.1 bias thin silhouettes out), a finer mesh (1.4 ->
        1.0 px edges, up to 20k faces), 5 cycles with a slow step decay (0.9) and iterate
        averaging (`average` 0.95: the step noise of the sampled views limits sheets under
        2 px thick). About twice the time of the defaults; on thick shapes no better
        (docs/reconstruction.md). `ReconstructOptions.nicolet().fine()` is the baseline at
        the same renderer, schedule and averaging.
        """
        more = {} if self.remesh is None else {"max_faces": max(self.face_budget, 20000)}
        return self.updated(sigma=0.03, lr_decay=0.9, average=0.95, n_cycles=5, initial_edge_length=1.4,
                            final_edge_length=1.0, **more)

    def for_refit(self, targets: str) -> "ReconstructOptions":
        """The options of a refit of `targets`: carving (`refit_carve`) switched on for normal maps
        when the weights do not set it already."""
        if targets == "normals" and self.refit_carve and not self.optimize.weights.carve:
            return self.updated(carve=self.refit_carve)
        return self

    def refit_count(self, height: int, width: int, targets: str = "normals") -> int:
        """Refits a run on `height x width` images of `targets` makes: `refits`, or when it
        is None, at most 2 for normal-map targets fitted through the resolution schedule
        (downsampled in the first cycles) and 0 otherwise (images fitted at their own
        size; silhouettes, which show no concavity to carve; photos, not measured)."""
        if self.refits is not None:
            return self.refits
        scheduled = resolution_factors(height, width, 1, self.coarse_resolution, 0)[0] > 1
        return 2 if scheduled and targets == "normals" else 0

    def edge_lengths(self) -> list[float]:
        """Target edge length of each remesh in pixels (coarse to fine); none without remeshing."""
        n = self.n_cycles - 1 if self.remesh is not None else 0
        if n <= 0:
            return []
        if n == 1:
            return [self.final_edge_length]
        r = (self.final_edge_length / self.initial_edge_length) ** (1.0 / (n - 1))
        return [self.initial_edge_length * r**i for i in range(n)]
