// XLA-free remeshing kernel: raw buffers in, raw buffers out, a status back.
// Every input is validated; nothing is thrown or aborted across this boundary.
#pragma once

#include <cstdint>
#include <string>
#include <type_traits>
#include <vector>

#include "kernels/status.h"

namespace jaxgenus {

// Status (kernels/status.h) as used by the remesher:
//   kOk
//   kCapacityExceeded: the sizing field was coarsened to fit the face capacity
//     (the output is a valid remesh), or, if even that result does not fit,
//     the output is the unchanged input
//   kInvalidInput: bad counts, indices, NaN, open/non-manifold/misoriented
//     mesh, isolated vertices or bad options; the output is the unchanged input
//   kTopologyChanged: the result failed validate(), chi or the component
//     count (never expected); the output is the unchanged input

// The remesh options, listed ONCE. Every other place derives from this list:
// the RemeshParams struct below, the XLA FFI attribute decoder
// (ffi/remesh_ffi.cc), the option dict of the numpy entry point and the
// exported table `_native.REMESH_PARAMS` (ffi/module.cc), from which the
// Python `RemeshOptions` builds its native options. Columns: C++ type (float or
// int32_t; flags are int32_t 0/1), name, default, doc. Lengths are absolute; a
// value <= 0 selects the documented default.
#define JAXGENUS_REMESH_PARAMS(X)                                                                  \
  X(float, target_edge_length, 0, "uniform target length h; <= 0: mean edge length of the input")   \
  X(int32_t, iterations, 5, "split/collapse/flip/smooth rounds, in [0, 1000]")                      \
  X(int32_t, adaptive, 0, "1: curvature-adaptive sizing")                                           \
  X(float, approx_error, 0, "adaptive approximation error eps; <= 0: 0.05 h")                        \
  X(float, min_edge_length, 0, "adaptive lower clamp of the sizing field; <= 0: 0.25 h")             \
  X(float, max_edge_length, 0, "adaptive upper clamp of the sizing field; <= 0: 4 h")                \
  X(float, coarsen_factor, 0, "V-cycle coarsening target factor; <= 0: 2 if adaptive else 1 (off)") \
  X(int32_t, smoothing_steps, 1, "tangential smoothing steps per iteration, in [0, 100]")           \
  X(float, smoothing_lambda, 1, "step size of tangential smoothing, in (0, 1]")                     \
  X(int32_t, project, 1, "1: project onto the input surface after smoothing")                       \
  X(int32_t, debug_validate, 0, "1: validate() after every operation (slow; tests/debugging)")

struct RemeshParams {
#define JAXGENUS_PARAM_MEMBER(type, name, default_value, doc) type name = default_value;
  JAXGENUS_REMESH_PARAMS(JAXGENUS_PARAM_MEMBER)
#undef JAXGENUS_PARAM_MEMBER
};

// Calls f(name, field, doc) for every option, in list order (`p` may be const).
// The adapters use it to decode and export options without restating them.
template <typename Params, typename F>
void for_each_remesh_param(Params& p, F&& f) {
  static_assert(std::is_same_v<std::remove_const_t<Params>, RemeshParams>);
#define JAXGENUS_PARAM_VISIT(type, name, default_value, doc) f(#name, p.name, doc);
  JAXGENUS_REMESH_PARAMS(JAXGENUS_PARAM_VISIT)
#undef JAXGENUS_PARAM_VISIT
}

struct RemeshReport {
  Status status = Status::kInvalidInput;
  int32_t n_vertices = 0, n_faces = 0;
  int64_t faces_estimated = 0;   // faces the unconstrained sizing field asks for
  int64_t chi_before = 0, chi_after = 0;
  double target_edge_length = 0; // h actually used
  int64_t splits = 0, collapses = 0, flips = 0;
  std::string message;           // reason when status != ok
};

// Capacity-buffer entry (the XLA FFI path). V: (vcap, 3), F: (fcap, 3),
// attr: (vcap, n_attr) or null; nv/nf live counts. Outputs have the same
// shapes; rows past the new counts are zero. Outputs may alias inputs. At
// most min(face_budget, fcap) faces are produced.
// Carried attributes: a vertex created by a split gets the mean of the edge's
// two endpoints, a collapse leaves the mean of the two merged vertices, and
// flips and smoothing leave them unchanged.
RemeshReport remesh_buffers(const float* V, int64_t vcap, const int32_t* F, int64_t fcap,
                            int64_t nv, int64_t nf, const float* attr, int64_t n_attr,
                            const RemeshParams& params, int64_t face_budget, float* V_out,
                            int32_t* F_out, float* attr_out);

// Growable entry (the numpy path): no capacity, at most face_budget faces.
RemeshReport remesh_arrays(const double* V, int64_t nv, const int32_t* F, int64_t nf,
                           const float* attr, int64_t n_attr, const RemeshParams& params,
                           int64_t face_budget, std::vector<double>* V_out,
                           std::vector<int32_t>* F_out, std::vector<float>* attr_out);

// Test hook for the half-edge operations: applies ops (n_ops rows of
// [kind, halfedge, param]) to (V, F): kind 0 = split at t = param / 1000,
// 1 = collapse to the midpoint, 2 = flip, 3 = one tangential smoothing step
// (no projection). The half-edge index is taken modulo the slot count; ops
// that are illegal (per is_*_ok) or hit a deleted face are skipped. validate()
// runs after every applied op; the first violation stops the run and is
// returned in `message` with status kTopologyChanged. *applied counts the ops
// that ran.
RemeshReport apply_operations(const double* V, int64_t nv, const int32_t* F, int64_t nf,
                              const int32_t* ops, int64_t n_ops, std::vector<double>* V_out,
                              std::vector<int32_t>* F_out, int64_t* applied);

const char* remesh_status_name(Status s);

// Layout of the int32 summary both entry points return (`info`), listed ONCE:
// entry i is the i-th row. Exported as `_native.REMESH_INFO_FIELDS`, from which
// the Python `RemeshInfo` is built. Columns: name, doc.
#define JAXGENUS_REMESH_INFO_FIELDS(X)                                            \
  X(status, "Status")                                                             \
  X(n_vertices, "live vertices of the result")                                    \
  X(n_faces, "live faces of the result")                                          \
  X(faces_estimated, "faces the unconstrained sizing field asks for (clamped)")   \
  X(chi_before, "Euler characteristic of the input")                              \
  X(chi_after, "Euler characteristic of the result")                              \
  X(splits, "edge splits applied (clamped to int32)")                             \
  X(collapses, "edge collapses applied (clamped to int32)")                       \
  X(flips, "edge flips applied (clamped to int32)")

namespace remesh_info {
enum Field : int {
#define JAXGENUS_INFO_ENUMERATOR(name, doc) name,
  JAXGENUS_REMESH_INFO_FIELDS(JAXGENUS_INFO_ENUMERATOR)
#undef JAXGENUS_INFO_ENUMERATOR
  kCount
};
inline constexpr const char* kNames[] = {
#define JAXGENUS_INFO_NAME(name, doc) #name,
    JAXGENUS_REMESH_INFO_FIELDS(JAXGENUS_INFO_NAME)
#undef JAXGENUS_INFO_NAME
};
static_assert(sizeof(kNames) / sizeof(kNames[0]) == kCount);
}  // namespace remesh_info

constexpr int kRemeshInfoSize = remesh_info::kCount;
void write_remesh_info(const RemeshReport& r, int32_t* info);

}  // namespace jaxgenus
