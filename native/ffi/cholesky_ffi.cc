// Thin XLA FFI adapter for kernels/cholesky: the factor of I + lambda L into
// fixed-capacity buffers (its status and size in `info`), and the solve with it.
//
// The factor's values are doubles held in a uint32 (capacity, 2) buffer, so that
// the factor keeps double precision in programs that run without x64.
#include <algorithm>
#include <cstdint>
#include <limits>
#include <string>

#include "ffi/handlers.h"
#include "kernels/cholesky.h"

namespace ffi = xla::ffi;

namespace {

template <typename T>
bool AlignedForDouble(T* p) {
  return reinterpret_cast<uintptr_t>(p) % alignof(double) == 0;
}

ffi::Error FactorImpl(ffi::BufferR2<ffi::S32> edges, ffi::BufferR1<ffi::F32> weights,
                      ffi::BufferR0<ffi::F32> lambda, ffi::ResultBufferR1<ffi::S32> perm,
                      ffi::ResultBufferR1<ffi::S32> colptr, ffi::ResultBufferR1<ffi::S32> rows,
                      ffi::ResultBufferR2<ffi::U32> values, ffi::ResultBufferR1<ffi::S32> info) {
  const auto ed = edges.dimensions();
  const int64_t n = int64_t(perm->element_count());
  const int64_t capacity = int64_t(rows->element_count());
  if (ed[1] != 2) return ffi::Error::InvalidArgument("cholesky_factor: edges must have shape (E, 2)");
  if (int64_t(weights.element_count()) != ed[0])
    return ffi::Error::InvalidArgument("cholesky_factor: weights must have shape (E,)");
  if (int64_t(colptr->element_count()) != n + 1 || values->dimensions()[0] != capacity ||
      values->dimensions()[1] != 2 || info->element_count() != 2)
    return ffi::Error::InvalidArgument("cholesky_factor: result shapes (n,), (n + 1,), (C,), (C, 2), (2,) expected");
  if (!AlignedForDouble(values->typed_data()))
    return ffi::Error::Internal("cholesky_factor: values buffer not aligned for double");
  int64_t nnz = 0;
  const jaxgenus::Status s = jaxgenus::cholesky_factor(
      n, edges.typed_data(), weights.typed_data(), ed[0], double(*lambda.typed_data()), capacity,
      perm->typed_data(), colptr->typed_data(), rows->typed_data(),
      reinterpret_cast<double*>(values->typed_data()), &nnz);
  info->typed_data()[0] = int32_t(s);
  info->typed_data()[1] = int32_t(std::min<int64_t>(nnz, std::numeric_limits<int32_t>::max()));
  return ffi::Error::Success();
}

ffi::Error SolveImpl(ffi::BufferR1<ffi::S32> perm, ffi::BufferR1<ffi::S32> colptr,
                     ffi::BufferR1<ffi::S32> rows, ffi::BufferR2<ffi::U32> values,
                     ffi::BufferR2<ffi::F32> b, ffi::ResultBufferR2<ffi::F32> x) {
  const int64_t n = int64_t(perm.element_count());
  const int64_t capacity = int64_t(rows.element_count());
  const auto bd = b.dimensions();
  if (int64_t(colptr.element_count()) != n + 1 || values.dimensions()[0] != capacity ||
      values.dimensions()[1] != 2)
    return ffi::Error::InvalidArgument("cholesky_solve: factor shapes (n,), (n + 1,), (C,), (C, 2) expected");
  if (bd[0] != n || x->dimensions()[0] != n || x->dimensions()[1] != bd[1])
    return ffi::Error::InvalidArgument("cholesky_solve: b and x must have shape (n, k)");
  if (!AlignedForDouble(values.typed_data()))
    return ffi::Error::Internal("cholesky_solve: values buffer not aligned for double");
  if (jaxgenus::cholesky_check(n, perm.typed_data(), colptr.typed_data(), rows.typed_data(), capacity) !=
      jaxgenus::Status::kOk)
    return ffi::Error::InvalidArgument("cholesky_solve: not a factor (use the output of cholesky_factor with status 0)");
  jaxgenus::cholesky_solve(n, perm.typed_data(), colptr.typed_data(), rows.typed_data(),
                           reinterpret_cast<const double*>(values.typed_data()), b.typed_data(), bd[1],
                           x->typed_data());
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(JgCholeskyFactor, FactorImpl,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::BufferR2<ffi::S32>>()
                                  .Arg<ffi::BufferR1<ffi::F32>>()
                                  .Arg<ffi::BufferR0<ffi::F32>>()
                                  .Ret<ffi::BufferR1<ffi::S32>>()
                                  .Ret<ffi::BufferR1<ffi::S32>>()
                                  .Ret<ffi::BufferR1<ffi::S32>>()
                                  .Ret<ffi::BufferR2<ffi::U32>>()
                                  .Ret<ffi::BufferR1<ffi::S32>>());

XLA_FFI_DEFINE_HANDLER_SYMBOL(JgCholeskySolve, SolveImpl,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::BufferR1<ffi::S32>>()
                                  .Arg<ffi::BufferR1<ffi::S32>>()
                                  .Arg<ffi::BufferR1<ffi::S32>>()
                                  .Arg<ffi::BufferR2<ffi::U32>>()
                                  .Arg<ffi::BufferR2<ffi::F32>>()
                                  .Ret<ffi::BufferR2<ffi::F32>>());
