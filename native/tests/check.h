// The native tests' one assertion: counts a failure and prints a "FAIL" line
// (ctest fails on the exit status, the failure count, and on that line).
#pragma once
#include <cstdio>

static int g_failures = 0;
#define CHECK(cond, ...)                                          \
  do {                                                            \
    if (!(cond)) {                                                \
      ++g_failures;                                               \
      std::printf("FAIL %s:%d: %s: ", __FILE__, __LINE__, #cond); \
      std::printf(__VA_ARGS__);                                   \
      std::printf("\n");                                          \
    }                                                             \
  } while (0)
