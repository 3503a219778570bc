// Thin XLA FFI adapter for kernels/remesh: capacity buffers in and out, status in `info`.
#include <algorithm>
#include <string>

#include "ffi/handlers.h"
#include "kernels/remesh.h"

namespace ffi = xla::ffi;

namespace {

ffi::Error RemeshImpl(ffi::BufferR2<ffi::F32> vertices, ffi::BufferR2<ffi::S32> faces,
                      ffi::BufferR1<ffi::S32> counts, ffi::BufferR2<ffi::F32> attributes,
                      ffi::BufferR0<ffi::F32> target_edge_length, int32_t iterations,
                      int32_t adaptive, float approx_error, float min_edge_length,
                      float max_edge_length, float coarsen_factor, int32_t smoothing_steps,
                      float smoothing_lambda, int32_t project, int32_t debug_validate, int64_t max_faces,
                      ffi::ResultBufferR2<ffi::F32> vertices_out,
                      ffi::ResultBufferR2<ffi::S32> faces_out,
                      ffi::ResultBufferR2<ffi::F32> attributes_out,
                      ffi::ResultBufferR1<ffi::S32> info) {
  const auto vd = vertices.dimensions(), fd = faces.dimensions(), ad = attributes.dimensions();
  if (vd[1] != 3 || fd[1] != 3)
    return ffi::Error::InvalidArgument("remesh: vertices and faces must have shape (N, 3)");
  if (ad[0] != vd[0]) return ffi::Error::InvalidArgument("remesh: attributes must have shape (Vcap, k)");
  if (counts.element_count() != 2) return ffi::Error::InvalidArgument("remesh: counts must have shape (2,)");
  if (vertices_out->dimensions()[0] != vd[0] || faces_out->dimensions()[0] != fd[0] ||
      attributes_out->dimensions()[1] != ad[1])
    return ffi::Error::InvalidArgument("remesh: output shapes must match the inputs");
  if (info->element_count() != jaxgenus::kRemeshInfoSize)
    return ffi::Error::InvalidArgument("remesh: info must have " +
                                       std::to_string(jaxgenus::kRemeshInfoSize) + " entries");
  const jaxgenus::RemeshParams p{*target_edge_length.typed_data(), iterations, adaptive, approx_error,
                                  min_edge_length, max_edge_length, coarsen_factor,
                                  smoothing_steps, smoothing_lambda, project, debug_validate};
  const int64_t k = ad[1];
  const jaxgenus::RemeshReport r = jaxgenus::remesh_buffers(
      vertices.typed_data(), vd[0], faces.typed_data(), fd[0], counts.typed_data()[0],
      counts.typed_data()[1], k > 0 ? attributes.typed_data() : nullptr, k, p, max_faces,
      vertices_out->typed_data(), faces_out->typed_data(),
      k > 0 ? attributes_out->typed_data() : nullptr);
  jaxgenus::write_remesh_info(r, info->typed_data());
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(JgRemesh, RemeshImpl,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::BufferR2<ffi::F32>>()
                                  .Arg<ffi::BufferR2<ffi::S32>>()
                                  .Arg<ffi::BufferR1<ffi::S32>>()
                                  .Arg<ffi::BufferR2<ffi::F32>>()
                                  .Arg<ffi::BufferR0<ffi::F32>>()
                                  .Attr<int32_t>("iterations")
                                  .Attr<int32_t>("adaptive")
                                  .Attr<float>("approx_error")
                                  .Attr<float>("min_edge_length")
                                  .Attr<float>("max_edge_length")
                                  .Attr<float>("coarsen_factor")
                                  .Attr<int32_t>("smoothing_steps")
                                  .Attr<float>("smoothing_lambda")
                                  .Attr<int32_t>("project")
                                  .Attr<int32_t>("debug_validate")
                                  .Attr<int64_t>("max_faces")
                                  .Ret<ffi::BufferR2<ffi::F32>>()
                                  .Ret<ffi::BufferR2<ffi::S32>>()
                                  .Ret<ffi::BufferR2<ffi::F32>>()
                                  .Ret<ffi::BufferR1<ffi::S32>>());
