// Plain C++ tests of kernels/cholesky (no framework): the solve of I + lambda L
// on torus grids and on a graph with isolated vertices and repeated edges,
// checked by the residual of the matrix built here edge by edge; the ordering a
// permutation with small fill; capacity and invalid input reported, not thrown.
// Exit status is the number of failed checks (at most 255).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "kernels/cholesky.h"

using namespace jaxgenus;

#include "check.h"

namespace {

struct Problem {
  int64_t n = 0;
  std::vector<int32_t> edges;  // (E, 2)
  std::vector<float> weights;
};

// A triangulated torus grid (each quad split in two): the directed edges of
// every face with weight 1/2, as the uniform Laplacian stores them.
Problem TorusGrid(int rows, int cols, int padding) {
  Problem p;
  p.n = int64_t(rows) * cols + padding;
  auto id = [&](int r, int c) { return int32_t(((r + rows) % rows) * cols + (c + cols) % cols); };
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const int32_t faces[2][3] = {{id(r, c), id(r + 1, c), id(r + 1, c + 1)},
                                   {id(r, c), id(r + 1, c + 1), id(r, c + 1)}};
      for (const auto& f : faces)
        for (int e = 0; e < 3; ++e) {
          p.edges.push_back(f[e]);
          p.edges.push_back(f[(e + 1) % 3]);
          p.weights.push_back(0.5f);
        }
    }
  for (int e = 0; e < 3 * padding; ++e) {  // padded faces (0, 0, 0): self loops of weight 0
    p.edges.push_back(0);
    p.edges.push_back(0);
    p.weights.push_back(0.0f);
  }
  return p;
}

// ||b - A x|| / ||b|| per column, in double, with A built from the edges directly.
double Residual(const Problem& p, double lambda, const std::vector<float>& b, const std::vector<float>& x, int k) {
  std::vector<double> ax(size_t(p.n * k));
  for (int64_t i = 0; i < p.n * k; ++i) ax[i] = x[i];
  for (size_t e = 0; e < p.weights.size(); ++e) {
    const int32_t i = p.edges[2 * e], j = p.edges[2 * e + 1];
    const double w = lambda * p.weights[e];
    for (int c = 0; c < k; ++c) {
      const double d = w * (double(x[i * k + c]) - x[j * k + c]);
      ax[i * k + c] += d;
      ax[j * k + c] -= d;
    }
  }
  double worst = 0;
  for (int c = 0; c < k; ++c) {
    double r2 = 0, b2 = 0;
    for (int64_t i = 0; i < p.n; ++i) {
      r2 += (b[i * k + c] - ax[i * k + c]) * (b[i * k + c] - ax[i * k + c]);
      b2 += double(b[i * k + c]) * b[i * k + c];
    }
    worst = std::max(worst, std::sqrt(r2 / b2));
  }
  return worst;
}

struct Factor {
  std::vector<int32_t> perm, colptr, rows;
  std::vector<double> values;
  int64_t nnz = 0;
  Status status = Status::kOk;
};

Factor Factorize(const Problem& p, double lambda, int64_t capacity) {
  Factor f;
  f.perm.resize(size_t(p.n));
  f.colptr.resize(size_t(p.n) + 1);
  f.rows.resize(size_t(capacity));
  f.values.resize(size_t(capacity));
  f.status = cholesky_factor(p.n, p.edges.data(), p.weights.data(), int64_t(p.weights.size()), lambda, capacity,
                             f.perm.data(), f.colptr.data(), f.rows.data(), f.values.data(), &f.nnz);
  return f;
}

void TestSolve(int rows, int cols, int padding, double lambda) {
  const Problem p = TorusGrid(rows, cols, padding);
  const Factor f = Factorize(p, lambda, 64 * p.n);
  CHECK(f.status == Status::kOk, "%dx%d lambda %g: status %d", rows, cols, lambda, int(f.status));
  if (f.status != Status::kOk) return;
  CHECK(cholesky_check(p.n, f.perm.data(), f.colptr.data(), f.rows.data(), 64 * p.n) == Status::kOk,
        "the factor's structure");
  std::vector<int32_t> sorted(f.perm);
  std::sort(sorted.begin(), sorted.end());
  bool permutation = true;
  for (int64_t i = 0; i < p.n; ++i) permutation &= sorted[i] == i;
  CHECK(permutation, "perm is a permutation");
  const double per_vertex = double(f.nnz) / p.n;
  std::printf("torus %dx%d (+%d padding) lambda %g: %.1f factor entries per vertex\n", rows, cols, padding, lambda,
              per_vertex);
  CHECK(per_vertex < 6 * std::log2(double(p.n)), "fill %.1f entries per vertex", per_vertex);  // n log n
  const int k = 3;
  std::mt19937 rng(7);
  std::normal_distribution<float> normal;
  std::vector<float> b(size_t(p.n * k)), x(size_t(p.n * k));
  for (float& v : b) v = normal(rng);
  cholesky_solve(p.n, f.perm.data(), f.colptr.data(), f.rows.data(), f.values.data(), b.data(), k, x.data());
  const double r = Residual(p, lambda, b, x, k);
  CHECK(r < 1e-6 * std::max(1.0, lambda), "residual %g at lambda %g", r, lambda);
  for (int64_t i = rows * cols; i < p.n; ++i)  // isolated vertices: identity rows
    for (int c = 0; c < k; ++c) CHECK(x[i * k + c] == b[i * k + c], "padding row %lld", (long long)i);
  std::vector<float> same(b);  // b and x may alias
  cholesky_solve(p.n, f.perm.data(), f.colptr.data(), f.rows.data(), f.values.data(), same.data(), k, same.data());
  CHECK(same == x, "aliased solve differs");
}

void TestReported() {
  Problem p = TorusGrid(8, 8, 0);
  Factor f = Factorize(p, 19.0, 10);
  CHECK(f.status == Status::kCapacityExceeded, "capacity: status %d", int(f.status));
  CHECK(f.nnz > 10, "capacity: the size it needs (%lld)", (long long)f.nnz);
  f = Factorize(p, -1.0, 64 * p.n);
  CHECK(f.status == Status::kInvalidInput, "negative lambda");
  f = Factorize(p, NAN, 64 * p.n);
  CHECK(f.status == Status::kInvalidInput, "NaN lambda");
  Problem bad = p;
  bad.edges[5] = int32_t(p.n);
  CHECK(Factorize(bad, 19.0, 64 * p.n).status == Status::kInvalidInput, "index out of range");
  bad = p;
  bad.weights[3] = NAN;
  CHECK(Factorize(bad, 19.0, 64 * p.n).status == Status::kInvalidInput, "NaN weight");
  bad = p;
  bad.weights[3] = -2.0f;
  CHECK(Factorize(bad, 19.0, 64 * p.n).status == Status::kInvalidInput, "negative weight");
  Problem empty;
  f = Factorize(empty, 19.0, 0);
  CHECK(f.status == Status::kOk && f.nnz == 0, "empty matrix");
  f = Factorize(p, 19.0, 64 * p.n);
  f.rows[f.colptr[3] + 1] = 2;  // a row above the diagonal
  CHECK(cholesky_check(p.n, f.perm.data(), f.colptr.data(), f.rows.data(), 64 * p.n) == Status::kInvalidInput,
        "a corrupted factor");
  f = Factorize(p, 19.0, 64 * p.n);
  f.perm[0] = f.perm[1];
  CHECK(cholesky_check(p.n, f.perm.data(), f.colptr.data(), f.rows.data(), 64 * p.n) == Status::kInvalidInput,
        "perm not a permutation");
}

}  // namespace

int main() {
  TestSolve(6, 5, 0, 19.0);
  TestSolve(40, 60, 37, 19.0);
  TestSolve(100, 100, 0, 19.0);
  TestSolve(30, 30, 5, 0.0);
  TestSolve(50, 70, 0, 1000.0);
  TestReported();
  std::printf("%d failures\n", g_failures);
  return std::min(g_failures, 255);
}
