// Thin XLA FFI adapter for kernels/mesh_check: shapes in, status out.
#include <string>

#include "ffi/handlers.h"
#include "kernels/mesh_check.h"

namespace ffi = xla::ffi;

namespace {

ffi::Error MeshCheckImpl(ffi::BufferR2<ffi::S32> faces, ffi::BufferR1<ffi::S32> counts,
                         int64_t vertex_capacity, ffi::ResultBufferR1<ffi::S32> report,
                         ffi::ResultBufferR1<ffi::S32> face_component) {
  const auto fdims = faces.dimensions();
  if (fdims[1] != 3) return ffi::Error::InvalidArgument("mesh_check: faces must have shape (F, 3)");
  if (counts.element_count() != 2)
    return ffi::Error::InvalidArgument("mesh_check: counts must have shape (2,)");
  if (report->element_count() != jaxgenus::kReportSize)
    return ffi::Error::InvalidArgument("mesh_check: report must have " +
                                       std::to_string(jaxgenus::kReportSize) + " entries");
  if (face_component->element_count() != static_cast<size_t>(fdims[0]))
    return ffi::Error::InvalidArgument("mesh_check: face_component must have F entries");
  const int32_t* c = counts.typed_data();
  // Invalid counts or indices are reported through the status field, not as an error,
  // so a jitted pipeline can branch on them.
  jaxgenus::mesh_check(faces.typed_data(), fdims[0], vertex_capacity, c[0], c[1],
                       report->typed_data(), face_component->typed_data());
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(JgMeshCheck, MeshCheckImpl,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::BufferR2<ffi::S32>>()
                                  .Arg<ffi::BufferR1<ffi::S32>>()
                                  .Attr<int64_t>("vertex_capacity")
                                  .Ret<ffi::BufferR1<ffi::S32>>()
                                  .Ret<ffi::BufferR1<ffi::S32>>());
