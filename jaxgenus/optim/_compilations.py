"""`count_compilations`: how many executables XLA compiles in a block of code, per jitted function.

It listens to JAX's own monitoring event for backend compilations (public
`jax.monitoring` listeners), only while the `with` block runs, so nothing stays
registered and no JAX internals are read.
"""

from __future__ import annotations

import collections
import contextlib
from typing import Iterator

import jax

__all__ = ["count_compilations"]

_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"


@contextlib.contextmanager
def count_compilations() -> Iterator[collections.Counter]:
    """`with count_compilations() as counts:` ... then `counts[name]` is the number of executables
    compiled for the jitted function `name` (its Python name, e.g. `"optimize_steps"`) inside the
    block; `sum(counts.values())` counts them all."""
    counts: collections.Counter = collections.Counter()

    def listen(event: str, _seconds: float, **meta) -> None:
        if event == _COMPILE_EVENT:
            name = str(meta.get("fun_name", "?"))
            counts[name[4:-1] if name.startswith("jit(") and name.endswith(")") else name] += 1

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield counts
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
