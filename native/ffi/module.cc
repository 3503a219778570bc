// The `jaxgenus._native` extension: the one table of XLA FFI registrations plus
// numpy entry points of the same kernels (for use outside jit and in tests).
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <stdexcept>

#include "ffi/handlers.h"
#include "kernels/mesh_check.h"

namespace nb = nanobind;

namespace {

template <typename T>
nb::capsule Capsule(T* fn) {
  return nb::capsule(reinterpret_cast<void*>(fn));
}

using FacesIn = nb::ndarray<const int32_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

nb::tuple MeshCheckNumpy(FacesIn faces, int64_t n_vertices, int64_t n_faces, int64_t vertex_capacity) {
  if (faces.shape(1) != 3) throw std::invalid_argument("faces must have shape (F, 3)");
  const int64_t fcap = static_cast<int64_t>(faces.shape(0));
  auto* report = new int32_t[jaxgenus::kReportSize];
  auto* comp = new int32_t[fcap > 0 ? fcap : 1];
  {
    nb::gil_scoped_release release;
    jaxgenus::mesh_check(faces.data(), fcap, vertex_capacity, n_vertices, n_faces, report, comp);
  }
  nb::capsule own_r(report, [](void* p) noexcept { delete[] static_cast<int32_t*>(p); });
  nb::capsule own_c(comp, [](void* p) noexcept { delete[] static_cast<int32_t*>(p); });
  return nb::make_tuple(
      nb::ndarray<nb::numpy, int32_t, nb::ndim<1>>(report, {size_t(jaxgenus::kReportSize)}, own_r),
      nb::ndarray<nb::numpy, int32_t, nb::ndim<1>>(comp, {size_t(fcap)}, own_c));
}

}  // namespace

NB_MODULE(_native, m) {
  m.doc() = "jaxgenus native kernels (XLA FFI handlers and numpy entry points)";
  m.def("registrations", []() {
    nb::dict table;
    table["jaxgenus_mesh_check"] = Capsule(JgMeshCheck);
    return table;
  });
  m.attr("REPORT_SIZE") = int(jaxgenus::kReportSize);
  m.def("mesh_check", &MeshCheckNumpy, nb::arg("faces"), nb::arg("n_vertices"), nb::arg("n_faces"),
        nb::arg("vertex_capacity"),
        "Topology report (int32[REPORT_SIZE]) and per-face component labels of a capacity mesh.");
}
