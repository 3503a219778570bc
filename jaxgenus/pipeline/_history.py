"""What a reconstruction run returns: the `Reconstruction` and its typed record, with dict-style
reads for scripts and JSON.

`History` holds the per-step arrays of every optimizer step (`RECORD_KEYS` of
`optimize_block` plus `time`), one `CycleRecord` per optimize/remesh cycle, and
what the run decided (start, thin-structure switch, compilations). Both classes
are frozen dataclasses; `history["loss"]`, `history["cycles"][0]["faces"]` and
`"remesh_status" in row` read them like the dicts they replace, and `to_json()`
gives plain JSON-ready values.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping

import numpy as np

from jaxgenus.geometry import Cameras, Mesh
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.rendering import render_photo

__all__ = ["CycleRecord", "GenusEstimate", "GenusEvidence", "HandleRecord", "History", "Plan", "Reconstruction"]


class _Readable:
    """`record[name]` over the dataclass fields; `name in record` is False for a field that is None."""

    def __getitem__(self, key: str) -> Any:
        if key not in self._names():
            raise KeyError(key)
        return getattr(self, key)

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str) and key in self._names() and getattr(self, key) is not None

    def get(self, key: str, default=None):
        return self[key] if key in self else default

    @classmethod
    def _names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))

    def to_json(self) -> dict:
        """Plain Python values (the fields that are not None) for `json.dumps`."""
        return {k: _plain(getattr(self, k)) for k in self._names() if k in self}


def _plain(v):
    if isinstance(v, _Readable):
        return v.to_json()
    if isinstance(v, Mapping):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


@dataclasses.dataclass(frozen=True)
class GenusEvidence(_Readable):
    """The genus of the largest visual-hull component on one grid (`-1`: no hull there)."""

    resolution: int
    closing: int
    genus: int


@dataclasses.dataclass(frozen=True)
class GenusEstimate(_Readable):
    """The genus a run estimated from what its images show.

    Attributes:
        genus: the estimate: the silhouettes' (the most frequent of the visual hull grids'
            persistent genera; ties: the lower), plus the holes that normal images confirm.
        agreement: how far the cues agree with it, in [0, 1]: the share of the grids that have
            the silhouettes' genus, and, where the images' interior was tested, at most the
            weakest of the hole tests' view votes (`pipeline._start_stage`).
        evidence: one `GenusEvidence` per hull built (every grid and closing).
        plausible: every genus a grid has, the estimate, and the genera the hole tests leave
            open (one value when every cue agrees).
        cue: what decided: `"silhouettes"`, or `"images"` when holes that no silhouette shows
            were confirmed in the normal images.
        holes: one record per hole hypothesis tested in the images (`pipeline.hole_tests`):
            `{"centre", "kept", "change", "better", "worse"}`, centre in the user's units.
    """

    genus: int
    agreement: float
    evidence: tuple[GenusEvidence, ...]
    plausible: tuple[int, ...] = ()
    cue: str = "silhouettes"
    holes: tuple[Mapping[str, Any], ...] = ()


@dataclasses.dataclass(frozen=True)
class Plan(_Readable):
    """Every automatic choice of a run, made once before any fit from what was measured
    (`pipeline._schedule.planned`), printed first and kept in `history["plan"]`. Each entry
    of `settings` is a setting's own name: `ReconstructOptions.updated(NAME=VALUE)` (CLI
    `--option NAME=VALUE`) holds it, and the plan then keeps it.

    Attributes:
        scene: what was measured: `views`, `size` `[width, height]` of the images fitted,
            `targets`, `genus` and whether it was `"given"` or `"estimated"`, `hull_thickness_px`,
            `texture_share` (photos: the share of the masks on albedo edges at the finest
            level), `resolved_faces` (photos: the faces they resolve; 0: not counted), `devices`.
        stages: the stages of the run in order (some run only where their condition holds,
            said in the stage's text).
        factors: per fit cycle, the downsampling factor of the level it fits (then the polish
            cycles at the last level).
        floor: the finest level (factor) the images are fitted at, from the face budget on the
            visual hull's area (`detail_floor`).
        settings: the settings the run chooses, by name: those a rule set (fine(), a fine
            texture, the face budget) and the fit's cycles, steps, face budget and nonzero
            loss weights.
        choices: one line per rule that changed a setting, with its measurement.
        views_per_step, pixels_per_step: what a step of the last level renders.
        image_bytes: memory the images and their pyramid levels take (float32).
    """

    scene: Mapping[str, Any]
    stages: tuple[str, ...]
    factors: tuple[int, ...]
    floor: int
    settings: Mapping[str, Any]
    choices: tuple[str, ...] = ()
    views_per_step: int = 0
    pixels_per_step: int = 0
    image_bytes: int = 0

    def lines(self) -> list[str]:
        """The plan as printed (`reconstruct`'s log, the CLI)."""
        sc = self.scene
        w, h = sc["size"]
        shown = ", ".join(f"{k}={v!r}" for k, v in self.settings.items())
        return [f"plan: {sc['views']} views of {w}x{h}, {sc['targets']}, genus {sc['genus']} ({sc['genus_from']})"
                + ("" if sc.get("hull_thickness_px") is None else f", visual hull {sc['hull_thickness_px']:.1f} px thick")
                + ("" if sc.get("texture_share") is None else f", albedo edges on {sc['texture_share']:.0%} of the masks")
                + (f", about {sc['resolved_faces']} faces resolved" if sc.get("resolved_faces") else "")
                + (f", {sc['devices']} devices" if sc.get("devices", 1) > 1 else ""),
                "plan: stages: " + " -> ".join(self.stages),
                f"plan: levels 1/{', 1/'.join(str(f) for f in self.factors)} (no finer than 1/{self.floor}); the last "
                f"renders {self.views_per_step} views, {self.pixels_per_step / 1e6:.2f} Mpixel a step; images "
                f"{self.image_bytes / 2**20:.0f} MiB with their levels",
                f"plan: settings {shown}", *[f"plan: chose {c}" for c in self.choices],
                "plan: each setting and plan entry holds when given by name (ReconstructOptions.updated, CLI --option "
                "NAME=VALUE)"]


@dataclasses.dataclass(frozen=True)
class HandleRecord(_Readable):
    """Where one handle of the start came from.

    Attributes:
        source: `"hull"` (the visual hull has it), `"images"` (opened where the images show a
            hole), `"drilled"` (a small tunnel at a spread-out site), `"primitive"` or `"sphere"`.
        cut: `"carve"` (a part of the fit the silhouettes show empty), `"hole"` (a cylinder
            into the surface at one patch) or `"tunnel"` (a straight tunnel between two patches,
            its mouths), `"images"` only.
        centre, radius, depth: the cut that opened it (`"images"` only; user units): for a
            tunnel, its first mouth, radius of a disc of its cross-section's area, and length;
            for a carve, its centre, the radius of a ball of its volume, its longest extent.
        end: a tunnel's other mouth (user units).
        loss_before, loss_after: the image loss before and after that cut (`"images"` only).
    """

    source: str
    centre: tuple[float, float, float] | None = None
    radius: float | None = None
    depth: float | None = None
    loss_before: float | None = None
    loss_after: float | None = None
    cut: str | None = None
    end: tuple[float, float, float] | None = None


@dataclasses.dataclass(frozen=True)
class CycleRecord(_Readable):
    """One optimize/remesh cycle.

    Attributes:
        cycle: index from 0.
        faces, vertices, chi: the mesh after the cycle (after its remesh, if any).
        loss: the objective at the cycle's last step.
        truncated_faces: faces the rasterizer drew incompletely (truncated or dropped)
            at the end of the cycle's optimizer block, over all views.
        compilations: new compiled executables during this cycle.
        seconds: wall time of the cycle; elapsed: since the run started.
        remesh_status: `RemeshStatus` name of the remesh after the cycle (None: no remesh).
        remesh_seconds: its wall time (None: no remesh).
        optimizer_seconds: the wall time of the cycle's optimizer steps (the rest of `seconds`
            is compiling, the remesh and transfers).
        eta: the seconds this fit was estimated to need after the cycle (its later cycles, from
            the pixels each renders per step, and its verdict); None where not estimated.
        n_cycles: cycles of this fit, its polish cycles included (`options.fine()` has more).
        fit, fits: this cycle's fit (0: the first; k: the k-th refit) and the fits the run
            plans (`1 + ReconstructOptions.refit_count`; a refit that fits its images
            worse than its start, or a default one that gains little, ends the run early).
        polish: a closing polish cycle (`ReconstructOptions.polish_cycles`: silhouettes and colour
            photo-consistency only, no remesh), after the fit's `options.n_cycles` cycles.
    """

    cycle: int
    faces: int
    vertices: int
    chi: int
    loss: float
    truncated_faces: int
    compilations: int
    seconds: float
    elapsed: float
    remesh_status: str | None = None
    remesh_seconds: float | None = None
    optimizer_seconds: float | None = None
    eta: float | None = None
    n_cycles: int = 0
    fit: int = 0
    fits: int = 1
    polish: bool = False


@dataclasses.dataclass(frozen=True)
class History(_Readable):
    """What a `reconstruct` run did.

    Attributes:
        steps: per-step `(cycles * steps_per_cycle,)` arrays (polish cycles included): every key of
            `RECORD_KEYS` (loss, alpha, normal, ..., status) and `time` (seconds
            since the start at each cycle's last step, NaN elsewhere).
            `history["loss"]` reads `history.steps["loss"]`.
        cycles: one `CycleRecord` per cycle (the polish cycles last).
        seconds: wall time of the whole `reconstruct` call, every stage included (callbacks excluded).
        faces: the face count of the returned mesh (the one the CLI writes).
        requested_genus: the genus asked for.
        start: where the start mesh came from (`Start.kind`).
        tunnels: handles drilled into a visual hull of too low a genus.
        hull_grid: `(resolution, closing)` of the visual-hull start, or None.
        hull_thickness: `2 * volume / area` of the visual hull in pixels (None when
            `fine_below` is 0).
        fine: the run switched to `options.fine()` (thin structures).
        render_plans: distinct rasterizer plans used.
        compilations: new compiled executables per jitted piece.
        targets: what the images held (`"silhouette"`, `"normals"` or `"photo"`).
        frame: `{"centre", "scale"}` of the canonical frame (`x_world = scale * x + centre`).
        genus_estimate: a `GenusEstimate` when the genus was estimated, else None.
        silhouette_iou: per view, the result's silhouette IoU with the target's (alpha 0.5).
        start_silhouette_iou: the same for the start mesh.
        normal_error_deg: per view, the mean angle between rendered and target normals
            where both cover the pixel (normal targets only, else None).
        photo_error: per view, the mean absolute RGB error of the result's render
            (albedo and lighting) against the photo where both cover (photo targets only).
        photo_consistency: per view, the result's photo-consistency residual (mean `1 - NCC`
            over textured windows against a neighbour view, at the finest level fitted; NaN where
            there was nothing to compare) when photos were fitted with it, else None.
        start_photo_consistency: the same of the start (the verdict fails views more than 0.05 above it).
        lighting: the estimated `(3, 24)` or `(3, 3)` lighting as nested lists (photo targets only;
            see `jaxgenus.render_photo` for its convention).
        resolution: per cycle, `{"factor", "size", "crop", "views", "window", "pixels"}`: the images
            were fitted downsampled by `factor` to `size = (height, width)`, through random
            `crop x crop` windows when `crop` > 0 (`ReconstructOptions.coarse_resolution`); a step
            rendered `views` views, whole or through `window x window` windows, `pixels` in all.
        devices: the devices the views were split over (`ReconstructOptions.devices`).
        handles: per handle of the start, a `HandleRecord` of where it came from.
        ok: the result matches its images (see `jaxgenus.pipeline._verdict`); warnings: why not,
            and what else to know.
        plan: the run's `Plan`, made before any fit.
    """

    steps: Mapping[str, np.ndarray]
    cycles: tuple[CycleRecord, ...]
    seconds: float
    requested_genus: int
    start: str
    tunnels: int
    hull_grid: tuple[int, int] | None
    hull_thickness: float | None
    fine: bool
    render_plans: int
    compilations: Mapping[str, int]
    targets: str = "silhouette"
    frame: Mapping[str, Any] | None = None
    genus_estimate: GenusEstimate | None = None
    silhouette_iou: list[float] = dataclasses.field(default_factory=list)
    start_silhouette_iou: list[float] = dataclasses.field(default_factory=list)
    normal_error_deg: list[float] | None = None
    photo_error: list[float] | None = None
    photo_consistency: list[float] | None = None
    start_photo_consistency: list[float] | None = None
    lighting: list | None = None
    resolution: list[dict] = dataclasses.field(default_factory=list)
    devices: int = 1
    handles: tuple[HandleRecord, ...] = ()
    ok: bool = True
    warnings: list[str] = dataclasses.field(default_factory=list)
    faces: int = 0
    plan: Plan | None = None

    def __getitem__(self, key: str) -> Any:
        if key in self.steps:
            return self.steps[key]
        return super().__getitem__(key)

    def __contains__(self, key: object) -> bool:
        return key in self.steps or super().__contains__(key)

    def keys(self) -> list[str]:
        return [*self.steps, *(k for k in self._names() if k != "steps" and k in self)]

    def to_json(self) -> dict:
        """Plain Python values (lists, floats, ints, str, None) for `json.dumps`."""
        out = {k: np.asarray(v).tolist() for k, v in self.steps.items()}
        out.update({k: _plain(getattr(self, k)) for k in self._names() if k != "steps"})
        return out


@dataclasses.dataclass(frozen=True)
class Reconstruction:
    """Result of `reconstruct`.

    Attributes:
        mesh: the final `Mesh` (`.to_numpy()` for arrays).
        genus: genus of `mesh` (-1 when it is not a closed manifold).
        genus_ok: `genus` equals the requested genus (0 for the sphere start).
        history: a `History`: per-step arrays (`history["loss"]`, ...), one
            `CycleRecord` per cycle (`history["cycles"]`), the start, the
            thin-structure switch and the compilations.
        options: the `ReconstructOptions` that ran (`options.fine()` when the run switched).
        albedo: photo targets: `(V, 3)` float32 RGB albedo per vertex, row for row with
            `mesh.to_numpy()[0]` (under the convention of `jaxgenus.render_photo`: the
            lighting `history["lighting"]` has mean 1), else None.
    """

    mesh: Mesh
    genus: int
    genus_ok: bool
    history: History
    options: ReconstructOptions
    albedo: np.ndarray | None = None

    @property
    def lighting(self) -> np.ndarray | None:
        """Photo targets: the estimated lighting (`history["lighting"]`: `(3, 24)` harmonics or `(3, 3)`
        directional, `options.lighting`), else None."""
        lt = self.history.lighting
        return None if lt is None else np.asarray(lt, np.float32)

    def render_photo(self, cams: Cameras, **render_kwargs):
        """Photo targets: RGBA renders of the result with its albedo and lighting in any `cams`
        (user units; held-out views), `(N, H, W, 4)`, shaded as it was fitted (`shading`)."""
        if self.albedo is None:
            raise ValueError("render_photo needs a reconstruction from photo targets (albedo is None)")
        pad = np.zeros((self.mesh.vertex_capacity, 3), np.float32)
        pad[: len(self.albedo)] = self.albedo
        render_kwargs.setdefault("shading", self.options.render.shading)
        return render_photo(self.mesh, cams, pad, self.lighting, **render_kwargs)
