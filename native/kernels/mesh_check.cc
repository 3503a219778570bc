#include "kernels/mesh_check.h"

#include <algorithm>
#include <numeric>
#include <vector>

namespace jaxgenus {
namespace {

struct UnionFind {
  std::vector<int32_t> parent;
  explicit UnionFind(size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
  int32_t find(int32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
  void unite(int32_t a, int32_t b) {
    a = find(a);
    b = find(b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  }
};

}  // namespace

Status mesh_check(const int32_t* faces, int64_t face_capacity, int64_t vertex_capacity,
                  int64_t n_vertices, int64_t n_faces, int32_t* report, int32_t* face_component) {
  std::fill(report, report + kReportSize, 0);
  std::fill(face_component, face_component + face_capacity, -1);
  auto fail = [&](Status s) {
    report[kReportStatus] = static_cast<int32_t>(s);
    return s;
  };
  if (n_faces < 0 || n_faces > face_capacity || n_vertices < 0 || n_vertices > vertex_capacity)
    return fail(Status::kInvalidInput);
  for (int64_t i = 0; i < 3 * n_faces; ++i)
    if (faces[i] < 0 || faces[i] >= n_vertices) return fail(Status::kInvalidInput);

  const int64_t nh = 3 * n_faces;  // half-edge h = 3 f + k goes from corner k to corner k+1
  auto tail = [&](int64_t h) { return faces[h]; };
  auto head = [&](int64_t h) { return faces[3 * (h / 3) + (h % 3 + 1) % 3]; };

  int32_t degenerate = 0;
  for (int64_t f = 0; f < n_faces; ++f) {
    const int32_t* t = faces + 3 * f;
    if (t[0] == t[1] || t[1] == t[2] || t[2] == t[0]) ++degenerate;
  }

  // Group half-edges by undirected edge: sort (min, max) keys.
  std::vector<std::pair<uint64_t, int32_t>> keys(nh);
  for (int64_t h = 0; h < nh; ++h) {
    uint64_t a = static_cast<uint32_t>(tail(h)), b = static_cast<uint32_t>(head(h));
    if (a > b) std::swap(a, b);
    keys[h] = {(a << 32) | b, static_cast<int32_t>(h)};
  }
  std::sort(keys.begin(), keys.end());

  UnionFind face_sets(static_cast<size_t>(n_faces));
  UnionFind corner_sets(static_cast<size_t>(nh));  // corner h = vertex tail(h) in face h/3
  // The corner of face h/3 at vertex v (v must be a vertex of that face).
  auto corner_at = [&](int64_t h, int32_t v) -> int32_t {
    const int64_t f = h / 3;
    for (int k = 0; k < 3; ++k)
      if (faces[3 * f + k] == v) return static_cast<int32_t>(3 * f + k);
    return static_cast<int32_t>(h);
  };

  int32_t edges = 0, boundary = 0, nonmanifold = 0, flipped = 0;
  for (int64_t i = 0; i < nh;) {
    int64_t j = i;
    while (j < nh && keys[j].first == keys[i].first) ++j;
    const int64_t count = j - i;
    ++edges;
    if (count == 1) ++boundary;
    if (count > 2) ++nonmanifold;
    if (count == 2) {
      const int64_t h0 = keys[i].second, h1 = keys[i + 1].second;
      if (tail(h0) == tail(h1)) ++flipped;  // same direction: inconsistent orientation
    }
    const int64_t h0 = keys[i].second;
    const int32_t a = tail(h0), b = head(h0);
    for (int64_t k = i + 1; k < j; ++k) {
      const int64_t h = keys[k].second;
      face_sets.unite(static_cast<int32_t>(h0 / 3), static_cast<int32_t>(h / 3));
      if (count == 2) {  // faces on one manifold edge share a fan at both ends
        corner_sets.unite(corner_at(h0, a), corner_at(h, a));
        corner_sets.unite(corner_at(h0, b), corner_at(h, b));
      }
    }
    i = j;
  }

  // Fans per vertex = distinct corner sets among its corners.
  std::vector<int32_t> fan_root(static_cast<size_t>(n_vertices), -1);
  std::vector<uint8_t> multi_fan(static_cast<size_t>(n_vertices), 0);
  for (int64_t c = 0; c < nh; ++c) {
    const int32_t v = faces[c];
    const int32_t r = corner_sets.find(static_cast<int32_t>(c));
    if (fan_root[v] < 0)
      fan_root[v] = r;
    else if (fan_root[v] != r)
      multi_fan[v] = 1;
  }
  int32_t nonmanifold_vertices = 0, isolated = 0;
  for (int64_t v = 0; v < n_vertices; ++v) {
    nonmanifold_vertices += multi_fan[v];
    isolated += fan_root[v] < 0;
  }

  std::vector<int32_t> label(static_cast<size_t>(n_faces), -1);
  int32_t components = 0;
  for (int64_t f = 0; f < n_faces; ++f) {
    const int32_t r = face_sets.find(static_cast<int32_t>(f));
    if (label[r] < 0) label[r] = components++;
    face_component[f] = label[r];
  }

  report[kReportStatus] = static_cast<int32_t>(Status::kOk);
  report[kReportVertices] = static_cast<int32_t>(n_vertices);
  report[kReportEdges] = edges;
  report[kReportFaces] = static_cast<int32_t>(n_faces);
  report[kReportEuler] = static_cast<int32_t>(n_vertices) - edges + static_cast<int32_t>(n_faces);
  report[kReportBoundaryEdges] = boundary;
  report[kReportNonManifoldEdges] = nonmanifold;
  report[kReportFlippedEdges] = flipped;
  report[kReportNonManifoldVertices] = nonmanifold_vertices;
  report[kReportDegenerateFaces] = degenerate;
  report[kReportComponents] = components;
  report[kReportIsolatedVertices] = isolated;
  return Status::kOk;
}

}  // namespace jaxgenus
