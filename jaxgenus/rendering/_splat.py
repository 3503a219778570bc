"""Face-major "splat" soft rasterization with a hand-written VJP (private).

Every face owns a `B x B` pixel window (its blurred bounding box, clipped to the
image). For each (face, window pixel) pair we evaluate the SoftRas coverage and
the depth score, and scatter per-pixel sums into a canvas padded by `B` on the
right and bottom. The backward pass recomputes the pairs, gathers per-pixel
upstream values into the windows and reduces per-face gradients over each window,
so no pixel x face temporaries exist and autodiff never sees the pair level.

Inputs are "tiers": groups of faces sharing a window size (see `_render.py`).
Coverage model: face j covers a pixel centre with `D_j = sigmoid(s_j / sigma)`,
`s_j` the signed distance (pixels, > 0 inside) to the face's projection; the
silhouette is the clamped sum `min(1, sum_j D_j)` over front faces. Two
front faces sharing an edge sum to exactly 1 along it, so the interior of a
fine mesh stays opaque (SoftRas' product `1 - prod(1 - D_j)` dips to 0.75 on
every interior edge, which biases a fit towards overlapping layers), and the
symmetric sigmoid of a signed distance puts a silhouette edge where it is.

Per tier and view, every face slot carries

* `v (K, 3, 2)`: its vertices in pixel coordinates,
* `plane (K, 3)`: `(gx, gy, c)`, the normalized inverse depth `q` as an affine
  function of the pixel position, `q = gx * u + gy * v + c`,
* `qrange (K, 2)`: `(lo, hi)`, the clamp of `q` (vertex min / max),
* `attr (K, A)`: face-constant blend attributes (normals, shading), or with
  `attr_planes` `(K, 5 A)`: per channel `(gx, gy, c, lo, hi)`, the value
  `clip(gx * u + gy * v + c, lo, hi)` at the pixel (interpolated over the face),
* `logw (K,)`: log of a face weight (the smooth facing cull): the face covers
  `w_j D_j` and enters the blend with score `log w_j + log D_j + q / gamma`,
* `valid (K,)` and `origin (K, 2)` (int, window corner `(col, row)`).

Per view, `dconst = (scale, offset)` turns `q` into inverse depth,
`1/z = q * scale + offset` (only used when the depth channel is blended).

Outputs per view: `cov (H, W)`, the coverage sum `sum_j D_j`,
and `blend (H, W, A + depth)`, the depth-softmax blend of the attributes with the
background. See docs/rendering.md for the model and the safe formulations.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

# D_j < 1e-4 is treated as exactly 0: d > sigma * ln(1e4) outside the face.
CUTOFF_LOG = math.log(1e4)
DC = 1.0 / (1.0 + 1e4)  # sigmoid(-CUTOFF_LOG): the coverage taper subtracts it


class SplatConfig(NamedTuple):
    """Static configuration of one splat call (hashable)."""

    height: int
    width: int
    windows: tuple[int, ...]  # window size per tier
    sigma: float
    gamma: float
    want_cov: bool
    n_attr: int  # face-constant blend channels
    want_depth: bool  # blend the per-pixel depth as one more channel
    background: tuple[float, ...]  # blend background, n_attr + want_depth values
    attr_planes: bool = False  # attributes are clamped planes in the pixel (5 values per channel)

    @property
    def sharpness(self) -> float:
        """Exponent p of the coverage in the blend weight `(w D)^p exp(q / gamma)`.

        With p = 1 a face's faint outer tail (D ~ 1e-4) in front of another surface
        wins the depth softmax by `exp(dq / gamma)` up to the blur cutoff, where the
        pixel then switches surfaces at once. With `p * ln(1e4) >= 1.5 / gamma` the
        tail hands over smoothly inside the cutoff for any depth gap (q is in [0, 1]).
        """
        return max(1.0, 1.5 / (self.gamma * CUTOFF_LOG))

    @property
    def n_blend(self) -> int:
        return self.n_attr + int(self.want_depth)

    @property
    def pad(self) -> int:
        return max(self.windows)


class Tier(NamedTuple):
    v: jax.Array
    plane: jax.Array
    qrange: jax.Array
    attr: jax.Array
    logw: jax.Array
    valid: jax.Array
    origin: jax.Array


def _materialize(x, token):
    """Force `x` into a buffer: XLA CPU otherwise fuses the whole producer into the
    (serial) scatter loop. `optimization_barrier` is stripped on CPU, a `cond` on a
    runtime predicate (always true, `token >= 0`) is not."""
    return jax.lax.cond(token >= 0, lambda a: a, lambda a: jax.tree.map(jnp.zeros_like, a), x)


def _neg(dtype):
    return jnp.asarray(-0.25 * jnp.finfo(dtype).max, dtype)


class _Pairs(NamedTuple):
    idx: jax.Array  # (K, P) flat canvas index (kept 2-D: a reshape here defeats XLA CPU vectorization)
    px: jax.Array  # (K, P) pixel centre
    py: jax.Array
    live: jax.Array  # (K, P) valid face and inside the blur radius
    inside: jax.Array
    x: jax.Array  # sigmoid argument, signed distance / sigma (> 0 inside)
    ea: jax.Array  # exp(-|x|)
    qraw: jax.Array
    q: jax.Array
    edges: tuple  # per edge (t, dx, dy, d2)
    sel: tuple  # per edge, bool: this edge is the nearest


def _pairs(cfg: SplatConfig, tier: Tier, b: int) -> _Pairs:
    """Recompute every per-pair quantity of one tier in one view."""
    dtype = tier.v.dtype
    off = jnp.arange(b)
    oy, ox = jnp.meshgrid(off, off, indexing="ij")
    oy, ox = oy.reshape(-1), ox.reshape(-1)
    col = tier.origin[:, 0:1] + ox[None, :]
    row = tier.origin[:, 1:2] + oy[None, :]
    idx = row * (cfg.width + cfg.pad) + col
    px = col.astype(dtype) + 0.5
    py = row.astype(dtype) + 0.5

    v = tier.v
    edges, crosses = [], []
    for i in range(3):
        ax, ay = v[:, i, 0:1], v[:, i, 1:2]
        bx, by = v[:, (i + 1) % 3, 0:1], v[:, (i + 1) % 3, 1:2]
        ex, ey = bx - ax, by - ay
        l2 = ex * ex + ey * ey
        ok = l2 > 1e-20
        il = jnp.where(ok, 1.0 / jnp.where(ok, l2, 1.0), 0.0)
        wx, wy = px - ax, py - ay
        t = jnp.clip((wx * ex + wy * ey) * il, 0.0, 1.0)
        dx, dy = wx - t * ex, wy - t * ey
        edges.append((t, dx, dy, dx * dx + dy * dy))
        crosses.append(ex * wy - ey * wx)
    e0 = v[:, 1] - v[:, 0]
    e2 = v[:, 2] - v[:, 0]
    area2 = (e0[:, 0] * e2[:, 1] - e0[:, 1] * e2[:, 0])[:, None]
    sgn = jnp.sign(area2)
    inside = (crosses[0] * sgn > 0) & (crosses[1] * sgn > 0) & (crosses[2] * sgn > 0)
    d0, d1, d2_ = edges[0][3], edges[1][3], edges[2][3]
    d2 = jnp.minimum(d0, jnp.minimum(d1, d2_))
    sel0 = d0 <= jnp.minimum(d1, d2_)
    sel1 = ~sel0 & (d1 <= d2_)
    sel2 = ~sel0 & ~sel1
    live = tier.valid[:, None] & (inside | (d2 <= (cfg.sigma * CUTOFF_LOG) ** 2))
    dist = jnp.sqrt(d2)
    x = jnp.where(inside, dist, -dist) / cfg.sigma
    ea = jnp.exp(-jnp.abs(x))
    qraw = tier.plane[:, 0:1] * px + tier.plane[:, 1:2] * py + tier.plane[:, 2:3]
    q = jnp.clip(qraw, tier.qrange[:, 0:1], tier.qrange[:, 1:2])
    return _Pairs(idx, px, py, live, inside, x, ea, qraw, q, tuple(edges), (sel0, sel1, sel2))


def _window_get(cfg: SplatConfig, canvas, origin, b: int):
    """`canvas[idx]` of the `(K, b*b)` window pairs, as `K * b` contiguous row slices
    (several times faster on XLA CPU than a per-element gather)."""
    rows = (origin[:, 1:2] + jnp.arange(b)[None, :]) * (cfg.width + cfg.pad) + origin[:, 0:1]
    dims = jax.lax.GatherDimensionNumbers(offset_dims=(2,), collapsed_slice_dims=(), start_index_map=(0,))
    out = jax.lax.gather(canvas, rows[..., None], dims, (b,), mode=jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS)
    return out.reshape(origin.shape[0], b * b)


def _log_terms(p: _Pairs):
    """The tapered coverage `T = clip((D - DC) / (1 - 2 DC), 0, 1)` of each pair,
    `D = sigmoid(x)`: exactly 0 at the blur cutoff (`D = DC`), so a face's coverage
    and blend weight fade in continuously as its tail reaches a pixel, and still
    `T(x) + T(-x) = 1` (neighbours sum to 1 along a shared edge). Returns
    `(log T, T, dT/dx, dlogT/dx, ok)`, `ok = T > 0`; stable for any x."""
    inv = 1.0 / (1.0 + p.ea)
    pos = p.x >= 0
    omd = jnp.where(pos, p.ea, 1.0) * inv  # 1 - D
    dm = jnp.where(pos, (1.0 - DC) - omd, p.ea * inv - DC)  # D - DC without cancellation inside
    ok = dm > 0
    free = ok & (dm < 1.0 - 2.0 * DC)
    slope = p.ea * inv * inv  # D (1 - D)
    dm = jnp.clip(dm, 0.0, 1.0 - 2.0 * DC)
    t = dm / (1.0 - 2.0 * DC)
    logt = jnp.log(jnp.where(ok, dm, 1.0)) - math.log1p(-2.0 * DC)
    dt = jnp.where(free, slope / (1.0 - 2.0 * DC), 0.0)
    dlog = jnp.where(free, slope / jnp.where(ok, dm, 1.0), 0.0)
    return logt, t, dt, dlog, ok


def _depth(q, dconst):
    return 1.0 / (q * dconst[0] + dconst[1])


def _attr_raw(tier, p, i):
    """Channel i's unclamped plane at every pair, and its clamp `(lo, hi)` (`attr_planes`)."""
    a = tier.attr[:, 5 * i : 5 * i + 5]
    return a[:, 0:1] * p.px + a[:, 1:2] * p.py + a[:, 2:3], a[:, 3:4], a[:, 4:5]


def _blend_values(cfg, tier, p, dconst):
    """Per blend channel, the value of every pair: `(K, 1)` (face constant) or `(K, P)`."""
    if cfg.attr_planes:
        vals = [jnp.clip(*_attr_raw(tier, p, i)) for i in range(cfg.n_attr)]
    else:
        vals = [tier.attr[:, i : i + 1] for i in range(cfg.n_attr)]
    if cfg.want_depth:
        vals.append(_depth(p.q, dconst))
    return vals


def _canvas_size(cfg):
    return (cfg.height + cfg.pad) * (cfg.width + cfg.pad)


def _crop(cfg, flat):
    img = flat.reshape((cfg.height + cfg.pad, cfg.width + cfg.pad) + flat.shape[1:])
    return img[: cfg.height, : cfg.width]


def _uncrop(cfg, img, fill=0.0):
    pad = [(0, cfg.pad), (0, cfg.pad)] + [(0, 0)] * (img.ndim - 2)
    return jnp.pad(img, pad, constant_values=fill).reshape((_canvas_size(cfg),) + img.shape[2:])


def _score_bg(cfg, dtype):
    # the background sits one normalized depth range behind the farthest vertex
    return jnp.asarray(-1.0 / cfg.gamma, dtype)


def _buffer_x(p: _Pairs, token) -> _Pairs:
    """Buffer `x` and `live`: each consumer would otherwise recompute the three edges."""
    x, live = _materialize((p.x, p.live), token)
    return p._replace(x=x, live=live, ea=jnp.exp(-jnp.abs(x)))


def _forward_view(cfg: SplatConfig, tiers, dconst):
    dtype = tiers[0].v.dtype
    size = _canvas_size(cfg)
    pairs = [_buffer_x(_pairs(cfg, t, b), t.origin[0, 0]) for t, b in zip(tiers, cfg.windows)]
    cov = jnp.zeros((size,), dtype)
    mcanvas = jnp.full((size,), _neg(dtype), dtype)
    scores = []
    for t, p in zip(tiers, pairs):
        logd, dval, _, _, ok = _log_terms(p)
        live = p.live & ok
        if cfg.want_cov:
            upd = _materialize(jnp.where(live, dval * jnp.exp(t.logw)[:, None], 0.0), t.origin[0, 0])
            cov = cov.at[p.idx].add(upd, mode="promise_in_bounds")
        if cfg.n_blend:
            s = jnp.where(live, cfg.sharpness * (logd + t.logw[:, None]) + p.q / cfg.gamma, _neg(dtype))
            s = _materialize(s, t.origin[0, 0])
            scores.append(s)
            mcanvas = mcanvas.at[p.idx].max(s, mode="promise_in_bounds")
    out = {"cov": _crop(cfg, cov)}
    if cfg.n_blend:
        m = jnp.maximum(mcanvas, _score_bg(cfg, dtype))
        acc = jnp.zeros((size, 1 + cfg.n_blend), dtype)
        for t, p, s, b in zip(tiers, pairs, scores, cfg.windows):
            w = _materialize(jnp.exp(s - _window_get(cfg, m, t.origin, b)), t.origin[0, 0])
            vals = _blend_values(cfg, t, p, dconst)
            stack = jnp.stack([w] + [w * v for v in vals], axis=-1)
            stack = _materialize(stack, t.origin[0, 0])
            acc = acc.at[p.idx].add(stack, mode="promise_in_bounds")
        wb = jnp.exp(_score_bg(cfg, dtype) - m)
        bg = jnp.asarray(cfg.background, dtype)
        wsum = acc[:, 0] + wb
        blend = (acc[:, 1:] + wb[:, None] * bg) / wsum[:, None]
        out["blend"] = _crop(cfg, blend)
        out["mlw"] = _crop(cfg, m + jnp.log(wsum))
    return out


def _backward_view(cfg: SplatConfig, tiers, dconst, res, g_cov, g_blend):
    """Per-face gradients of one view (envelope theorem for the distance)."""
    dtype = tiers[0].v.dtype
    cols = [g_cov]
    if cfg.n_blend:
        cols += [res["mlw"], jnp.sum(g_blend * res["blend"], axis=-1)]
        cols += [g_blend[..., i] for i in range(cfg.n_blend)]
    # one contiguous canvas per channel: channel-minor gathers are several times slower
    # off-image pixels: zero upstream gradient and (for mlw) a huge normalizer, so exp() -> 0
    pix = [_uncrop(cfg, c, -_neg(dtype) if i == 1 else 0.0) for i, c in enumerate(cols)]
    grads = []
    gdc = jnp.zeros((2,), dtype)
    for t, b in zip(tiers, cfg.windows):
        p = _pairs(cfg, t, b)
        k = p.x.shape[0]
        tok = t.origin[0, 0]
        gp = [_window_get(cfg, c, t.origin, b) for c in pix]
        # XLA CPU fuses each reduction below with its whole producer chain (three edges,
        # exp, log1p), so buffer the nearest edge once: (t, dvec) and a code, -1 for a
        # dead pair, else its index + 3 if inside. Everything else is cheap from these.
        sel0, sel1 = p.sel[:2]
        pick = lambda i: jnp.where(sel0, p.edges[0][i], jnp.where(sel1, p.edges[1][i], p.edges[2][i]))
        near = jnp.where(sel0, 0, jnp.where(sel1, 1, 2)) + jnp.where(p.inside, 3, 0)
        tn, dxn, dyn, code = _materialize((pick(0), pick(1), pick(2), jnp.where(p.live, near, -1)), tok)
        live, inside = code >= 0, code >= 3
        dist = jnp.sqrt(dxn * dxn + dyn * dyn)
        p = p._replace(x=jnp.where(inside, dist, -dist) / cfg.sigma)
        p = p._replace(ea=jnp.exp(-jnp.abs(p.x)))
        logd, dval, dslope, dlog, ok = _log_terms(p)
        live = live & ok
        w = jnp.exp(t.logw)[:, None]
        gw = jnp.where(live, gp[0] * w * dval, 0.0) if cfg.want_cov else jnp.zeros_like(p.x)  # d/d(log w)
        gx = gp[0] * w * dslope if cfg.want_cov else jnp.zeros_like(p.x)
        gq = jnp.zeros_like(p.x)
        pj = None
        if cfg.n_blend:
            s = cfg.sharpness * (logd + t.logw[:, None]) + p.q / cfg.gamma
            pj = jnp.where(live, jnp.exp(s - gp[1]), 0.0)
            gb = gp[3:]
            vals = _blend_values(cfg, t, p, dconst)
            gscore = pj * (sum(g * v for g, v in zip(gb, vals)) - gp[2])
            gx = gx + cfg.sharpness * gscore * dlog
            gw = gw + cfg.sharpness * jnp.where(live, gscore, 0.0)
            gq = gscore / cfg.gamma
            if cfg.want_depth:
                gz = -pj * gb[-1] * vals[-1] * vals[-1]  # d(out)/d(1/z) of this pair
                gq = gq + gz * dconst[0]
                gdc = gdc + jnp.stack([jnp.sum(jnp.where(live, gz * p.q, 0.0)), jnp.sum(jnp.where(live, gz, 0.0))])
        gx = jnp.where(live, gx, 0.0)
        gq = jnp.where(live, gq, 0.0)
        # x = +-sqrt(d^2) / sigma; gd2 carries the -2 of d(d^2)/d(vertex) below
        gd2 = jnp.where(dist > 0, -jnp.where(inside, gx, -gx) / (cfg.sigma * jnp.where(dist > 0, dist, 1.0)), 0.0)
        gd2, gq, pj, gw = _materialize((gd2, gq, pj, gw), tok)
        # envelope theorem: only the nearest edge moves d^2; with t its (clamped)
        # parameter, d(d^2)/d(start) = -2 (1 - t) dvec and d(d^2)/d(end) = -2 t dvec
        edge = jnp.where(inside, code - 3, code)
        c = [
            gd2 * (jnp.where(edge == i, 1.0 - tn, 0.0) + jnp.where(edge == (i - 1) % 3, tn, 0.0))
            for i in range(3)
        ]
        lo, hi = t.qrange[:, 0:1], t.qrange[:, 1:2]
        free = (p.qraw > lo) & (p.qraw < hi)
        gqf = jnp.where(free, gq, 0.0)
        glo = jnp.where(p.qraw <= lo, gq, 0.0)
        ghi = jnp.where(~free & (p.qraw > lo), gq, 0.0)
        c0, c1, c2 = c
        # one reduction per field (XLA CPU turns a stacked reduction into a slow concatenate)
        fields = [c0 * dxn, c0 * dyn, c1 * dxn, c1 * dyn, c2 * dxn, c2 * dyn, gqf, gqf * p.px, gqf * p.py, glo, ghi, gw]
        for i in range(cfg.n_attr):
            ga = pj * gp[3 + i]
            if not cfg.attr_planes:
                fields.append(ga)
                continue
            raw, alo, ahi = _attr_raw(t, p, i)
            afree = (raw > alo) & (raw < ahi)
            gf = jnp.where(afree, ga, 0.0)
            fields += [gf * p.px, gf * p.py, gf, jnp.where(raw <= alo, ga, 0.0), jnp.where(~afree & (raw > alo), ga, 0.0)]
        red = jnp.stack([jnp.sum(f, axis=1) for f in fields], -1)
        gv = red[:, :6].reshape(k, 3, 2)
        gplane = jnp.stack([red[:, 7], red[:, 8], red[:, 6]], -1)
        gattr = red[:, 12:] if cfg.n_attr else jnp.zeros((k, 0), dtype)  # the layout of `attr`
        grads.append(Tier(gv, gplane, red[:, 9:11], gattr, red[:, 11], None, None))
    return tuple(grads), gdc


def splat(cfg: SplatConfig, tiers: tuple[Tier, ...], dconst: jax.Array):
    """Rasterize all views: returns `(cov (N, H, W), blend (N, H, W, C) or None)`.

    Every tier array has a leading view axis N; `dconst` is `(N, 2)`.
    """

    @jax.custom_vjp
    def run(tiers, dconst):
        out = jax.lax.map(lambda a: _forward_view(cfg, *a), (tiers, dconst))
        return out["cov"], out.get("blend")

    def fwd(tiers, dconst):
        out = jax.lax.map(lambda a: _forward_view(cfg, *a), (tiers, dconst))
        return (out["cov"], out.get("blend")), (tiers, dconst, out)

    def bwd(res, g):
        tiers, dconst, out = res
        g_cov, g_blend = g
        res_b = {k: v for k, v in out.items() if k != "cov"}

        def one(a):
            t, d, r, gl, gb = a
            return _backward_view(cfg, t, d, r, gl, gb)

        grads, gdc = jax.lax.map(one, (tiers, dconst, res_b, g_cov, g_blend))
        return grads, gdc

    run.defvjp(fwd, bwd)
    return run(tiers, dconst)


