"""What each optimizer step reports: `RECORD_KEYS` and the `StepRecord` of `optimize_block`."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jax import Array

__all__ = ["RECORD_KEYS", "StepRecord", "step_record"]

RECORD_KEYS = (
    "loss",
    "alpha",
    "normal",
    "bilaplacian",
    "inversion",
    "photo",
    "albedo_smoothness",
    "containment",
    "consistency",
    "shading_ratio",
    "stereo",
    "grad_norm",
    "cg_iterations_forward",
    "cg_iterations_backward",
    "cg_residual",
    "inverted_faces",
    "status",
)
"""Keys of the per-step record of `optimize_block`.

`loss` and the weighted terms are evaluated at the step's starting `x` (a term
that is switched off reads 0); `grad_norm` is `||d loss / d x||`;
`cg_iterations_*` are the iterations of the gradient pull-back (backward) and
of the new-`x` solve (forward), 0 where the solve is direct (the factor, on CPU); `cg_residual` is the larger true relative
residual of the two; `inverted_faces` counts faces flipped relative to the rest
shape after the step; `status` is 0 (ok), 1 (a solve hit `cg_max_iter`) or
2 (non-finite loss, gradient or update: the step is skipped, the state unchanged)."""


class StepRecord(eqx.Module):
    """What each optimizer step reports (`RECORD_KEYS`; see there): scalars inside a step,
    `(n_steps,)` arrays after a block. `record["loss"]` reads a field by name."""

    loss: Array
    alpha: Array
    normal: Array
    bilaplacian: Array
    inversion: Array
    photo: Array
    albedo_smoothness: Array
    containment: Array
    consistency: Array
    shading_ratio: Array
    stereo: Array
    grad_norm: Array
    cg_iterations_forward: Array
    cg_iterations_backward: Array
    cg_residual: Array
    inverted_faces: Array
    status: Array

    def __getitem__(self, name: str) -> Array:
        if name not in RECORD_KEYS:
            raise KeyError(name)
        return getattr(self, name)

    def keys(self) -> tuple[str, ...]:
        return RECORD_KEYS


def step_record(loss, terms, gx, info_b, info_f, ok, inverted) -> StepRecord:
    status = jnp.where(ok, jnp.where(info_b.converged & info_f.converged, 0, 1), 2).astype(jnp.int32)
    zero = jnp.zeros((), loss.dtype)
    return StepRecord(
        loss=loss, **{name: terms.get(name, zero) for name in RECORD_KEYS[1:11]},
        grad_norm=jnp.sqrt(jnp.sum(gx * gx)), cg_iterations_forward=info_f.iterations,
        cg_iterations_backward=info_b.iterations, cg_residual=jnp.maximum(info_f.residual, info_b.residual),
        inverted_faces=inverted, status=status,
    )
