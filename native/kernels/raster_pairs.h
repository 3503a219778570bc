// Per-pair math of the splat rasterizer (internal to kernels/raster.cc): face
// constants, the pixels of a face's blurred footprint, and the coverage / depth
// terms of one (face, pixel) pair, mirroring `_pairs` and `_log_terms` of
// jaxgenus/_splat.py.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>

#include "kernels/raster.h"

namespace jaxgenus {
namespace raster_detail {


inline const double kCutoffLog = std::log(1e4);  // D < 1e-4 is exactly 0 (beyond the blur radius)
inline constexpr double kDC = 1.0 / (1.0 + 1e4);  // sigmoid(-kCutoffLog), subtracted by the taper

// Per-face constants of one view.
template <typename T>
struct Face {
  T ax[3], ay[3], ex[3], ey[3], il[3];
  T sgn;
  T gx, gy, c, lo, hi;
  T logw, w;
  const T* attr;
};

// Everything one (face, pixel) pair needs; `ok` is live & (T > 0).
template <typename T>
struct Pair {
  bool inside;
  int edge;  // nearest edge
  T t, dx, dy, dist, qraw, q;
  T logt, tv, dt, dlog;
};

// Scalar constants, converted to T once (Python scalars are weakly typed in JAX).
template <typename T>
struct Consts {
  T r2, sigma, gamma, sharp, score_bg, inv_sigma, inv_gamma, inv_1m2dc;
  T one_m_dc, dc, one_m_2dc, log1p_m2dc;
  explicit Consts(const RasterConfig& cfg)
      : r2(T((cfg.sigma * kCutoffLog) * (cfg.sigma * kCutoffLog))),
        sigma(T(cfg.sigma)),
        gamma(T(cfg.gamma)),
        sharp(T(cfg.sharpness)),
        score_bg(T(-1.0 / cfg.gamma)),
        inv_sigma(T(1.0 / cfg.sigma)),
        inv_gamma(T(1.0 / cfg.gamma)),
        inv_1m2dc(T(1.0 / (1.0 - 2.0 * kDC))),
        one_m_dc(T(1.0 - kDC)),
        dc(T(kDC)),
        one_m_2dc(T(1.0 - 2.0 * kDC)),
        log1p_m2dc(T(std::log1p(-2.0 * kDC))) {}
};

// `n_attr` counts the face's attribute values (channels times their stride).
template <typename T>
bool make_face(const RasterFaces<T>& fs, int64_t view, int64_t f, int64_t n_attr, Face<T>& out) {
  const int64_t k = view * fs.n_faces + f;
  if (!fs.valid[k]) return false;
  const T* v = fs.v + k * 6;
  for (int i = 0; i < 6; ++i)
    if (!std::isfinite(double(v[i]))) return false;
  for (int i = 0; i < 3; ++i) {
    const int j = (i + 1) % 3;
    out.ax[i] = v[2 * i];
    out.ay[i] = v[2 * i + 1];
    out.ex[i] = v[2 * j] - v[2 * i];
    out.ey[i] = v[2 * j + 1] - v[2 * i + 1];
    const T l2 = out.ex[i] * out.ex[i] + out.ey[i] * out.ey[i];
    out.il[i] = l2 > T(1e-20) ? T(1) / l2 : T(0);
  }
  const T e2x = v[4] - v[0], e2y = v[5] - v[1];
  const T area2 = out.ex[0] * e2y - out.ey[0] * e2x;
  out.sgn = area2 > T(0) ? T(1) : (area2 < T(0) ? T(-1) : T(0));
  const T* pl = fs.plane + k * 3;
  out.gx = pl[0];
  out.gy = pl[1];
  out.c = pl[2];
  out.lo = fs.qrange[k * 2];
  out.hi = fs.qrange[k * 2 + 1];
  out.logw = fs.logw[k];
  out.w = std::exp(out.logw);
  out.attr = n_attr > 0 ? fs.attr + k * n_attr : nullptr;
  return true;
}

// One attribute channel's value at pixel centre (px, py): the constant a[0], or the
// plane (gx, gy, c) = a[0..2] clamped to [a[3], a[4]].
template <typename T>
inline T attr_value(const T* a, bool planes, T px, T py) {
  if (!planes) return a[0];
  return std::min(std::max(a[0] * px + a[1] * py + a[2], a[3]), a[4]);
}

// Geometry of up to kChunk pixels (a run of one row, or the whole bounding box of
// a small face), structure of arrays: pixel index and centre, nearest edge, its
// parameter and offset, squared distance, inside flag.
inline constexpr int kChunk = 32;

template <typename T>
struct Chunk {
  T px[kChunk], py[kChunk];
  T d2[kChunk], t[kChunk], dx[kChunk], dy[kChunk];
  int64_t idx[kChunk];
  int32_t edge[kChunk], inside[kChunk];
};

// One edge's part of a pixel's geometry: clamped parameter, offset, squared distance.
template <typename T>
struct EdgeGeo {
  T t, dx, dy, d2, side;
};

template <typename T>
inline EdgeGeo<T> edge_geometry(T ax, T ay, T ex, T ey, T il, T px, T py) {
  const T wx = px - ax, wy = py - ay;
  const T t = std::min(std::max((wx * ex + wy * ey) * il, T(0)), T(1));
  const T dx = wx - t * ex, dy = wy - t * ey;
  return {t, dx, dy, dx * dx + dy * dy, ex * wy - ey * wx};
}

// Written with scalar selects only (no arrays indexed by edge, no branches) so the
// compiler vectorizes the pixel loop (with -fno-trapping-math, see CMakeLists.txt).
template <typename T>
inline void chunk_geometry(const Face<T>& face, int n, Chunk<T>& c) {
  const Face<T> f = face;  // a local copy: the stores below cannot alias it
  for (int j = 0; j < n; ++j) {
    const T px = c.px[j], py = c.py[j];
    const EdgeGeo<T> g0 = edge_geometry(f.ax[0], f.ay[0], f.ex[0], f.ey[0], f.il[0], px, py);
    const EdgeGeo<T> g1 = edge_geometry(f.ax[1], f.ay[1], f.ex[1], f.ey[1], f.il[1], px, py);
    const EdgeGeo<T> g2 = edge_geometry(f.ax[2], f.ay[2], f.ex[2], f.ey[2], f.il[2], px, py);
    const bool s1 = g1.d2 <= g2.d2;
    const T m12 = s1 ? g1.d2 : g2.d2;
    const bool s0 = g0.d2 <= m12;
    const T t12 = s1 ? g1.t : g2.t, dx12 = s1 ? g1.dx : g2.dx, dy12 = s1 ? g1.dy : g2.dy;
    c.d2[j] = s0 ? g0.d2 : m12;
    c.t[j] = s0 ? g0.t : t12;
    c.dx[j] = s0 ? g0.dx : dx12;
    c.dy[j] = s0 ? g0.dy : dy12;
    c.edge[j] = s0 ? 0 : (s1 ? 1 : 2);
    const bool in = (g0.side * f.sgn > T(0)) & (g1.side * f.sgn > T(0)) & (g2.side * f.sgn > T(0));
    c.inside[j] = in ? 1 : 0;
  }
}

// The rest of one pair from its geometry; false when it contributes nothing (not
// live or T == 0). `grad` also fills dt and dlog.
template <typename T>
inline bool eval_pair(const Face<T>& f, const Consts<T>& k, const Chunk<T>& c, int j, bool need_log, bool grad,
                      Pair<T>& p) {
  const bool inside = c.inside[j] != 0;
  if (!(inside || c.d2[j] <= k.r2)) return false;
  const T dist = std::sqrt(c.d2[j]);
  const T x = (inside ? dist : -dist) * k.inv_sigma;  // reciprocals: <= 1 ulp from JAX's divisions
  const T ea = std::exp(-std::abs(x));
  const T inv = T(1) / (T(1) + ea);
  const bool pos = x >= T(0);
  const T omd = (pos ? ea : T(1)) * inv;
  T dm = pos ? k.one_m_dc - omd : ea * inv - k.dc;
  if (!(dm > T(0))) return false;
  const bool free = dm < k.one_m_2dc;
  dm = free ? dm : k.one_m_2dc;
  p.inside = inside;
  p.edge = c.edge[j];
  p.t = c.t[j];
  p.dx = c.dx[j];
  p.dy = c.dy[j];
  p.dist = dist;
  p.tv = dm * k.inv_1m2dc;
  p.logt = need_log ? std::log(dm) - k.log1p_m2dc : T(0);
  if (grad) {
    const T slope = ea * inv * inv;
    p.dt = free ? slope * k.inv_1m2dc : T(0);
    p.dlog = free ? slope / dm : T(0);
  }
  p.qraw = f.gx * c.px[j] + f.gy * c.py[j] + f.c;
  p.q = std::min(std::max(p.qraw, f.lo), f.hi);
  return true;
}

// Pixels of a face's blurred footprint: rows whose centre is within R of the
// vertex y-range; per row, the columns within R (in x) of the triangle's part in
// the band |y - py| <= R (a superset of the pixels within R of the triangle).
struct Footprint {
  double vx[3], vy[3], R;
  int64_t H, W;

  void rows(int64_t& r0, int64_t& r1) const {
    const double lo = std::min({vy[0], vy[1], vy[2]}) - R - 0.5;
    const double hi = std::max({vy[0], vy[1], vy[2]}) + R - 0.5;
    r0 = int64_t(std::clamp(std::ceil(lo), 0.0, double(H)));
    r1 = int64_t(std::clamp(std::floor(hi), -1.0, double(H - 1)));
  }

  // columns within R of the vertex x-range (a superset of every row's span)
  void bbox_cols(int64_t& c0, int64_t& c1) const {
    const double lo = std::min({vx[0], vx[1], vx[2]}) - R - 0.5;
    const double hi = std::max({vx[0], vx[1], vx[2]}) + R - 0.5;
    c0 = int64_t(std::clamp(std::ceil(lo), 0.0, double(W)));
    c1 = int64_t(std::clamp(std::floor(hi), -1.0, double(W - 1)));
  }

  bool cols(int64_t row, int64_t& c0, int64_t& c1) const {
    const double y0 = row + 0.5 - R, y1 = row + 0.5 + R;
    double xmin = std::numeric_limits<double>::infinity(), xmax = -xmin;
    for (int i = 0; i < 3; ++i) {
      const int j = (i + 1) % 3;
      double ax = vx[i], ay = vy[i], bx = vx[j], by = vy[j];
      if (ay > by) std::swap(ax, bx), std::swap(ay, by);
      if (by < y0 || ay > y1) continue;
      double xa = ax, xb = bx;
      if (by > ay) {
        const double s = (bx - ax) / (by - ay);
        xa = ax + s * (std::max(y0, ay) - ay);
        xb = ax + s * (std::min(y1, by) - ay);
      }
      xmin = std::min({xmin, xa, xb});
      xmax = std::max({xmax, xa, xb});
    }
    if (!(xmin <= xmax)) return false;
    c0 = int64_t(std::clamp(std::ceil(xmin - R - 0.5), 0.0, double(W)));
    c1 = int64_t(std::clamp(std::floor(xmax + R - 0.5), -1.0, double(W - 1)));
    return c0 <= c1;
  }
};

template <typename T>
Footprint footprint(const Face<T>& f, const RasterConfig& cfg) {
  Footprint fp;
  for (int i = 0; i < 3; ++i) fp.vx[i] = double(f.ax[i]), fp.vy[i] = double(f.ay[i]);
  const double r = cfg.sigma * kCutoffLog;
  fp.R = r * (1.0 + 1e-6) + 1e-3;  // slack for rounding; the live test is exact
  fp.H = cfg.height;
  fp.W = cfg.width;
  return fp;
}

// Evaluates the chunk's first n pixels and calls fn on the contributing ones.
template <typename T, typename Fn>
inline void eval_chunk(const Face<T>& f, const Consts<T>& k, int n, bool need_log, bool grad, Chunk<T>& ch,
                       Pair<T>& p, Fn& fn) {
  chunk_geometry(f, n, ch);
  for (int j = 0; j < n; ++j)
    if (eval_pair(f, k, ch, j, need_log, grad, p)) fn(ch.idx[j], ch.px[j], ch.py[j], p);
}

// Calls fn(pixel index, px, py, pair) for every contributing pair of a face. A face
// whose blurred bounding box has at most kChunk pixels (most faces at working
// resolutions) is one chunk; a larger one goes row by row over the row's span.
// The pixels visited differ, the pairs that contribute (exact test) do not.
template <typename T, typename Fn>
void for_each_pair(const Face<T>& f, const Consts<T>& k, const RasterConfig& cfg, bool need_log, bool grad,
                   Fn&& fn) {
  const Footprint fp = footprint(f, cfg);
  int64_t r0, r1, b0, b1;
  fp.rows(r0, r1);
  fp.bbox_cols(b0, b1);
  if (r1 < r0 || b1 < b0) return;
  Pair<T> p;
  Chunk<T> ch;
  const int64_t bw = b1 - b0 + 1, bh = r1 - r0 + 1;
  if (bw * bh <= kChunk) {
    int n = 0;
    for (int64_t row = r0; row <= r1; ++row)
      for (int64_t col = b0; col <= b1; ++col, ++n) {
        ch.px[n] = T(col) + T(0.5);
        ch.py[n] = T(row) + T(0.5);
        ch.idx[n] = row * cfg.width + col;
      }
    eval_chunk(f, k, n, need_log, grad, ch, p, fn);
    return;
  }
  for (int64_t row = r0; row <= r1; ++row) {
    int64_t c0, c1;
    if (!fp.cols(row, c0, c1)) continue;
    const T py = T(row) + T(0.5);
    const int64_t base = row * cfg.width;
    for (int64_t col0 = c0; col0 <= c1; col0 += kChunk) {
      const int n = int(std::min<int64_t>(kChunk, c1 - col0 + 1));
      for (int j = 0; j < n; ++j) {
        ch.px[j] = T(col0 + j) + T(0.5);
        ch.py[j] = py;
        ch.idx[j] = base + col0 + j;
      }
      eval_chunk(f, k, n, need_log, grad, ch, p, fn);
    }
  }
}

}  // namespace raster_detail
}  // namespace jaxgenus
