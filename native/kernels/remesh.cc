// Remeshing kernel: input validation, defaults, the half-edge remesher, and
// output checks (validate() + chi + components) before anything is written.
#include "kernels/remesh.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>

#include "halfedge/operations.h"

namespace jaxgenus {
namespace {

bool is_finite(float x) { return std::isfinite(x); }

// Remeshes `input` into `result`. Only fills the report's status on failure paths.
RemeshReport run(const he::Mesh& input, const RemeshParams& p, int64_t face_budget,
                 he::Mesh* result) {
  RemeshReport r;
  r.status = Status::kInvalidInput;
  if (p.iterations < 0 || p.iterations > 1000 || p.smoothing_steps < 0 || p.smoothing_steps > 100 ||
      !(p.smoothing_lambda > 0 && p.smoothing_lambda <= 1) || !is_finite(p.target_edge_length) ||
      !is_finite(p.approx_error) || !is_finite(p.min_edge_length) ||
      !is_finite(p.max_edge_length) || !is_finite(p.coarsen_factor) || face_budget < 4) {
    r.message = "invalid options";
    return r;
  }
  double h = p.target_edge_length;
  if (!(h > 0)) {
    double sum = 0;
    for (int32_t e = 0; e < input.halfedge_slots(); ++e) sum += input.length(he::HalfedgeId{e});
    h = input.halfedge_slots() > 0 ? sum / input.halfedge_slots() : 0;
  }
  if (!(h > 0) || !std::isfinite(h)) {
    r.message = "target edge length is zero (all vertices coincide?)";
    return r;
  }
  he::RemeshSettings s;
  s.target_edge_length = h;
  s.iterations = p.iterations;
  s.adaptive = p.adaptive != 0;
  s.approx_error = p.approx_error > 0 ? p.approx_error : 0.05 * h;
  s.min_edge_length = p.min_edge_length > 0 ? p.min_edge_length : 0.25 * h;
  s.max_edge_length = p.max_edge_length > 0 ? p.max_edge_length : 4.0 * h;
  if (s.max_edge_length < s.min_edge_length) {
    r.message = "max_edge_length < min_edge_length";
    return r;
  }
  s.coarsen_factor = p.coarsen_factor > 0 ? p.coarsen_factor : (s.adaptive ? 2.0 : 1.0);
  s.smoothing_steps = p.smoothing_steps;
  s.smoothing_lambda = p.smoothing_lambda;
  s.project = p.project != 0;
  s.face_budget = face_budget;
  s.validate_each_operation = p.debug_validate != 0;
  r.target_edge_length = h;
  r.chi_before = input.euler_characteristic();
  *result = input;
  const he::RemeshOutcome o = he::remesh(*result, s);
  r.splits = o.splits;
  r.collapses = o.collapses;
  r.flips = o.flips;
  r.faces_estimated = o.faces_estimated;
  r.chi_after = result->euler_characteristic();
  std::string err = o.error.empty() ? he::validate(*result, r.chi_before) : o.error;
  if (err.empty() && he::connected_components(*result) != he::connected_components(input))
    err = "number of connected components changed";
  if (!err.empty()) {
    r.status = Status::kTopologyChanged;
    r.message = err;
    return r;
  }
  r.status = o.budget_limited ? Status::kCapacityExceeded : Status::kOk;
  if (o.budget_limited) r.message = "sizing coarsened to fit the face capacity";
  r.n_vertices = result->live_vertices();
  r.n_faces = result->live_faces();
  return r;
}

}  // namespace

const char* remesh_status_name(Status s) {
  switch (s) {
    case Status::kOk: return "ok";
    case Status::kCapacityExceeded: return "capacity_exceeded";
    case Status::kInvalidInput: return "invalid_input";
    case Status::kTopologyChanged: return "topology_changed";
  }
  return "unknown";
}

void write_remesh_info(const RemeshReport& r, int32_t* info) {
  auto clamp32 = [](int64_t x) { return int32_t(std::min<int64_t>(std::max<int64_t>(x, INT32_MIN), INT32_MAX)); };
  namespace ri = remesh_info;
  info[ri::status] = int32_t(r.status);
  info[ri::n_vertices] = r.n_vertices;
  info[ri::n_faces] = r.n_faces;
  info[ri::faces_estimated] = clamp32(r.faces_estimated);
  info[ri::chi_before] = clamp32(r.chi_before);
  info[ri::chi_after] = clamp32(r.chi_after);
  info[ri::splits] = clamp32(r.splits);
  info[ri::collapses] = clamp32(r.collapses);
  info[ri::flips] = clamp32(r.flips);
  static_assert(ri::kCount == 9, "write every field of JAXGENUS_REMESH_INFO_FIELDS above");
}

RemeshReport remesh_buffers(const float* V, int64_t vcap, const int32_t* F, int64_t fcap,
                            int64_t nv, int64_t nf, const float* attr, int64_t n_attr,
                            const RemeshParams& params, int64_t face_budget, float* V_out,
                            int32_t* F_out, float* attr_out) {
  RemeshReport r;
  auto keep_input = [&](Status status, const std::string& msg) {
    if (V_out != V && vcap > 0) std::memmove(V_out, V, sizeof(float) * 3 * vcap);
    if (F_out != F && fcap > 0) std::memmove(F_out, F, sizeof(int32_t) * 3 * fcap);
    if (attr_out != attr && vcap > 0 && n_attr > 0)
      std::memmove(attr_out, attr, sizeof(float) * n_attr * vcap);
    r.status = status;
    r.message = msg;
    r.n_vertices = int32_t(nv);
    r.n_faces = int32_t(nf);
    return r;
  };
  if (vcap < 0 || fcap < 0 || n_attr < 0 || vcap >= INT32_MAX / 4 || fcap >= INT32_MAX / 4 ||
      (vcap > 0 && (V == nullptr || V_out == nullptr)) ||
      (fcap > 0 && (F == nullptr || F_out == nullptr)) ||
      (n_attr > 0 && vcap > 0 && (attr == nullptr || attr_out == nullptr))) {
    r.message = "invalid buffers";
    return r;  // nothing can be copied safely
  }
  if (nv < 0 || nf < 0 || nv > vcap || nf > fcap)
    return keep_input(Status::kInvalidInput, "live counts out of range");
  try {
    std::vector<double> vd(V, V + 3 * nv);
    he::Mesh input;
    const he::BuildStatus b =
        he::Mesh::build(vd.data(), nv, F, nf, n_attr > 0 ? attr : nullptr, int32_t(n_attr), &input);
    if (b != he::BuildStatus::ok) return keep_input(Status::kInvalidInput, he::build_status_name(b));
    he::Mesh result;
    RemeshReport run_r = run(input, params, std::min(face_budget, fcap), &result);
    if (run_r.status != Status::kOk && run_r.status != Status::kCapacityExceeded) {
      RemeshReport kept = keep_input(run_r.status, run_r.message);
      kept.chi_before = run_r.chi_before;
      kept.chi_after = run_r.chi_after;
      return kept;
    }
    if (run_r.n_vertices > vcap || run_r.n_faces > fcap) {
      RemeshReport kept = keep_input(Status::kCapacityExceeded, "result exceeds the capacity");
      kept.faces_estimated = run_r.faces_estimated;
      return kept;
    }
    const int64_t nvo = run_r.n_vertices, nfo = run_r.n_faces;
    for (int64_t i = 0; i < vcap; ++i) {
      const bool live = i < nvo;
      V_out[3 * i] = live ? float(result.pos[i].x) : 0.f;
      V_out[3 * i + 1] = live ? float(result.pos[i].y) : 0.f;
      V_out[3 * i + 2] = live ? float(result.pos[i].z) : 0.f;
      for (int64_t k = 0; k < n_attr; ++k)
        attr_out[i * n_attr + k] = live ? float(result.attr[i * n_attr + k]) : 0.f;
    }
    for (int64_t i = 0; i < 3 * fcap; ++i) F_out[i] = i < 3 * nfo ? result.origin[i] : 0;
    return run_r;
  } catch (const std::exception& e) {
    return keep_input(Status::kInvalidInput, std::string("internal error: ") + e.what());
  } catch (...) {
    return keep_input(Status::kInvalidInput, "internal error");
  }
}

RemeshReport remesh_arrays(const double* V, int64_t nv, const int32_t* F, int64_t nf,
                           const float* attr, int64_t n_attr, const RemeshParams& params,
                           int64_t face_budget, std::vector<double>* V_out,
                           std::vector<int32_t>* F_out, std::vector<float>* attr_out) {
  RemeshReport r;
  if (nv < 0 || nf < 0 || n_attr < 0 || nv >= INT32_MAX / 4 || nf >= INT32_MAX / 4 ||
      (n_attr > 0 && nv > 0 && attr == nullptr) || (nv > 0 && V == nullptr) || (nf > 0 && F == nullptr)) {
    r.message = "invalid arrays";
    return r;
  }
  try {
    he::Mesh input;
    const he::BuildStatus b =
        he::Mesh::build(V, nv, F, nf, n_attr > 0 ? attr : nullptr, int32_t(n_attr), &input);
    if (b != he::BuildStatus::ok) {
      r.message = he::build_status_name(b);
      return r;
    }
    he::Mesh result;
    r = run(input, params, face_budget, &result);
    if (r.status != Status::kOk && r.status != Status::kCapacityExceeded) return r;
    result.write(V_out, F_out);
    attr_out->assign(result.attr.begin(), result.attr.end());
    return r;
  } catch (const std::exception& e) {
    r.status = Status::kInvalidInput;
    r.message = std::string("internal error: ") + e.what();
    return r;
  } catch (...) {
    r.status = Status::kInvalidInput;
    r.message = "internal error";
    return r;
  }
}

RemeshReport apply_operations(const double* V, int64_t nv, const int32_t* F, int64_t nf,
                              const int32_t* ops, int64_t n_ops, std::vector<double>* V_out,
                              std::vector<int32_t>* F_out, int64_t* applied) {
  RemeshReport r;
  *applied = 0;
  if (nv < 0 || nf < 0 || n_ops < 0 || nv >= INT32_MAX / 4 || nf >= INT32_MAX / 4) {
    r.message = "invalid arrays";
    return r;
  }
  try {
    he::Mesh m;
    const he::BuildStatus b = he::Mesh::build(V, nv, F, nf, nullptr, 0, &m);
    if (b != he::BuildStatus::ok) {
      r.message = he::build_status_name(b);
      return r;
    }
    r.chi_before = m.euler_characteristic();
    const int32_t components = he::connected_components(m);
    r.status = Status::kOk;
    for (int64_t i = 0; i < n_ops; ++i) {
      const int32_t kind = ops[3 * i], param = ops[3 * i + 2];
      const int32_t slots = m.halfedge_slots();
      if (slots == 0) break;
      const he::HalfedgeId h{int32_t((int64_t(ops[3 * i + 1]) % slots + slots) % slots)};
      if (m.is_dead(he::Mesh::face(h))) continue;
      if (kind == 0 && he::is_split_ok(m, h)) {
        he::split(m, h, std::clamp(param, 1, 999) / 1000.0);
      } else if (kind == 1) {
        const he::Vec3 p = (m.pos[m.from(h).idx] + m.pos[m.to(h).idx]) * 0.5;
        if (!he::is_collapse_ok(m, h, p, INFINITY)) continue;
        he::collapse(m, h, p);
      } else if (kind == 2 && he::is_flip_ok(m, h)) {
        he::flip(m, h);
      } else if (kind == 3) {
        he::tangential_smooth(m, 0.5, nullptr);
      } else {
        continue;
      }
      ++*applied;
      std::string err = he::validate(m, r.chi_before);
      if (err.empty() && he::connected_components(m) != components) err = "components changed";
      if (!err.empty()) {
        r.status = Status::kTopologyChanged;
        r.message = "op " + std::to_string(i) + ": " + err;
        break;
      }
    }
    m.compact();
    r.chi_after = m.euler_characteristic();
    r.n_vertices = m.live_vertices();
    r.n_faces = m.live_faces();
    m.write(V_out, F_out);
    return r;
  } catch (const std::exception& e) {
    r.status = Status::kInvalidInput;
    r.message = std::string("internal error: ") + e.what();
    return r;
  }
}

}  // namespace jaxgenus
