"""Loads the `jaxgenus._native` extension and registers its XLA FFI targets (CPU).

Registration happens once, at import, in jax's own target registry; this module
keeps no state of its own. The native kernels run on the host: `host_ffi_call` calls
one directly in a CPU program, and from a program on another platform (a GPU) through a
host callback that runs the same call on the CPU device (the arrays cross to the host
and back).
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from jaxgenus import _native

for _name, _capsule in _native.registrations().items():
    jax.ffi.register_ffi_target(_name, _capsule, platform="cpu")

native = _native

__all__ = ["host_ffi_call", "native"]


def _on_cpu(name, result_shapes, attrs, *args):
    """The host side of `host_ffi_call`: the FFI call compiled for the CPU device."""
    cpu = jax.devices("cpu")[0]
    call = jax.ffi.ffi_call(name, result_shapes, vmap_method="sequential")
    run = jax.jit(lambda *a: call(*a, **attrs))
    out = run(*[jax.device_put(np.asarray(a), cpu) for a in args])
    return tuple(np.asarray(o) for o in out)


def host_ffi_call(name: str, result_shapes, *args, **attrs):
    """`jax.ffi.ffi_call(name, result_shapes, vmap_method="sequential")(*args, **attrs)` for a CPU
    target, from a program on any platform: direct on CPU, elsewhere a `pure_callback` that runs it
    on the CPU device. Works inside `jit`, `lax.scan` and `vmap` (sequentially)."""
    direct = lambda *a: tuple(jax.ffi.ffi_call(name, result_shapes, vmap_method="sequential")(*a, **attrs))
    host = lambda *a: tuple(jax.pure_callback(functools.partial(_on_cpu, name, result_shapes, attrs),
                                              result_shapes, *a, vmap_method="sequential"))
    return jax.lax.platform_dependent(*args, cpu=direct, default=host)
