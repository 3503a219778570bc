// Sparse Cholesky factor of A = I + lambda * L, with L the weighted graph
// Laplacian of a mesh's edges: the direct solve of the "large steps"
// reparametrization (x = A^-1 u), factored once per mesh and applied every step.
// Plain C++17: no XLA, no Python. Used by the FFI adapter and the numpy binding.
//
// The factor is P A P^T = L L^T with a nested-dissection ordering P found from
// the graph alone (breadth-first level structures: the middle level of a
// level structure is a vertex separator), stored by columns with the diagonal
// first in each column and the rows below it ascending, in double precision.
#pragma once
#include <cstdint>

#include "kernels/status.h"

namespace jaxgenus {

// A = I + lambda L, where each edge (i, j) with weight w (edges row-major (E, 2),
// i != j) adds w to L_ii and L_jj and -w to L_ij and L_ji; an edge with i == j
// or w == 0 adds nothing (padding). Writes perm[n] (perm[k] = the original index
// of the k-th pivot), colptr[n + 1], rows[capacity] and values[capacity] and
// sets *nnz to the entries of the factor. Never aborts: an index outside
// [0, n), a weight or lambda that is negative or not finite gives kInvalidInput;
// a factor with more than `capacity` entries gives kCapacityExceeded (*nnz is
// then the size it needs).
Status cholesky_factor(int64_t n, const int32_t* edges, const float* weights, int64_t n_edges,
                       double lambda, int64_t capacity, int32_t* perm, int32_t* colptr,
                       int32_t* rows, double* values, int64_t* nnz);

// Checks that (perm, colptr, rows) is a factor's structure for n unknowns with
// at most `capacity` entries (cholesky_solve reads no index it has not checked).
Status cholesky_check(int64_t n, const int32_t* perm, const int32_t* colptr, const int32_t* rows,
                      int64_t capacity);

// x = A^-1 b for k right-hand sides (b and x row-major (n, k); they may alias),
// from a factor that cholesky_check accepts; accumulates in double.
void cholesky_solve(int64_t n, const int32_t* perm, const int32_t* colptr, const int32_t* rows,
                    const double* values, const float* b, int64_t k, float* x);

}  // namespace jaxgenus
