"""The "large steps" reparametrization of Nicolet et al. (2021).

Vertices `x` are optimized through `u = (I + lambda L) x`, with `L` the uniform
Laplacian. Each step recovers `x = (I + lambda L)^-1 u`; the gradient with respect
to `u` is the gradient with respect to `x` pulled back through the same solve
(`(I + lambda L)` is symmetric). The paper's other form `(1 - alpha) I + alpha L`
is the same matrix up to the factor `1 - alpha`, with `lambda = alpha / (1 - alpha)`
(`lambda_from_alpha`).

The solve is a matrix-free, Jacobi-preconditioned conjugate gradient in a
`lax.while_loop`, warm-started from the previous `x` (per column, only where
the warm start's residual is smaller than `||b||`). Each of the 3 coordinate
columns is its own CG system (vectorized). Padded vertices are isolated, so
their rows are the identity and the matrix stays symmetric positive definite on
padded meshes. Non-convergence is reported in `SolveInfo`, never hidden: the
iteration stops at `max_iter` and returns the (finite) iterate together with
its true relative residual.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxgenus._operators import UniformLaplacian

__all__ = [
    "SolveInfo",
    "lambda_from_alpha",
    "largesteps_solve",
    "to_differential",
    "from_differential",
]

DEFAULT_LAMBDA = 19.0
DEFAULT_RTOL = 1e-6
DEFAULT_MAX_ITER = 2000


class SolveInfo(eqx.Module):
    """What a `(I + lambda L) x = b` solve did.

    Attributes:
        iterations: int32 CG iterations taken.
        residual: the true relative residual `max_c ||b_c - A x_c|| / ||b_c||`
            over the coordinate columns (0 where `b_c = 0`).
        converged: bool, the CG residual reached `rtol` within `max_iter` (False
            whenever `b` or the result is not finite).
    """

    iterations: Int[Array, ""]
    residual: Float[Array, ""]
    converged: Bool[Array, ""]


def lambda_from_alpha(alpha: float) -> float:
    """The `lambda` with `(1 - alpha) I + alpha L = (1 - alpha)(I + lambda L)`, for `0 <= alpha < 1`."""
    alpha = float(alpha)
    if not 0.0 <= alpha < 1.0:
        raise ValueError(f"alpha must be in [0, 1), got {alpha}")
    return alpha / (1.0 - alpha)


def _check_lambda(lambda_):
    if isinstance(lambda_, (int, float)) and not lambda_ >= 0.0:
        raise ValueError(f"lambda_ must be >= 0, got {lambda_}")


def to_differential(laplacian: UniformLaplacian, x: Float[Array, "V 3"], lambda_=DEFAULT_LAMBDA) -> Float[Array, "V 3"]:
    """`u = (I + lambda L) x`."""
    _check_lambda(lambda_)
    return x + lambda_ * laplacian(x)


def _column_norms(r):
    return jnp.sqrt(jnp.sum(r * r, axis=0))


def largesteps_solve(
    laplacian: UniformLaplacian,
    b: Float[Array, "V 3"],
    lambda_=DEFAULT_LAMBDA,
    x0: Float[Array, "V 3"] | None = None,
    *,
    rtol: float = DEFAULT_RTOL,
    max_iter: int = DEFAULT_MAX_ITER,
) -> tuple[Float[Array, "V 3"], SolveInfo]:
    """Solve `(I + lambda L) x = b` by preconditioned CG, warm-started at `x0`.

    Not differentiable by itself (use `from_differential` for that). Stops when
    every column's preconditioned-CG residual is `<= rtol * ||b_c||` or after
    `max_iter` iterations; `SolveInfo` says which.
    """
    _check_lambda(lambda_)
    if b.ndim != 2 or b.shape[0] != laplacian.degree.shape[0]:
        raise ValueError(f"b must have shape ({laplacian.degree.shape[0]}, k), got {b.shape}")
    if rtol <= 0:
        raise ValueError(f"rtol must be > 0, got {rtol}")
    if max_iter < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter}")

    def matvec(v):
        return v + lambda_ * laplacian(v)

    inv_diag = (1.0 / (1.0 + lambda_ * laplacian.degree)).astype(b.dtype)[:, None]
    bnorm = _column_norms(b)
    nonzero = bnorm > 0
    if x0 is None:
        x, r = jnp.zeros_like(b), b
    else:
        # keep the warm start only in columns where it beats x = 0 (a start far larger
        # than the solution would cost float32 accuracy); a zero b gets x = 0 at once
        x = x0.astype(b.dtype)
        r = b - matvec(x)
        use = nonzero & (_column_norms(r) < bnorm)
        x, r = jnp.where(use, x, 0.0), jnp.where(use, r, b)
    tol2 = (rtol * bnorm) ** 2
    z = inv_diag * r
    rz = jnp.sum(r * z, axis=0)
    tiny = jnp.finfo(b.dtype).tiny

    def active(r):
        return nonzero & (jnp.sum(r * r, axis=0) > tol2)

    def cond(carry):
        k, _, r, _, _ = carry
        return (k < max_iter) & jnp.any(active(r))

    def body(carry):
        k, x, r, p, rz = carry
        on = active(r)
        ap = matvec(p)
        pap = jnp.sum(p * ap, axis=0)
        alpha = jnp.where(on & (pap > tiny), rz / jnp.where(pap > tiny, pap, 1.0), 0.0)
        x = x + alpha * p
        r = r - alpha * ap
        z = inv_diag * r
        rz_new = jnp.sum(r * z, axis=0)
        beta = jnp.where(rz > tiny, rz_new / jnp.where(rz > tiny, rz, 1.0), 0.0)
        p = jnp.where(on, z + beta * p, p)
        return k + 1, x, r, p, rz_new

    k, x, r, _, _ = jax.lax.while_loop(cond, body, (jnp.int32(0), x, r, z, rz))
    true_r = _column_norms(b - matvec(x))
    rel = jnp.max(jnp.where(nonzero, true_r / jnp.where(nonzero, bnorm, 1.0), 0.0))
    # NaN compares False in `active`: a non-finite b or iterate must not read as converged
    finite = jnp.all(jnp.isfinite(bnorm)) & jnp.isfinite(rel)
    converged = ~jnp.any(active(r)) & finite
    return x, SolveInfo(iterations=k, residual=rel, converged=converged)


def from_differential(
    laplacian: UniformLaplacian,
    u: Float[Array, "V 3"],
    lambda_=DEFAULT_LAMBDA,
    x0: Float[Array, "V 3"] | None = None,
    *,
    rtol: float = DEFAULT_RTOL,
    max_iter: int = DEFAULT_MAX_ITER,
) -> Float[Array, "V 3"]:
    """`x = (I + lambda L)^-1 u`, differentiable in `u`: the backward pass is a second solve.

    `x0` (a warm start) and the Laplacian get no gradient.
    """
    x0 = jnp.zeros_like(u) if x0 is None else x0

    def solve(b, start):
        return largesteps_solve(laplacian, b, lambda_, start, rtol=rtol, max_iter=max_iter)[0]

    @jax.custom_vjp
    def inverse(u, start):
        return solve(u, start)

    def fwd(u, start):
        return solve(u, start), None

    def bwd(_, g):
        return solve(g, jnp.zeros_like(g)), jnp.zeros_like(g)

    inverse.defvjp(fwd, bwd)
    return inverse(u, jax.lax.stop_gradient(x0))
