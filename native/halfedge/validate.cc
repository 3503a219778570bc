// validate(): full invariant check of a half-edge mesh (O(V + F log F)).
#include <algorithm>
#include <numeric>
#include <string>
#include <utility>

#include "halfedge/mesh.h"

namespace jaxgenus::he {

std::string validate(const Mesh& m, int64_t expected_chi) {
  const int32_t nvs = m.vertex_slots(), nfs = m.face_slots(), nhs = m.halfedge_slots();
  if (int32_t(m.origin.size()) != nhs || int32_t(m.twin.size()) != nhs)
    return "half-edge arrays do not match the face count";
  if (int32_t(m.v_out.size()) != nvs || int32_t(m.sizing.size()) != nvs || int32_t(m.hint.size()) != nvs ||
      m.attr.size() != size_t(nvs) * m.n_attr)
    return "vertex arrays do not match the vertex count";
  int32_t live_f = 0, live_v = 0;
  std::vector<int32_t> corners(nvs, 0);
  std::vector<std::pair<uint64_t, int32_t>> directed;
  for (int32_t f = 0; f < nfs; ++f) {
    if (m.is_dead(FaceId{f})) continue;
    ++live_f;
    for (int k = 0; k < 3; ++k) {
      const HalfedgeId h{3 * f + k};
      // Next-cycle of length 3 inside the face.
      if (Mesh::next(Mesh::next(Mesh::next(h))) != h || Mesh::face(Mesh::next(h)) != FaceId{f})
        return "next-cycle is not a triangle";
      const int32_t a = m.from(h).idx, b = m.to(h).idx;
      if (a < 0 || a >= nvs || m.is_dead(VertexId{a}))
        return "face " + std::to_string(f) + " uses a missing vertex";
      if (a == b) return "degenerate face " + std::to_string(f);
      ++corners[a];
      const int32_t t = m.twin[h.idx];
      if (t < 0 || t >= nhs || m.is_dead(Mesh::face(HalfedgeId{t})))
        return "half-edge " + std::to_string(h.idx) + " has no live twin";
      if (m.twin[t] != h.idx) return "twin is not an involution at " + std::to_string(h.idx);
      if (t / 3 == f) return "twin inside the same face at " + std::to_string(h.idx);
      if (m.from(HalfedgeId{t}).idx != b || m.to(HalfedgeId{t}).idx != a)
        return "inconsistent orientation at half-edge " + std::to_string(h.idx);
      directed.push_back({(uint64_t(uint32_t(a)) << 32) | uint32_t(b), h.idx});
    }
  }
  if (live_f != m.live_faces()) return "live face count is stale";
  // Edge-manifoldness: each directed edge at most once (with twins: each edge exactly twice).
  std::sort(directed.begin(), directed.end());
  for (size_t i = 1; i < directed.size(); ++i)
    if (directed[i].first == directed[i - 1].first) return "non-manifold (repeated) edge";
  for (int32_t v = 0; v < nvs; ++v) {
    if (m.is_dead(VertexId{v})) continue;
    ++live_v;
    const int32_t s = m.v_out[v];
    if (s >= nhs || m.is_dead(Mesh::face(HalfedgeId{s})) || m.origin[s] != v)
      return "bad vertex back-pointer at vertex " + std::to_string(v);
    if (corners[v] == 0) return "isolated vertex " + std::to_string(v);
    HalfedgeId g{s};
    int32_t fan = 0;
    do {
      ++fan;
      g = m.rotate(g);
    } while (g.idx != s && fan <= corners[v]);
    if (fan != corners[v]) return "non-manifold vertex " + std::to_string(v);
  }
  if (live_v != m.live_vertices()) return "live vertex count is stale";
  if (expected_chi != kAnyChi && m.euler_characteristic() != expected_chi)
    return "Euler characteristic changed: " + std::to_string(m.euler_characteristic()) +
           " != " + std::to_string(expected_chi);
  return "";
}

int32_t connected_components(const Mesh& m) {
  std::vector<int32_t> parent(m.vertex_slots());
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&](int32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (int32_t h = 0; h < m.halfedge_slots(); ++h) {
    if (m.is_dead(Mesh::face(HalfedgeId{h}))) continue;
    const int32_t a = find(m.from(HalfedgeId{h}).idx), b = find(m.to(HalfedgeId{h}).idx);
    if (a != b) parent[a] = b;
  }
  int32_t n = 0;
  for (int32_t v = 0; v < m.vertex_slots(); ++v)
    if (!m.is_dead(VertexId{v}) && find(v) == v) ++n;
  return n;
}

}  // namespace jaxgenus::he
