"""`ReconstructOptions`: the settings of `reconstruct`, and the plan entries a run decides itself.

A person holds the 24 settings below, grouped by the stage that uses them. The run's plan
(`pipeline._schedule.planned`) decides a few more from the images (`ENTRIES`: the face budget's
start, the texture settings, the stages after the fit, ...); each of those can be given by name
too, and is then held. Everything else is a constant of the stage that uses it (the defaults of
`OptimizeOptions`, `LossWeights`, `RenderSettings` and `RemeshOptions`, with their reasons there).
The optimizer's and the remesher's settings are derived: `options.optimize`, `options.remesh_options`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from jaxgenus.geometry import RemeshOptions
from jaxgenus.optim import LossWeights, OptimizeOptions, resolution_factors
from jaxgenus.rendering import RenderSettings

__all__ = ["ENTRIES", "ReconstructOptions"]

#: The plan entries: settings a run decides itself where they are not given (`planned`, `prepare`,
#: `fine()`), each with its default. Any of them given by name (`ReconstructOptions(name=...)`,
#: `updated`, CLI `--option NAME=VALUE`) is held: no rule of the run changes it.
ENTRIES: dict[str, Any] = {
    # the start and the schedule (fine() changes the last four)
    "initial_faces": 2000,  # faces of the starting primitive
    "initial_edge_length": 2.0,  # pixels: the first remesh's target (geometric to the last)
    "final_edge_length": 1.4,  # pixels: the last remesh's target
    "lr_decay": 0.5,  # the step is learning_rate * lr_decay ** cycle
    "average": OptimizeOptions.average,  # iterate averaging of a block (fine(): 0.95)
    "adam_quantile": OptimizeOptions.adam_quantile,  # uniform Adam's quantile (nicolet(): 1, the max)
    "fine_below": 3.0,  # pixels: a visual hull thinner than this at the first level runs fine() (0: never)
    "one_jit": False,  # all cycles as one compiled scan (one compilation; callbacks after the run)
    "crop": OptimizeOptions.crop,  # native cycles of the schedule fit crop x crop windows (0: whole images)
    "max_pixels": OptimizeOptions.max_pixels,  # the most pixels one step renders
    # photos: the face budget, the texture settings, the stereo start
    "detail_faces": 40000,  # the most faces the photos' detail budget may raise max_faces to
    "fine_texture": True,  # photos of a fine texture get pipeline._setup.TEXTURE_SETTINGS
    "shading_ratio": LossWeights.shading_ratio,  # the albedo-free shading ratios (fine texture: 6)
    "consistency_blur": LossWeights.consistency_blur,  # photo-consistency's blur (fine texture: 0)
    "polish_cycles": 0,  # cycles without remeshing after the fit, colour terms only (fine texture: 2)
    "adaptive": False,  # curvature-adaptive remeshing (fine texture: on)
    "stereo": LossWeights.stereo,  # the plane-sweep depths' term of photo fits
    "stereo_carve": 2.0,  # cells: the stereo depths carve the visual hull start (0: off)
    "albedo_edges": LossWeights.albedo_edges,  # the albedo's smoothness stops at the photos' edges
    # normal maps: refits
    "refit_carve": 1.0,  # carving (LossWeights.carve) in refits of normal maps (0: off)
    "carve": LossWeights.carve,  # carving in every fit
    # the stages after the fit
    "fill_unseen": True,  # photos: the surface no camera sees onto the membrane the seen surface spans
    "fit_outline": True,  # the outline onto the masks at the images' own size
    "fit_photo_depth": True,  # photos: the depth at the images' own size (plane sweep along the normals)
}
_WEIGHT_ENTRIES = ("shading_ratio", "consistency_blur", "stereo", "albedo_edges", "carve")
_OPTIMIZE_ENTRIES = ("average", "adam_quantile", "crop", "max_pixels")
#: Remeshes between cycles run this many split/collapse/flip/smooth rounds (3 of RemeshOptions' 5:
#: the optimizer moves the mesh between two remeshes by a fraction of an edge).
REMESH_ITERATIONS = 3


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


def _flag(name, v):
    if not isinstance(v, bool):
        raise ValueError(f"options.{name} must be True or False, got {v!r}")


def _same(a, b) -> bool:
    try:
        return bool(a == b)
    except (TypeError, ValueError):  # arrays compare element-wise
        return False


@dataclasses.dataclass(frozen=True, repr=False)
class ReconstructOptions:
    """Settings of `reconstruct` (immutable), by the stage that uses them. Lengths in pixels.

    The fit:
        n_cycles: optimize/remesh cycles; the last one is not followed by a remesh.
        steps_per_cycle: optimizer steps per cycle.
        max_faces: the face budget (it picks the run's capacity bucket). Photos that resolve
            more detail may get more (`detail_faces`), photos of a fine texture less, unless given.
        remesh: remesh between cycles, coarse to fine, to edges of `initial_edge_length` to
            `final_edge_length` pixels (one pixel: the median footprint over the cameras of a pixel
            at the visual hull's centre). False keeps the start's connectivity (Nicolet's baseline;
            the budget is then `initial_faces`).
        learning_rate, lambda_: uniform Adam's step size and the large-steps smoothing
            (`OptimizeOptions`).
        views_per_step: views sampled per step (None: all).
        sigma: the soft rasterizer's edge width in pixels (`RenderSettings.sigma`).

    The objective (`LossWeights`: 0 turns a term off):
        alpha, normal, photo, consistency: the silhouettes, the normal maps, the photos through
            shading, the photos' multi-view consistency.
        bilaplacian, inversion: the paper's smoothness and triangle-inversion terms.

    The start and the genus:
        start: `"auto"` (the silhouettes' visual hull where it has the genus, its missing handles
            opened where the images show holes or drilled; else the genus-g primitive),
            `"primitive"` or `"sphere"` (genus 0).
        hidden_handles: handles no silhouette shows: `"images"` (normal maps: fit at the hull's
            genus, cut where the normals disagree the way a hole does and the loss drops) or
            `"drill"` (small tunnels at spread-out sites).

    The images:
        downsample: fit copies area-averaged over `downsample x downsample` blocks (cameras scaled).
        coarse_resolution: images whose longer side is 1.5 x this or more are fitted through a
            pyramid (copies of about this size first, the images' own size last; 0: full size only).
        lighting: photos: `"sh"` (spherical harmonics of order <= 4) or `"directional"`.

    The verdict:
        min_view_iou: a run whose silhouette IoU is under this in any view is not ok.
        max_photo_error: photos fitted without photo-consistency: not ok when the median view's mean
            absolute RGB error is above this (with it: a warning).

    The result:
        subdivide: a result whose median edge is longer than 2 pixels at the images' own size goes
            through one Phong subdivision (the verdict judges the mesh written).

    The run:
        devices: the devices the views are split over (None: all of the default backend's, with
            processes joined by `jax.distributed` every process's; 1: one).
        refits: fits after the first, each from the previous result (None: up to two for normal
            maps fitted through the pyramid, the second only when the first gained 3 %).

    Bookkeeping:
        entries: the plan entries given or chosen (`ENTRIES`), as sorted `(name, value)` pairs;
            read them as attributes (`options.polish_cycles`).
        held: the names given (the constructor, `updated`, `--option`): no automatic choice of
            the run changes them, also when the value given is the default.

    Presets are constructors: `ReconstructOptions.nicolet()`, `options.fine()`. What each default
    bought is in docs/results.md.
    """

    n_cycles: int = 4
    steps_per_cycle: int = 150
    max_faces: int = 12000
    remesh: bool = True
    learning_rate: float = OptimizeOptions.learning_rate
    lambda_: float = OptimizeOptions.lambda_
    views_per_step: int | None = OptimizeOptions.views_per_step
    sigma: float = RenderSettings.sigma
    alpha: float = LossWeights.alpha
    normal: float = LossWeights.normal
    photo: float = LossWeights.photo
    consistency: float = LossWeights.consistency
    bilaplacian: float = LossWeights.bilaplacian
    inversion: float = LossWeights.inversion
    start: str = "auto"
    hidden_handles: str = "images"
    downsample: int = 1
    coarse_resolution: int = 128
    lighting: str = "sh"
    min_view_iou: float = 0.8
    max_photo_error: float = 0.1
    subdivide: bool = True
    devices: int | None = None
    refits: int | None = None
    entries: tuple = ()
    held: frozenset = frozenset()

    #: Constants of the stages (not settings): the visual hull's grids for the start and the genus
    #: estimate, tried in order (the genus evidence was measured on them); the verdict's gap of a view
    #: under the median IoU that fails it; the cycles at the images' own size in the pyramid.
    hull_resolutions = (64, 48, 80)
    outlier_gap = 0.15
    native_cycles = 1

    def __post_init__(self):
        for name in ("n_cycles", "steps_per_cycle", "max_faces", "downsample"):
            _positive_int(name, getattr(self, name))
        _positive_int("coarse_resolution", self.coarse_resolution, 0)
        for name, v in (("refits", self.refits), ("devices", self.devices)):
            if v is not None:
                _positive_int(name, v, 0 if name == "refits" else 1)
        for name in ("min_view_iou", "max_photo_error"):
            _number(name, getattr(self, name), 0.0, 1.0)
        for name in ("remesh", "subdivide"):
            _flag(name, getattr(self, name))
        _choice("hidden_handles", self.hidden_handles, ("images", "drill"))
        _choice("lighting", self.lighting, ("sh", "directional"))
        _choice("start", self.start, ("auto", "primitive", "sphere"))
        if (not isinstance(self.entries, tuple) or not all(isinstance(e, tuple) and len(e) == 2 for e in self.entries)
                or any(e[0] not in ENTRIES for e in self.entries)):
            raise ValueError(f"options.entries must be (name, value) pairs of plan entries, got {self.entries!r}")
        for name in ("initial_faces", "detail_faces", "polish_cycles"):
            _positive_int(name, getattr(self, name), 1 if name == "initial_faces" else 0)
        _number("lr_decay", self.lr_decay, 0.0, 1.0, open_lo=True)
        for name in ("initial_edge_length", "final_edge_length"):
            _number(name, getattr(self, name), 0.0, math.inf, open_lo=True)
        for name in ("refit_carve", "fine_below", "stereo_carve"):
            _number(name, getattr(self, name), 0.0, math.inf)
        for name in ("fill_unseen", "fit_outline", "fit_photo_depth", "fine_texture", "one_jit", "adaptive"):
            _flag(name, getattr(self, name))
        unknown = sorted(n for n in self.held if not isinstance(n, str) or n not in setting_names())
        if not isinstance(self.held, frozenset) or unknown:
            raise ValueError(f"options.held must be a frozenset of setting names, got {self.held!r}")
        for name in ("learning_rate", "lambda_", "sigma", "alpha", "normal", "photo", "consistency", "bilaplacian",
                     "inversion", *_WEIGHT_ENTRIES, "average", "adam_quantile"):
            if isinstance(getattr(self, name), bool):
                raise ValueError(f"options.{name} must be a number, got {getattr(self, name)!r}")
        try:  # the parts validate their own fields
            self.optimize, self.remesh_options  # noqa: B018
        except ValueError as err:
            raise ValueError(f"options: {err}") from None
        if self.adaptive and not self.remesh:
            raise ValueError("options.adaptive set on a run without remeshing (remesh=False)")
        if self.face_budget < self.initial_faces:
            raise ValueError("options.max_faces must be >= options.initial_faces")

    def __getattr__(self, name):  # the plan entries read as attributes
        if name in ENTRIES:
            return dict(self.__dict__.get("entries", ())).get(name, ENTRIES[name])
        raise AttributeError(f"'ReconstructOptions' has no attribute {name!r}")

    def __repr__(self) -> str:
        changed = [f"{f.name}={getattr(self, f.name)!r}" for f in dataclasses.fields(self)
                   if f.name not in ("entries", "held") and not _same(getattr(self, f.name), f.default)]
        return f"ReconstructOptions({', '.join(changed + [f'{k}={v!r}' for k, v in self.entries])})"

    @property
    def optimize(self) -> OptimizeOptions:
        """The `OptimizeOptions` of every optimizer block: the settings above, the plan entries,
        the class's defaults for the rest."""
        weights = LossWeights(alpha=self.alpha, normal=self.normal, photo=self.photo, consistency=self.consistency,
                              bilaplacian=self.bilaplacian, inversion=self.inversion,
                              **{n: getattr(self, n) for n in _WEIGHT_ENTRIES})
        return OptimizeOptions(learning_rate=self.learning_rate, lambda_=self.lambda_, weights=weights,
                               views_per_step=self.views_per_step, render=RenderSettings(sigma=self.sigma),
                               **{n: getattr(self, n) for n in _OPTIMIZE_ENTRIES})

    @property
    def remesh_options(self) -> RemeshOptions | None:
        """The `RemeshOptions` of the remeshes between cycles (the schedule sets the edge length);
        None without remeshing."""
        if not self.remesh:
            return None
        return RemeshOptions(iterations=REMESH_ITERATIONS, adaptive=self.adaptive, max_faces=self.max_faces)

    @property
    def face_budget(self) -> int:
        """Faces the run may reach (`max_faces`; `initial_faces` without remeshing)."""
        return int(self.max_faces) if self.remesh else self.initial_faces

    @property
    def render(self) -> RenderSettings:
        """The renderer's settings of the fits and the verdict."""
        return self.optimize.render

    def updated(self, **settings) -> "ReconstructOptions":
        """A copy with settings or plan entries changed by name, each held as given: no automatic
        choice of the run changes it, also when it is the default (`updated(n_cycles=4)` stays 4 for
        photos of a fine texture). `stereo=0` also turns off the stereo carving of the start, and a
        `max_faces` under `initial_faces` lowers that. The CLI's `--option NAME=VALUE` is this."""
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
        own, entries = {}, dict(self.entries)
        fields = {f.name for f in dataclasses.fields(self)}
        for name, value in settings.items():
            if name in fields:
                own[name] = value
            elif name in ENTRIES:
                entries[name] = value
            else:
                raise ValueError(_unknown(name))
        if "entries" not in own:
            own["entries"] = _entries(entries)
        return dataclasses.replace(self, **own)

    @classmethod
    def nicolet(cls, **settings) -> "ReconstructOptions":
        """Nicolet et al. 2021: sphere start, no remeshing, same renderer, their uniform Adam (the max),
        the result as fitted (no `subdivide`)."""
        return cls().replaced(start="sphere", remesh=False, subdivide=False, adam_quantile=1.0).updated(**settings)

    def fine(self) -> "ReconstructOptions":
        """A copy set up for thin structures a few pixels wide (e.g. sheets 2 px thick).

        `reconstruct` switches to it by itself when the visual hull is thinner than
        `fine_below` pixels of the level the first cycles fit. Sharper edges (`sigma` 0.03 px: the
        outward tails of the contour faces at the default 0.1 bias thin silhouettes out), a finer
        mesh (1.4 -> 1.0 px edges, up to 20k faces), 5 cycles with a slow step decay (0.9) and
        iterate averaging (`average` 0.95: the step noise of the sampled views limits sheets under
        2 px thick). About twice the time of the defaults; on thick shapes no better
        (docs/reconstruction.md). `ReconstructOptions.nicolet().fine()` is the baseline at the same
        renderer, schedule and averaging. Settings in `held` keep their values.
        """
        more = {"max_faces": max(self.face_budget, 20000)} if self.remesh else {}
        change = dict(sigma=0.03, lr_decay=0.9, average=0.95, n_cycles=5, initial_edge_length=1.4,
                      final_edge_length=1.0, **more)
        return self.replaced(**{k: v for k, v in change.items() if k not in self.held})

    def for_refit(self, targets: str) -> "ReconstructOptions":
        """The options of a refit of `targets`: carving (`refit_carve`) switched on for normal maps
        when the weights do not set it already."""
        if targets == "normals" and self.refit_carve and not self.carve:
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
        n = self.n_cycles - 1 if self.remesh else 0
        if n <= 0:
            return []
        if n == 1:
            return [self.final_edge_length]
        r = (self.final_edge_length / self.initial_edge_length) ** (1.0 / (n - 1))
        return [self.initial_edge_length * r**i for i in range(n)]


def _entries(values: dict) -> tuple:
    """Plan entries as stored: sorted `(name, value)` pairs, those at their default left out."""
    at_default = lambda k, v: k in ENTRIES and type(v) is type(ENTRIES[k]) and _same(v, ENTRIES[k])  # noqa: E731
    return tuple(sorted((k, v) for k, v in values.items() if not at_default(k, v)))


def _unknown(name: str) -> str:
    return (f"options: no setting named {name!r} (the settings are ReconstructOptions' fields, the plan entries "
            "jaxgenus.pipeline.ENTRIES; the CLI's --option list prints both)")


def setting_names() -> frozenset:
    """Every name `ReconstructOptions.updated` takes: its fields and the plan entries."""
    own = {f.name for f in dataclasses.fields(ReconstructOptions)} - {"entries", "held"}
    return frozenset(own | set(ENTRIES))


_generated_init = ReconstructOptions.__init__


def _init_holding_what_is_given(self, *args, **kwargs):
    """`ReconstructOptions(...)`: fields and plan entries by name; what is passed is held (`held`), as
    with `updated`. `dataclasses.replace` passes `held` itself and holds nothing more."""
    entries = {k: kwargs.pop(k) for k in list(kwargs) if k in ENTRIES}
    fields = {f.name for f in dataclasses.fields(ReconstructOptions)}
    unknown = sorted(set(kwargs) - fields)
    if unknown:
        raise ValueError(_unknown(unknown[0]))
    given = kwargs.get("entries", ())
    if entries or (given and isinstance(given, tuple) and all(isinstance(e, tuple) and len(e) == 2 for e in given)):
        kwargs["entries"] = _entries({**dict(given), **entries})  # sorted, one pair a name, none at its default
    _generated_init(self, *args, **kwargs)
    if "held" in kwargs:
        return
    given = ({f.name for f in dataclasses.fields(self)[: len(args)]} | set(kwargs) | set(entries)) - {"entries", "held"}
    given |= {k for k, _ in self.entries} if "entries" in kwargs and not entries else set()
    if given:
        object.__setattr__(self, "held", self.held | frozenset(given))
        ReconstructOptions.__post_init__(self)


ReconstructOptions.__init__ = _init_holding_what_is_given
