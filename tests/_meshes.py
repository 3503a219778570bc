"""Shared test meshes: trimesh's torus and icosphere, as trimesh meshes, numpy arrays or jaxgenus Meshes.

Each builder reproduces exactly what the test modules used to build locally (same vertices
and faces, in the same order and dtypes), so their assertions are unchanged. `dtype=None`
hands trimesh's float64 vertices to `jg.Mesh.from_numpy` as they are (float32 there unless
jax x64 is on); a dtype casts them first.
"""

from __future__ import annotations

import numpy as np
import trimesh

import jaxgenus as jg


def torus_trimesh(major=1.0, minor=0.3, major_sections=24, minor_sections=12, scale=None) -> trimesh.Trimesh:
    """trimesh's torus about z; `scale` (3,) stretches it along the axes (an elliptic torus)."""
    t = trimesh.creation.torus(
        major_radius=major, minor_radius=minor, major_sections=major_sections, minor_sections=minor_sections
    )
    if scale is None:
        return t
    return trimesh.Trimesh(t.vertices * np.asarray(scale), t.faces, process=False)


def torus(major=1.0, minor=0.3, major_sections=24, minor_sections=12, *, capacity=None, dtype=None) -> jg.Mesh:
    """`torus_trimesh(...)` as a jaxgenus Mesh of the given capacity."""
    t = torus_trimesh(major, minor, major_sections, minor_sections)
    v = t.vertices if dtype is None else np.asarray(t.vertices, dtype)
    return jg.Mesh.from_numpy(v, np.asarray(t.faces), capacity=capacity)


def icosphere_trimesh(subdivisions=2, radius=1.0) -> trimesh.Trimesh:
    """trimesh's icosphere."""
    return trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)


def icosphere_arrays(subdivisions=2, radius=1.0, noise=0.0, seed=0):
    """`(vertices (V, 3) float64, faces (F, 3) int64)` of an icosphere; `noise > 0` scales each
    vertex by `1 + noise * N(0, 1)`, drawn from `np.random.default_rng(seed)` (a Generator
    passed as `seed` is used, and advanced, as it is)."""
    s = icosphere_trimesh(subdivisions, radius)
    v = np.asarray(s.vertices)
    if noise:
        rng = np.random.default_rng(seed)
        v = v * (1.0 + noise * rng.standard_normal((len(v), 1)))
    return v, np.asarray(s.faces)


def icosphere(subdivisions=2, radius=1.0, noise=0.0, seed=0, *, capacity=None, dtype=None) -> jg.Mesh:
    """`icosphere_arrays(...)` as a jaxgenus Mesh of the given capacity."""
    v, f = icosphere_arrays(subdivisions, radius, noise, seed)
    if dtype is not None:
        v = np.asarray(v, dtype)
    return jg.Mesh.from_numpy(v, f, capacity=capacity)
