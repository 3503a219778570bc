"""Views split over devices: which device mesh the cameras are sharded over, and running a
per-view function there.

An XLA FFI call (the native CPU kernel) is not partitioned by XLA: under `jit`, sharded inputs
are gathered and every device renders every view. `per_device` runs the function with
`jax.shard_map` instead: each device gets its own views (the cameras' leading axis, split over
the mesh axis the cameras name), the mesh and everything else replicated, and the images come
back split the same way; the gradient of replicated inputs is summed over the devices by
`shard_map`'s transpose.
"""

from __future__ import annotations

from typing import Callable

import jax
from jax.sharding import NamedSharding, PartitionSpec as P

__all__ = ["ViewSharding", "per_device", "view_sharding"]


class ViewSharding(tuple):
    """`(mesh, axis)`: the device mesh and the mesh axis (a name or a tuple of names) the views are split over."""

    @property
    def mesh(self):
        return self[0]

    @property
    def axis(self):
        return self[1]

    @property
    def devices(self) -> int:
        names = self.axis if isinstance(self.axis, tuple) else (self.axis,)
        size = 1
        for name in names:
            size *= self.mesh.shape[name]
        return size


def view_sharding(array) -> ViewSharding | None:
    """The mesh and axis `array`'s leading (view) axis is split over, when it is split: a concrete
    array with a `NamedSharding`, or a traced one under explicit sharding; None otherwise (one
    device, replicated, or a tracer whose sharding is left to XLA)."""
    sharding = None
    if isinstance(array, jax.Array) and not isinstance(array, jax.core.Tracer):
        sharding = array.sharding
    else:
        try:
            sharding = jax.typeof(array).sharding
        except (AttributeError, TypeError):
            return None
    if not isinstance(sharding, NamedSharding) or len(sharding.spec) == 0 or sharding.spec[0] is None:
        return None
    found = ViewSharding((sharding.mesh, sharding.spec[0]))
    return found if found.devices > 1 else None


def per_device(fn: Callable, where: ViewSharding, n_views: int, *, replicated, split, out_split=True):
    """`fn(*replicated, *split)` run on every device of `where` with its share of the `split`
    arguments' leading axis (`n_views` views, which must divide evenly), `replicated` whole.
    `out_split`: a pytree prefix of the outputs, True where they are split by view, False where
    they are the same on every device."""
    if n_views % where.devices:
        raise ValueError(f"cameras: {n_views} views cannot be split evenly over the {where.devices} devices of mesh "
                         f"axis {where.axis!r}; shard a multiple of {where.devices} views")
    axis = where.axis
    specs_out = jax.tree.map(lambda s: P(axis) if s else P(), out_split)
    mapped = jax.shard_map(
        lambda rep, spl: fn(*rep, *spl), mesh=where.mesh, in_specs=(P(), P(axis)), out_specs=specs_out,
        check_vma=False,
    )
    return mapped(tuple(replicated), tuple(split))
