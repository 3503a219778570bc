// Discrete curvature (angle deficit, cotangent Laplace-Beltrami, mixed area)
// and the curvature-to-edge-length rule.
#include <algorithm>
#include <cmath>

#include "halfedge/operations.h"

namespace jaxgenus::he {

Curvature vertex_curvature(const Mesh& m) {
  const int32_t nvs = m.vertex_slots();
  Curvature out;
  out.gaussian.assign(nvs, 2 * M_PI);
  out.mean.assign(nvs, 0.0);
  out.area.assign(nvs, 0.0);
  std::vector<Vec3> lap(nvs);
  for (int32_t f = 0; f < m.face_slots(); ++f) {
    if (m.is_dead(FaceId{f})) continue;
    const int32_t v[3] = {m.origin[3 * f], m.origin[3 * f + 1], m.origin[3 * f + 2]};
    const Vec3 p[3] = {m.pos[v[0]], m.pos[v[1]], m.pos[v[2]]};
    const double area = 0.5 * norm(cross(p[1] - p[0], p[2] - p[0]));
    double cot[3], ang[3];
    for (int i = 0; i < 3; ++i) {
      const Vec3 e1 = p[(i + 1) % 3] - p[i], e2 = p[(i + 2) % 3] - p[i];
      const double c = dot(e1, e2), s = norm(cross(e1, e2));
      ang[i] = std::atan2(s, c);
      cot[i] = s > 0 ? c / s : 0.0;
    }
    for (int i = 0; i < 3; ++i) {
      const int j = (i + 1) % 3, k = (i + 2) % 3;
      out.gaussian[v[i]] -= ang[i];
      // Edge (j, k) is opposite corner i.
      const Vec3 e = p[k] - p[j];
      lap[v[j]] += e * (0.5 * cot[i]);
      lap[v[k]] += e * (-0.5 * cot[i]);
      // Mixed Voronoi area.
      if (ang[0] > M_PI / 2 || ang[1] > M_PI / 2 || ang[2] > M_PI / 2) {
        out.area[v[i]] += ang[i] > M_PI / 2 ? area / 2 : area / 4;
      } else {
        const Vec3 eij = p[j] - p[i], eik = p[k] - p[i];
        out.area[v[i]] += (dot(eik, eik) * cot[j] + dot(eij, eij) * cot[k]) / 8;
      }
    }
  }
  for (int32_t v = 0; v < nvs; ++v) {
    if (m.is_dead(VertexId{v}) || !(out.area[v] > 0)) {
      out.gaussian[v] = out.mean[v] = 0;
      continue;
    }
    out.gaussian[v] /= out.area[v];
    out.mean[v] = -dot(lap[v], m.vertex_normal(VertexId{v})) / (2 * out.area[v]);
  }
  return out;
}

double max_abs_principal(double mean, double gaussian) {
  return std::fabs(mean) + std::sqrt(std::max(mean * mean - gaussian, 0.0));
}

double target_length_from_curvature(double kappa, double eps, double lmin, double lmax) {
  if (!(kappa > 0)) return lmax;
  const double r = 6 * eps / kappa - 3 * eps * eps;
  const double l = r > 0 ? std::sqrt(r) : lmin;
  return std::clamp(l, lmin, lmax);
}

}  // namespace jaxgenus::he
