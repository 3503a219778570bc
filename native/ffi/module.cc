// The `jaxgenus._native` extension: the one table of XLA FFI registrations plus
// numpy entry points of the same kernels (for use outside jit and in tests).
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>

#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "ffi/handlers.h"
#include "kernels/mesh_check.h"
#include "kernels/remesh.h"

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

using VerticesIn = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using AttributesIn = nb::ndarray<const float, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

// Hands a vector to numpy without copying, as a (size / cols, cols) array.
template <typename T>
nb::ndarray<nb::numpy, T> ToNumpy(std::vector<T>&& data, size_t cols) {
  auto* owned = new std::vector<T>(std::move(data));
  nb::capsule own(owned, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
  const size_t shape[2] = {cols ? owned->size() / cols : 0, cols};
  return nb::ndarray<nb::numpy, T>(owned->data(), 2, shape, own);
}

template <typename T>
nb::ndarray<nb::numpy, T> ToNumpy1D(std::vector<T>&& data) {
  auto* owned = new std::vector<T>(std::move(data));
  nb::capsule own(owned, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
  const size_t shape[1] = {owned->size()};
  return nb::ndarray<nb::numpy, T>(owned->data(), 1, shape, own);
}

template <typename T>
constexpr const char* DtypeName() {
  static_assert(std::is_same_v<T, float> || std::is_same_v<T, int32_t>,
                "remesh options are float or int32_t (add a dtype name here for another type)");
  return std::is_same_v<T, float> ? "float32" : "int32";
}

// `_native.REMESH_PARAMS`: one (name, dtype, default, doc) row per option of
// JAXGENUS_REMESH_PARAMS, in list order.
nb::tuple RemeshParamsTable() {
  const jaxgenus::RemeshParams defaults;
  nb::list rows;
  jaxgenus::for_each_remesh_param(defaults, [&](const char* name, const auto& field, const char* doc) {
    using T = std::decay_t<decltype(field)>;
    rows.append(nb::make_tuple(name, DtypeName<T>(), field, doc));
  });
  return nb::tuple(rows);
}

template <size_t N>
nb::tuple NameTuple(const char* const (&names)[N]) {
  nb::list out;
  for (const char* n : names) out.append(nb::str(n));
  return nb::tuple(out);
}

// Decodes the option dict of the numpy entry by the same field list as the FFI
// handler: a missing option keeps its default, an unknown name or a value that
// does not convert to the option's type raises ValueError.
jaxgenus::RemeshParams ParamsFromDict(const nb::dict& options) {
  jaxgenus::RemeshParams p;
  size_t decoded = 0;
  jaxgenus::for_each_remesh_param(p, [&](const char* name, auto& field, const char*) {
    using T = std::decay_t<decltype(field)>;
    if (!options.contains(name)) return;
    if (!nb::try_cast<T>(options[name], field))
      throw std::invalid_argument(std::string("remesh option '") + name + "' must be " + DtypeName<T>());
    ++decoded;
  });
  if (decoded != options.size()) {
    for (auto [key, value] : options) {
      bool known = false;
      jaxgenus::for_each_remesh_param(p, [&](const char* n, auto&, const char*) {
        known |= nb::isinstance<nb::str>(key) && nb::cast<std::string>(key) == n;
      });
      if (!known) throw std::invalid_argument("unknown remesh option " + nb::cast<std::string>(nb::repr(key)));
    }
  }
  return p;
}

// Remeshes (V, F) outside jit: no capacity, at most face_budget faces. `options`
// maps option names (REMESH_PARAMS) to values. Returns (vertices f64 (V', 3),
// faces i32 (F', 3), attributes f32 (V', k), info i32[REMESH_INFO_SIZE], message,
// target_edge_length).
nb::tuple RemeshNumpy(VerticesIn vertices, FacesIn faces, AttributesIn attributes,
                      const nb::dict& options, int64_t face_budget) {
  if (vertices.shape(1) != 3) throw std::invalid_argument("vertices must have shape (V, 3)");
  if (faces.shape(1) != 3) throw std::invalid_argument("faces must have shape (F, 3)");
  if (attributes.shape(0) != vertices.shape(0))
    throw std::invalid_argument("attributes must have shape (V, k)");
  const jaxgenus::RemeshParams p = ParamsFromDict(options);
  const int64_t k = int64_t(attributes.shape(1));
  std::vector<double> v_out;
  std::vector<int32_t> f_out;
  std::vector<float> a_out;
  jaxgenus::RemeshReport r;
  {
    nb::gil_scoped_release release;
    r = jaxgenus::remesh_arrays(vertices.data(), int64_t(vertices.shape(0)), faces.data(),
                                int64_t(faces.shape(0)), k > 0 ? attributes.data() : nullptr, k, p,
                                face_budget, &v_out, &f_out, &a_out);
  }
  std::vector<int32_t> info(jaxgenus::kRemeshInfoSize);
  jaxgenus::write_remesh_info(r, info.data());
  return nb::make_tuple(ToNumpy(std::move(v_out), 3), ToNumpy(std::move(f_out), 3),
                        ToNumpy(std::move(a_out), size_t(k)), ToNumpy1D(std::move(info)),
                        r.message, r.target_edge_length);
}

// Test hook: runs kernels/remesh's apply_operations; returns (V, F, applied, status, message).
nb::tuple ApplyOperationsNumpy(VerticesIn vertices, FacesIn faces,
                               nb::ndarray<const int32_t, nb::ndim<2>, nb::c_contig, nb::device::cpu> ops) {
  if (vertices.shape(1) != 3 || faces.shape(1) != 3 || ops.shape(1) != 3)
    throw std::invalid_argument("vertices, faces and ops must have 3 columns");
  std::vector<double> v_out;
  std::vector<int32_t> f_out;
  int64_t applied = 0;
  jaxgenus::RemeshReport r;
  {
    nb::gil_scoped_release release;
    r = jaxgenus::apply_operations(vertices.data(), int64_t(vertices.shape(0)), faces.data(),
                                   int64_t(faces.shape(0)), ops.data(), int64_t(ops.shape(0)), &v_out,
                                   &f_out, &applied);
  }
  return nb::make_tuple(ToNumpy(std::move(v_out), 3), ToNumpy(std::move(f_out), 3), applied,
                        int(r.status), r.message);
}

}  // namespace

NB_MODULE(_native, m) {
  m.doc() = "jaxgenus native kernels (XLA FFI handlers and numpy entry points)";
  m.def("registrations", []() {
    nb::dict table;
    table["jaxgenus_mesh_check"] = Capsule(JgMeshCheck);
    table["jaxgenus_remesh"] = Capsule(JgRemesh);
    table["jaxgenus_raster_forward"] = Capsule(JgRasterForward);
    table["jaxgenus_raster_backward"] = Capsule(JgRasterBackward);
    table["jaxgenus_cholesky_factor"] = Capsule(JgCholeskyFactor);
    table["jaxgenus_cholesky_solve"] = Capsule(JgCholeskySolve);
    return table;
  });
  m.attr("REPORT_SIZE") = int(jaxgenus::kReportSize);
  m.attr("REPORT_FIELDS") = NameTuple(jaxgenus::kReportFieldNames);
  m.def("mesh_check", &MeshCheckNumpy, nb::arg("faces"), nb::arg("n_vertices"), nb::arg("n_faces"),
        nb::arg("vertex_capacity"),
        "Topology report (int32[REPORT_SIZE], entries named by REPORT_FIELDS) and per-face "
        "component labels of a capacity mesh.");
  m.attr("REMESH_INFO_SIZE") = int(jaxgenus::kRemeshInfoSize);
  m.attr("REMESH_INFO_FIELDS") = NameTuple(jaxgenus::remesh_info::kNames);
  m.attr("REMESH_PARAMS") = RemeshParamsTable();
  m.def("remesh", &RemeshNumpy, nb::arg("vertices"), nb::arg("faces"), nb::arg("attributes"),
        nb::arg("options"), nb::arg("face_budget"),
        "Remesh (V f64, F i32, attributes f32 (V, k)) outside jit with `options` a dict "
        "{name: value} of REMESH_PARAMS (missing: default); returns (V, F, attributes, "
        "info int32[REMESH_INFO_SIZE] named by REMESH_INFO_FIELDS, message, target_edge_length).");
  m.def("apply_halfedge_operations", &ApplyOperationsNumpy, nb::arg("vertices"), nb::arg("faces"),
        nb::arg("ops"),
        "Test hook: apply (kind, halfedge, param) rows of split/collapse/flip/smooth with validate() "
        "after each; returns (V, F, applied, status, message).");
}
