"""The start stage of a fit: its start mesh, and where each of its handles came from.

A first fit starts from `start_mesh` (the visual hull with the requested genus, missing
handles drilled, or a primitive). With normal-map targets and `hidden_handles="images"`,
a hull with fewer handles than asked is first fitted at its own genus, and the missing
holes are opened where that fit's normals disagree with the images (`open_handles`);
only what the images do not show is drilled. A refit starts from the previous result,
remeshed to the first edge length.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from jaxgenus.geometry import Mesh
from jaxgenus.optim import pyramid_level, scaled_cameras
from jaxgenus.pipeline._handles import open_handles
from jaxgenus.pipeline._history import HandleRecord
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.pipeline._setup import Setup
from jaxgenus.pipeline._start import Start, drill_tunnels, remeshed_start, start_mesh

__all__ = ["first_edge_length", "first_start", "refit_start"]


def first_edge_length(options: ReconstructOptions) -> float:
    """The edge length (pixels) of a start: that of the first remesh."""
    lengths = options.edge_lengths()
    return lengths[0] if lengths else options.final_edge_length


def _sources(start: Start, genus: int) -> tuple[HandleRecord, ...]:
    if start.kind in ("primitive", "sphere"):
        return tuple(HandleRecord(start.kind) for _ in range(genus if start.kind == "primitive" else 0))
    return (HandleRecord("hull"),) * (genus - start.tunnels) + (HandleRecord("drilled"),) * start.tunnels


def _evidence_level(setup: Setup) -> tuple[object, np.ndarray]:
    """The cameras and normal images at about 256 px, where holes are looked for."""
    cams, factor = setup.cams, 1
    while max(cams.height, cams.width) / (2 * factor) >= 192:
        factor *= 2
    return scaled_cameras(cams, factor), setup.all_views(pyramid_level(setup.targets.fit, factor, normals=True))


def _image_handles(setup: Setup, start: Start, fit_genus: Callable, edge: float) -> Start:
    """`start` with its missing handles opened where the images show holes, in a fit of the
    hull's own genus (`fit_genus(genus)`, a `Reconstruction`); drilled where they show none.
    The given start when that fails."""
    have, frame = setup.genus - start.tunnels, setup.frame
    pre = fit_genus(have)
    v, f = pre.mesh.to_numpy()
    v = (np.asarray(v, np.float64) - frame.centre) / frame.scale
    try:
        v, f, opened = open_handles(v, f, *_evidence_level(setup), start.tunnels)
    except ValueError:  # the fit is not a manifold solid to cut: drill as before
        opened = []
    mesh = Mesh.from_numpy(np.asarray(v, np.float32), np.asarray(f, np.int32))
    missing = start.tunnels - len(opened)
    if missing:
        mesh = drill_tunnels(mesh, missing, edge)
    mesh = None if mesh is None else remeshed_start(mesh, setup.genus, edge, setup.options)
    if mesh is None:
        return dataclasses.replace(start, handles=_sources(start, setup.genus))
    def user(point):
        return None if point is None else tuple((np.asarray(point) * frame.scale + frame.centre).tolist())

    found = tuple(HandleRecord("images", centre=user(r["centre"]), radius=r["radius"] * frame.scale,
                               depth=r["depth"] * frame.scale, loss_before=r["loss_before"],
                               loss_after=r["loss_after"], cut=r["cut"], end=user(r.get("end"))) for r in opened)
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
