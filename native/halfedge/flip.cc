// Edge flip with a fold-over test.
#include "halfedge/operations.h"

namespace jaxgenus::he {

bool is_flip_ok(const Mesh& m, HalfedgeId h) {
  if (!h.valid() || h.idx >= m.halfedge_slots() || m.is_dead(Mesh::face(h))) return false;
  const Diamond q = diamond(m, h);
  if (q.c == q.d || m.valence(q.a) <= 3 || m.valence(q.b) <= 3) return false;
  const HalfedgeId start = m.out(q.c);
  HalfedgeId g = start;
  do {
    if (m.to(g) == q.d) return false;  // edge c-d exists already
    g = m.rotate(g);
  } while (g != start);
  const Vec3 &a = m.pos[q.a.idx], &b = m.pos[q.b.idx], &c = m.pos[q.c.idx], &d = m.pos[q.d.idx];
  const Vec3 n_old = cross(b - a, c - a) + cross(a - b, d - b);
  const Vec3 n0 = cross(b - d, c - d), n1 = cross(d - a, c - a);  // new faces (d,b,c), (a,d,c)
  return dot(n0, n1) > 0 && dot(n0, n_old) > 0 && dot(n1, n_old) > 0;
}

void flip(Mesh& m, HalfedgeId h) {
  const Diamond q = diamond(m, h);
  m.set_face(q.f0, q.d, q.b, q.c);  // d->b, b->c, c->d
  m.set_face(q.f1, q.a, q.d, q.c);  // a->d, d->c, c->a
  auto H = [](FaceId f, int k) { return Mesh::halfedge(f, k); };
  m.link(H(q.f0, 0), q.o_db);
  m.link(H(q.f0, 1), q.o_bc);
  m.link(H(q.f0, 2), H(q.f1, 1));
  m.link(H(q.f1, 0), q.o_ad);
  m.link(H(q.f1, 2), q.o_ca);
  m.v_out[q.a.idx] = H(q.f1, 0).idx;
  m.v_out[q.b.idx] = H(q.f0, 1).idx;
  m.v_out[q.c.idx] = H(q.f0, 2).idx;
  m.v_out[q.d.idx] = H(q.f0, 0).idx;
}

}  // namespace jaxgenus::he
