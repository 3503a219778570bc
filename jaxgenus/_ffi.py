"""Loads the `jaxgenus._native` extension and registers its XLA FFI targets (CPU).

Registration happens once, at import, in jax's own target registry; this module
keeps no state of its own.
"""

from __future__ import annotations

import jax

from jaxgenus import _native

for _name, _capsule in _native.registrations().items():
    jax.ffi.register_ffi_target(_name, _capsule, platform="cpu")

native = _native

__all__ = ["native"]
