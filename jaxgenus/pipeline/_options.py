"""`ReconstructOptions`: every setting of `reconstruct`, validated, with its presets."""

from __future__ import annotations

import dataclasses
import math

from jaxgenus.optim import LossWeights
from jaxgenus.optim import resolution_factors

__all__ = ["ReconstructOptions"]


@dataclasses.dataclass(frozen=True)
class ReconstructOptions:
    """Settings of `reconstruct` (immutable). Edge lengths are in pixels (see below).

    Attributes:
        n_cycles: optimize/remesh cycles; the last one is not followed by a remesh.
        steps_per_cycle: optimizer steps per cycle (the paper remeshes every 130-200).
        views_per_step: cameras sampled per step (`None`: all of them).
        learning_rate, lambda_: large-steps uniform Adam step and smoothing.
        adam_quantile: quantile of uniform Adam's shared second moment (1: the max,
            Nicolet's; the default 0.99 keeps a few vertices with outlier gradients,
            e.g. on a tiny handle, from freezing the rest of the mesh).
        average: each block returns the exponential moving average of its iterates
            with this decay (0: the last iterate; see `OptimizeOptions.average`).
        lr_decay: the step is `learning_rate * lr_decay ** cycle` (coarse to fine; no recompile).
        weights: `LossWeights` of the objective.
        sigma, gamma: soft rasterizer edge blur (px) and depth temperature.
        initial_faces: face count of the starting primitive.
        max_faces: face budget (sets the capacity bucket; the remesher coarsens to fit).
        initial_edge_length, final_edge_length: remesh targets of the first and the last
            remesh (geometric in between: coarse to fine), in pixels: one pixel is the
            median over the cameras of the world-space footprint of a pixel at the
            visual hull's centre, so the mesh is as fine as the images resolve.
        adaptive: curvature-adaptive remeshing (`False`: uniform).
        remesh: remesh between cycles (`False` keeps the connectivity: Nicolet's baseline).
        start: `"auto"` (the silhouettes' visual hull when its largest component has the
            requested genus at one of `hull_resolutions`, possibly after closing
            thin spurious tunnels; when it has fewer handles, the missing ones are
            added as small tunnels under its surface; else the genus-g primitive),
            `"primitive"` (always the genus-g primitive) or `"sphere"` (genus 0).
        hull_resolutions: grid sizes tried, in order, for the visual-hull start.
        fine_below: thin-structure switch: when the silhouettes' visual hull (grid
            `hull_resolutions[0]`, largest piece) is thinner than this many pixels
            of the level the first cycles fit (see `coarse_resolution`: the
            heptoroid from 512² images, 4x thicker in native pixels, fitted CD
            0.0068 without the switch and 0.0021 with it), as `2 * volume / area` (a slab's thickness, a tube's radius),
            `reconstruct` runs with `self.fine()` instead (`history["fine"]`,
            `Reconstruction.options`). At 24 views of 128², the heptoroid's hull is
            2.6 px thick (its sheets 1.8 px), the 21 other benchmark shapes' 5.9 px
            and more; the demo's three_tori at 64² is 3.2 px. 0 turns it off.
        min_view_iou: the verdict's threshold: a run whose silhouette IoU (result against
            target, both at alpha 0.5) is under this in any view is not ok.
        outlier_gap: the verdict's test of views that disagree with the rest: a view
            whose IoU is this far under the median of the views makes the run not ok.
        lighting: photo targets: the lighting model, `"sh"` (spherical harmonics of
            order <= 4: any smooth distant light) or `"directional"` (one lamp plus
            ambient, exact); `jaxgenus.irradiance`, docs/photometric.md.
        hidden_handles: handles the visual hull lacks (holes no silhouette shows):
            `"images"` (normal targets) first fits the hull's genus, then opens holes
            where that fit's normals disagree with the targets and the image loss drops
            (`jaxgenus.open_handles`), drilling only what the images do not show; `"drill"`
            drills them all as small tunnels at spread-out sites (`drill_tunnels`).
        albedo_learning_rate, lighting_learning_rate: photo targets: plain-Adam steps
            of the per-vertex albedo and of the lighting (scaled by `lr_decay ** cycle`).
        max_photo_error: photo targets: the verdict fails when the median over the views
            of the mean absolute RGB error (result rendered with its albedo and
            lighting, against the photos) is above this.
        coarse_resolution, native_cycles, crop: the resolution schedule for images of
            any size. When the images' longer side is at least 1.5 x
            `coarse_resolution`, all but the last `native_cycles` cycles fit copies
            area-averaged by a power of two to about `coarse_resolution` pixels
            (edge lengths in those pixels), and the last ones fit the images at their
            own resolution, whole (`crop = 0`, the default) or through random
            `crop x crop` windows centred in the silhouettes, which bounds the cost
            of a step at any image size but fits worse (skull, 24 views of 512²:
            CD 0.0068 with 128² crops against 0.0056 whole; docs/reconstruction.md).
            `coarse_resolution = 0` fits every cycle at full size.
        refits: fits after the first, each started from the previous result
            (remeshed to the first edge length, the optimizer and its step size
            reset) with the same settings; None (the default): `refit_count`,
            up to two for normal maps fitted through the resolution schedule
            (longer side >= 1.5 x `coarse_resolution`), else none; the second
            only when the first lowered the mean normal error by 3 % or more.
            A refit that fits the images worse than its start is dropped (a
            warning says so). A refit carves concavities that few cameras see
            (eye sockets, a boot's shaft: surface the visual hull covers and only
            normals show), which one fit leaves partly filled, and what larger
            images show there is lost without it: skull from 24 views of 512²,
            CD 0.0054 / 0.0037 / 0.0030 with 0 / 1 / 2 refits, against 0.0045
            from 128² images, where one refit gains less (docs/reconstruction.md).
            `history["start"]` ends with `+refit` per refit; `callback` sees each
            fit's cycles from 0.
        refit_carve: `LossWeights.carve` in refits of normal maps (when `weights.carve`
            is 0): the visible surface moves away from the camera where its normal
            is more than 37 degrees from the image's (`jaxgenus.optim._carving`), which
            opens what a cap over a concavity hides. Boot, 24 views of 512²: CD
            0.0037 -> 0.0033 (few-views surface 0.0144 -> 0.0109); skull 0.0030 ->
            0.0027. A carving refit that fits the images worse is dropped and the
            next refit runs without carving (the heptoroid's tubes). 0 turns it off.
        one_jit: run all cycles (optimizer blocks and FFI remeshes) as one
            jit-compiled `lax.scan` with one rasterizer plan sized for the final
            face count, instead of one compiled block per cycle driven from Python
            (which re-plans the rasterizer from the geometry every cycle). One
            compilation per run; `callback` is then called after the run, once per
            cycle, with that cycle's row and mesh.
    """

    n_cycles: int = 4
    steps_per_cycle: int = 150
    views_per_step: int | None = 4
    learning_rate: float = 8e-2
    lr_decay: float = 0.5
    adam_quantile: float = 0.99
    average: float = 0.0
    lambda_: float = 19.0
    weights: LossWeights = LossWeights()
    sigma: float = 0.1
    gamma: float = 0.01
    initial_faces: int = 2000
    max_faces: int = 12000
    initial_edge_length: float = 2.0
    final_edge_length: float = 1.4
    adaptive: bool = False
    remesh: bool = True
    start: str = "auto"
    hull_resolutions: tuple[int, ...] = (64, 48, 80)
    fine_below: float = 3.0
    min_view_iou: float = 0.8
    outlier_gap: float = 0.15
    coarse_resolution: int = 128
    native_cycles: int = 1
    crop: int = 0
    one_jit: bool = False
    max_photo_error: float = 0.1
    albedo_learning_rate: float = 1e-2
    lighting_learning_rate: float = 5e-2
    lighting: str = "sh"
    hidden_handles: str = "images"
    refits: int | None = None
    refit_carve: float = 1.0

    def __post_init__(self):
        for name in ("coarse_resolution", "native_cycles", "crop", "refits"):
            v = getattr(self, name)
            if v is None and name == "refits":
                continue
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                what = " or None (as the images' size asks)" if name == "refits" else ""
                raise ValueError(f"options.{name} must be an int >= 0{what}, got {v!r}")
        for name in ("n_cycles", "steps_per_cycle", "initial_faces", "max_faces"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValueError(f"options.{name} must be a positive int, got {v!r}")
        if not 0.0 < self.lr_decay <= 1.0:
            raise ValueError(f"options.lr_decay must be in (0, 1], got {self.lr_decay!r}")
        for name in ("learning_rate", "sigma", "gamma", "initial_edge_length", "final_edge_length",
                     "albedo_learning_rate", "lighting_learning_rate"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"options.{name} must be a positive number, got {v!r}")
        if not (isinstance(self.refit_carve, (int, float)) and math.isfinite(self.refit_carve)
                and self.refit_carve >= 0):
            raise ValueError(f"options.refit_carve must be a number >= 0, got {self.refit_carve!r}")
        if not (isinstance(self.average, (int, float)) and 0.0 <= self.average < 1.0):
            raise ValueError(f"options.average must be in [0, 1), got {self.average!r}")
        if not (isinstance(self.adam_quantile, (int, float)) and 0.0 < self.adam_quantile <= 1.0):
            raise ValueError(f"options.adam_quantile must be in (0, 1], got {self.adam_quantile!r}")
        if self.hidden_handles not in ("images", "drill"):
            raise ValueError(f"options.hidden_handles must be 'images' or 'drill', got {self.hidden_handles!r}")
        if self.lighting not in ("sh", "directional"):
            raise ValueError(f"options.lighting must be 'sh' or 'directional', got {self.lighting!r}")
        if self.start not in ("auto", "primitive", "sphere"):
            raise ValueError(f"options.start must be 'auto', 'primitive' or 'sphere', got {self.start!r}")
        if not all(isinstance(r, int) and r >= 8 for r in self.hull_resolutions):
            raise ValueError(f"options.hull_resolutions must be ints >= 8, got {self.hull_resolutions!r}")
        if not (isinstance(self.fine_below, (int, float)) and math.isfinite(self.fine_below) and self.fine_below >= 0):
            raise ValueError(f"options.fine_below must be a number >= 0, got {self.fine_below!r}")
        for name in ("min_view_iou", "outlier_gap", "max_photo_error"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 <= v <= 1.0):
                raise ValueError(f"options.{name} must be in [0, 1], got {v!r}")
        if self.max_faces < self.initial_faces:
            raise ValueError("options.max_faces must be >= options.initial_faces")

    @classmethod
    def nicolet(cls, **overrides) -> "ReconstructOptions":
        """Nicolet et al. 2021: sphere start, no remeshing, same renderer, their uniform Adam (the max)."""
        base = dict(start="sphere", remesh=False, adam_quantile=1.0)
        base.update(overrides)
        return cls(**base)

    def fine(self) -> "ReconstructOptions":
        """A copy set up for thin structures a few pixels wide (e.g. sheets 2 px thick).

        `reconstruct` switches to it by itself when the visual hull is thinner than
        `fine_below` pixels.

        Sharper edges (`sigma` 0.03 px: at the default 0.1 the outward tails of
        the contour faces bias silhouettes out, and the fit thins such tubes by
        ~9 % in volume), a finer mesh (1.4 -> 1.0 px edges, up to 20k faces),
        5 cycles with a slow step decay (0.9) and iterate averaging (`average`
        0.95: the step noise of the sampled views, not the step size, limits
        sheets under 2 px thick). About twice the time of the defaults.
        `ReconstructOptions.nicolet().fine()` is the baseline at the same renderer,
        schedule and averaging. On thick shapes it costs twice the time for the
        same result (pretzel: CD 0.0015 / IoU 0.985 against 0.0015 / 0.984).
        """
        return dataclasses.replace(
            self, sigma=0.03, lr_decay=0.9, average=0.95, n_cycles=5, max_faces=max(self.max_faces, 20000),
            initial_edge_length=1.4, final_edge_length=1.0,
        )

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
        """Target edge length of each remesh in pixels (coarse to fine)."""
        n = self.n_cycles - 1
        if n <= 0:
            return []
        if n == 1:
            return [self.final_edge_length]
        r = (self.final_edge_length / self.initial_edge_length) ** (1.0 / (n - 1))
        return [self.initial_edge_length * r**i for i in range(n)]
