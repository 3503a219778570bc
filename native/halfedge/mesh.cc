// Half-edge mesh: construction from (V, F), low-level mutation, compaction.
#include "halfedge/mesh.h"

#include <algorithm>
#include <utility>

namespace jaxgenus::he {

const char* build_status_name(BuildStatus s) {
  switch (s) {
    case BuildStatus::ok: return "ok";
    case BuildStatus::invalid_index: return "face index out of range";
    case BuildStatus::degenerate_face: return "face with a repeated vertex";
    case BuildStatus::not_finite: return "vertex coordinate is NaN or inf";
    case BuildStatus::non_manifold_edge: return "edge shared by more than two faces";
    case BuildStatus::open_or_misoriented: return "open boundary or inconsistent orientation";
    case BuildStatus::non_manifold_vertex: return "non-manifold vertex (more than one fan)";
    case BuildStatus::isolated_vertex: return "vertex used by no face";
  }
  return "unknown";
}

BuildStatus Mesh::build(const double* V, int64_t nv, const int32_t* F, int64_t nf,
                        const float* attr_in, int32_t n_attr, Mesh* out) {
  Mesh m;
  m.pos.resize(nv);
  for (int64_t i = 0; i < nv; ++i) {
    const double x = V[3 * i], y = V[3 * i + 1], z = V[3 * i + 2];
    if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) return BuildStatus::not_finite;
    m.pos[i] = {x, y, z};
  }
  m.origin.resize(3 * nf);
  for (int64_t f = 0; f < nf; ++f) {
    const int32_t a = F[3 * f], b = F[3 * f + 1], c = F[3 * f + 2];
    if (a < 0 || b < 0 || c < 0 || a >= nv || b >= nv || c >= nv) return BuildStatus::invalid_index;
    if (a == b || b == c || c == a) return BuildStatus::degenerate_face;
    m.origin[3 * f] = a;
    m.origin[3 * f + 1] = b;
    m.origin[3 * f + 2] = c;
  }
  m.f_dead.assign(nf, 0);
  m.twin.assign(3 * nf, -1);
  m.v_out.assign(nv, -1);
  m.sizing.assign(nv, 0.0);
  m.hint.assign(nv, -1);
  m.n_attr = n_attr;
  m.attr.assign(static_cast<size_t>(nv) * n_attr, 0.0);
  if (attr_in != nullptr)
    for (int64_t i = 0; i < nv * n_attr; ++i) m.attr[i] = attr_in[i];

  // Twins: sort half-edges by undirected edge key.
  const int64_t nh = 3 * nf;
  std::vector<std::pair<uint64_t, int32_t>> keys(nh);
  for (int64_t h = 0; h < nh; ++h) {
    const uint32_t a = m.origin[h], b = m.origin[next({int32_t(h)}).idx];
    const uint64_t lo = std::min(a, b), hi = std::max(a, b);
    keys[h] = {(lo << 32) | hi, int32_t(h)};
  }
  std::sort(keys.begin(), keys.end());
  for (int64_t i = 0; i < nh;) {
    int64_t j = i + 1;
    while (j < nh && keys[j].first == keys[i].first) ++j;
    if (j - i > 2) return BuildStatus::non_manifold_edge;
    if (j - i < 2) return BuildStatus::open_or_misoriented;
    const HalfedgeId h0{keys[i].second}, h1{keys[i + 1].second};
    if (m.from(h0) == m.from(h1)) return BuildStatus::open_or_misoriented;
    m.link(h0, h1);
    i = j;
  }

  std::vector<int32_t> corners(nv, 0);
  for (int64_t h = 0; h < nh; ++h) {
    m.v_out[m.origin[h]] = int32_t(h);
    ++corners[m.origin[h]];
  }
  for (int64_t v = 0; v < nv; ++v) {
    if (m.v_out[v] < 0) return BuildStatus::isolated_vertex;
    const HalfedgeId start{m.v_out[v]};
    HalfedgeId g = start;
    int32_t fan = 0;
    do {
      ++fan;
      g = m.rotate(g);
    } while (g != start && fan <= corners[v]);
    if (fan != corners[v]) return BuildStatus::non_manifold_vertex;
  }
  m.n_live_vertices_ = int32_t(nv);
  m.n_live_faces_ = int32_t(nf);
  *out = std::move(m);
  return BuildStatus::ok;
}

int64_t Mesh::euler_characteristic() const {
  return int64_t(n_live_vertices_) - 3 * int64_t(n_live_faces_) / 2 + n_live_faces_;
}

int Mesh::valence(VertexId v) const {
  const HalfedgeId start = out(v);
  HalfedgeId g = start;
  int n = 0;
  do {
    ++n;
    g = rotate(g);
  } while (g != start);
  return n;
}

HalfedgeId Mesh::find_halfedge(VertexId a, VertexId b) const {
  if (is_dead(a)) return {};
  const HalfedgeId start = out(a);
  HalfedgeId g = start;
  do {
    if (to(g) == b) return g;
    g = rotate(g);
  } while (g != start);
  return {};
}

Vec3 Mesh::face_normal(FaceId f) const {
  const Vec3& a = pos[origin[3 * f.idx]];
  const Vec3& b = pos[origin[3 * f.idx + 1]];
  const Vec3& c = pos[origin[3 * f.idx + 2]];
  return cross(b - a, c - a);
}

Vec3 Mesh::vertex_normal(VertexId v) const {
  Vec3 n;
  const HalfedgeId start = out(v);
  HalfedgeId g = start;
  do {
    n += face_normal(face(g));
    g = rotate(g);
  } while (g != start);
  const double l = norm(n);
  return l > 0 ? n * (1.0 / l) : n;
}

VertexId Mesh::add_vertex(const Vec3& p) {
  pos.push_back(p);
  v_out.push_back(-1);
  sizing.push_back(0.0);
  hint.push_back(-1);
  attr.resize(attr.size() + n_attr, 0.0);
  ++n_live_vertices_;
  return {int32_t(pos.size()) - 1};
}

FaceId Mesh::add_face() {
  f_dead.push_back(0);
  origin.resize(origin.size() + 3, -1);
  twin.resize(twin.size() + 3, -1);
  ++n_live_faces_;
  return {int32_t(f_dead.size()) - 1};
}

void Mesh::set_face(FaceId f, VertexId a, VertexId b, VertexId c) {
  origin[3 * f.idx] = a.idx;
  origin[3 * f.idx + 1] = b.idx;
  origin[3 * f.idx + 2] = c.idx;
}

void Mesh::interpolate_vertex_data(VertexId dst, VertexId a, VertexId b, double t) {
  sizing[dst.idx] = (1 - t) * sizing[a.idx] + t * sizing[b.idx];
  hint[dst.idx] = t < 0.5 ? hint[a.idx] : hint[b.idx];
  for (int32_t k = 0; k < n_attr; ++k) {
    attr[size_t(dst.idx) * n_attr + k] =
        (1 - t) * attr[size_t(a.idx) * n_attr + k] + t * attr[size_t(b.idx) * n_attr + k];
  }
}

void Mesh::compact() {
  const int32_t nvs = vertex_slots(), nfs = face_slots();
  std::vector<int32_t> vmap(nvs, -1), fmap(nfs, -1);
  int32_t nv = 0, nf = 0;
  for (int32_t v = 0; v < nvs; ++v) {
    if (v_out[v] < 0) continue;
    vmap[v] = nv;
    pos[nv] = pos[v];
    sizing[nv] = sizing[v];
    hint[nv] = hint[v];
    for (int32_t k = 0; k < n_attr; ++k) attr[size_t(nv) * n_attr + k] = attr[size_t(v) * n_attr + k];
    ++nv;
  }
  for (int32_t f = 0; f < nfs; ++f)
    if (!f_dead[f]) fmap[f] = nf++;
  auto hmap = [&](int32_t h) { return 3 * fmap[h / 3] + h % 3; };
  for (int32_t f = 0; f < nfs; ++f) {
    if (f_dead[f]) continue;
    const int32_t g = fmap[f];
    for (int k = 0; k < 3; ++k) {
      origin[3 * g + k] = vmap[origin[3 * f + k]];
      twin[3 * g + k] = hmap(twin[3 * f + k]);
    }
  }
  std::vector<int32_t> new_out(nv);
  for (int32_t v = 0; v < nvs; ++v)
    if (v_out[v] >= 0) new_out[vmap[v]] = hmap(v_out[v]);
  pos.resize(nv);
  sizing.resize(nv);
  hint.resize(nv);
  attr.resize(size_t(nv) * n_attr);
  v_out = std::move(new_out);
  origin.resize(3 * nf);
  twin.resize(3 * nf);
  f_dead.assign(nf, 0);
  n_live_vertices_ = nv;
  n_live_faces_ = nf;
}

void Mesh::write(std::vector<double>* V, std::vector<int32_t>* F) const {
  V->resize(3 * pos.size());
  for (size_t i = 0; i < pos.size(); ++i) {
    (*V)[3 * i] = pos[i].x;
    (*V)[3 * i + 1] = pos[i].y;
    (*V)[3 * i + 2] = pos[i].z;
  }
  F->assign(origin.begin(), origin.end());
}

}  // namespace jaxgenus::he
