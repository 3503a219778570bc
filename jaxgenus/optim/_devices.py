"""An optimizer step over several devices: the views split over a device mesh, the mesh replicated.

`spread_views` lays N views out over D devices: view i goes to device i mod D, each device's
block padded to the same length with copies of its first view marked invalid. `views_gradient`
is the step's loss and gradient computed on every device from its own views with
`jax.shard_map`: each device samples its share of the step's views among its valid ones (a key
folded with its index), renders them and takes the gradient of the objective there; the losses
and gradients are averaged over the devices (`pmean`), which is the mean over all sampled views
(every device samples the same number). The geometric terms are computed alike on every device
and stay as they are. One device: not used (the caller's path is today's).

Across processes each process may hold only its own views (`held_views`: those its devices
render): `place_held` lays them out on the mesh without the others, and `gathered_views` hands
every process all views of a small per-view array (silhouettes at the hull's level, scores).
"""

from __future__ import annotations

import math
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import AxisType, NamedSharding, PartitionSpec as P

__all__ = ["AXIS", "device_mesh", "gathered_views", "held_views", "place", "place_held", "spread_views",
           "summed_over_processes", "views_gradient", "views_layout"]

AXIS = "views"


def device_mesh(devices: int | None):
    """A 1-D mesh (axis `"views"`) of the first `devices` devices of the default backend (None: all of
    them; every process's when processes were joined by `jax.distributed`); None when that is one."""
    local = jax.devices() if jax.process_count() > 1 else jax.local_devices()
    n = len(local) if devices is None else int(devices)
    if not 1 <= n <= len(local):
        raise ValueError(f"devices must be between 1 and the {len(local)} devices, got {devices}")
    if n == 1:
        return None
    return jax.make_mesh((n,), (AXIS,), axis_types=(AxisType.Auto,), devices=local[:n])


def spread_views(n_views: int, n_devices: int) -> tuple[np.ndarray, np.ndarray]:
    """`(order (N_pad,), valid (N_pad,))`: the view in each slot, device by device, and whether it is
    a real view (not padding); `N_pad` is a multiple of `n_devices`."""
    if n_views < n_devices:
        raise ValueError(f"devices: {n_devices} devices for {n_views} views; use at most one device per view")
    per = math.ceil(n_views / n_devices)
    order = np.zeros(per * n_devices, np.int64)
    valid = np.zeros(per * n_devices, bool)
    for d in range(n_devices):
        mine = np.arange(d, n_views, n_devices)
        order[d * per : d * per + len(mine)] = mine
        order[d * per + len(mine) : (d + 1) * per] = mine[0]
        valid[d * per : d * per + len(mine)] = True
    return order, valid


def views_layout(n_views: int, devices: int | None):
    """`(mesh, order, valid)` of `n_views` views over `devices` devices (None: all, at most one per
    view): the device mesh (None for one device) and `spread_views`' layout on it."""
    mesh = device_mesh(min(devices or jax.device_count(), n_views))
    return (mesh,) + (spread_views(n_views, mesh.size) if mesh is not None else (None, None))


def held_views(n_views: int, devices: int | None = None) -> np.ndarray:
    """The views (sorted indices) this process's devices render when `n_views` views are split over
    `devices` devices (None: all of every process): what this process needs to load. All views
    with one process, one device, or a process none of whose devices is used."""
    mesh, order, _ = views_layout(n_views, devices)
    if mesh is None or jax.process_count() == 1:
        return np.arange(n_views)
    per = len(order) // mesh.size
    mine = [d.process_index == jax.process_index() for d in mesh.devices.flat]
    held = np.unique([order[s] for s in range(len(order)) if mine[s // per]])
    return held if len(held) else np.arange(n_views)


def gathered_views(local, held: np.ndarray | None, n_views: int) -> np.ndarray:
    """`(n_views, ...)`: every process's rows of a per-view array put together. `local` holds the
    views `held` (None: all of them, nothing to gather); every view must be held by some process."""
    local = np.asarray(local)
    if held is None:
        return local
    held = np.asarray(held, np.int64)
    if jax.process_count() == 1:
        if len(held) != n_views or not np.array_equal(np.sort(held), np.arange(n_views)):
            raise ValueError(f"views: one process must hold all {n_views} views, got {len(held)}")
        out = np.empty_like(local)
        out[held] = local
        return out
    from jax.experimental import multihost_utils

    most = int(np.max(multihost_utils.process_allgather(np.int64(len(held)))))
    pad = np.zeros((most - len(held),) + local.shape[1:], local.dtype)
    rows = multihost_utils.process_allgather(np.concatenate([local, pad]))
    index = multihost_utils.process_allgather(np.concatenate([held, np.full(most - len(held), -1, np.int64)]))
    out = np.zeros((n_views,) + local.shape[1:], local.dtype)
    seen = np.zeros(n_views, bool)
    for r, i in zip(rows.reshape((-1,) + local.shape[1:]), index.reshape(-1)):
        if i >= 0:
            out[i], seen[i] = r, True
    if not seen.all():
        raise ValueError(f"views: no process holds views {np.flatnonzero(~seen)[:10].tolist()} of {n_views}")
    return out


def summed_over_processes(local) -> np.ndarray:
    """`local` (an array of the same shape in every process) summed over the processes joined by
    `jax.distributed`, in process order (every process gets the same values); `local` itself with one."""
    local = np.asarray(local)
    if jax.process_count() == 1:
        return local
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.process_allgather(local)).reshape((-1,) + local.shape).sum(axis=0)


def place_held(tree, mesh, order: np.ndarray, held: np.ndarray):
    """Per-view arrays that hold only the views `held` (leading axis), split over `mesh` in the
    layout `order` (`spread_views`): each process hands over the slots its devices keep, which
    must be views it holds (`held_views`)."""
    sharding = NamedSharding(mesh, P(AXIS))
    row = {int(v): r for r, v in enumerate(held)}

    def put(a):
        if a is None:
            return None
        host = np.asarray(a)

        def part(index):
            slots = np.arange(len(order))[index[0]]
            missing = [int(order[s]) for s in slots if int(order[s]) not in row]
            if missing:
                raise ValueError(f"views: this process's devices render views {missing[:10]} it does not hold")
            return host[np.array([row[int(order[s])] for s in slots])][(slice(None),) + tuple(index[1:])]

        return jax.make_array_from_callback((len(order),) + host.shape[1:], sharding, part)

    return jax.tree.map(put, tree, is_leaf=lambda x: x is None)


def place(tree, mesh, split: bool):
    """`tree`'s arrays on `mesh`: split along their leading axis, or replicated. Across processes every
    process holds the whole value and hands over the parts its own devices keep."""
    sharding = NamedSharding(mesh, P(AXIS) if split else P())

    def put(a):
        if not isinstance(a, (jax.Array, np.ndarray)):
            return a
        if jax.process_count() == 1:
            return jax.device_put(a, sharding)
        if jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key):  # keys travel as their raw data
            impl = jax.random.key_impl(a)
            return jax.random.wrap_key_data(put(jax.random.key_data(a)), impl=impl)
        host = np.asarray(a)
        return jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])

    return jax.tree.map(put, tree)


def views_gradient(loss_fn: Callable, mesh, per_device: int, select: Callable) -> Callable:
    """`gradient(key, x, app, views, valid, geometry, everyone) -> ((loss, terms), (gx, g_app))` over the
    devices of `mesh` (module doc): `loss_fn(x, app, cameras, targets, outside, geometry, near)`,
    everything it reads passed in (a value closed over from outside `shard_map` would carry the outer
    sharding). `views`: a tuple of per-view arrays (or None) split over the devices; `everyone`: arrays
    every device holds whole (or None); `select(key, views, index, everyone)` turns a device's sampled
    view indices into `(cameras, targets, outside, near)` it renders (crops, photo-consistency
    neighbours and all). A device samples `per_device` of its views, its valid ones first (when it has
    fewer valid ones, copies of its first view fill in)."""

    def local(x, app, key, geometry, everyone, views, valid):
        sub = jax.random.fold_in(key, jax.lax.axis_index(AXIS))
        weights = valid + 1e-6 * (1.0 - valid)  # padding only when a device runs out of views
        idx = jax.random.choice(sub, valid.shape[0], (per_device,), replace=False, p=weights / jnp.sum(weights))
        cams, tgt, out, near = select(sub, views, idx, everyone)
        result = jax.value_and_grad(loss_fn, argnums=(0, 1), has_aux=True)(x, app, cams, tgt, out, geometry, near)
        return jax.lax.pmean(result, AXIS)

    mapped = jax.shard_map(local, mesh=mesh, in_specs=(P(), P(), P(), P(), P(), P(AXIS), P(AXIS)), out_specs=P(),
                           check_vma=False)

    def gradient(key, x, app, views, valid, geometry, everyone=None):
        return mapped(x, app, key, geometry, everyone, views, valid.astype(jnp.float32))

    return gradient
