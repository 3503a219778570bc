// Local operations on the half-edge mesh, each a legality test plus the
// operation, and the passes/driver built from them.
#pragma once

#include <string>
#include <vector>

#include "halfedge/mesh.h"

namespace jaxgenus::he {

// The two faces around the edge of h: f0 = (a, b, c) holds h = a->b,
// f1 = (b, a, d) holds t = twin(h) = b->a; o_xy is the outside half-edge
// opposite to the half-edge x->y of the diamond.
struct Diamond {
  HalfedgeId h, t;
  FaceId f0, f1;
  VertexId a, b, c, d;
  HalfedgeId o_bc, o_ca, o_ad, o_db;
};
Diamond diamond(const Mesh& m, HalfedgeId h);

// Split: inserts a vertex at (1 - t) * from(h) + t * to(h); 2 new faces.
bool is_split_ok(const Mesh& m, HalfedgeId h);
VertexId split(Mesh& m, HalfedgeId h, double t);

// Collapse: removes from(h) and moves to(h) to p. Legal when the link
// condition holds, valences stay >= 3, no face of the one-ring flips or
// degenerates, and no new edge is longer than max_edge_length.
bool is_collapse_ok(const Mesh& m, HalfedgeId h, const Vec3& p, double max_edge_length);
VertexId collapse(Mesh& m, HalfedgeId h, const Vec3& p);

// Flip: replaces edge a-b by c-d. Legal when valence(a), valence(b) > 3, the
// edge c-d does not exist yet and the two new faces do not fold over.
bool is_flip_ok(const Mesh& m, HalfedgeId h);
void flip(Mesh& m, HalfedgeId h);

// Closest-point queries on a fixed reference surface (a median-split AABB
// tree over its triangles), with a per-vertex value interpolated at the
// closest point.
class SurfaceProjector {
 public:
  SurfaceProjector(const Mesh& reference);
  // Closest point to p; *value gets the interpolated per-vertex value there.
  // *hint: a triangle to try first (speeds up the search; -1 for none); on
  // return, the triangle of the closest point.
  Vec3 project(const Vec3& p, double* value, int32_t* hint) const;

 private:
  struct Node {
    Vec3 lo, hi;
    int32_t first, count;  // leaf: triangles [first, first+count); inner: count = 0, right = first
  };
  void build(int32_t node, int32_t begin, int32_t end, std::vector<Vec3>* centroids);
  std::vector<Vec3> tri_;       // 3 corners per triangle
  std::vector<double> value_;   // 3 values per triangle
  std::vector<int32_t> order_;  // triangle order in the leaves
  std::vector<Node> nodes_;
};

// Tangential smoothing: each vertex moves by lambda times the tangential part
// of (area-weighted centroid of its incident face centroids - position), then
// is projected onto `reference` (if given), which also re-interpolates the
// sizing field there. Carried attributes are not changed by smoothing.
// `max_move` > 0 caps a vertex's move at max_move times its sizing value (0: no cap).
void tangential_smooth(Mesh& m, double lambda, const SurfaceProjector* reference,
                       double max_move = 0.0);

// Per-vertex discrete curvatures: K = angle deficit / A, H from the cotangent
// Laplace-Beltrami operator (H > 0 on a sphere with outward normals), A the
// mixed Voronoi area of Meyer et al.
struct Curvature {
  std::vector<double> gaussian, mean, area;
};
Curvature vertex_curvature(const Mesh& m);
// max(|k1|, |k2|) with k1,2 = H +- sqrt(max(H^2 - K, 0)).
double max_abs_principal(double mean, double gaussian);
// Dunyach et al. 2013: L = sqrt(6 eps / kappa - 3 eps^2), clamped to [lmin, lmax].
double target_length_from_curvature(double kappa, double eps, double lmin, double lmax);

struct RemeshSettings {
  double target_edge_length = 1.0;  // uniform target, or the scale for adaptive defaults
  int iterations = 5;
  bool adaptive = false;
  double approx_error = 0.0;        // adaptive: eps (absolute)
  double min_edge_length = 0.0;     // adaptive: clamp (absolute)
  double max_edge_length = 0.0;
  double coarsen_factor = 1.0;      // > 1: V-cycle coarsening phase toward factor * target
  int smoothing_steps = 1;
  double smoothing_lambda = 1.0;
  bool project = true;              // project onto the input surface after smoothing
  int64_t face_budget = INT32_MAX;  // never more live faces than this
  bool validate_each_operation = false;  // debugging/tests: validate() after every operation
};

struct RemeshOutcome {
  std::string error;            // non-empty: an invariant broke (only with validate_each_operation)
  bool budget_limited = false;  // the sizing field was scaled up to fit face_budget
  int64_t faces_estimated = 0;  // faces the unscaled sizing field asks for
  int64_t splits = 0, collapses = 0, flips = 0;
};

// Botsch-Kobbelt loop (split > 4/3 L, collapse < 4/5 L, valence flips,
// tangential smoothing + projection) with a curvature-adaptive sizing field L
// and an optional coarsening phase first (V-cycle). Ends with compact(),
// except when validate_each_operation finds a violation (out.error set).
RemeshOutcome remesh(Mesh& m, const RemeshSettings& s);

}  // namespace jaxgenus::he
