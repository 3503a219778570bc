// Face-major soft rasterizer: see raster.h. Formulas mirror jaxgenus/_splat.py
// (`_pairs`, `_log_terms`, `_forward_view`, `_backward_view`) term by term.
#include "kernels/raster.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <exception>
#include <limits>
#include <mutex>
#include <thread>
#include <vector>

#include "kernels/raster_pairs.h"

namespace jaxgenus {
namespace {

using namespace raster_detail;

// Runs fn(view, scratch) over the views on up to n_threads threads (dynamic).
template <typename Scratch, typename Fn>
std::string parallel_views(int64_t n_views, int64_t n_threads, Fn fn) {
  if (n_threads <= 0) n_threads = std::max<int64_t>(1, std::thread::hardware_concurrency());
  n_threads = std::max<int64_t>(1, std::min(n_threads, n_views));
  std::atomic<int64_t> next{0};
  std::mutex mu;
  std::string error;
  auto worker = [&]() {
    try {
      Scratch scratch;
      for (int64_t view = next++; view < n_views; view = next++) fn(view, scratch);
    } catch (const std::exception& e) {
      std::lock_guard<std::mutex> lock(mu);
      if (error.empty()) error = std::string("raster: ") + e.what();
      next = n_views;
    }
  };
  std::vector<std::thread> pool;
  try {
    for (int64_t i = 1; i < n_threads; ++i) pool.emplace_back(worker);
  } catch (const std::exception&) {
    // fewer threads than asked: the remaining ones (and this one) do the work
  }
  worker();
  for (auto& t : pool) t.join();
  return error;
}

Status fail(std::string* error, const std::string& msg) {
  if (error) *error = msg;
  return Status::kInvalidInput;
}

template <typename T>
Status check_common(const RasterConfig& cfg, const RasterFaces<T>& fs, std::string* error) {
  if (cfg.height <= 0 || cfg.width <= 0 || cfg.height > (1 << 20) || cfg.width > (1 << 20) ||
      cfg.height * cfg.width > std::numeric_limits<int32_t>::max())
    return fail(error, "raster: height and width must be positive with H * W < 2^31");
  if (!(cfg.sigma > 0 && std::isfinite(cfg.sigma)) || !(cfg.gamma > 0 && std::isfinite(cfg.gamma)) ||
      !std::isfinite(cfg.sharpness))
    return fail(error, "raster: sigma and gamma must be positive and finite, sharpness finite");
  if (cfg.n_attr < 0) return fail(error, "raster: n_attr must be >= 0");
  if (cfg.n_blend() > 0 && !cfg.background) return fail(error, "raster: background is missing");
  if (fs.n_views < 0 || fs.n_faces < 0) return fail(error, "raster: negative view or face count");
  if (fs.n_views > 0 && !fs.dconst) return fail(error, "raster: dconst is missing");
  if (fs.n_views > 0 && fs.n_faces > 0 &&
      (!fs.v || !fs.plane || !fs.qrange || !fs.logw || !fs.valid || (cfg.n_attr > 0 && !fs.attr)))
    return fail(error, "raster: a face array is missing");
  return Status::kOk;
}

template <typename T>
struct ForwardScratch {
  struct Rec {
    int32_t idx;
    T s, q;
  };
  std::vector<Rec> recs;
  std::vector<std::pair<int64_t, size_t>> faces;  // (face, first rec)
  std::vector<T> wsum;
};

template <typename T>
void forward_view(const RasterConfig& cfg, const RasterFaces<T>& fs, int64_t view, T* cov, T* blend,
                  T* mlw, ForwardScratch<T>& sc) {
  const Consts<T> k(cfg);
  const int64_t hw = cfg.height * cfg.width, nb = cfg.n_blend(), na = cfg.n_attr, st = cfg.attr_stride();
  T* cv = cov + view * hw;
  std::fill(cv, cv + hw, T(0));
  T* m = nb ? mlw + view * hw : nullptr;
  T* bl = nb ? blend + view * hw * nb : nullptr;
  if (nb) {
    std::fill(m, m + hw, k.score_bg);  // max(mcanvas, background score)
    std::fill(bl, bl + hw * nb, T(0));
    sc.wsum.assign(hw, T(0));
    sc.recs.clear();
    sc.faces.clear();
  } else if (mlw) {
    std::fill(mlw + view * hw, mlw + (view + 1) * hw, T(0));
  }
  Face<T> f;
  for (int64_t fi = 0; fi < fs.n_faces; ++fi) {
    if (!make_face(fs, view, fi, na * st, f)) continue;
    if (nb) sc.faces.emplace_back(fi, sc.recs.size());
    for_each_pair(f, k, cfg, nb > 0, false, [&](int64_t idx, T, T, const Pair<T>& p) {
      if (cfg.want_cov) cv[idx] += p.tv * f.w;
      if (nb) {
        const T s = k.sharp * (p.logt + f.logw) + p.q * k.inv_gamma;
        m[idx] = std::max(m[idx], s);
        sc.recs.push_back({int32_t(idx), s, p.q});
      }
    });
  }
  if (!nb) return;
  const T scale = fs.dconst[view * 2], offset = fs.dconst[view * 2 + 1];
  for (size_t i = 0; i < sc.faces.size(); ++i) {
    const T* attr = na ? fs.attr + (view * fs.n_faces + sc.faces[i].first) * na * st : nullptr;
    const size_t end = i + 1 < sc.faces.size() ? sc.faces[i + 1].second : sc.recs.size();
    for (size_t r = sc.faces[i].second; r < end; ++r) {
      const auto& rec = sc.recs[r];
      const T w = std::exp(rec.s - m[rec.idx]);
      sc.wsum[rec.idx] += w;
      T* out = bl + int64_t(rec.idx) * nb;
      const T px = T(rec.idx % cfg.width) + T(0.5), py = T(rec.idx / cfg.width) + T(0.5);
      for (int64_t c = 0; c < na; ++c) out[c] += w * attr_value(attr + c * st, cfg.attr_planes, px, py);
      if (cfg.want_depth) out[na] += w * (T(1) / (rec.q * scale + offset));
    }
  }
  for (int64_t i = 0; i < hw; ++i) {
    const T wb = std::exp(k.score_bg - m[i]);
    const T ws = sc.wsum[i] + wb;
    for (int64_t c = 0; c < nb; ++c) bl[i * nb + c] = (bl[i * nb + c] + wb * T(cfg.background[c])) / ws;
    m[i] = m[i] + std::log(ws);
  }
}

template <typename T>
struct BackwardScratch {
  std::vector<T> sgb;         // per pixel sum_c g_blend * blend
  std::vector<double> gattr;  // per face
};

template <typename T>
void backward_view(const RasterConfig& cfg, const RasterFaces<T>& fs, const RasterCotangents<T>& cot,
                   const RasterGrads<T>& g, int64_t view, BackwardScratch<T>& sc) {
  const Consts<T> k(cfg);
  const int64_t hw = cfg.height * cfg.width, nb = cfg.n_blend(), na = cfg.n_attr, nf = fs.n_faces;
  const int64_t st = cfg.attr_stride(), nav = na * st;  // attribute values per face
  const int64_t f0 = view * nf;
  std::fill(g.v + f0 * 6, g.v + (f0 + nf) * 6, T(0));
  std::fill(g.plane + f0 * 3, g.plane + (f0 + nf) * 3, T(0));
  std::fill(g.qrange + f0 * 2, g.qrange + (f0 + nf) * 2, T(0));
  if (na) std::fill(g.attr + f0 * nav, g.attr + (f0 + nf) * nav, T(0));
  std::fill(g.logw + f0, g.logw + f0 + nf, T(0));
  const T* gc = cot.g_cov + view * hw;
  const T* mlw = nb ? cot.mlw + view * hw : nullptr;
  const T* gb = nb ? cot.g_blend + view * hw * nb : nullptr;
  if (nb) {
    const T* bl = cot.blend + view * hw * nb;
    sc.sgb.assign(hw, T(0));
    for (int64_t i = 0; i < hw; ++i) {
      T s = T(0);
      for (int64_t c = 0; c < nb; ++c) s += gb[i * nb + c] * bl[i * nb + c];
      sc.sgb[i] = s;
    }
  }
  sc.gattr.assign(std::max<int64_t>(nav, 1), 0.0);
  const T scale = fs.dconst[view * 2], offset = fs.dconst[view * 2 + 1];
  double gdc0 = 0, gdc1 = 0;
  Face<T> f;
  for (int64_t fi = 0; fi < nf; ++fi) {
    if (!make_face(fs, view, fi, nav, f)) continue;
    double gv[3][2] = {{0, 0}, {0, 0}, {0, 0}}, gqf = 0, gqx = 0, gqy = 0, glo = 0, ghi = 0, gw_sum = 0;
    std::fill(sc.gattr.begin(), sc.gattr.end(), 0.0);
    for_each_pair(f, k, cfg, nb > 0, true, [&](int64_t idx, T px, T py, const Pair<T>& p) {
      T gx = T(0), gw = T(0), gq = T(0);
      if (cfg.want_cov) {
        const T a = gc[idx] * f.w;
        gw = a * p.tv;
        gx = a * p.dt;
      }
      if (nb) {
        const T s = k.sharp * (p.logt + f.logw) + p.q * k.inv_gamma;
        const T pj = std::exp(s - mlw[idx]);
        const T* g_b = gb + idx * nb;
        T dot = T(0);
        for (int64_t c = 0; c < na; ++c) {
          const T* a = f.attr + c * st;
          dot += g_b[c] * attr_value(a, cfg.attr_planes, px, py);
          const double ga = double(pj * g_b[c]);
          if (!cfg.attr_planes) {
            sc.gattr[c] += ga;
            continue;
          }
          const T raw = a[0] * px + a[1] * py + a[2];
          double* gp = sc.gattr.data() + c * st;
          if (raw > a[3] && raw < a[4]) {
            gp[0] += ga * double(px);
            gp[1] += ga * double(py);
            gp[2] += ga;
          } else if (raw <= a[3]) {
            gp[3] += ga;
          } else {
            gp[4] += ga;
          }
        }
        T depth = T(0);
        if (cfg.want_depth) {
          depth = T(1) / (p.q * scale + offset);
          dot += g_b[na] * depth;
        }
        const T gscore = pj * (dot - sc.sgb[idx]);
        gx += k.sharp * gscore * p.dlog;
        gw += k.sharp * gscore;
        gq = gscore * k.inv_gamma;
        if (cfg.want_depth) {
          const T gz = -pj * g_b[na] * depth * depth;
          gq += gz * scale;
          gdc0 += double(gz * p.q);
          gdc1 += double(gz);
        }
      }
      gw_sum += double(gw);
      if (p.dist > T(0)) {
        const T gd2 = -(p.inside ? gx : -gx) / (k.sigma * p.dist);
        const int e = p.edge, e1 = (p.edge + 1) % 3;
        const double ca = double(gd2 * (T(1) - p.t)), cb = double(gd2 * p.t);
        gv[e][0] += ca * double(p.dx);
        gv[e][1] += ca * double(p.dy);
        gv[e1][0] += cb * double(p.dx);
        gv[e1][1] += cb * double(p.dy);
      }
      if (p.qraw > f.lo && p.qraw < f.hi) {
        gqf += double(gq);
        gqx += double(gq * px);
        gqy += double(gq * py);
      } else if (p.qraw <= f.lo) {
        glo += double(gq);
      } else if (p.qraw > f.lo) {
        ghi += double(gq);
      }
    });
    const int64_t kf = f0 + fi;
    for (int i = 0; i < 3; ++i) g.v[kf * 6 + 2 * i] = T(gv[i][0]), g.v[kf * 6 + 2 * i + 1] = T(gv[i][1]);
    g.plane[kf * 3] = T(gqx);
    g.plane[kf * 3 + 1] = T(gqy);
    g.plane[kf * 3 + 2] = T(gqf);
    g.qrange[kf * 2] = T(glo);
    g.qrange[kf * 2 + 1] = T(ghi);
    for (int64_t c = 0; c < nav; ++c) g.attr[kf * nav + c] = T(sc.gattr[c]);
    g.logw[kf] = T(gw_sum);
  }
  g.dconst[view * 2] = T(gdc0);
  g.dconst[view * 2 + 1] = T(gdc1);
}

}  // namespace

template <typename T>
Status raster_forward(const RasterConfig& cfg, const RasterFaces<T>& faces, T* cov, T* blend, T* mlw,
                      std::string* error) {
  if (Status s = check_common(cfg, faces, error); s != Status::kOk) return s;
  if (faces.n_views == 0) return Status::kOk;
  if (!cov || (cfg.n_blend() > 0 && (!blend || !mlw))) return fail(error, "raster: an output is missing");
  std::string err = parallel_views<ForwardScratch<T>>(
      faces.n_views, cfg.n_threads,
      [&](int64_t view, ForwardScratch<T>& sc) { forward_view(cfg, faces, view, cov, blend, mlw, sc); });
  if (!err.empty()) return fail(error, err);
  return Status::kOk;
}

template <typename T>
Status raster_backward(const RasterConfig& cfg, const RasterFaces<T>& faces, const RasterCotangents<T>& cot,
                       const RasterGrads<T>& grads, std::string* error) {
  if (Status s = check_common(cfg, faces, error); s != Status::kOk) return s;
  if (faces.n_views == 0) return Status::kOk;
  const bool need_faces = faces.n_faces > 0;
  if (!grads.dconst || (need_faces && (!grads.v || !grads.plane || !grads.qrange || !grads.logw ||
                                       (cfg.n_attr > 0 && !grads.attr))))
    return fail(error, "raster: a gradient output is missing");
  if (!cot.g_cov || (cfg.n_blend() > 0 && (!cot.blend || !cot.mlw || !cot.g_blend)))
    return fail(error, "raster: a cotangent or residual is missing");
  std::string err = parallel_views<BackwardScratch<T>>(
      faces.n_views, cfg.n_threads,
      [&](int64_t view, BackwardScratch<T>& sc) { backward_view(cfg, faces, cot, grads, view, sc); });
  if (!err.empty()) return fail(error, err);
  return Status::kOk;
}

template Status raster_forward<float>(const RasterConfig&, const RasterFaces<float>&, float*, float*, float*,
                                      std::string*);
template Status raster_forward<double>(const RasterConfig&, const RasterFaces<double>&, double*, double*,
                                       double*, std::string*);
template Status raster_backward<float>(const RasterConfig&, const RasterFaces<float>&,
                                       const RasterCotangents<float>&, const RasterGrads<float>&, std::string*);
template Status raster_backward<double>(const RasterConfig&, const RasterFaces<double>&,
                                        const RasterCotangents<double>&, const RasterGrads<double>&,
                                        std::string*);

}  // namespace jaxgenus
