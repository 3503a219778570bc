// Status codes shared by every native kernel (returned, never thrown).
#pragma once
#include <cstdint>

namespace jaxgenus {

enum class Status : int32_t {
  kOk = 0,
  kInvalidInput = 1,      // counts out of range, bad indices, NaN, ...
  kCapacityExceeded = 2,  // an output buffer is too small
  kTopologyChanged = 3,   // an operation would change (or changed) the topology
};

}  // namespace jaxgenus
