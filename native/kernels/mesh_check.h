// Topology report of a triangle mesh stored in capacity buffers.
// Plain C++17: no XLA, no Python. Used by the FFI adapter and the numpy binding.
#pragma once
#include <cstdint>

#include "kernels/status.h"

namespace jaxgenus {

// Layout of the int32 report written by mesh_check, listed ONCE: entry i is
// the i-th row. Exported as `_native.REPORT_FIELDS`, from which the Python
// `MeshReport` is built. Columns: C++ enumerator, Python name, doc.
#define JAXGENUS_REPORT_FIELDS(X)                                                                  \
  X(kReportStatus, status, "Status")                                                               \
  X(kReportVertices, n_vertices, "live vertex count V")                                            \
  X(kReportEdges, n_edges, "unique undirected edges E")                                            \
  X(kReportFaces, n_faces, "live face count F")                                                    \
  X(kReportEuler, euler_characteristic, "V - E + F")                                               \
  X(kReportBoundaryEdges, boundary_edges, "edges with one incident face")                          \
  X(kReportNonManifoldEdges, nonmanifold_edges, "edges with more than two incident faces")        \
  X(kReportFlippedEdges, flipped_edges, "two-face edges whose faces disagree on orientation")     \
  X(kReportNonManifoldVertices, nonmanifold_vertices, "vertices whose faces form more than one fan") \
  X(kReportDegenerateFaces, degenerate_faces, "faces with a repeated vertex index")                \
  X(kReportComponents, n_components, "edge-connected face components")                            \
  X(kReportIsolatedVertices, isolated_vertices, "live vertices used by no live face")

enum ReportField : int {
#define JAXGENUS_REPORT_ENUMERATOR(enumerator, name, doc) enumerator,
  JAXGENUS_REPORT_FIELDS(JAXGENUS_REPORT_ENUMERATOR)
#undef JAXGENUS_REPORT_ENUMERATOR
  kReportFieldCount,
  kReportSize = 16,  // buffer length; the entries past kReportFieldCount are reserved (zero)
};
static_assert(kReportFieldCount <= kReportSize);

inline constexpr const char* kReportFieldNames[] = {
#define JAXGENUS_REPORT_NAME(enumerator, name, doc) #name,
    JAXGENUS_REPORT_FIELDS(JAXGENUS_REPORT_NAME)
#undef JAXGENUS_REPORT_NAME
};
static_assert(sizeof(kReportFieldNames) / sizeof(kReportFieldNames[0]) == kReportFieldCount);

// faces: row-major (face_capacity, 3). Reads the first n_faces rows; indices must
// lie in [0, n_vertices). Writes report[kReportSize] and, for every row of the
// buffer, face_component[f] in [0, components) for live faces and -1 for padding.
// Never aborts: invalid input sets report[kReportStatus] and returns it.
Status mesh_check(const int32_t* faces, int64_t face_capacity, int64_t vertex_capacity,
                  int64_t n_vertices, int64_t n_faces, int32_t* report, int32_t* face_component);

}  // namespace jaxgenus
