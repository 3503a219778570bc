"""The "large steps" reparametrization of Nicolet et al. (2021).

Vertices `x` are optimized through `u = (I + lambda L) x`, with `L` the uniform
Laplacian. Each step recovers `x = (I + lambda L)^-1 u`; the gradient with respect
to `u` is the gradient with respect to `x` pulled back through the same solve
(`(I + lambda L)` is symmetric). The paper's other form `(1 - alpha) I + alpha L`
is the same matrix up to the factor `1 - alpha`, with `lambda = alpha / (1 - alpha)`
(`lambda_from_alpha`).

On the CPU the solve is direct: `largesteps_factor` factors `I + lambda L` once per
mesh (a sparse Cholesky factor in double precision, nested-dissection order, in the
native kernel `kernels/cholesky`), and each solve with it is two triangular solves
(about 2x cheaper a step than CG's 60-90 iterations at 3-7k vertices). Where there
is no factor (another platform, no `factor` passed, or a factor that did not fit its
buffer) the solve is CG. A fit's cycle computes its block's factor first (`block_factor`) and
reads `ok` on the host: a block whose factor fit is compiled without the CG fallback
(`fallback=False`), which is a third of its compile time. The CG:

The CG solve is `lineax.CG` on a matrix-free `lineax.FunctionLinearOperator`, with a
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
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from jaxgenus import _ffi  # noqa: F401  (registers the native factor and solve)
from jaxgenus.geometry import UniformLaplacian

__all__ = [
    "Factor",
    "SolveInfo",
    "largesteps_factor",
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


class Factor(eqx.Module):
    """A sparse Cholesky factor of `I + lambda L` (`largesteps_factor`), in fixed-capacity buffers.

    Attributes:
        perm: `(V,)` int32, the elimination order (`perm[k]` is the k-th pivot's vertex).
        colptr: `(V + 1,)` int32, where each column of the factor starts (its diagonal first).
        rows: `(C,)` int32 row of each entry.
        values: `(C, 2)` uint32, each entry's float64 value (kept in double without x64).
        ok: bool, the factor is there (False off the CPU, or when it needed more than `C` entries).
        entries: int32, the entries it holds (or needed).
    """

    perm: Int[Array, " V"]
    colptr: Int[Array, " V1"]
    rows: Int[Array, " C"]
    values: Array
    ok: Bool[Array, ""]
    entries: Int[Array, ""]


def factor_capacity(n_vertices: int) -> int:
    """Entries the factor's buffers hold for `n_vertices` unknowns: `6 n log2 n` (at least `32 n`).

    Nested dissection fills a surface mesh's factor with about `3-5 n log2 n` entries
    (tests/test_largesteps_factor.py measures it); a mesh that needs more is solved by CG."""
    n = max(int(n_vertices), 2)
    return max(32, int(np.ceil(6 * np.log2(n)))) * n


def largesteps_factor(laplacian: UniformLaplacian, lambda_=DEFAULT_LAMBDA, *, capacity: int | None = None) -> Factor:
    """The sparse Cholesky factor of `I + lambda L` for `largesteps_solve(..., factor=)`.

    Computed on the CPU by the native kernel (`ok` says whether it fit its `capacity` entries,
    default `factor_capacity(V)`); on another platform `ok` is False and the solves stay CG.
    Works under `jit`, `vmap` (sequentially) and `shard_map`; `lambda_` may be traced."""
    _check_lambda(lambda_)
    n = laplacian.degree.shape[0]
    cap = factor_capacity(n) if capacity is None else int(capacity)
    if cap < 1:
        raise ValueError(f"capacity must be >= 1, got {capacity}")
    i32 = jnp.int32
    shapes = (jax.ShapeDtypeStruct((n,), i32), jax.ShapeDtypeStruct((n + 1,), i32),
              jax.ShapeDtypeStruct((cap,), i32), jax.ShapeDtypeStruct((cap, 2), jnp.uint32),
              jax.ShapeDtypeStruct((2,), i32))
    edges = laplacian.edges.astype(i32)
    weights = laplacian.weights.astype(jnp.float32)
    lam = jnp.asarray(lambda_, jnp.float32)

    def native(e, w, lam):
        return tuple(jax.ffi.ffi_call("jaxgenus_cholesky_factor", shapes, vmap_method="sequential")(e, w, lam))

    def elsewhere(e, w, lam):  # no factor: `ok` False (status 1)
        return tuple(jnp.zeros(s.shape, s.dtype) for s in shapes[:4]) + (jnp.array([1, 0], i32),)

    perm, colptr, rows, values, info = jax.lax.platform_dependent(edges, weights, lam, cpu=native, default=elsewhere)
    return Factor(perm=perm, colptr=colptr, rows=rows, values=values, ok=info[0] == 0, entries=info[1])


def _factor_solve(factor: Factor, b):
    shape = jax.ShapeDtypeStruct(b.shape, jnp.float32)
    call = jax.ffi.ffi_call("jaxgenus_cholesky_solve", shape, vmap_method="sequential")
    return call(factor.perm, factor.colptr, factor.rows, factor.values, b.astype(jnp.float32)).astype(b.dtype)


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
    factor: Factor | None = None,
    fallback: bool = True,
) -> tuple[Float[Array, "V 3"], SolveInfo]:
    """Solve `(I + lambda L) x = b`: with the matrix's `factor` directly (on the CPU, when it fit),
    otherwise by preconditioned CG (`lineax.CG`), warm-started at `x0`.

    Not differentiable by itself (use `from_differential` for that). A direct solve reports
    0 iterations and its true residual (it reads as converged when finite). Each CG column
    stops when its CG residual is `<= rtol * ||b_c||` or after `max_iter`
    iterations; `SolveInfo` says which. A column with `b_c = 0` is `x_c = 0`
    (no iteration); a non-finite column stops at once (its `x_c` is the start)
    and the solve reads as not converged. `fallback=False`: the caller read `factor.ok` on the
    host (a factor computed before): on the CPU the solve is the direct one alone, and the CG
    fallback, a third of an optimizer block's compile time, is not compiled.
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

    def true_info(b, x, iterations, ok):
        bnorm = _column_norms(b)
        nonzero = bnorm > 0
        rel = jnp.max(jnp.where(nonzero, _column_norms(b - matvec(x)) / jnp.where(nonzero, bnorm, 1.0), 0.0))
        # NaN stops lineax's loop as if converged: a non-finite b or iterate must not read as converged
        converged = ok & jnp.all(jnp.isfinite(bnorm)) & jnp.isfinite(rel)
        return SolveInfo(iterations=iterations.astype(jnp.int32), residual=rel, converged=converged)

    cg = lambda b, x0: _cg_solve(matvec, laplacian, b, lambda_, x0, rtol, max_iter, true_info)
    if factor is None:
        return cg(b, x0)

    def direct(b, x0):
        x = _factor_solve(factor, b)
        return x, true_info(b, x, jnp.int32(0), jnp.bool_(True))

    on_cpu = (lambda b, x0: jax.lax.cond(factor.ok, direct, cg, b, x0)) if fallback else direct
    x0 = jnp.zeros_like(b) if x0 is None else x0.astype(b.dtype)
    return jax.lax.platform_dependent(b, x0, cpu=on_cpu, default=cg)


def _cg_solve(matvec, laplacian, b, lambda_, x0, rtol, max_iter, true_info):
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
    return x, true_info(b, x, jnp.max(steps), jnp.all(ok))


def from_differential(
    laplacian: UniformLaplacian,
    u: Float[Array, "V 3"],
    lambda_=DEFAULT_LAMBDA,
    x0: Float[Array, "V 3"] | None = None,
    *,
    rtol: float = DEFAULT_RTOL,
    max_iter: int = DEFAULT_MAX_ITER,
    factor: Factor | None = None,
) -> Float[Array, "V 3"]:
    """`x = (I + lambda L)^-1 u`, differentiable in `u`: the backward pass is a second solve.

    `x0` (a warm start), the Laplacian and the `factor` (`largesteps_factor`) get no gradient.
    """
    x0 = jnp.zeros_like(u) if x0 is None else x0

    def solve(b, start):
        return largesteps_solve(laplacian, b, lambda_, start, rtol=rtol, max_iter=max_iter, factor=factor)[0]

    @jax.custom_vjp
    def inverse(u, start):
        return solve(u, start)

    def fwd(u, start):
        return solve(u, start), None

    def bwd(_, g):
        return solve(g, jnp.zeros_like(g)), jnp.zeros_like(g)

    inverse.defvjp(fwd, bwd)
    return inverse(u, jax.lax.stop_gradient(x0))
