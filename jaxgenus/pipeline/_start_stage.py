"""The start stage of a fit: its start mesh, and where each of its handles came from.

A first fit starts from `start_mesh` (the visual hull with the requested genus, missing
handles drilled, or a primitive). With normal-map targets and `hidden_handles="images"`,
a hull with fewer handles than asked is first fitted at its own genus, and the missing
holes are opened where that fit's normals disagree with the images (`open_handles`);
only what the images do not show is drilled. A refit starts from the previous result,
remeshed to the first edge length.

The genus the images show: the silhouettes' count, then the holes the normal images confirm.

The visual hull counts the holes some silhouette sees through (`estimate_genus`). A hole
seen only against other parts of the object (an eyelet over a tongue, holes through a plate
over a base) is missed there, but not in the images' interior: a fit at the hull's genus
spans a surface over it, and its rendered normals disagree with the target normals there.
So, for normal-map targets, `reconstruct` without a genus (and `genus_estimate`, through the
same code) fits the hull's genus, tests a cut at every patch where the fit disagrees with
the images the way a hole does (`hole_tests`; no cut narrower than a pixel, which no image
can show), and counts the cuts that lower the image loss. The estimate is the hull's genus plus that count (`cue="images"` when it is not zero).

The agreement is honest about what was tested and what was not explained. Each test is a
vote of the views whose loss the cut changed: a real hole lowers it in the views that see the
hole, a cut where there is none raises it where a view now sees background or a wall. A
decision is as sure as the share of the loss it moved that moved its way (kept: down;
rejected: up), and the estimate as sure as its weakest decision, times one minus the largest
share of the fit's normal misfit that lies on one hole-shaped patch no kept cut explains (a
disagreement there may be a hole of a shape no cut tested: a slot behind an arch, a bent
tunnel), times the grids' agreement when the silhouettes' genus stands. Such a patch, or a
rejected cut that some views liked, leaves one more handle plausible; a kept cut that some
views disliked leaves one fewer plausible.

The verdict tests the topology of every normal-map result the same way (`holes_not_had`): a
cut at one of its strongest disagreements that lowers the loss, with the views two to one for
it, is a hole the images show and the result lacks: the run is not ok, and says where.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from jaxgenus.geometry import Mesh
from jaxgenus.optim import pyramid_level, scaled_cameras
from jaxgenus.pipeline._handles import HoleTests, open_handles
from jaxgenus.pipeline._history import GenusEstimate, HandleRecord
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.pipeline._setup import Setup
from jaxgenus.pipeline._start import Start, drill_tunnels, remeshed_start, start_mesh

__all__ = ["CHECK_TRIES", "CHECK_VOTE", "estimate_line", "evidence_level", "evidence_pixel", "first_edge_length", "first_start",
           "holes_not_had", "image_handle_records", "images_estimate", "refit_start"]


def first_edge_length(options: ReconstructOptions) -> float:
    """The edge length (pixels) of a start: that of the first remesh."""
    lengths = options.edge_lengths()
    return lengths[0] if lengths else options.final_edge_length


def _sources(start: Start, genus: int) -> tuple[HandleRecord, ...]:
    if start.kind in ("primitive", "sphere"):
        return tuple(HandleRecord(start.kind) for _ in range(genus if start.kind == "primitive" else 0))
    return (HandleRecord("hull"),) * (genus - start.tunnels) + (HandleRecord("drilled"),) * start.tunnels


def _evidence_factor(cams) -> int:
    """The downsampling factor of `evidence_level`: images of about 256 px."""
    factor = 1
    while max(cams.height, cams.width) / (2 * factor) >= 192:
        factor *= 2
    return factor


def evidence_pixel(setup: Setup) -> float:
    """The size of a pixel of `evidence_level` (canonical frame): no narrower hole can be seen there."""
    return setup.pixel * setup.cams.width / scaled_cameras(setup.cams, _evidence_factor(setup.cams)).width


def evidence_level(setup: Setup) -> tuple[object, np.ndarray]:
    """The cameras and images (normal maps, or photos premultiplied) at about 256 px, where holes are looked for."""
    factor = _evidence_factor(setup.cams)
    level = pyramid_level(setup.targets.fit, factor, normals=setup.targets.kind == "normals")
    return scaled_cameras(setup.cams, factor), setup.all_views(level)


def image_handle_records(opened: list, frame) -> tuple[HandleRecord, ...]:
    """`HandleRecord`s (user units) of the cuts `open_handles` / `hole_tests` kept (canonical frame)."""
    def user(point):
        return None if point is None else tuple((np.asarray(point) * frame.scale + frame.centre).tolist())

    return tuple(HandleRecord("images", centre=user(r["centre"]), radius=r["radius"] * frame.scale,
                              depth=r["depth"] * frame.scale, loss_before=r["loss_before"],
                              loss_after=r["loss_after"], cut=r["cut"], end=user(r.get("end"))) for r in opened)


def _image_handles(setup: Setup, start: Start, fit_genus: Callable, edge: float) -> Start:
    """`start` with its missing handles opened where the images show holes, in a fit of the
    hull's own genus (`fit_genus(genus)`, a `Reconstruction`); drilled where they show none.
    The given start when that fails."""
    have, frame = setup.genus - start.tunnels, setup.frame
    pre = fit_genus(have)
    v, f = pre.mesh.to_numpy()
    v = (np.asarray(v, np.float64) - frame.centre) / frame.scale
    try:
        v, f, opened = open_handles(v, f, *evidence_level(setup), start.tunnels, min_radius=evidence_pixel(setup))
    except ValueError:  # the fit is not a manifold solid to cut: drill as before
        opened = []
    mesh = Mesh.from_numpy(np.asarray(v, np.float32), np.asarray(f, np.int32))
    missing = start.tunnels - len(opened)
    if missing:
        mesh = drill_tunnels(mesh, missing, edge)
    mesh = None if mesh is None else remeshed_start(mesh, setup.genus, edge, setup.options)
    if mesh is None:
        return dataclasses.replace(start, handles=_sources(start, setup.genus))
    found = image_handle_records(opened, frame)
    handles = (HandleRecord("hull"),) * have + found + (HandleRecord("drilled"),) * missing
    return Start(mesh, "fit+images" + ("+tunnels" if missing else ""), start.hull_grid, missing, handles)


def first_start(setup: Setup, fit_genus: Callable, say: Callable[[str], None]) -> Start:
    """The start of a run's first fit (module doc); `fit_genus(genus)` fits the same images at
    another genus (used to find hidden handles)."""
    options = setup.options
    edge = first_edge_length(options) * setup.pixel
    start = start_mesh(setup.hulls, setup.genus, setup.bounds, edge, options)
    if not (start.tunnels and setup.targets.kind == "normals" and options.hidden_handles == "images"):
        return dataclasses.replace(start, handles=_sources(start, setup.genus))
    say(f"hidden handles: the visual hull has {setup.genus - start.tunnels} of {setup.genus} handles; fitting that "
        "genus to find the others in the images")
    start = _image_handles(setup, start, fit_genus, edge)
    say(f"hidden handles: {sum(h.source == 'images' for h in start.handles)} opened where the images show holes, "
        f"{start.tunnels} drilled")
    return start


def refit_start(mesh: Mesh, prior: Start, setup: Setup, options: ReconstructOptions) -> Start | None:
    """A refit's start: the previous result `mesh` (user frame) in the canonical frame, remeshed
    to the first edge length, with `prior`'s record (None when the remesh fails)."""
    v, f = mesh.to_numpy()
    v = (np.asarray(v, np.float64) - setup.frame.centre) / setup.frame.scale
    edge = first_edge_length(options) * setup.pixel
    m = remeshed_start(Mesh.from_numpy(v.astype(np.float32), np.asarray(f, np.int32)), setup.genus, edge, options)
    return None if m is None else dataclasses.replace(prior, mesh=m, kind=prior.kind + "+refit")

def _vote(test) -> float:
    """The share of the loss the cut moved (summed over the views) that moved the way the test
    decided: down for a kept cut, up for a rejected one (0.5: it moved nothing)."""
    n = test["gain"] + test["rise"]
    if n <= 0:
        return 0.5
    return (test["gain"] if test["kept"] else test["rise"]) / n


def images_estimate(hull: GenusEstimate, tests: HoleTests, to_user=None) -> GenusEstimate:
    """The estimate from the silhouettes' `hull` and the hole `tests` of a fit at its genus
    (module doc). `to_user(point)` maps a canonical point to the user's frame (None: as is)."""
    found = len(tests.opened)
    genus = hull.genus + found
    votes = [_vote(t) for t in tests.tested]
    agreement = (1.0 if found else hull.agreement) * min(votes, default=1.0) * (1.0 - tests.unexplained)
    plausible = set(hull.plausible) | {genus}
    if tests.unexplained > 0 or any(not t["kept"] and t["gain"] > 0 for t in tests.tested):
        plausible.add(genus + 1)
    if any(t["kept"] and t["worse"] > 0 for t in tests.tested):
        plausible.add(genus - 1)
    move = (lambda p: p) if to_user is None else to_user
    holes = tuple({**t, "centre": [float(x) for x in move(np.asarray(t["centre"], float))]} for t in tests.tested)
    return GenusEstimate(genus, float(agreement), hull.evidence, tuple(sorted(plausible)),
                         cue="images" if found else "silhouettes", holes=holes)


def estimate_line(hull: GenusEstimate, est: GenusEstimate, seconds: float) -> str:
    """The log line of the images' part of the estimate."""
    kept = sum(h["kept"] for h in est.holes)
    tested = len(est.holes)
    if est.cue == "images":
        carved = sum(h["kept"] and h.get("cut") == "carve" for h in est.holes)
        how = (f"; {carved} of them where the silhouettes show empty space at a pixel's grid, too thin for the "
               "closings" if carved else "")
        what = (f"{kept} hole{'s' if kept != 1 else ''} the visual hull does not count confirmed in the normal images "
                f"(of {tested} tested{how}): genus {hull.genus} -> {est.genus}, decided by the images")
    elif tested:
        what = f"none of {tested} hole-shaped disagreements of the normal images lowered the loss: genus {est.genus} stands"
    else:
        what = f"the normal images show no hole-shaped disagreement: genus {est.genus} stands"
    low = "; low agreement: give the genus if you know it" if est.agreement < 0.5 else ""
    return (f"genus: {what}; agreement {est.agreement:.0%}, plausible {list(est.plausible)}{low} ({seconds:.0f}s)")


#: Candidates the verdict tests on a result (the strongest; each costs up to 60 booleans and a render).
CHECK_TRIES = 4
#: A cut the verdict holds against a result must move the loss this much more down than up
#: (`_vote` >= 2/3: the views it improved outweigh those it made worse two to one), so that a
#: result is not failed on a cut the views are split about.
CHECK_VOTE = 2.0 / 3.0


def holes_not_had(tests: HoleTests, genus: int, to_user=None) -> str:
    """Why a result of genus `genus` does not match its images' topology ("" when it does): the
    cuts of `tests` (on the result) that the views confirm (`CHECK_VOTE`), with where they are."""
    move = (lambda p: p) if to_user is None else to_user
    sure = [t for t in tests.tested if t["kept"] and _vote(t) >= CHECK_VOTE]
    if not sure:
        return ""
    where = "; ".join(str([round(float(x), 4) for x in move(np.asarray(t["centre"], float))]) for t in sure)
    return (f"the images show {len(sure)} hole{'s' if len(sure) > 1 else ''} that the result (genus {genus}) does "
            f"not have: a cut there lowers the image loss (at {where}, user units); the object's genus may be "
            f"{genus + len(sure)}")
