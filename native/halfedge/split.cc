// Edge split (and the diamond helper shared by split, collapse and flip).
#include "halfedge/operations.h"

namespace jaxgenus::he {

Diamond diamond(const Mesh& m, HalfedgeId h) {
  Diamond q;
  q.h = h;
  q.t = m.opposite(h);
  q.f0 = Mesh::face(h);
  q.f1 = Mesh::face(q.t);
  q.a = m.from(h);
  q.b = m.to(h);
  q.c = m.from(Mesh::prev(h));
  q.d = m.from(Mesh::prev(q.t));
  q.o_bc = m.opposite(Mesh::next(h));
  q.o_ca = m.opposite(Mesh::prev(h));
  q.o_ad = m.opposite(Mesh::next(q.t));
  q.o_db = m.opposite(Mesh::prev(q.t));
  return q;
}

bool is_split_ok(const Mesh& m, HalfedgeId h) {
  if (!h.valid() || h.idx >= m.halfedge_slots() || m.is_dead(Mesh::face(h))) return false;
  const Diamond q = diamond(m, h);
  return q.c != q.d;
}

VertexId split(Mesh& m, HalfedgeId h, double t) {
  const Diamond q = diamond(m, h);
  const VertexId v = m.add_vertex(m.pos[q.a.idx] * (1 - t) + m.pos[q.b.idx] * t);
  m.interpolate_vertex_data(v, q.a, q.b, t);
  const FaceId f2 = m.add_face(), f3 = m.add_face();
  m.set_face(q.f0, q.a, v, q.c);  // a->v, v->c, c->a
  m.set_face(f2, v, q.b, q.c);    // v->b, b->c, c->v
  m.set_face(q.f1, q.b, v, q.d);  // b->v, v->d, d->b
  m.set_face(f3, v, q.a, q.d);    // v->a, a->d, d->v
  auto H = [](FaceId f, int k) { return Mesh::halfedge(f, k); };
  m.link(H(q.f0, 0), H(f3, 0));
  m.link(H(q.f0, 1), H(f2, 2));
  m.link(H(q.f0, 2), q.o_ca);
  m.link(H(f2, 0), H(q.f1, 0));
  m.link(H(f2, 1), q.o_bc);
  m.link(H(q.f1, 1), H(f3, 2));
  m.link(H(q.f1, 2), q.o_db);
  m.link(H(f3, 1), q.o_ad);
  m.v_out[q.a.idx] = H(q.f0, 0).idx;
  m.v_out[q.b.idx] = H(f2, 1).idx;
  m.v_out[q.c.idx] = H(q.f0, 2).idx;
  m.v_out[q.d.idx] = H(q.f1, 2).idx;
  m.v_out[v.idx] = H(q.f0, 1).idx;
  return v;
}

}  // namespace jaxgenus::he
