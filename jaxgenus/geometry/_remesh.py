"""Adaptive isotropic remeshing (native C++ half-edge remesher) that never changes the genus.

Two entry points run the same kernel (`native/kernels/remesh.cc`):

* `remesh(mesh, options)` -- outside `jit`, on numpy or JAX arrays; returns a new
  `Mesh` in a fresh capacity bucket and a `RemeshInfo` of Python values.
* `remesh_in_jit(mesh, options, attributes)` -- an XLA FFI call on the mesh's
  capacity buffers, usable inside `jit` and between `lax.scan` blocks; the
  output keeps the input's capacities and reports a status instead of raising.

The algorithm is the Botsch-Kobbelt loop (split edges longer than 4/3 L,
collapse edges shorter than 4/5 L, flip toward valence 6, tangential smoothing
projected back onto the input surface) with a per-vertex target length L: the
uniform `target_edge_length`, or, with `adaptive=True`, the curvature rule of
Dunyach et al. 2013, `L = sqrt(6 eps / kappa - 3 eps^2)` with kappa the largest
absolute principal curvature, clamped to `[min_edge_length, max_edge_length]`
and scaled up to fit the face budget. Adaptive runs first do a V-cycle
coarsening phase (collapse toward `coarsen_factor * L`) and then refine.

Every operation is legality-checked (link condition, no normal flips, valence
>= 3, no fold-overs), and the result is validated before it is returned
(half-edge invariants, Euler characteristic, number of components): on any
failure the input comes back unchanged with a non-zero status.

Carried per-vertex attributes (e.g. Adam moments, rest positions for the
inversion penalty) follow the operations: a split vertex gets the mean of its
edge's endpoints, a collapse keeps the mean of the two merged vertices, flips
and smoothing leave them as they are. Interpolated moments are a reasonable
warm start; callers that prefer to reset them can zero the returned array.
"""

from __future__ import annotations

import dataclasses
import enum

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from jaxgenus._ffi import host_ffi_call, native
from jaxgenus.geometry._mesh import Mesh, capacity_bucket

__all__ = ["RemeshOptions", "RemeshInfo", "RemeshStatus", "remesh", "remesh_in_jit", "settings_repr"]


def settings_repr(settings, default=None) -> str:
    """`Name(field=value, ...)` of a frozen settings dataclass whose fields all have defaults,
    naming only the fields that differ from `default` (the class's defaults): `RemeshOptions()`
    reads `RemeshOptions()`, and nested settings name only what differs from the default's own."""
    default = type(settings)() if default is None else default
    changed = []
    for f in dataclasses.fields(settings):
        value, base = getattr(settings, f.name), getattr(default, f.name)
        try:
            same = bool(value == base)
        except (TypeError, ValueError):  # arrays compare element-wise
            same = False
        if same:
            continue
        nested = dataclasses.is_dataclass(value) and type(value) is type(base)
        changed.append(f"{f.name}={settings_repr(value, base) if nested else repr(value)}")
    return f"{type(settings).__name__}({', '.join(changed)})"


class RemeshStatus(enum.IntEnum):
    """Status codes shared by the native kernels (`native/kernels/status.h`)."""

    OK = 0
    INVALID_INPUT = 1
    CAPACITY_EXCEEDED = 2
    TOPOLOGY_CHANGED = 3


@dataclasses.dataclass(frozen=True, repr=False)
class RemeshOptions:
    """Remeshing parameters (immutable and hashable, so usable as a static `jit` argument).

    Lengths are absolute (mesh units). `None` selects the default shown, where
    `h` is `target_edge_length` or, when that is `None`, the mean edge length of
    the input mesh. The fields mirror the native option list
    (`JAXGENUS_REMESH_PARAMS`, exported as `_native.REMESH_PARAMS`) plus
    `max_faces`; `_native_params` converts them (see docs/remesh.md).

    Attributes:
        target_edge_length: uniform target `h` (`None`: the input's mean edge length).
            Inside `jit` it may be a traced scalar.
        adaptive: use the curvature-adaptive sizing field instead of a uniform one.
        iterations: number of split/collapse/flip/smooth rounds (default 5).
        approx_error: adaptive: the approximation error `eps` (default `0.05 h`).
        min_edge_length: adaptive: lower clamp of the sizing field (default `0.25 h`).
        max_edge_length: adaptive: upper clamp of the sizing field (default `4 h`).
        coarsen_factor: V-cycle: collapse toward `coarsen_factor * L` before refining
            (default 2 when adaptive, 1 = no coarsening phase when uniform).
        smoothing_steps: tangential smoothing steps per iteration (default 1).
        smoothing_lambda: step of tangential smoothing, in (0, 1] (default 1).
        project: project smoothed vertices onto the input surface (default True).
        debug_validate: run the half-edge `validate()` after every single operation
            and report the first violation as TOPOLOGY_CHANGED (slow; for tests).
        max_faces: face budget (`None`: the output capacity in `remesh_in_jit`,
            unlimited in `remesh`). The sizing field is scaled up to fit it and the
            status is then CAPACITY_EXCEEDED (the result is still a valid mesh).
    """

    def __repr__(self) -> str:
        return settings_repr(self)


    target_edge_length: float | None = None
    adaptive: bool = False
    iterations: int = 5
    approx_error: float | None = None
    min_edge_length: float | None = None
    max_edge_length: float | None = None
    coarsen_factor: float | None = None
    smoothing_steps: int = 1
    smoothing_lambda: float = 1.0
    project: bool = True
    debug_validate: bool = False
    max_faces: int | None = None

    def __post_init__(self):
        def positive(name, allow_none=True):
            x = getattr(self, name)
            if x is None and allow_none:
                return
            if isinstance(x, jax.Array) and name == "target_edge_length":
                return  # traced inside jit; checked by the kernel
            if not np.isfinite(x) or x <= 0:
                raise ValueError(f"{name} must be a positive finite number, got {x!r}")

        for name in ("target_edge_length", "approx_error", "min_edge_length", "max_edge_length"):
            positive(name)
        if self.coarsen_factor is not None and not (np.isfinite(self.coarsen_factor) and self.coarsen_factor >= 1):
            raise ValueError(f"coarsen_factor must be >= 1, got {self.coarsen_factor!r}")
        if not 0 <= int(self.iterations) <= 1000:
            raise ValueError(f"iterations must be in [0, 1000], got {self.iterations!r}")
        if not 0 <= int(self.smoothing_steps) <= 100:
            raise ValueError(f"smoothing_steps must be in [0, 100], got {self.smoothing_steps!r}")
        if not 0 < self.smoothing_lambda <= 1:
            raise ValueError(f"smoothing_lambda must be in (0, 1], got {self.smoothing_lambda!r}")
        if (
            self.min_edge_length is not None
            and self.max_edge_length is not None
            and self.max_edge_length < self.min_edge_length
        ):
            raise ValueError("max_edge_length must be >= min_edge_length")
        if self.max_faces is not None and int(self.max_faces) < 4:
            raise ValueError(f"max_faces must be >= 4, got {self.max_faces!r}")

    def _native_params(self, skip: tuple[str, ...] = ()) -> dict:
        """The options typed for the kernel, generated from the native list `_native.REMESH_PARAMS`.

        Every native option takes the field of the same name: `None` -> 0 (the
        kernel's "use the default"), a bool field -> 0/1, then a cast to the native
        dtype. `max_faces` is not a native option (it is the face budget argument);
        `skip` leaves out names passed otherwise (`target_edge_length` is a 0-d
        operand of the FFI call).
        """
        out = {}
        for name, dtype, _default, _doc in native.REMESH_PARAMS:
            if name in skip:
                continue
            value = getattr(self, name)
            if value is None:
                value = 0
            elif isinstance(_PYTHON_DEFAULTS[name], bool):
                value = bool(value)
            elif isinstance(value, jax.Array):
                value = value.item()  # a concrete target_edge_length outside jit
            out[name] = np.dtype(dtype).type(value)
        return out


# RemeshOptions fields that are not native options (REMESH_PARAMS): the face budget.
_PYTHON_ONLY_OPTIONS = ("max_faces",)
_PYTHON_DEFAULTS = {f.name: f.default for f in dataclasses.fields(RemeshOptions)}


class RemeshInfo(eqx.Module):
    """What a remesh did. Python ints from `remesh`, int32 scalars from `remesh_in_jit`.

    Attributes:
        status: a `RemeshStatus` value (0 = OK).
        n_vertices, n_faces: live counts of the result.
        faces_estimated: faces the unconstrained sizing field asks for.
        chi_before, chi_after: Euler characteristic of input and result.
        splits, collapses, flips: operations applied.
        attributes: the carried per-vertex attributes `(V, k)` (`remesh` only;
            `None` when none were given).
        target_edge_length: the `h` used (`remesh` only).
        message: why the status is not OK (`remesh` only).
    """

    status: Int[Array, ""] | int
    n_vertices: Int[Array, ""] | int
    n_faces: Int[Array, ""] | int
    faces_estimated: Int[Array, ""] | int
    chi_before: Int[Array, ""] | int
    chi_after: Int[Array, ""] | int
    splits: Int[Array, ""] | int
    collapses: Int[Array, ""] | int
    flips: Int[Array, ""] | int
    attributes: np.ndarray | None = None
    target_edge_length: float | None = eqx.field(default=None, static=True)
    message: str = eqx.field(default="", static=True)

    @staticmethod
    def _from_info(info, **extra) -> "RemeshInfo":
        """From the native int32 info vector, whose entries `_native.REMESH_INFO_FIELDS` names."""
        return RemeshInfo(**{n: info[i] for i, n in enumerate(native.REMESH_INFO_FIELDS)}, **extra)


def _check_options(options) -> RemeshOptions:
    if options is None:
        return RemeshOptions()
    if not isinstance(options, RemeshOptions):
        raise ValueError(f"options must be a RemeshOptions, got {type(options).__name__}")
    return options


def remesh(mesh, options: RemeshOptions | None = None, *, attributes=None) -> tuple[Mesh, RemeshInfo]:
    """Remesh a closed manifold mesh outside `jit` (numpy path through nanobind).

    Args:
        mesh: a `Mesh`, or a `(vertices (V, 3), faces (F, 3))` pair of numpy/JAX arrays.
        options: `RemeshOptions` (default: uniform, mean input edge length, 5 iterations).
        attributes: optional `(V, k)` per-vertex floats to carry (see the module doc);
            returned as `info.attributes` (float32).

    Returns:
        `(mesh, info)`: the result in a `capacity_bucket` of its face count, and a
        `RemeshInfo` with Python values.

    Raises:
        ValueError: when the mesh is not a closed, oriented, manifold triangle mesh
            (or other invalid input), naming the problem.
    """
    options = _check_options(options)
    if isinstance(mesh, Mesh):
        v, f = mesh.to_numpy()
    elif isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        v, f = np.asarray(mesh[0]), np.asarray(mesh[1])
    else:
        raise ValueError(f"mesh must be a Mesh or a (vertices, faces) pair, got {type(mesh).__name__}")
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"mesh vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"mesh faces must have shape (F, 3), got {f.shape}")
    if attributes is None:
        attr = np.zeros((v.shape[0], 0), np.float32)
    else:
        attr = np.ascontiguousarray(np.asarray(attributes, np.float32))
        if attr.ndim == 1:
            attr = attr[:, None]
        if attr.ndim != 2 or attr.shape[0] != v.shape[0]:
            raise ValueError(f"attributes must have shape (V, k) with V={v.shape[0]}, got {attr.shape}")
    budget = options.max_faces if options.max_faces is not None else 2**30
    v_out, f_out, a_out, info, message, h = native.remesh(
        np.ascontiguousarray(v, np.float64),
        np.ascontiguousarray(f, np.int32),
        attr,
        options=options._native_params(),
        face_budget=int(budget),
    )
    info = [int(x) for x in info]
    status = info[native.REMESH_INFO_FIELDS.index("status")]
    if status not in (RemeshStatus.OK, RemeshStatus.CAPACITY_EXCEEDED):
        raise ValueError(f"mesh: cannot remesh ({RemeshStatus(status).name}): {message}")
    vcap, fcap = capacity_bucket(f_out.shape[0])
    out = Mesh.from_numpy(v_out, f_out, capacity=(max(vcap, v_out.shape[0]), fcap))
    carried = np.asarray(a_out).reshape(v_out.shape[0], -1) if attributes is not None else None
    return out, RemeshInfo._from_info(info, attributes=carried, target_edge_length=float(h), message=message)


def remesh_in_jit(
    mesh: Mesh,
    options: RemeshOptions | None = None,
    attributes: Float[Array, "V k"] | None = None,
) -> tuple[Mesh, Float[Array, "V k"] | None, RemeshInfo]:
    """Remesh a capacity mesh through the XLA FFI (on the host: from a GPU program through a host
    callback, `jaxgenus._ffi.host_ffi_call`); works inside `jit` and `lax.scan`.

    The output keeps the input's capacities; the sizing field is scaled up to fit
    them (`max_faces` defaults to the face capacity). Not differentiable: the
    inputs pass through `lax.stop_gradient`. On invalid input (bad counts or
    indices, NaN, open/non-manifold meshes) the input comes back unchanged with
    `info.status != 0` -- check it with `RemeshStatus`.

    Args:
        mesh: a `Mesh` (vertices float32 or float64, cast to float32 for the kernel).
        options: static `RemeshOptions`; `target_edge_length` may be traced.
        attributes: optional `(Vcap, k)` per-vertex floats to carry (float32).

    Returns:
        `(mesh, attributes, info)` with `info` holding int32 scalars.
    """
    options = _check_options(options)
    if not isinstance(mesh, Mesh):
        raise ValueError(f"mesh must be a jaxgenus.Mesh, got {type(mesh).__name__}")
    vcap, fcap = mesh.vertex_capacity, mesh.face_capacity
    if attributes is None:
        attr = jnp.zeros((vcap, 0), jnp.float32)
    else:
        attr = jnp.asarray(attributes, jnp.float32)
        if attr.ndim != 2 or attr.shape[0] != vcap:
            raise ValueError(f"attributes must have shape (Vcap, k) with Vcap={vcap}, got {attr.shape}")
    target = options.target_edge_length
    target = jnp.asarray(0.0 if target is None else target, jnp.float32)
    budget = fcap if options.max_faces is None else min(int(options.max_faces), fcap)
    sg = jax.lax.stop_gradient
    v, f, a, info = host_ffi_call(
        "jaxgenus_remesh",
        (
            jax.ShapeDtypeStruct((vcap, 3), jnp.float32),
            jax.ShapeDtypeStruct((fcap, 3), jnp.int32),
            jax.ShapeDtypeStruct(attr.shape, jnp.float32),
            jax.ShapeDtypeStruct((native.REMESH_INFO_SIZE,), jnp.int32),
        ),
        sg(mesh.vertices.astype(jnp.float32)),
        sg(mesh.faces.astype(jnp.int32)),
        sg(jnp.stack([mesh.n_vertices, mesh.n_faces]).astype(jnp.int32)),
        sg(attr),
        sg(target),
        options=options._native_params(skip=("target_edge_length",)),
        max_faces=np.int64(budget),
    )
    info = RemeshInfo._from_info(info)
    out = Mesh(vertices=v.astype(mesh.vertices.dtype), faces=f, n_vertices=info.n_vertices, n_faces=info.n_faces)
    return out, (a if attributes is not None else None), info
