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
            (`history["fine"]`, `Reconstruction.options`; the settings in `held` keep their values).
            0 turns it off.
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
        fine_texture: photo targets whose albedo edges (`jaxgenus.optim.albedo_edges`) cover
            `FINE_TEXTURE` (30 %) of the masks or more in the finest images a fit sees (a texture
            finer than the mesh's albedo holds) get `pipeline._setup.TEXTURE_SETTINGS` (shading ratios
            on, the silhouettes weighed more, the photometric term less, photo-consistency unblurred,
            two polish cycles, five cycles, adaptive remeshing) for each of those settings not in
            `held`, and a face budget lowered to what they resolve unless `max_faces` is held.
            False: never.
        held: the names of the settings given by name (`updated`, the CLI's `--option`):
            no automatic choice of the run changes them (the fine-texture settings, the photos'
            detail budget, the thin-structure switch to `fine()`).
        polish_cycles: photo targets fitted with photo-consistency (one device): after the cycles,
            this many more cycles at the finest level, without remeshing, on the silhouettes
            and colour photo-consistency only, with fresh moments, less smoothing and iterate
            averaging (`pipeline._cycles.POLISH_LAMBDA`, `POLISH_AVERAGE`). 0 (default): none, but
            see `fine_texture`.
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
    stereo_carve: float = 2.0
    polish_cycles: int = 0
    subdivide: bool = True
    fill_unseen: bool = True
    fit_outline: bool = True
    fit_photo_depth: bool = True
    depth_edge_px: float = 8.0
    fine_texture: bool = True
    held: frozenset = frozenset()

    def __post_init__(self):
        for name in ("n_cycles", "steps_per_cycle", "initial_faces", "downsample"):
            _positive_int(name, getattr(self, name))
        for name in ("coarse_resolution", "native_cycles", "detail_faces", "polish_cycles"):
            _positive_int(name, getattr(self, name), 0)
        if self.refits is not None:
            _positive_int("refits", self.refits, 0)
        if self.devices is not None:
            _positive_int("devices", self.devices)
        _number("lr_decay", self.lr_decay, 0.0, 1.0, open_lo=True)
        for name in ("initial_edge_length", "final_edge_length"):
            _number(name, getattr(self, name), 0.0, math.inf, open_lo=True)
        for name in ("refit_carve", "fine_below", "stereo_carve", "depth_edge_px"):
            _number(name, getattr(self, name), 0.0, math.inf)
        for name in ("min_view_iou", "outlier_gap", "max_photo_error"):
            _number(name, getattr(self, name), 0.0, 1.0)
        for name in ("subdivide", "fill_unseen", "fit_outline", "fit_photo_depth", "fine_texture"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"options.{name} must be True or False, got {getattr(self, name)!r}")
        unknown = sorted(n for n in self.held if not isinstance(n, str) or n not in _setting_names())
        if not isinstance(self.held, frozenset) or unknown:
            raise ValueError(f"options.held must be a frozenset of setting names, got {self.held!r}")
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
        `ReconstructOptions().updated(learning_rate=0.05, sigma=0.03, adaptive=True, max_faces=30000)`.

        Every setting named is held as given (added to `held`): no automatic choice of the run
        changes it, also when it is the default (`updated(n_cycles=4)` stays 4 for photos of a
        fine texture; `max_faces` is not raised for detailed photos). `stereo=0` also turns off
        the stereo carving of the start, and a `max_faces` under `initial_faces` lowers that.
        The command line's `--option NAME=VALUE` and `--max-faces` are this."""
        change = dict(settings)
        if not settings.get("stereo", 1) and "stereo_carve" not in settings:
            change["stereo_carve"] = 0.0
        if isinstance(settings.get("max_faces"), int) and "initial_faces" not in settings:
            change["initial_faces"] = min(self.initial_faces, settings["max_faces"])
        if "held" not in settings:
            change["held"] = self.held | frozenset(settings)
        return self.replaced(**change)

    def replaced(self, **settings) -> "ReconstructOptions":
        """`updated` without holding what it names: the run's own choices (presets, the
        fine-texture settings, the detail budget) go through this."""
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

    @classmethod
    def nicolet(cls, **settings) -> "ReconstructOptions":
        """Nicolet et al. 2021: sphere start, no remeshing, same renderer, their uniform Adam (the max),
        the result as fitted (no `subdivide`)."""
        return cls().replaced(start="sphere", remesh=None, subdivide=False, adam_quantile=1.0).updated(**settings)

    def fine(self) -> "ReconstructOptions":
        """A copy set up for thin structures a few pixels wide (e.g. sheets 2 px thick).

        `reconstruct` switches to it by itself when the visual hull is thinner than
        `fine_below` pixels. Sharper edges (`sigma` 0.03 px: the outward tails of the
        contour faces at the default 0.1 bias thin silhouettes out), a finer mesh (1.4 ->
        1.0 px edges, up to 20k faces), 5 cycles with a slow step decay (0.9) and iterate
        averaging (`average` 0.95: the step noise of the sampled views limits sheets under
        2 px thick). About twice the time of the defaults; on thick shapes no better
        (docs/reconstruction.md). `ReconstructOptions.nicolet().fine()` is the baseline at
        the same renderer, schedule and averaging. Settings in `held` keep their values.
        """
        more = {} if self.remesh is None else {"max_faces": max(self.face_budget, 20000)}
        change = dict(sigma=0.03, lr_decay=0.9, average=0.95, n_cycles=5, initial_edge_length=1.4,
                      final_edge_length=1.0, **more)
        return self.replaced(**{k: v for k, v in change.items() if k not in self.held})

    def for_refit(self, targets: str) -> "ReconstructOptions":
        """The options of a refit of `targets`: carving (`refit_carve`) switched on for normal maps
        when the weights do not set it already."""
        if targets == "normals" and self.refit_carve and not self.optimize.weights.carve:
            return self.replaced(carve=self.refit_carve)
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


def _nested_changes(part, default) -> set[str]:
    """The names of the fields of settings `part` (and of its nested settings) that differ from `default`'s."""
    if part is None or default is None or type(part) is not type(default):
        return set()
    names = set()
    for f in dataclasses.fields(part):
        value, base = getattr(part, f.name), getattr(default, f.name)
        if dataclasses.is_dataclass(value):
            names |= _nested_changes(value, base if base is not None else type(value)())
        elif not _same(value, base):
            names.add(f.name)
    return names


def _same(a, b) -> bool:
    try:
        return bool(a == b)
    except (TypeError, ValueError):  # arrays compare element-wise
        return False


_generated_init = ReconstructOptions.__init__


def _init_holding_what_is_given(self, *args, **kwargs):
    """`ReconstructOptions(...)`: the settings passed are held (`held`), as with `updated`; nested
    settings passed (`optimize=OptimizeOptions(...)`) hold the fields they set. `dataclasses.replace`
    passes `held` itself and holds nothing more."""
    _generated_init(self, *args, **kwargs)
    if "held" in kwargs:
        return
    given = {f.name for f in dataclasses.fields(self)[: len(args)]} | set(kwargs)
    names = set()
    for name in given:
        value = getattr(self, name)
        if dataclasses.is_dataclass(value):
            names |= _nested_changes(value, _DEFAULTS[name] if _DEFAULTS[name] is not None else type(value)())
        else:
            names.add(name)
    if names:
        object.__setattr__(self, "held", self.held | frozenset(names))


_DEFAULTS = {f.name: f.default for f in dataclasses.fields(ReconstructOptions)}
ReconstructOptions.__init__ = _init_holding_what_is_given


def _setting_names() -> frozenset:
    """Every name `ReconstructOptions.updated` takes."""
    classes = (ReconstructOptions, OptimizeOptions, LossWeights, RenderSettings, RemeshOptions)
    return frozenset(f.name for cls in classes for f in dataclasses.fields(cls))
