"""The "large steps" reparametrization of Nicolet et al. (2021).

Vertices `x` are optimized through `u = (I + lambda L) x`, with `L` the uniform
Laplacian. Each step recovers `x = (I + lambda L)^-1 u`; the gradient with respect
to `u` is the gradient with respect to `x` pulled back through the same solve
(`(I + lambda L)` is symmetric). The paper's other form `(1 - alpha) I + alpha L`
is the same matrix up to the factor `1 - alpha`, with `lambda = alpha / (1 - alpha)`
(`lambda_from_alpha`).

The solve is `lineax.CG` on a matrix-free `lineax.FunctionLinearOperator`, with a
Jacobi preconditioner, warm-started from the previous `x` (per column, only where
the warm start's residual is smaller than `||b||`). Each of the 3 coordinate
columns is its own CG system (the solve is vmapped over the columns), stopped
when `||b_c - A x_c|| <= rtol * ||b_c||` by the CG recursion. Padded vertices are
isolated, so their rows are the identity and the matrix stays symmetric
positive definite on padded meshes. Non-convergence is reported in `SolveInfo`,
never hidden: the iteration stops at `max_iter` and returns the (finite) iterate
together with its true relative residual.

It replaced a hand-written PCG with the same stopping rule: same iterations
and residuals, 0.62-1.01 of its time per solve (about 15% faster typically)
but more compile time (docs/results.md, `benchmarks/solve.py`).
Three lineax settings make it match (measured, float32):

* `rtol=0, atol=rtol * ||b_c||, norm=` the 2-norm: lineax's default test is
  elementwise (`|r_i| <= atol + rtol |b_i|` in the max norm), which a row with
  `b_i = 0` (padding, a coordinate plane) never meets without `atol`.
* `stabilise_every=None`: lineax otherwise recomputes `b - A x` every 10
  iterations, and that true residual has a float32 floor (`~eps * ||A||`,
  about 2e-5 relative at lambda 19) above `rtol = 1e-6`: from a good warm
  start it ran into `max_iter` (2000 iterations instead of 40).
* the Jacobi preconditioner is scaled so its smallest entry is
  `max(1, 1000 eps n)`: lineax declares a breakdown (and returns NaN) when
  `p.Ap <= 200 eps n (r.M^-1 r)`; with the plain `1 / (1 + lambda deg)` that
  ratio is as small as `1 / (1 + lambda deg_max)` for smooth directions, which
  tripped it at lambda 1000 (and lambda 19 on one coupled 3V system). A constant
  factor leaves the CG iterates unchanged, and with `A >= I` it keeps
  `p.Ap >= min(M^-1) r.M^-1 r`.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
from jaxtyping import Array, Bool, Float, Int

from jaxgenus.geometry import UniformLaplacian

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
        iterations: int32 CG iterations taken (the most of any column).
        residual: the true relative residual `max_c ||b_c - A x_c|| / ||b_c||`
            over the coordinate columns (0 where `b_c = 0`).
        converged: bool, every column's CG residual reached `rtol` within
            `max_iter` (False whenever `b` or the result is not finite, and
            for a column that needed all `max_iter` iterations).
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


def _two_norm(r):
    return jnp.sqrt(jnp.sum(r * r))


def largesteps_solve(
    laplacian: UniformLaplacian,
    b: Float[Array, "V 3"],
    lambda_=DEFAULT_LAMBDA,
    x0: Float[Array, "V 3"] | None = None,
    *,
    rtol: float = DEFAULT_RTOL,
    max_iter: int = DEFAULT_MAX_ITER,
) -> tuple[Float[Array, "V 3"], SolveInfo]:
    """Solve `(I + lambda L) x = b` by preconditioned CG (`lineax.CG`), warm-started at `x0`.

    Not differentiable by itself (use `from_differential` for that). Each column
    stops when its CG residual is `<= rtol * ||b_c||` or after `max_iter`
    iterations; `SolveInfo` says which. A column with `b_c = 0` is `x_c = 0`
    (no iteration); a non-finite column stops at once (its `x_c` is the start)
    and the solve reads as not converged.
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

    n = b.shape[0]
    diag = 1.0 + lambda_ * laplacian.degree
    floor = max(1.0, 1000.0 * float(jnp.finfo(b.dtype).eps) * n)  # see the module docstring
    column = jax.ShapeDtypeStruct((n,), b.dtype)
    operator = lx.FunctionLinearOperator(matvec, column, lx.positive_semidefinite_tag)
    jacobi = lx.TaggedLinearOperator(
        lx.DiagonalLinearOperator((floor * jnp.max(diag) / diag).astype(b.dtype)), lx.positive_semidefinite_tag
    )
    bnorm = _column_norms(b)
    nonzero = bnorm > 0
    if x0 is None:
        x0 = jnp.zeros_like(b)
    else:
        # keep the warm start only in columns where it beats x = 0 (a start far larger
        # than the solution would cost float32 accuracy); a zero b gets x = 0 at once
        x0 = x0.astype(b.dtype)
        x0 = jnp.where(nonzero & (_column_norms(b - matvec(x0)) < bnorm), x0, 0.0)

    def solve_column(b_c, x0_c, bnorm_c):
        cg = lx.CG(
            rtol=0.0,
            atol=jnp.where(bnorm_c > 0, rtol * bnorm_c, 1.0),
            norm=_two_norm,
            stabilise_every=None,
            max_steps=max_iter,
        )
        sol = lx.linear_solve(operator, b_c, cg, options={"preconditioner": jacobi, "y0": x0_c}, throw=False)
        return sol.value, sol.stats["num_steps"], sol.result == lx.RESULTS.successful

    x, steps, ok = jax.vmap(solve_column, in_axes=(1, 1, 0), out_axes=(1, 0, 0))(b, x0, bnorm)
    true_r = _column_norms(b - matvec(x))
    rel = jnp.max(jnp.where(nonzero, true_r / jnp.where(nonzero, bnorm, 1.0), 0.0))
    # NaN stops lineax's loop as if converged: a non-finite b or iterate must not read as converged
    finite = jnp.all(jnp.isfinite(bnorm)) & jnp.isfinite(rel)
    converged = jnp.all(ok) & finite
    return x, SolveInfo(iterations=jnp.max(steps).astype(jnp.int32), residual=rel, converged=converged)


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
