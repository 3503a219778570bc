// Sparse Cholesky factor and solve of I + lambda L (see cholesky.h).
#include "kernels/cholesky.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <utility>
#include <vector>

namespace jaxgenus {
namespace {

// Subsets at most this large are not split further: their vertices are
// eliminated in the order they come (the fill inside them is small anyway).
constexpr size_t kLeafSize = 64;

// The symmetric graph of the edges: no self loops, one entry per neighbour with
// the summed weight, and each vertex's weighted degree.
struct Graph {
  std::vector<int32_t> ptr, adj;
  std::vector<double> weight, degree;
};

bool BuildGraph(int64_t n, const int32_t* edges, const float* weights, int64_t n_edges, Graph* g) {
  struct Entry {
    int32_t a, b;
    double w;
  };
  std::vector<Entry> list;
  list.reserve(size_t(2 * n_edges));
  for (int64_t e = 0; e < n_edges; ++e) {
    const int32_t a = edges[2 * e], b = edges[2 * e + 1];
    const double w = weights[e];
    if (a < 0 || a >= n || b < 0 || b >= n || !std::isfinite(w) || w < 0) return false;
    if (a == b || w == 0) continue;
    list.push_back({a, b, w});
    list.push_back({b, a, w});
  }
  std::sort(list.begin(), list.end(),
            [](const Entry& x, const Entry& y) { return x.a != y.a ? x.a < y.a : x.b < y.b; });
  g->ptr.assign(static_cast<size_t>(n) + 1, 0);
  g->degree.assign(size_t(n), 0.0);
  g->adj.clear();
  g->weight.clear();
  for (size_t p = 0; p < list.size(); ++p) {
    const Entry& e = list[p];
    g->degree[e.a] += e.w;
    if (!g->adj.empty() && p > 0 && list[p - 1].a == e.a && list[p - 1].b == e.b) {
      g->weight.back() += e.w;
      continue;
    }
    g->adj.push_back(e.b);
    g->weight.push_back(e.w);
    ++g->ptr[e.a + 1];
  }
  for (int64_t v = 0; v < n; ++v) g->ptr[v + 1] += g->ptr[v];
  return true;
}

// A fill-reducing elimination order: nested dissection by level structures.
// A connected subset is searched breadth-first from a pseudo-peripheral vertex;
// the level holding its median vertex separates the levels before it from the
// levels after it (an edge joins only neighbouring levels), so those two parts
// are ordered first (each the same way) and the separator last.
std::vector<int32_t> NestedDissection(int64_t n, const Graph& g) {
  struct Item {
    std::vector<int32_t> vertices;
    bool emit;  // a separator (or a leaf): eliminated as it is
  };
  std::vector<int32_t> order;
  order.reserve(static_cast<size_t>(n));
  std::vector<int32_t> label(size_t(n), -1), level(size_t(n), -1), queue;
  std::vector<Item> stack;
  stack.push_back({std::vector<int32_t>(static_cast<size_t>(n)), false});
  std::iota(stack.back().vertices.begin(), stack.back().vertices.end(), 0);
  int32_t next_label = 0;
  while (!stack.empty()) {
    Item item = std::move(stack.back());
    stack.pop_back();
    std::vector<int32_t>& vs = item.vertices;
    if (item.emit || vs.size() <= kLeafSize) {
      order.insert(order.end(), vs.begin(), vs.end());
      continue;
    }
    const int32_t id = next_label++;
    for (int32_t v : vs) label[v] = id;
    // breadth-first search inside the subset; returns the last level
    auto search = [&](int32_t root) {
      for (int32_t v : vs) level[v] = -1;
      queue.assign(1, root);
      level[root] = 0;
      for (size_t head = 0; head < queue.size(); ++head) {
        const int32_t v = queue[head];
        for (int32_t p = g.ptr[v]; p < g.ptr[v + 1]; ++p) {
          const int32_t u = g.adj[p];
          if (label[u] == id && level[u] < 0) {
            level[u] = level[v] + 1;
            queue.push_back(u);
          }
        }
      }
      return level[queue.back()];
    };
    int32_t root = vs[0];
    int32_t depth = search(root);
    if (queue.size() < vs.size()) {  // not connected: each component on its own
      std::vector<int32_t> rest;
      rest.reserve(vs.size() - queue.size());
      for (int32_t v : vs)
        if (level[v] < 0) rest.push_back(v);
      stack.push_back({std::move(rest), false});
      stack.push_back({queue, false});
      continue;
    }
    for (int tries = 0; tries < 4; ++tries) {  // a pseudo-peripheral root: the far end, again
      int32_t candidate = queue.back();
      for (size_t q = queue.size(); q-- > 0 && level[queue[q]] == depth;) {
        const int32_t v = queue[q];
        if (g.ptr[v + 1] - g.ptr[v] < g.ptr[candidate + 1] - g.ptr[candidate]) candidate = v;
      }
      const int32_t d = search(candidate);
      if (d <= depth) {
        search(root);
        break;
      }
      root = candidate;
      depth = d;
    }
    if (depth < 2) {  // every vertex within one step of the root: nothing separates
      order.insert(order.end(), vs.begin(), vs.end());
      continue;
    }
    // the separator: the level at which half of the subset has been reached, inside [1, depth - 1]
    const int32_t median = level[queue[queue.size() / 2]];
    const int32_t cut = std::min(std::max(median, 1), depth - 1);
    Item before{{}, false}, separator{{}, true}, after{{}, false};
    for (int32_t v : queue) (level[v] < cut ? before : level[v] == cut ? separator : after).vertices.push_back(v);
    stack.push_back(std::move(separator));
    stack.push_back(std::move(after));
    stack.push_back(std::move(before));
  }
  return order;
}

// The nonzero columns j < k of row k of the factor, ascending: the vertices met
// walking up the elimination tree from each row of column k's upper part.
void RowPattern(int32_t k, const std::vector<int32_t>& uptr, const std::vector<int32_t>& urow,
                const std::vector<int32_t>& parent, std::vector<int32_t>* flag, std::vector<int32_t>* pattern) {
  pattern->clear();
  (*flag)[k] = k;
  for (int32_t p = uptr[k]; p < uptr[k + 1]; ++p) {
    for (int32_t j = urow[p]; j >= 0 && (*flag)[j] != k; j = parent[j]) {
      pattern->push_back(j);
      (*flag)[j] = k;
    }
  }
  std::sort(pattern->begin(), pattern->end());
}

}  // namespace

Status cholesky_factor(int64_t n, const int32_t* edges, const float* weights, int64_t n_edges,
                       double lambda, int64_t capacity, int32_t* perm, int32_t* colptr,
                       int32_t* rows, double* values, int64_t* nnz) {
  *nnz = 0;
  if (n < 0 || n_edges < 0 || capacity < 0 || n > std::numeric_limits<int32_t>::max() - 1 ||
      !std::isfinite(lambda) || lambda < 0)
    return Status::kInvalidInput;
  Graph g;
  if (!BuildGraph(n, edges, weights, n_edges, &g)) return Status::kInvalidInput;
  const std::vector<int32_t> order = NestedDissection(n, g);
  std::vector<int32_t> inverse(static_cast<size_t>(n));
  for (int64_t k = 0; k < n; ++k) {
    perm[k] = order[k];
    inverse[order[k]] = int32_t(k);
  }
  // the upper triangle of P A P^T by columns (rows i < k of column k), and its diagonal
  std::vector<int32_t> uptr(static_cast<size_t>(n) + 1, 0), urow;
  std::vector<double> uval, diagonal(static_cast<size_t>(n));
  for (int64_t a = 0; a < n; ++a)
    for (int32_t p = g.ptr[a]; p < g.ptr[a + 1]; ++p)
      if (inverse[g.adj[p]] < inverse[a]) ++uptr[inverse[a] + 1];
  for (int64_t k = 0; k < n; ++k) uptr[k + 1] += uptr[k];
  urow.resize(size_t(uptr[n]));
  uval.resize(size_t(uptr[n]));
  std::vector<int32_t> next(uptr.begin(), uptr.end() - 1);
  for (int64_t a = 0; a < n; ++a) {
    const int32_t k = inverse[a];
    diagonal[k] = 1.0 + lambda * g.degree[a];
    for (int32_t p = g.ptr[a]; p < g.ptr[a + 1]; ++p) {
      const int32_t i = inverse[g.adj[p]];
      if (i < k) {
        urow[next[k]] = i;
        uval[next[k]++] = -lambda * g.weight[p];
      }
    }
  }
  // elimination tree (ancestors compressed along the way)
  std::vector<int32_t> parent(size_t(n), -1), ancestor(size_t(n), -1);
  for (int32_t k = 0; k < n; ++k) {
    for (int32_t p = uptr[k]; p < uptr[k + 1]; ++p) {
      for (int32_t i = urow[p], up; i >= 0 && i < k; i = up) {
        up = ancestor[i];
        ancestor[i] = k;
        if (up < 0) parent[i] = k;
      }
    }
  }
  // column counts, then the column pointers (the diagonal first in each column)
  std::vector<int32_t> flag(size_t(n), -1), pattern;
  std::vector<int64_t> count(size_t(n), 1);
  for (int32_t k = 0; k < n; ++k) {
    RowPattern(k, uptr, urow, parent, &flag, &pattern);
    for (int32_t j : pattern) ++count[j];
  }
  int64_t total = 0;
  for (int64_t j = 0; j < n; ++j) total += count[j];
  *nnz = total;
  if (total > capacity || total > std::numeric_limits<int32_t>::max()) return Status::kCapacityExceeded;
  colptr[0] = 0;
  for (int64_t j = 0; j < n; ++j) colptr[j + 1] = colptr[j] + int32_t(count[j]);
  // numeric: row k of the factor by a sparse triangular solve with the rows above it
  std::vector<double> x(size_t(n), 0.0);
  std::vector<int32_t> fill(static_cast<size_t>(n));
  for (int64_t j = 0; j < n; ++j) fill[j] = colptr[j] + 1;
  std::fill(flag.begin(), flag.end(), -1);
  for (int32_t k = 0; k < n; ++k) {
    RowPattern(k, uptr, urow, parent, &flag, &pattern);
    for (int32_t p = uptr[k]; p < uptr[k + 1]; ++p) x[urow[p]] = uval[p];
    double d = diagonal[k];
    for (int32_t j : pattern) {
      const double lkj = x[j] / values[colptr[j]];
      x[j] = 0.0;
      for (int32_t p = colptr[j] + 1; p < fill[j]; ++p) x[rows[p]] -= values[p] * lkj;
      d -= lkj * lkj;
      rows[fill[j]] = k;
      values[fill[j]++] = lkj;
    }
    if (!(d > 0.0) || !std::isfinite(d)) return Status::kInvalidInput;  // not positive definite
    rows[colptr[k]] = k;
    values[colptr[k]] = std::sqrt(d);
  }
  return Status::kOk;
}

Status cholesky_check(int64_t n, const int32_t* perm, const int32_t* colptr, const int32_t* rows,
                      int64_t capacity) {
  if (n < 0 || colptr[0] != 0 || colptr[n] > capacity) return Status::kInvalidInput;
  std::vector<char> seen(size_t(n), 0);
  for (int64_t k = 0; k < n; ++k) {
    if (perm[k] < 0 || perm[k] >= n || seen[perm[k]]) return Status::kInvalidInput;
    seen[perm[k]] = 1;
    if (colptr[k + 1] <= colptr[k] || rows[colptr[k]] != k) return Status::kInvalidInput;
    for (int32_t p = colptr[k] + 1; p < colptr[k + 1]; ++p)
      if (rows[p] <= k || rows[p] >= n) return Status::kInvalidInput;
  }
  return Status::kOk;
}

void cholesky_solve(int64_t n, const int32_t* perm, const int32_t* colptr, const int32_t* rows,
                    const double* values, const float* b, int64_t k, float* x) {
  std::vector<double> y(static_cast<size_t>(n * k));
  for (int64_t r = 0; r < n; ++r)
    for (int64_t c = 0; c < k; ++c) y[r * k + c] = b[int64_t(perm[r]) * k + c];
  for (int64_t j = 0; j < n; ++j) {  // L y' = y
    double* yj = &y[j * k];
    const double d = values[colptr[j]];
    for (int64_t c = 0; c < k; ++c) yj[c] /= d;
    for (int32_t p = colptr[j] + 1; p < colptr[j + 1]; ++p) {
      double* yi = &y[int64_t(rows[p]) * k];
      for (int64_t c = 0; c < k; ++c) yi[c] -= values[p] * yj[c];
    }
  }
  for (int64_t j = n - 1; j >= 0; --j) {  // L^T z = y'
    double* yj = &y[j * k];
    for (int32_t p = colptr[j] + 1; p < colptr[j + 1]; ++p) {
      const double* yi = &y[int64_t(rows[p]) * k];
      for (int64_t c = 0; c < k; ++c) yj[c] -= values[p] * yi[c];
    }
    const double d = values[colptr[j]];
    for (int64_t c = 0; c < k; ++c) yj[c] /= d;
  }
  for (int64_t r = 0; r < n; ++r)
    for (int64_t c = 0; c < k; ++c) x[int64_t(perm[r]) * k + c] = float(y[r * k + c]);
}

}  // namespace jaxgenus
