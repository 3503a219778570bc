"""Test-only dense soft rasterizer: every pixel against every face, plain autodiff.

Written independently of jaxgenus/_render.py and _splat.py from the model in
docs/rendering.md: barycentric depth interpolation instead of the plane form,
a per-pixel log-sum-exp and no windows, compaction or custom VJP. Only for tiny
scenes (it materializes N x H x W x F arrays).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

CUT = math.log(1e4)
FACING = 0.03  # docs/rendering.md: facing-weight width in cosine


def _seg_d2(px, py, ax, ay, bx, by):
    ex, ey = bx - ax, by - ay
    l2 = ex * ex + ey * ey
    ok = l2 > 1e-20
    il = jnp.where(ok, 1.0 / jnp.where(ok, l2, 1.0), 0.0)
    t = jnp.clip(((px - ax) * ex + (py - ay) * ey) * il, 0.0, 1.0)
    dx, dy = px - ax - t * ex, py - ay - t * ey
    return dx * dx + dy * dy


def _dense_render(mesh, cameras, *, channels, sigma, gamma, znear=1e-4, cull=True, background=None,
                  light=None, ambient=0.3):
    bgs = {"normal": jnp.zeros(3), "depth": jnp.zeros(1), "shaded": jnp.zeros(1)}
    for k, v in (background or {}).items():
        bgs[k] = jnp.atleast_1d(jnp.asarray(v, jnp.float32))
    dt = mesh.vertices.dtype
    h, w = cameras.height, cameras.width
    verts = mesh.vertices
    tri_w = verts[mesh.faces]  # (F,3,3)
    cr = jnp.cross(tri_w[:, 1] - tri_w[:, 0], tri_w[:, 2] - tri_w[:, 0])
    n2 = jnp.sum(cr * cr, -1, keepdims=True)
    ok = n2 > jnp.finfo(dt).tiny
    nrm = jnp.where(ok, cr / jnp.sqrt(jnp.where(ok, n2, 1.0)), 0.0)
    nrm = jnp.where(mesh.face_mask[:, None], nrm, 0.0)

    cols = jnp.arange(w, dtype=dt) + 0.5
    rows = jnp.arange(h, dtype=dt) + 0.5
    py, px = jnp.meshgrid(rows, cols, indexing="ij")
    px = px[..., None]
    py = py[..., None]  # (H, W, 1) against faces (F,)

    outs = []
    for n in range(len(cameras)):
        R = cameras.rotation[n].astype(dt)
        t = cameras.translation[n].astype(dt)
        xc = verts @ R.T + t
        tri = xc[mesh.faces]
        z = tri[..., 2]
        zs = jnp.where(z > znear, z, 1.0)
        u = tri[..., 0] / zs * cameras.focal[n, 0] + cameras.principal_point[n, 0]
        v = tri[..., 1] / zs * cameras.focal[n, 1] + cameras.principal_point[n, 1]
        infront = mesh.face_mask & jnp.all(z > znear, -1)
        valid = infront
        logw = jnp.zeros(z.shape[0], dt)
        if cull:  # smooth facing weight sigmoid(cos / FACING) of normal vs direction to the camera
            nc = jnp.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            cen = tri.mean(axis=1)
            nn = jnp.linalg.norm(nc, axis=-1) * jnp.linalg.norm(cen, axis=-1)
            cos = -jnp.sum(nc * cen, -1) / jnp.where(nn > 0, nn, 1.0)
            dc = 1.0 / (1.0 + 1e4)
            wt = jnp.minimum((jax.nn.sigmoid(cos / FACING) - dc) / (1.0 - 2 * dc), 1.0)  # tapered like the coverage
            valid = valid & (wt > 0)
            logw = jnp.log(jnp.where(valid, wt, 1.0))
        zmin = jnp.min(jnp.where(infront[:, None], z, jnp.inf))
        zmax = jnp.max(jnp.where(infront[:, None], z, -jnp.inf))
        anyv = jnp.any(infront)
        zmin = jnp.where(anyv, zmin, 1.0)
        zmax = jnp.where(anyv, zmax, 1.0)
        scale = jnp.maximum(1 / zmin - 1 / zmax, 1e-6 / zmin)
        q = jnp.where(valid[:, None], (1 / zs - 1 / zmax) / scale, 0.0)  # (F,3)

        d2 = jnp.minimum(
            _seg_d2(px, py, u[:, 0], v[:, 0], u[:, 1], v[:, 1]),
            jnp.minimum(_seg_d2(px, py, u[:, 1], v[:, 1], u[:, 2], v[:, 2]),
                        _seg_d2(px, py, u[:, 2], v[:, 2], u[:, 0], v[:, 0])),
        )
        # barycentrics from edge functions
        def edge(i, j):
            return (u[:, j] - u[:, i]) * (py - v[:, i]) - (v[:, j] - v[:, i]) * (px - u[:, i])
        w0, w1, w2 = edge(1, 2), edge(2, 0), edge(0, 1)
        area = (u[:, 1] - u[:, 0]) * (v[:, 2] - v[:, 0]) - (v[:, 1] - v[:, 0]) * (u[:, 2] - u[:, 0])
        sg = jnp.sign(area)
        inside = (w0 * sg > 0) & (w1 * sg > 0) & (w2 * sg > 0)
        aok = jnp.abs(area) > 1e-12
        ia = jnp.where(aok, 1.0 / jnp.where(aok, area, 1.0), 0.0)
        qb = jnp.where(aok, (w0 * q[:, 0] + w1 * q[:, 1] + w2 * q[:, 2]) * ia, jnp.mean(q, -1))
        qp = jnp.clip(qb, jnp.min(q, -1), jnp.max(q, -1))

        pos = d2 > 0
        dist = jnp.where(pos, jnp.sqrt(jnp.where(pos, d2, 1.0)), 0.0)
        x = jnp.where(inside, dist, -dist) / sigma
        live = valid & (inside | (dist <= sigma * CUT))
        # tapered coverage: sigmoid minus its value at the cutoff, rescaled (0 at the cutoff)
        dc = 1.0 / (1.0 + 1e4)
        taper = jnp.minimum((jax.nn.sigmoid(x) - dc) / (1.0 - 2 * dc), 1.0)
        live = live & (taper > 0)
        taper = jnp.where(live, taper, 1.0)
        cover = jnp.where(live, jnp.exp(logw) * taper, 0.0)
        alpha = jnp.minimum(jnp.sum(cover, -1), 1.0)[..., None]
        p = max(1.0, 1.5 / (gamma * CUT))  # coverage exponent of the blend weight
        res = []
        for c in channels:
            if c == "alpha":
                res.append(alpha)
                continue
            score = jnp.where(live, p * (logw + jnp.log(taper)) + qp / gamma, -jnp.inf)
            sb = jnp.full((h, w, 1), -1.0 / gamma, dt)
            allsc = jnp.concatenate([score, sb], -1)
            m = jax.lax.stop_gradient(jnp.max(allsc, -1, keepdims=True))
            wts = jnp.exp(allsc - m)
            wts = wts / jnp.sum(wts, -1, keepdims=True)
            if c == "normal":
                val = jnp.broadcast_to(nrm, (h, w) + nrm.shape)
            elif c == "shaded":
                l = -R[2] if light is None else jnp.asarray(light, dt) / jnp.linalg.norm(jnp.asarray(light, dt))
                s = ambient + (1 - ambient) * jnp.maximum(nrm @ l, 0.0)
                val = jnp.broadcast_to(s[:, None], (h, w, s.shape[0], 1))
            else:  # depth
                zp = 1.0 / (qp * scale + 1.0 / zmax)
                val = zp[..., None]
            bgv = jnp.broadcast_to(bgs[c], (h, w, 1, val.shape[-1]))
            vals = jnp.concatenate([val, bgv], axis=2)
            blended = jnp.einsum("hwf,hwfc->hwc", wts, vals)
            res.append(alpha * blended + (1 - alpha) * bgs[c])  # composited over the background
        outs.append(jnp.concatenate(res, -1))
    return jnp.stack(outs)


#: One compiled program per scene and setting (the forward pass and, under `jax.grad`, its
#: transpose), not an op-by-op trace: the reference's arithmetic is unchanged.
dense_render = jax.jit(_dense_render, static_argnames=("channels", "sigma", "gamma", "znear", "cull", "ambient"))
