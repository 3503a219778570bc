// XLA-free remeshing kernel: raw buffers in, raw buffers out, a status back.
// Every input is validated; nothing is thrown or aborted across this boundary.
#pragma once

#include <cstdint>
#include <string>
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

// Lengths are absolute; a value <= 0 selects the documented default.
struct RemeshParams {
  float target_edge_length = 0;  // <= 0: mean edge length of the input (h)
  int32_t iterations = 5;
  int32_t adaptive = 0;          // 1: curvature-adaptive sizing
  float approx_error = 0;        // adaptive eps; <= 0: 0.05 h
  float min_edge_length = 0;     // adaptive clamp; <= 0: 0.25 h
  float max_edge_length = 0;     // adaptive clamp; <= 0: 4 h
  float coarsen_factor = 0;      // V-cycle coarsening target factor; <= 0: 2 if adaptive else 1 (off)
  int32_t smoothing_steps = 1;   // tangential smoothing steps per iteration
  float smoothing_lambda = 1;    // step size of tangential smoothing, in (0, 1]
  int32_t project = 1;           // project onto the input surface after smoothing
  int32_t debug_validate = 0;    // 1: validate() after every operation (slow; tests/debugging)
};

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

// The int32 summary both entry points return: status, n_vertices, n_faces,
// faces_estimated (clamped to int32), chi_before, chi_after, splits,
// collapses, flips (the last three clamped to int32).
constexpr int kRemeshInfoSize = 9;
void write_remesh_info(const RemeshReport& r, int32_t* info);

}  // namespace jaxgenus
