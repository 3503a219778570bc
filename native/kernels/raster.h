// Face-major soft rasterizer ("splat") on the CPU: forward and hand-written VJP.
// Plain C++17: no XLA, no Python. Numerically the model of jaxgenus/_splat.py
// (tapered sigmoid coverage of the signed distance, depth-softmax blend with a
// background, envelope-theorem gradients of the nearest edge), but without
// windows or tiers: every valid face of a view is visited over the pixels of its
// blurred footprint (its whole box when that has at most 32 pixels, else a scanline
// span per row), clipped to the image.
//
// Layouts (row-major, leading view axis of n_views):
//   v (V, F, 3, 2) pixel coordinates, plane (V, F, 3) = (gx, gy, c) of the
//   normalized inverse depth q = gx * u + gy * v + c, qrange (V, F, 2) its clamp,
//   attr (V, F, A) face constants, or with attr_planes (V, F, A, 5) = per channel
//   (gx, gy, c, lo, hi): the value clamp(gx * u + gy * v + c, lo, hi) at pixel (u, v)
//   (an attribute interpolated over the face, e.g. Gouraud shading),
//   logw (V, F), valid (V, F) (bool), dconst (V, 2) = (scale, offset): 1/z = q * scale + offset.
//   cov (V, H, W), blend (V, H, W, C), mlw (V, H, W), C = n_attr + want_depth.
// Views are processed in parallel (std::thread, at most one thread per view).
#pragma once
#include <cstdint>
#include <string>

#include "kernels/status.h"

namespace jaxgenus {

struct RasterConfig {
  int64_t height = 0;
  int64_t width = 0;
  double sigma = 1.0;      // edge blur (pixels)
  double gamma = 0.01;     // depth softmax temperature
  double sharpness = 1.0;  // coverage exponent p of the blend weight
  bool want_cov = true;
  int64_t n_attr = 0;
  bool attr_planes = false;  // attributes are clamped planes in the pixel (5 values each), not constants
  bool want_depth = false;
  const double* background = nullptr;  // n_attr + want_depth values (may be null if 0)
  int64_t n_threads = 0;               // 0: std::thread::hardware_concurrency()

  int64_t n_blend() const { return n_attr + (want_depth ? 1 : 0); }
  int64_t attr_stride() const { return attr_planes ? 5 : 1; }  // values per attribute channel
};

template <typename T>
struct RasterFaces {
  int64_t n_views = 0;
  int64_t n_faces = 0;
  const T* v = nullptr;
  const T* plane = nullptr;
  const T* qrange = nullptr;
  const T* attr = nullptr;  // may be null when n_attr == 0
  const T* logw = nullptr;
  const bool* valid = nullptr;
  const T* dconst = nullptr;
};

// Upstream cotangents and residuals of the backward pass (per view as above).
template <typename T>
struct RasterCotangents {
  const T* blend = nullptr;    // forward blend (only read when C > 0)
  const T* mlw = nullptr;      // forward log normalizer (only read when C > 0)
  const T* g_cov = nullptr;    // (V, H, W)
  const T* g_blend = nullptr;  // (V, H, W, C) (only read when C > 0)
};

// Gradient outputs, same shapes as the face inputs; every one is overwritten.
template <typename T>
struct RasterGrads {
  T* v = nullptr;
  T* plane = nullptr;
  T* qrange = nullptr;
  T* attr = nullptr;  // may be null when n_attr == 0
  T* logw = nullptr;
  T* dconst = nullptr;
};

// Forward: writes cov (zeros unless want_cov) and, when C > 0, blend and mlw
// (mlw = log of the softmax normalizer, the residual of the backward). When C == 0
// blend and mlw may be null; mlw, if given, is set to 0. Returns kOk, or
// kInvalidInput with *error set (null pointers, bad sizes or parameters).
template <typename T>
Status raster_forward(const RasterConfig& cfg, const RasterFaces<T>& faces, T* cov, T* blend, T* mlw,
                      std::string* error);

// Backward (VJP) of raster_forward with respect to v, plane, qrange, attr, logw
// and dconst.
template <typename T>
Status raster_backward(const RasterConfig& cfg, const RasterFaces<T>& faces,
                       const RasterCotangents<T>& cot, const RasterGrads<T>& grads, std::string* error);

extern template Status raster_forward<float>(const RasterConfig&, const RasterFaces<float>&, float*, float*,
                                             float*, std::string*);
extern template Status raster_forward<double>(const RasterConfig&, const RasterFaces<double>&, double*,
                                              double*, double*, std::string*);
extern template Status raster_backward<float>(const RasterConfig&, const RasterFaces<float>&,
                                              const RasterCotangents<float>&, const RasterGrads<float>&,
                                              std::string*);
extern template Status raster_backward<double>(const RasterConfig&, const RasterFaces<double>&,
                                               const RasterCotangents<double>&, const RasterGrads<double>&,
                                               std::string*);

}  // namespace jaxgenus
