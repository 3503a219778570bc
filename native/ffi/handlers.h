// Every XLA FFI handler the extension exports; module.cc lists them in one table.
#pragma once
#include "xla/ffi/api/ffi.h"

XLA_FFI_DECLARE_HANDLER_SYMBOL(JgMeshCheck);
XLA_FFI_DECLARE_HANDLER_SYMBOL(JgRemesh);
XLA_FFI_DECLARE_HANDLER_SYMBOL(JgRasterForward);
XLA_FFI_DECLARE_HANDLER_SYMBOL(JgRasterBackward);
XLA_FFI_DECLARE_HANDLER_SYMBOL(JgCholeskyFactor);
XLA_FFI_DECLARE_HANDLER_SYMBOL(JgCholeskySolve);
