"""`uniform_adam`: Adam with one shared step size per parameter array (Nicolet et al. 2021).

The moments are Adam's, but the denominator is `eps + max(sqrt(v_hat))` over all
entries of each parameter array instead of `eps + sqrt(v_hat)` per entry, so a
step moves every vertex by the same scale and never amplifies a small, noisy
gradient component. The transformation is an optax-style
`GradientTransformation` (a NamedTuple of pure `init` and `update` functions):
it composes with optax when optax is installed and plugs into
`optimistix.OptaxMinimiser` without it.

Padding: entries whose gradient is always zero (padded vertices) keep zero
moments and get zero updates, and since `sqrt(v_hat) >= 0` they never change the
max, which therefore only sees live entries.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Int, PyTree

__all__ = ["GradientTransformation", "UniformAdamState", "adam", "uniform_adam"]


class GradientTransformation(NamedTuple):
    """The optax interface: `init(params) -> state`, `update(grads, state, params=None) -> (updates, state)`."""

    init: Callable[..., Any]
    update: Callable[..., Any]


class UniformAdamState(NamedTuple):
    """`count` (int32 steps taken), `mu` and `nu` (first and second moments, like params)."""

    count: Int[Array, ""]
    mu: PyTree
    nu: PyTree


def uniform_adam(
    learning_rate: float, b1: float = 0.9, b2: float = 0.999, eps: float = 1e-8, quantile: float = 1.0
) -> GradientTransformation:
    """Adam whose denominator is `eps + max over all entries of sqrt(v_hat)` (per parameter array).

    Updates are `-learning_rate * m_hat / (eps + max(sqrt(v_hat)))` with the usual
    bias corrections; add them to the parameters (`optax.apply_updates` or `p + u`).
    `learning_rate` may be a float or a traced scalar.

    `quantile < 1` makes the shared scale robust to a few outliers: it is the
    `quantile` of `sqrt(v_hat)` over the entries with a nonzero second moment, and
    an entry above it is divided by its own `sqrt(v_hat)` (plain Adam), so no
    entry steps much further than `learning_rate` and a handful of vertices with
    huge gradients (a tiny feature) cannot shrink everyone else's step.
    `quantile=1` is exactly the max (Nicolet et al.).
    """
    for name, val, lo, hi in (("b1", b1, 0.0, 1.0), ("b2", b2, 0.0, 1.0)):
        if not lo <= float(val) < hi:
            raise ValueError(f"{name} must be in [0, 1), got {val}")
    if not 0.0 < float(quantile) <= 1.0:
        raise ValueError(f"quantile must be in (0, 1], got {quantile}")
    if float(eps) < 0:
        raise ValueError(f"eps must be >= 0, got {eps}")
    if isinstance(learning_rate, (int, float)) and learning_rate < 0:
        raise ValueError(f"learning_rate must be >= 0, got {learning_rate}")

    def init(params):
        # two separate buffers, so that a state can be donated to a jit-compiled function
        return UniformAdamState(
            count=jnp.zeros((), jnp.int32),
            mu=jax.tree.map(jnp.zeros_like, params),
            nu=jax.tree.map(jnp.zeros_like, params),
        )

    def update(grads, state, params=None, **extra_args):
        del params, extra_args
        count = state.count + 1
        mu = jax.tree.map(lambda m, g: b1 * m + (1.0 - b1) * g, state.mu, grads)
        nu = jax.tree.map(lambda v, g: b2 * v + (1.0 - b2) * g * g, state.nu, grads)
        t = count.astype(jnp.result_type(float))
        c1 = 1.0 - b1**t
        c2 = 1.0 - b2**t

        def step(m, v):
            if quantile == 1.0:
                shared = jnp.max(v)
            else:  # entries with zero moments (padding) do not count
                shared = jnp.nanquantile(jnp.where(v > 0, v, jnp.nan), quantile)
                shared = jnp.maximum(jnp.where(jnp.isnan(shared), 0.0, shared), v)
            denom = eps + jnp.sqrt(shared / c2.astype(v.dtype))
            return (-learning_rate * (m / c1.astype(m.dtype)) / denom).astype(m.dtype)

        updates = jax.tree.map(step, mu, nu)
        return updates, UniformAdamState(count=count, mu=mu, nu=nu)

    return GradientTransformation(init, update)


def adam(learning_rate, b1: float = 0.9, b2: float = 0.999, eps: float = 1e-8) -> GradientTransformation:
    """Plain (per-entry) Adam as an optax-style transformation: `-lr * m_hat / (eps + sqrt(v_hat))`.

    Used for the per-vertex albedo and the lighting of photometric fits, whose
    entries have their own scales (uniform Adam's shared step suits positions).
    """
    for name, val in (("b1", b1), ("b2", b2)):
        if not 0.0 <= float(val) < 1.0:
            raise ValueError(f"{name} must be in [0, 1), got {val}")

    def init(params):
        return UniformAdamState(
            count=jnp.zeros((), jnp.int32),
            mu=jax.tree.map(jnp.zeros_like, params),
            nu=jax.tree.map(jnp.zeros_like, params),
        )

    def update(grads, state, params=None, **extra_args):
        del params, extra_args
        count = state.count + 1
        mu = jax.tree.map(lambda m, g: b1 * m + (1.0 - b1) * g, state.mu, grads)
        nu = jax.tree.map(lambda v, g: b2 * v + (1.0 - b2) * g * g, state.nu, grads)
        t = count.astype(jnp.result_type(float))
        c1, c2 = 1.0 - b1**t, 1.0 - b2**t

        def step(m, v):
            m_hat = m / c1.astype(m.dtype)
            return (-learning_rate * m_hat / (eps + jnp.sqrt(v / c2.astype(v.dtype)))).astype(m.dtype)

        return jax.tree.map(step, mu, nu), UniformAdamState(count=count, mu=mu, nu=nu)

    return GradientTransformation(init, update)
