// Thin XLA FFI adapter for kernels/remesh: capacity buffers in and out, status in `info`.
//
// Attributes: `options`, a dictionary decoded into RemeshParams by the field
// list JAXGENUS_REMESH_PARAMS (kernels/remesh.h), and `max_faces`, the face
// budget. The target edge length is a 0-d operand (it may be traced), so it is
// not part of `options`.
#include <string>
#include <type_traits>

#include "ffi/handlers.h"
#include "kernels/remesh.h"

namespace ffi = xla::ffi;

namespace {

// Decodes the `options` dictionary into *p in one pass over the field list. A
// missing option keeps its default; an unknown name, a wrong scalar type, or
// the operand `target_edge_length` is an error naming the option.
ffi::Error DecodeOptions(const ffi::Dictionary& options, jaxgenus::RemeshParams* p) {
  std::string error;
  size_t decoded = 0;
  jaxgenus::for_each_remesh_param(*p, [&](const char* name, auto& field, const char*) {
    using T = std::decay_t<decltype(field)>;
    if (!error.empty() || !options.contains(name)) return;
    ffi::ErrorOr<T> value = options.get<T>(name);
    if (value.has_error()) {
      error = std::string("remesh: option '") + name + "': " + value.error().message();
      return;
    }
    field = *value;
    ++decoded;
  });
  if (!error.empty()) return ffi::Error::InvalidArgument(error);
  if (options.contains("target_edge_length"))
    return ffi::Error::InvalidArgument("remesh: target_edge_length is an operand, not an option");
  if (decoded != options.size()) {
    for (std::string_view name : options) {
      bool known = false;
      jaxgenus::for_each_remesh_param(*p, [&](const char* n, auto&, const char*) { known |= name == n; });
      if (!known) return ffi::Error::InvalidArgument("remesh: unknown option '" + std::string(name) + "'");
    }
  }
  return ffi::Error::Success();
}

ffi::Error RemeshImpl(ffi::BufferR2<ffi::F32> vertices, ffi::BufferR2<ffi::S32> faces,
                      ffi::BufferR1<ffi::S32> counts, ffi::BufferR2<ffi::F32> attributes,
                      ffi::BufferR0<ffi::F32> target_edge_length, ffi::Dictionary options,
                      int64_t max_faces, ffi::ResultBufferR2<ffi::F32> vertices_out,
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
  jaxgenus::RemeshParams p;
  if (ffi::Error e = DecodeOptions(options, &p); e.failure()) return e;
  p.target_edge_length = *target_edge_length.typed_data();
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
                                  .Attr<ffi::Dictionary>("options")
                                  .Attr<int64_t>("max_faces")
                                  .Ret<ffi::BufferR2<ffi::F32>>()
                                  .Ret<ffi::BufferR2<ffi::S32>>()
                                  .Ret<ffi::BufferR2<ffi::F32>>()
                                  .Ret<ffi::BufferR1<ffi::S32>>());
