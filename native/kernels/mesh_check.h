// Topology report of a triangle mesh stored in capacity buffers.
// Plain C++17: no XLA, no Python. Used by the FFI adapter and the numpy binding.
#pragma once
#include <cstdint>

#include "kernels/status.h"

namespace jaxgenus {

// Layout of the int32 report written by mesh_check (kReportSize entries).
enum ReportField : int {
  kReportStatus = 0,          // Status
  kReportVertices = 1,        // live vertex count V
  kReportEdges = 2,           // unique undirected edges E
  kReportFaces = 3,           // live face count F
  kReportEuler = 4,           // V - E + F
  kReportBoundaryEdges = 5,   // edges with one incident face
  kReportNonManifoldEdges = 6,  // edges with more than two incident faces
  kReportFlippedEdges = 7,    // two-face edges whose faces disagree on orientation
  kReportNonManifoldVertices = 8,  // vertices whose faces form more than one fan
  kReportDegenerateFaces = 9,  // faces with a repeated vertex index
  kReportComponents = 10,     // edge-connected face components
  kReportIsolatedVertices = 11,  // live vertices used by no live face
  kReportSize = 16,
};

// faces: row-major (face_capacity, 3). Reads the first n_faces rows; indices must
// lie in [0, n_vertices). Writes report[kReportSize] and, for every row of the
// buffer, face_component[f] in [0, components) for live faces and -1 for padding.
// Never aborts: invalid input sets report[kReportStatus] and returns it.
Status mesh_check(const int32_t* faces, int64_t face_capacity, int64_t vertex_capacity,
                  int64_t n_vertices, int64_t n_faces, int32_t* report, int32_t* face_component);

}  // namespace jaxgenus
