// Edge collapse with the link condition and geometric legality checks.
#include "halfedge/operations.h"

namespace jaxgenus::he {
namespace {

constexpr int kMaxRing = 64;  // larger one-rings are refused (never seen on sane meshes)

// Faces (v, x, y) around v other than f0/f1 keep their orientation and stay
// non-degenerate when v moves to p, and no new edge v-x exceeds max_len.
bool ring_ok(const Mesh& m, VertexId v, FaceId f0, FaceId f1, const Vec3& p, double max_len) {
  const HalfedgeId start = m.out(v);
  HalfedgeId g = start;
  const Vec3& pv = m.pos[v.idx];
  do {
    const FaceId f = Mesh::face(g);
    const Vec3& px = m.pos[m.to(g).idx];
    if (norm(px - p) > max_len && f != f0 && f != f1) return false;
    if (f != f0 && f != f1) {
      const Vec3& py = m.pos[m.from(Mesh::prev(g)).idx];
      const Vec3 n_old = cross(px - pv, py - pv), n_new = cross(px - p, py - p);
      const double l_old = norm(n_old), l_new = norm(n_new);
      if (l_new <= 1e-12 * (l_old + dot(px - p, px - p)) || dot(n_old, n_new) <= 0.0) return false;
    }
    g = m.rotate(g);
  } while (g != start);
  return true;
}

}  // namespace

bool is_collapse_ok(const Mesh& m, HalfedgeId h, const Vec3& p, double max_edge_length) {
  if (!h.valid() || h.idx >= m.halfedge_slots() || m.is_dead(Mesh::face(h))) return false;
  const Diamond q = diamond(m, h);
  if (q.c == q.d) return false;
  const int va = m.valence(q.a), vb = m.valence(q.b);
  if (m.valence(q.c) <= 3 || m.valence(q.d) <= 3 || va + vb - 4 < 3) return false;
  if (va > kMaxRing) return false;
  // Link condition: the only common neighbours of a and b are c and d.
  int32_t ring_a[kMaxRing];
  int n = 0;
  HalfedgeId g = m.out(q.a);
  const HalfedgeId start_a = g;
  do {
    ring_a[n++] = m.to(g).idx;
    g = m.rotate(g);
  } while (g != start_a);
  const HalfedgeId start_b = m.out(q.b);
  g = start_b;
  do {
    const int32_t x = m.to(g).idx;
    if (x != q.a.idx && x != q.c.idx && x != q.d.idx)
      for (int i = 0; i < n; ++i)
        if (ring_a[i] == x) return false;
    g = m.rotate(g);
  } while (g != start_b);
  return ring_ok(m, q.a, q.f0, q.f1, p, max_edge_length) &&
         ring_ok(m, q.b, q.f0, q.f1, p, max_edge_length);
}

VertexId collapse(Mesh& m, HalfedgeId h, const Vec3& p) {
  const Diamond q = diamond(m, h);
  HalfedgeId g = h;  // every corner at a becomes b
  do {
    m.origin[g.idx] = q.b.idx;
    g = m.rotate(g);
  } while (g != h);
  m.link(q.o_bc, q.o_ca);  // c->b with (a->c, now b->c)
  m.link(q.o_ad, q.o_db);  // (d->a, now d->b) with b->d
  m.interpolate_vertex_data(q.b, q.a, q.b, 0.5);
  m.pos[q.b.idx] = p;
  m.v_out[q.b.idx] = q.o_ca.idx;
  m.v_out[q.c.idx] = q.o_bc.idx;
  m.v_out[q.d.idx] = q.o_ad.idx;
  m.kill_face(q.f0);
  m.kill_face(q.f1);
  m.kill_vertex(q.a);
  return q.b;
}

}  // namespace jaxgenus::he
