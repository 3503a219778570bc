"""The Python mirrors of the native definitions agree with what the extension exports.

The remesh options (`JAXGENUS_REMESH_PARAMS`), the remesh info layout
(`JAXGENUS_REMESH_INFO_FIELDS`) and the mesh_check report layout
(`JAXGENUS_REPORT_FIELDS`) are each defined once in C++ and exported as
`_native.REMESH_PARAMS`, `_native.REMESH_INFO_FIELDS` and `_native.REPORT_FIELDS`.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgenus as jg
from jaxgenus._ffi import native
from jaxgenus.geometry._remesh import _PYTHON_ONLY_OPTIONS, RemeshInfo, RemeshOptions


# the native kernels are CPU targets called directly here: pin the CPU device (conftest.py)
pytestmark = pytest.mark.usefixtures("cpu_device")
from jaxgenus.geometry._topology import MeshReport

# RemeshInfo fields filled by the caller, not from the info vector.
_INFO_EXTRAS = {"attributes", "target_edge_length", "message"}


def _python_to_native_default(value):
    """The documented mapping of a RemeshOptions default to the native one: None -> 0, bool -> 0/1."""
    return 0 if value is None else int(value) if isinstance(value, bool) else value


def test_remesh_options_mirror_the_native_list():
    native_rows = {name: (dtype, default) for name, dtype, default, _doc in native.REMESH_PARAMS}
    python_fields = {f.name: f for f in dataclasses.fields(RemeshOptions)}
    assert len(native_rows) == len(native.REMESH_PARAMS), "duplicate native option names"
    assert set(native_rows) == set(python_fields) - set(_PYTHON_ONLY_OPTIONS)
    for name, (dtype, default) in native_rows.items():
        assert dtype in ("float32", "int32"), name
        assert _python_to_native_default(python_fields[name].default) == default, name
    for _name, _dtype, _default, doc in native.REMESH_PARAMS:
        assert isinstance(doc, str) and doc


def test_native_params_are_typed_by_the_native_list():
    params = RemeshOptions(adaptive=True, approx_error=0.02, project=False, iterations=3)._native_params()
    assert list(params) == [row[0] for row in native.REMESH_PARAMS]
    for name, dtype, _default, _doc in native.REMESH_PARAMS:
        assert params[name].dtype == np.dtype(dtype), name
    assert params["adaptive"] == 1 and params["project"] == 0 and params["iterations"] == 3
    assert params["approx_error"] == np.float32(0.02)
    assert params["min_edge_length"] == 0 and params["target_edge_length"] == 0  # None -> default
    defaults = RemeshOptions()._native_params()
    assert {k: v.item() for k, v in defaults.items()} == {r[0]: r[2] for r in native.REMESH_PARAMS}
    assert "target_edge_length" not in RemeshOptions()._native_params(skip=("target_edge_length",))


def test_remesh_info_layout():
    names = tuple(native.REMESH_INFO_FIELDS)
    assert len(names) == native.REMESH_INFO_SIZE == len(set(names))
    fields = {f.name for f in dataclasses.fields(RemeshInfo)}
    assert set(names) == fields - _INFO_EXTRAS
    assert names[0] == "status"


def test_report_layout():
    names = tuple(native.REPORT_FIELDS)
    assert len(names) == len(set(names)) <= native.REPORT_SIZE
    fields = {f.name for f in dataclasses.fields(MeshReport)}
    assert set(names) == fields - {"face_component"}
    # The exported order is the buffer order: a tetrahedron has V=4, E=6, F=4, chi=2.
    faces = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]], np.int32)
    report, comp = native.mesh_check(faces, 4, 4, 4)
    r = {n: int(report[i]) for i, n in enumerate(names)}
    assert (r["status"], r["n_vertices"], r["n_edges"], r["n_faces"]) == (0, 4, 6, 4)
    assert (r["euler_characteristic"], r["n_components"], r["boundary_edges"]) == (2, 1, 0)
    assert not report[len(names) :].any()  # reserved entries


def test_numpy_entry_decodes_the_option_dict():
    mesh = jg.genus_primitive(1)
    v, f = mesh.to_numpy()
    args = (np.ascontiguousarray(v, np.float64), np.ascontiguousarray(f, np.int32), np.zeros((v.shape[0], 0), np.float32))
    full = native.remesh(*args, RemeshOptions()._native_params(), 2**30)
    empty = native.remesh(*args, {}, 2**30)  # missing options keep their defaults
    for a, b in zip(full[:4], empty[:4]):
        np.testing.assert_array_equal(a, b)
    plain = native.remesh(*args, {"iterations": 2, "smoothing_lambda": 1, "project": True}, 2**30)
    typed = native.remesh(*args, RemeshOptions(iterations=2)._native_params(), 2**30)
    np.testing.assert_array_equal(plain[0], typed[0])
    with pytest.raises(ValueError, match="unknown remesh option 'iteration'"):
        native.remesh(*args, {"iteration": 2}, 2**30)
    with pytest.raises(ValueError, match="'iterations' must be int32"):
        native.remesh(*args, {"iterations": "five"}, 2**30)
    with pytest.raises(ValueError, match="'iterations' must be int32"):
        native.remesh(*args, {"iterations": 2**40}, 2**30)


def _ffi_remesh(mesh, options):
    vcap, fcap = mesh.vertex_capacity, mesh.face_capacity
    return jax.ffi.ffi_call(
        "jaxgenus_remesh",
        (
            jax.ShapeDtypeStruct((vcap, 3), jnp.float32),
            jax.ShapeDtypeStruct((fcap, 3), jnp.int32),
            jax.ShapeDtypeStruct((vcap, 0), jnp.float32),
            jax.ShapeDtypeStruct((native.REMESH_INFO_SIZE,), jnp.int32),
        ),
        vmap_method="sequential",
    )(
        mesh.vertices.astype(jnp.float32),
        mesh.faces,
        jnp.stack([mesh.n_vertices, mesh.n_faces]).astype(jnp.int32),
        jnp.zeros((vcap, 0), jnp.float32),
        jnp.float32(0),
        options=options,
        max_faces=np.int64(fcap),
    )


def test_ffi_handler_decodes_the_option_dict():
    mesh = jg.genus_primitive(2)
    _, _, info = jg.geometry.remesh_in_jit(mesh, RemeshOptions())
    v, f, _, info_empty = _ffi_remesh(mesh, {})  # missing options keep their defaults
    np.testing.assert_array_equal(info_empty, np.stack([getattr(info, n) for n in native.REMESH_INFO_FIELDS]))
    for bad, message in (
        ({"iteration": np.int32(2)}, "unknown option 'iteration'"),
        ({"iterations": np.float32(2)}, "option 'iterations'"),
        ({"target_edge_length": np.float32(1)}, "operand"),
    ):
        with pytest.raises(Exception, match=message):
            jax.block_until_ready(_ffi_remesh(mesh, bad))
