#!/usr/bin/env bash
# Builds the native half-edge core, the remesh and raster kernels and their tests with
# AddressSanitizer + UBSan (plain g++, no XLA, no Python) and runs them.
# Any sanitizer report aborts with a nonzero status. Extra arguments are OBJ
# files of closed meshes to remesh as well (e.g. ../shared/meshes/pretzel.obj).
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
out="${TMPDIR:-/tmp}/jaxgenus_native_tests"
mkdir -p "$out"
flags=(-std=c++17 -O1 -g -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=all
       -Wall -Wextra -I"$root/native")
export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
"${CXX:-g++}" "${flags[@]}" "$root"/native/halfedge/*.cc "$root"/native/kernels/*.cc \
  "$root/native/tests/test_halfedge.cc" -o "$out/test_halfedge"
"$out/test_halfedge" "$@"
# the raster kernel with the options CMakeLists.txt gives it
"${CXX:-g++}" "${flags[@]}" -fno-trapping-math -fno-math-errno "$root"/native/kernels/raster.cc \
  "$root/native/tests/test_raster.cc" -o "$out/test_raster" -lpthread
"$out/test_raster"
