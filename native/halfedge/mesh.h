// Half-edge mesh for closed, oriented, manifold triangle meshes.
//
// Storage is structure-of-arrays in flat std::vectors. Half-edges are stored
// face-major: face f owns half-edges 3f, 3f+1, 3f+2, and half-edge 3f+k runs
// from corner k to corner k+1 of f. So `next`, `prev` and `face` are index
// arithmetic (next-cycles have length 3 by construction) and only the origin
// vertex and the twin of each half-edge are stored. Deleted faces and vertices
// are tombstoned and removed by `compact()`.
//
// Plain C++17: no XLA and no Python headers.
#pragma once

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

namespace jaxgenus::he {

struct Vec3 {
  double x = 0, y = 0, z = 0;
  Vec3 operator+(const Vec3& o) const { return {x + o.x, y + o.y, z + o.z}; }
  Vec3 operator-(const Vec3& o) const { return {x - o.x, y - o.y, z - o.z}; }
  Vec3 operator*(double s) const { return {x * s, y * s, z * s}; }
  Vec3& operator+=(const Vec3& o) { x += o.x; y += o.y; z += o.z; return *this; }
};
inline double dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double norm(const Vec3& a) { return std::sqrt(dot(a, a)); }

// Typed handles: plain int32 indices that cannot be mixed up.
struct VertexId {
  int32_t idx = -1;
  bool valid() const { return idx >= 0; }
  bool operator==(VertexId o) const { return idx == o.idx; }
  bool operator!=(VertexId o) const { return idx != o.idx; }
};
struct HalfedgeId {
  int32_t idx = -1;
  bool valid() const { return idx >= 0; }
  bool operator==(HalfedgeId o) const { return idx == o.idx; }
  bool operator!=(HalfedgeId o) const { return idx != o.idx; }
};
struct FaceId {
  int32_t idx = -1;
  bool valid() const { return idx >= 0; }
  bool operator==(FaceId o) const { return idx == o.idx; }
  bool operator!=(FaceId o) const { return idx != o.idx; }
};

enum class BuildStatus { ok, invalid_index, degenerate_face, not_finite, non_manifold_edge,
                         open_or_misoriented, non_manifold_vertex, isolated_vertex };
const char* build_status_name(BuildStatus s);

class Mesh {
 public:
  // Per vertex.
  std::vector<Vec3> pos;
  std::vector<int32_t> v_out;      // one outgoing half-edge; -1 for a deleted vertex
  std::vector<double> sizing;      // target edge length (interpolated by the operations)
  std::vector<int32_t> hint;       // last reference triangle a vertex was projected onto (or -1)
  std::vector<double> attr;        // n_attr carried floats per vertex (interpolated)
  int32_t n_attr = 0;
  // Per half-edge (3 per face slot).
  std::vector<int32_t> origin;     // origin vertex (= corner of the face)
  std::vector<int32_t> twin;
  // Per face slot.
  std::vector<uint8_t> f_dead;

  // Builds from (V, F) arrays (positions as doubles, nv x 3 and nf x 3).
  // Checks index range, finiteness, degenerate faces, edge- and
  // vertex-manifoldness, closedness, consistent orientation and isolated
  // vertices. Twins are matched by sorting undirected edge keys (no hashing).
  static BuildStatus build(const double* V, int64_t nv, const int32_t* F, int64_t nf,
                           const float* attr, int32_t n_attr, Mesh* out);

  // Navigation (index arithmetic for next/prev/face).
  static HalfedgeId next(HalfedgeId h) { return {h.idx % 3 == 2 ? h.idx - 2 : h.idx + 1}; }
  static HalfedgeId prev(HalfedgeId h) { return {h.idx % 3 == 0 ? h.idx + 2 : h.idx - 1}; }
  static FaceId face(HalfedgeId h) { return {h.idx / 3}; }
  static HalfedgeId halfedge(FaceId f, int k) { return {3 * f.idx + k}; }
  HalfedgeId opposite(HalfedgeId h) const { return {twin[h.idx]}; }
  VertexId from(HalfedgeId h) const { return {origin[h.idx]}; }
  VertexId to(HalfedgeId h) const { return {origin[next(h).idx]}; }
  // Next outgoing half-edge of the same vertex (rotation around from(h)).
  HalfedgeId rotate(HalfedgeId h) const { return {twin[prev(h).idx]}; }
  HalfedgeId out(VertexId v) const { return {v_out[v.idx]}; }

  int32_t vertex_slots() const { return static_cast<int32_t>(pos.size()); }
  int32_t face_slots() const { return static_cast<int32_t>(f_dead.size()); }
  int32_t halfedge_slots() const { return 3 * face_slots(); }
  bool is_dead(FaceId f) const { return f_dead[f.idx] != 0; }
  bool is_dead(VertexId v) const { return v_out[v.idx] < 0; }
  int32_t live_vertices() const { return n_live_vertices_; }
  int32_t live_faces() const { return n_live_faces_; }
  int64_t euler_characteristic() const;  // V - E + F of the live part (E = 3F/2)

  int valence(VertexId v) const;
  // The half-edge a->b, or an invalid id when a and b are not adjacent (or a is dead).
  HalfedgeId find_halfedge(VertexId a, VertexId b) const;
  Vec3 face_normal(FaceId f) const;      // unnormalised, |n| = 2 * area
  Vec3 vertex_normal(VertexId v) const;  // area-weighted, unit length
  double length(HalfedgeId h) const { return norm(pos[to(h).idx] - pos[from(h).idx]); }

  // Low-level mutation used by the operations.
  VertexId add_vertex(const Vec3& p);
  FaceId add_face();
  void set_face(FaceId f, VertexId a, VertexId b, VertexId c);
  void link(HalfedgeId a, HalfedgeId b) { twin[a.idx] = b.idx; twin[b.idx] = a.idx; }
  void kill_face(FaceId f) { f_dead[f.idx] = 1; --n_live_faces_; }
  void kill_vertex(VertexId v) { v_out[v.idx] = -1; --n_live_vertices_; }
  // Per-vertex carried data of `dst` := (1-t) * a + t * b.
  void interpolate_vertex_data(VertexId dst, VertexId a, VertexId b, double t);

  // Removes tombstones; keeps the relative order of live elements.
  void compact();
  // Writes the live part (requires compact()).
  void write(std::vector<double>* V, std::vector<int32_t>* F) const;

 private:
  int32_t n_live_vertices_ = 0;
  int32_t n_live_faces_ = 0;
};

// validate(): twin involution and opposite direction, next-cycles of length 3,
// vertex and face back-pointers, edge- and vertex-manifoldness (one fan per
// vertex), consistent orientation, no degenerate faces, no isolated vertices,
// and chi == expected_chi (skipped when expected_chi is INT64_MIN). Returns ""
// when valid, else a description of the first violation.
std::string validate(const Mesh& m, int64_t expected_chi);
constexpr int64_t kAnyChi = INT64_MIN;

// Number of connected components of the live part.
int32_t connected_components(const Mesh& m);

}  // namespace jaxgenus::he
