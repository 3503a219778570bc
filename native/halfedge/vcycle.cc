// The remeshing driver: sizing field, V-cycle (coarsen, then refine), valence
// flips and tangential smoothing with projection.
#include <algorithm>
#include <cmath>
#include <memory>
#include <utility>
#include <vector>

#include "halfedge/operations.h"

namespace jaxgenus::he {
namespace {

constexpr int kKappaSmoothing = 3;   // one-ring averaging rounds of the curvature
constexpr double kGradation = 0.5;   // max growth of the sizing field per unit length

double edge_target(const Mesh& m, HalfedgeId h) {
  return 0.5 * (m.sizing[m.from(h).idx] + m.sizing[m.to(h).idx]);
}

// Checks the invariants after an operation when asked to; returns false on failure.
bool checked(const Mesh& m, const RemeshSettings& s, int64_t chi, const char* op, RemeshOutcome* out) {
  if (!s.validate_each_operation) return true;
  const std::string err = validate(m, chi);
  if (err.empty()) return true;
  out->error = std::string("after ") + op + ": " + err;
  return false;
}

// Edges (as vertex pairs) whose length / target ratio passes `keep`, sorted
// by that ratio (descending when `longest_first`). Edges are named by their
// endpoints because operations rewrite the half-edge slots of their faces.
template <typename Keep>
std::vector<std::pair<VertexId, VertexId>> candidates(const Mesh& m, double scale, bool longest_first,
                                                      Keep keep) {
  std::vector<std::pair<double, int32_t>> ratio;
  for (int32_t h = 0; h < m.halfedge_slots(); ++h) {
    if (m.is_dead(Mesh::face(HalfedgeId{h})) || m.twin[h] < h) continue;
    const double r = m.length(HalfedgeId{h}) / (scale * edge_target(m, HalfedgeId{h}));
    if (keep(r)) ratio.push_back({longest_first ? -r : r, h});
  }
  std::sort(ratio.begin(), ratio.end());
  std::vector<std::pair<VertexId, VertexId>> out;
  out.reserve(ratio.size());
  for (const auto& [r, h] : ratio) out.push_back({m.from(HalfedgeId{h}), m.to(HalfedgeId{h})});
  return out;
}

// Splits edges longer than 4/3 of their target, longest first, in sweeps over
// the edges present at the start of each sweep, until none is left.
bool split_long_edges(Mesh& m, const RemeshSettings& s, int64_t chi, RemeshOutcome* out) {
  for (int sweep = 0; sweep < 32; ++sweep) {
    const auto todo = candidates(m, 1.0, true, [](double r) { return r > 4.0 / 3.0; });
    int64_t n = 0;
    for (const auto& [a, b] : todo) {
      if (m.live_faces() + 2 > s.face_budget) break;
      const HalfedgeId e = m.find_halfedge(a, b);
      if (!e.valid() || m.length(e) <= 4.0 / 3.0 * edge_target(m, e) || !is_split_ok(m, e)) continue;
      split(m, e, 0.5);
      ++n;
      if (!checked(m, s, chi, "split", out)) return false;
    }
    out->splits += n;
    if (n == 0 || m.live_faces() + 2 > s.face_budget) break;
  }
  return true;
}

// Collapses edges shorter than 4/5 of scale * target to their midpoint,
// shortest first, when no new edge exceeds 4/3 of scale * target.
bool collapse_short_edges(Mesh& m, const RemeshSettings& s, double scale, int64_t chi,
                          RemeshOutcome* out) {
  for (int sweep = 0; sweep < 8; ++sweep) {
    const auto todo = candidates(m, scale, false, [](double r) { return r < 0.8; });
    int64_t n = 0;
    for (const auto& [a, b] : todo) {
      const HalfedgeId e = m.find_halfedge(a, b);
      if (!e.valid()) continue;
      const double target = scale * edge_target(m, e);
      if (m.length(e) >= 0.8 * target) continue;
      const Vec3 mid = (m.pos[a.idx] + m.pos[b.idx]) * 0.5;
      if (!is_collapse_ok(m, e, mid, 4.0 / 3.0 * target)) continue;
      collapse(m, e, mid);
      ++n;
      if (!checked(m, s, chi, "collapse", out)) return false;
    }
    out->collapses += n;
    if (n == 0) break;
  }
  return true;
}

// Flips edges whose flip brings the four diamond valences closer to 6.
bool equalize_valences(Mesh& m, const RemeshSettings& s, int64_t chi, RemeshOutcome* out) {
  std::vector<int32_t> val(m.vertex_slots(), 0);
  for (int32_t h = 0; h < m.halfedge_slots(); ++h)
    if (!m.is_dead(Mesh::face(HalfedgeId{h}))) ++val[m.origin[h]];
  auto dev = [](int x) { return (x - 6) * (x - 6); };
  for (int32_t h = 0; h < m.halfedge_slots(); ++h) {
    if (m.is_dead(Mesh::face(HalfedgeId{h})) || m.twin[h] < h) continue;
    const HalfedgeId e{h};
    const Diamond q = diamond(m, e);
    const int a = val[q.a.idx], b = val[q.b.idx], c = val[q.c.idx], d = val[q.d.idx];
    const int before = dev(a) + dev(b) + dev(c) + dev(d);
    const int after = dev(a - 1) + dev(b - 1) + dev(c + 1) + dev(d + 1);
    if (after >= before || !is_flip_ok(m, e)) continue;
    flip(m, e);
    --val[q.a.idx];
    --val[q.b.idx];
    ++val[q.c.idx];
    ++val[q.d.idx];
    ++out->flips;
    if (!checked(m, s, chi, "flip", out)) return false;
  }
  return true;
}

// Sizing field on the input: uniform, or from curvature (Dunyach et al. 2013);
// then scaled up (uniformly) if it asks for more faces than the budget allows.
void assign_sizing(Mesh& m, const RemeshSettings& s, RemeshOutcome* out) {
  const int32_t nvs = m.vertex_slots();
  if (!s.adaptive) {
    std::fill(m.sizing.begin(), m.sizing.end(), s.target_edge_length);
  } else {
    const Curvature curv = vertex_curvature(m);
    // A few rounds of one-ring averaging make kappa robust to noise and slivers.
    std::vector<double> kappa(nvs), next(nvs);
    for (int32_t v = 0; v < nvs; ++v) kappa[v] = max_abs_principal(curv.mean[v], curv.gaussian[v]);
    for (int round = 0; round < kKappaSmoothing; ++round) {
      for (int32_t v = 0; v < nvs; ++v) {
        double sum = kappa[v];
        int n = 1;
        const HalfedgeId start = m.out(VertexId{v});
        HalfedgeId g = start;
        do {
          sum += kappa[m.to(g).idx];
          ++n;
          g = m.rotate(g);
        } while (g != start);
        next[v] = sum / n;
      }
      kappa.swap(next);
    }
    for (int32_t v = 0; v < nvs; ++v)
      m.sizing[v] = target_length_from_curvature(kappa[v], s.approx_error, s.min_edge_length,
                                                 s.max_edge_length);
    // Gradation: L may grow by at most kGradation per unit of distance, so
    // triangles between fine and coarse regions stay well shaped.
    for (int sweep = 0; sweep < 16; ++sweep) {
      bool changed = false;
      for (int32_t h = 0; h < m.halfedge_slots(); ++h) {
        const int32_t a = m.origin[h], b = m.to(HalfedgeId{h}).idx;
        const double limit = m.sizing[b] + kGradation * m.length(HalfedgeId{h});
        if (m.sizing[a] > limit) {
          m.sizing[a] = limit;
          changed = true;
        }
      }
      if (!changed) break;
    }
  }
  double faces = 0;  // equilateral triangles of side L cover sqrt(3)/4 L^2 each
  for (int32_t f = 0; f < m.face_slots(); ++f) {
    const int32_t* v = &m.origin[3 * f];
    const double l = (m.sizing[v[0]] + m.sizing[v[1]] + m.sizing[v[2]]) / 3;
    faces += 0.5 * norm(m.face_normal(FaceId{f})) / (std::sqrt(3.0) / 4 * l * l);
  }
  out->faces_estimated = int64_t(std::ceil(faces));
  const double allowed = 0.8 * double(s.face_budget);
  if (faces > allowed) {
    out->budget_limited = true;
    const double scale = std::sqrt(faces / allowed);
    for (double& l : m.sizing) l *= scale;
  }
}

void smooth_and_project(Mesh& m, const RemeshSettings& s, const SurfaceProjector* ref,
                        double max_move = 0.0) {
  for (int i = 0; i < s.smoothing_steps; ++i) tangential_smooth(m, s.smoothing_lambda, ref, max_move);
}

}  // namespace

RemeshOutcome remesh(Mesh& m, const RemeshSettings& s) {
  RemeshOutcome out;
  const int64_t chi = m.euler_characteristic();
  assign_sizing(m, s, &out);
  std::unique_ptr<SurfaceProjector> ref;
  if (s.project) {
    ref = std::make_unique<SurfaceProjector>(m);  // its triangle t is face t of m (no tombstones yet)
    for (int32_t v = 0; v < m.vertex_slots(); ++v) m.hint[v] = m.v_out[v] / 3;
  }
  auto fail = [&]() { return out; };  // out.error is set; the mesh is left as it is
  if (s.coarsen_factor > 1) {  // V-cycle: coarsening phase toward a longer target
    if (!collapse_short_edges(m, s, s.coarsen_factor, chi, &out)) return fail();
    if (!equalize_valences(m, s, chi, &out)) return fail();
    // The mesh is not refined yet: on a coarse input (a boolean cut's long faces)
    // a ring's centroid can lie far across the surface, and the projection would
    // put the vertex on another part of it (the far side of a thin wall), folding
    // the mesh. So a move is capped at half the coarsened target.
    smooth_and_project(m, s, ref.get(), 0.5 * s.coarsen_factor);
    m.compact();
  }
  for (int it = 0; it < s.iterations; ++it) {  // refinement phase at the target
    if (!split_long_edges(m, s, chi, &out)) return fail();
    if (!collapse_short_edges(m, s, 1.0, chi, &out)) return fail();
    if (!equalize_valences(m, s, chi, &out)) return fail();
    smooth_and_project(m, s, ref.get());
    m.compact();
  }
  return out;
}

}  // namespace jaxgenus::he
