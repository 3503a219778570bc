// Tangential smoothing and closest-point projection onto a reference surface.
//
// Projection choice: an AABB tree over the triangles of the remesher's input
// (median split on the longest centroid axis, leaves of <= 4 triangles,
// nearest-child-first descent). Projecting onto the input rather than onto the
// previous iteration keeps the result on the original surface after any number
// of iterations and lets the V-cycle's refinement recover detail that the
// coarsening phase removed.
#include <algorithm>
#include <limits>
#include <utility>

#include "halfedge/operations.h"

namespace jaxgenus::he {
namespace {

// Closest point to p on triangle (a, b, c) by Voronoi-region tests; writes
// the barycentric coordinates of the result.
Vec3 closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c, double w[3]) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  auto at = [&](double u, double v, double t) {
    w[0] = u; w[1] = v; w[2] = t;
    return a * u + b * v + c * t;
  };
  if (d1 <= 0 && d2 <= 0) return at(1, 0, 0);
  const Vec3 bp = p - b;
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return at(0, 1, 0);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) {
    const double t = d1 / (d1 - d3);
    return at(1 - t, t, 0);
  }
  const Vec3 cp = p - c;
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return at(0, 0, 1);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) {
    const double t = d2 / (d2 - d6);
    return at(1 - t, 0, t);
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) {
    const double t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return at(0, 1 - t, t);
  }
  const double sum = va + vb + vc;
  if (!(sum > 0)) return at(1, 0, 0);  // degenerate triangle
  const double v = vb / sum, t = vc / sum;
  return at(1 - v - t, v, t);
}

double box_distance2(const Vec3& p, const Vec3& lo, const Vec3& hi) {
  const double dx = p.x < lo.x ? lo.x - p.x : (p.x > hi.x ? p.x - hi.x : 0.0);
  const double dy = p.y < lo.y ? lo.y - p.y : (p.y > hi.y ? p.y - hi.y : 0.0);
  const double dz = p.z < lo.z ? lo.z - p.z : (p.z > hi.z ? p.z - hi.z : 0.0);
  return dx * dx + dy * dy + dz * dz;
}

}  // namespace

SurfaceProjector::SurfaceProjector(const Mesh& ref) {
  std::vector<Vec3> centroids;
  for (int32_t f = 0; f < ref.face_slots(); ++f) {
    if (ref.is_dead(FaceId{f})) continue;
    Vec3 c;
    for (int k = 0; k < 3; ++k) {
      const int32_t v = ref.origin[3 * f + k];
      tri_.push_back(ref.pos[v]);
      value_.push_back(ref.sizing[v]);
      c += ref.pos[v];
    }
    centroids.push_back(c * (1.0 / 3.0));
  }
  const int32_t n = int32_t(centroids.size());
  order_.resize(n);
  for (int32_t i = 0; i < n; ++i) order_[i] = i;
  nodes_.reserve(2 * (n / 2 + 1));
  nodes_.push_back({});
  if (n > 0) build(0, 0, n, &centroids);
}

void SurfaceProjector::build(int32_t node, int32_t begin, int32_t end, std::vector<Vec3>* centroids) {
  const double inf = std::numeric_limits<double>::infinity();
  Vec3 lo{inf, inf, inf}, hi{-inf, -inf, -inf}, clo = lo, chi = hi;
  for (int32_t i = begin; i < end; ++i) {
    const int32_t t = order_[i];
    for (int k = 0; k < 3; ++k) {
      const Vec3& p = tri_[3 * t + k];
      lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
      hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
    }
    const Vec3& c = (*centroids)[t];
    clo = {std::min(clo.x, c.x), std::min(clo.y, c.y), std::min(clo.z, c.z)};
    chi = {std::max(chi.x, c.x), std::max(chi.y, c.y), std::max(chi.z, c.z)};
  }
  if (end - begin <= 4) {
    nodes_[node] = {lo, hi, begin, end - begin};
    return;
  }
  const Vec3 ext = chi - clo;
  const int axis = (ext.x >= ext.y && ext.x >= ext.z) ? 0 : (ext.y >= ext.z ? 1 : 2);
  auto key = [&](int32_t t) {
    const Vec3& c = (*centroids)[t];
    return axis == 0 ? c.x : axis == 1 ? c.y : c.z;
  };
  const int32_t mid = (begin + end) / 2;
  std::nth_element(order_.begin() + begin, order_.begin() + mid, order_.begin() + end,
                   [&](int32_t s, int32_t t) { return key(s) < key(t); });
  const int32_t left = int32_t(nodes_.size());
  nodes_.push_back({});
  build(left, begin, mid, centroids);
  const int32_t right = int32_t(nodes_.size());
  nodes_.push_back({});
  build(right, mid, end, centroids);
  nodes_[node] = {lo, hi, right, 0};
}

Vec3 SurfaceProjector::project(const Vec3& p, double* value, int32_t* hint) const {
  if (order_.empty()) return p;
  double best = std::numeric_limits<double>::infinity();
  Vec3 best_p = p;
  int32_t best_t = -1;
  double best_w[3] = {1, 0, 0};
  auto try_triangle = [&](int32_t t) {
    double w[3];
    const Vec3 q = closest_on_triangle(p, tri_[3 * t], tri_[3 * t + 1], tri_[3 * t + 2], w);
    const Vec3 dq = q - p;
    const double d2 = dot(dq, dq);
    if (d2 < best) {
      best = d2;
      best_p = q;
      best_t = t;
      best_w[0] = w[0];
      best_w[1] = w[1];
      best_w[2] = w[2];
    }
  };
  const int32_t n_tri = int32_t(order_.size());
  if (*hint >= 0 && *hint < n_tri) try_triangle(*hint);
  // Depth-first, nearer child first; entries carry their box distance.
  std::pair<int32_t, double> stack[128];
  int top = 0;
  stack[top++] = {0, box_distance2(p, nodes_[0].lo, nodes_[0].hi)};
  while (top > 0) {
    const auto [ni, nd2] = stack[--top];
    if (nd2 >= best) continue;
    const Node& nd = nodes_[ni];
    if (nd.count > 0) {
      for (int32_t i = nd.first; i < nd.first + nd.count; ++i) try_triangle(order_[i]);
      continue;
    }
    const int32_t l = ni + 1, r = nd.first;
    const double dl = box_distance2(p, nodes_[l].lo, nodes_[l].hi);
    const double dr = box_distance2(p, nodes_[r].lo, nodes_[r].hi);
    if (top + 2 > 128) continue;  // depth is ~log2(F), far below this
    if (dl < dr) {
      stack[top++] = {r, dr};
      stack[top++] = {l, dl};
    } else {
      stack[top++] = {l, dl};
      stack[top++] = {r, dr};
    }
  }
  *hint = best_t;
  if (value != nullptr && best_t >= 0)
    *value = best_w[0] * value_[3 * best_t] + best_w[1] * value_[3 * best_t + 1] +
             best_w[2] * value_[3 * best_t + 2];
  return best_p;
}

void tangential_smooth(Mesh& m, double lambda, const SurfaceProjector* reference, double max_move) {
  const int32_t nvs = m.vertex_slots();
  std::vector<Vec3> moved(nvs);
  for (int32_t v = 0; v < nvs; ++v) {
    if (m.is_dead(VertexId{v})) continue;
    const Vec3& p = m.pos[v];
    Vec3 centroid_sum, normal_sum;
    double weight = 0;
    const HalfedgeId start = m.out(VertexId{v});
    HalfedgeId g = start;
    do {
      const FaceId f = Mesh::face(g);
      const Vec3 n = m.face_normal(f);
      const double area = 0.5 * norm(n);
      const Vec3 c = (m.pos[m.origin[3 * f.idx]] + m.pos[m.origin[3 * f.idx + 1]] +
                      m.pos[m.origin[3 * f.idx + 2]]) * (1.0 / 3.0);
      centroid_sum += c * area;
      normal_sum += n;
      weight += area;
      g = m.rotate(g);
    } while (g != start);
    const double nl = norm(normal_sum);
    if (!(weight > 0) || !(nl > 0)) {
      moved[v] = p;
      continue;
    }
    const Vec3 nrm = normal_sum * (1.0 / nl);
    Vec3 d = centroid_sum * (1.0 / weight) - p;
    d = (d - nrm * dot(nrm, d)) * lambda;
    const double dl = norm(d), cap = max_move * m.sizing[v];
    if (cap > 0 && dl > cap) d = d * (cap / dl);
    moved[v] = p + d;
  }
  for (int32_t v = 0; v < nvs; ++v) {
    if (m.is_dead(VertexId{v})) continue;
    m.pos[v] = reference != nullptr ? reference->project(moved[v], &m.sizing[v], &m.hint[v]) : moved[v];
  }
}

}  // namespace jaxgenus::he
