// The grouped recursion of bench_riccati_real.py compiled: per interval a block LU over the
// groups G1 | G2 | G3 of the padded block M_k (size NT = NL + NC), the incoming Schur complement
// added first, the trailing NC x NC block passed on; G3's inertia by a Bunch-Kaufman LDL^T of its
// pivot block. Plain C entry points for ctypes. Built by bench_riccati_real.py:
//
//   g++ -std=c++17 -O3 -march=native -shared -fPIC -DB1=12 -DB2=32 -DNL=49 -DNC=15
//       riccati_grouped.cc -o libriccati_grouped.so
//
// Arrays are row-major (C order), F64. Interval i of the arrays is the i-th of the recursion
// (the last interval in time first), as in the JAX scan. Per group [a, b) the pivot block P is
// LU-factored with partial pivoting in place; the columns right of the group that it couples to
// (``cols``) are gathered into compact buffers: Y = P^{-1} M[a:b, cols] replaces M[a:b, cols],
// M[b:, a:b] is kept, and M[cols, cols] -= M[cols, a:b] Y (the pattern is symmetric, so the
// coupled rows are the coupled columns). The solve: forward r[cols] -= M[cols, a:b] P^{-1} r[a:b],
// backward x[a:b] = P^{-1} r[a:b] - Y x[cols].
#include <cmath>
#include <cstdint>
#include <cstring>
#include <utility>

#ifndef B1
#define B1 12
#endif
#ifndef B2
#define B2 32
#endif
#ifndef NL
#define NL 49
#endif
#ifndef NC
#define NC 15
#endif

namespace {

constexpr int nt = NL + NC;
constexpr int bounds[4] = {0, B1, B2, NL};
constexpr int g3 = NL - B2;
constexpr int gmax = B1 > B2 - B1 ? (B1 > g3 ? B1 : g3) : (B2 - B1 > g3 ? B2 - B1 : g3);

// LU with partial pivoting of the block M[a:b, a:b] in place; piv[i] = row swapped with a + i.
bool lu(double* M, int a, int b, int32_t* piv) {
  bool ok = true;
  for (int k = a; k < b; ++k) {
    int p = k;
    double best = std::fabs(M[k * nt + k]);
    for (int i = k + 1; i < b; ++i)
      if (std::fabs(M[i * nt + k]) > best) best = std::fabs(M[i * nt + k]), p = i;
    piv[k - a] = p;
    if (p != k)
      for (int j = a; j < b; ++j) std::swap(M[k * nt + j], M[p * nt + j]);
    const double d = M[k * nt + k];
    if (d == 0.0) { ok = false; continue; }
    for (int i = k + 1; i < b; ++i) {
      const double l = M[i * nt + k] /= d;
      for (int j = k + 1; j < b; ++j) M[i * nt + j] -= l * M[k * nt + j];
    }
  }
  return ok;
}

// x <- P^{-1} x for the LU of M[a:b, a:b].
void lu_solve(const double* M, int a, int b, const int32_t* piv, double* x) {
  for (int k = a; k < b; ++k)
    if (piv[k - a] != k) std::swap(x[k - a], x[piv[k - a] - a]);
  for (int i = a; i < b; ++i)
    for (int k = a; k < i; ++k) x[i - a] -= M[i * nt + k] * x[k - a];
  for (int i = b - 1; i >= a; --i) {
    for (int k = i + 1; k < b; ++k) x[i - a] -= M[i * nt + k] * x[k - a];
    x[i - a] /= M[i * nt + i];
  }
}

// Y <- P^{-1} Y for the LU of P = M[a:b, a:b], Y (b - a) x nc row-major: row operations on
// contiguous rows, which the compiler vectorises.
void solve_compact(const double* M, int a, int b, const int32_t* piv, double* Y, int nc) {
  for (int k = a; k < b; ++k)
    if (piv[k - a] != k)
      for (int c = 0; c < nc; ++c) std::swap(Y[(k - a) * nc + c], Y[(piv[k - a] - a) * nc + c]);
  for (int i = a; i < b; ++i)
    for (int k = a; k < i; ++k) {
      const double l = M[i * nt + k];
      for (int c = 0; c < nc; ++c) Y[(i - a) * nc + c] -= l * Y[(k - a) * nc + c];
    }
  for (int i = b - 1; i >= a; --i) {
    for (int k = i + 1; k < b; ++k) {
      const double u = M[i * nt + k];
      for (int c = 0; c < nc; ++c) Y[(i - a) * nc + c] -= u * Y[(k - a) * nc + c];
    }
    const double d = 1.0 / M[i * nt + i];
    for (int c = 0; c < nc; ++c) Y[(i - a) * nc + c] *= d;
  }
}

// Inertia of the symmetric n x n matrix A (destroyed) by Bunch-Kaufman pivoting.
void inertia_bk(double* A, int n, int64_t* cnt) {
  const double alpha = (1.0 + std::sqrt(17.0)) / 8.0;
  auto at = [&](int i, int j) -> double& { return A[i * n + j]; };
  auto swap_sym = [&](int p, int q) {
    if (p == q) return;
    for (int j = 0; j < n; ++j) std::swap(at(p, j), at(q, j));
    for (int i = 0; i < n; ++i) std::swap(at(i, p), at(i, q));
  };
  int k = 0;
  while (k < n) {
    const double akk = std::fabs(at(k, k));
    int imax = k;
    double colmax = 0.0;
    for (int i = k + 1; i < n; ++i)
      if (std::fabs(at(i, k)) > colmax) colmax = std::fabs(at(i, k)), imax = i;
    if (akk == 0.0 && colmax == 0.0) { ++cnt[2]; ++k; continue; }
    int size = 1, p = k;
    if (akk < alpha * colmax) {
      double rowmax = 0.0;
      for (int j = k; j < n; ++j)
        if (j != imax) rowmax = std::fmax(rowmax, std::fabs(at(imax, j)));
      if (akk * rowmax >= alpha * colmax * colmax) p = k;
      else if (std::fabs(at(imax, imax)) >= alpha * rowmax) p = imax;
      else size = 2, p = imax;
    }
    if (size == 1) {
      swap_sym(k, p);
      const double d = at(k, k);
      ++cnt[d > 0 ? 0 : (d < 0 ? 1 : 2)];
      for (int i = k + 1; i < n; ++i) {
        const double l = at(i, k) / d;
        for (int j = k + 1; j < n; ++j) at(i, j) -= l * at(k, j);
      }
      k += 1;
    } else {
      swap_sym(k + 1, p);
      const double a = at(k, k), b = at(k + 1, k), c = at(k + 1, k + 1), det = a * c - b * b;
      if (det < 0) ++cnt[0], ++cnt[1];
      else if (det > 0) cnt[a + c > 0 ? 0 : 1] += 2;
      else cnt[2] += 2;  // not reached with Bunch-Kaufman's choice
      for (int i = k + 2; i < n; ++i) {
        const double w0 = (c * at(i, k) - b * at(i, k + 1)) / det;
        const double w1 = (a * at(i, k + 1) - b * at(i, k)) / det;
        for (int j = k + 2; j < n; ++j) at(i, j) -= w0 * at(k, j) + w1 * at(k + 1, j);
      }
      k += 2;
    }
  }
}

}  // namespace

extern "C" {

// Factor in place: M (N, nt, nt) the gathered blocks, becomes the factors; piv (N, NL);
// cols (N, 3, nt) and ncols (N, 3): per group, the columns right of it that it couples to;
// inpos (N, NC) slots of the incoming complement, inmask (N, NC); cnt[3] += G3's inertia.
// Returns the number of singular pivot blocks.
int grouped_factor_c(int64_t N, double* M, int32_t* piv, int32_t* cols, int32_t* ncols, const int32_t* inpos,
                     const uint8_t* inmask, int64_t* cnt) {
  int singular = 0;
  double P3[g3 * g3], Y[gmax * nt], L[nt * gmax], T[nt * nt];
  for (int64_t s = 0; s < N; ++s) {
    double* Mk = M + s * nt * nt;
    if (s > 0) {
      const double* S = M + (s - 1) * nt * nt;
      for (int p = 0; p < NC; ++p) {
        if (!inmask[s * NC + p]) continue;
        for (int q = 0; q < NC; ++q)
          if (inmask[s * NC + q]) Mk[inpos[s * NC + p] * nt + inpos[s * NC + q]] += S[(NL + p) * nt + NL + q];
      }
    }
    for (int g = 0; g < 3; ++g) {
      const int a = bounds[g], b = bounds[g + 1], w = b - a;
      if (g == 2) {
        for (int i = 0; i < g3; ++i)
          for (int j = 0; j < g3; ++j) P3[i * g3 + j] = 0.5 * (Mk[(a + i) * nt + a + j] + Mk[(a + j) * nt + a + i]);
        inertia_bk(P3, g3, cnt);
      }
      int32_t* cl = cols + (s * 3 + g) * nt;
      int nc = 0;
      for (int j = b; j < nt; ++j)
        for (int i = a; i < b; ++i)
          if (Mk[i * nt + j] != 0.0) { cl[nc++] = j; break; }
      ncols[s * 3 + g] = nc;
      singular += !lu(Mk, a, b, piv + s * NL + a);
      // the coupled part, compact: Y = M[a:b, cl], L = M[cl, a:b], T = M[cl, cl]
      for (int t = 0; t < w; ++t)
        for (int c = 0; c < nc; ++c) Y[t * nc + c] = Mk[(a + t) * nt + cl[c]];
      for (int c = 0; c < nc; ++c) {
        for (int t = 0; t < w; ++t) L[c * w + t] = Mk[cl[c] * nt + a + t];
        for (int d = 0; d < nc; ++d) T[c * nc + d] = Mk[cl[c] * nt + cl[d]];
      }
      solve_compact(Mk, a, b, piv + s * NL + a, Y, nc);
      for (int c = 0; c < nc; ++c)
        for (int t = 0; t < w; ++t) {
          const double l = L[c * w + t];
          for (int d = 0; d < nc; ++d) T[c * nc + d] -= l * Y[t * nc + d];
        }
      for (int t = 0; t < w; ++t)
        for (int c = 0; c < nc; ++c) Mk[(a + t) * nt + cl[c]] = Y[t * nc + c];
      for (int c = 0; c < nc; ++c)
        for (int d = 0; d < nc; ++d) Mk[cl[c] * nt + cl[d]] = T[c * nc + d];
    }
  }
  return singular;
}

// Solve with the factors: r (N, NL) the right-hand sides in the slots, becomes the solution.
void grouped_solve_c(int64_t N, const double* M, const int32_t* piv, const int32_t* cols, const int32_t* ncols,
                     const int32_t* inpos, const uint8_t* inmask, double* r) {
  double v[nt], rc[NC] = {0};
  for (int64_t s = 0; s < N; ++s) {  // forward
    const double* Mk = M + s * nt * nt;
    std::memcpy(v, r + s * NL, NL * sizeof(double));
    std::memset(v + NL, 0, NC * sizeof(double));
    for (int p = 0; p < NC; ++p)
      if (s > 0 && inmask[s * NC + p]) v[inpos[s * NC + p]] += rc[p];
    for (int g = 0; g < 3; ++g) {
      const int a = bounds[g], b = bounds[g + 1];
      const int32_t* cl = cols + (s * 3 + g) * nt;
      double y[gmax];
      std::memcpy(y, v + a, (b - a) * sizeof(double));
      lu_solve(Mk, a, b, piv + s * NL + a, y);
      for (int c = 0; c < ncols[s * 3 + g]; ++c) {
        double acc = 0.0;
        for (int t = a; t < b; ++t) acc += Mk[cl[c] * nt + t] * y[t - a];
        v[cl[c]] -= acc;
      }
    }
    std::memcpy(r + s * NL, v, NL * sizeof(double));
    std::memcpy(rc, v + NL, NC * sizeof(double));
  }
  double xc[NC] = {0};
  for (int64_t s = N - 1; s >= 0; --s) {  // backward: the first interval in time first
    const double* Mk = M + s * nt * nt;
    std::memcpy(v, r + s * NL, NL * sizeof(double));
    std::memcpy(v + NL, xc, NC * sizeof(double));
    for (int g = 2; g >= 0; --g) {
      const int a = bounds[g], b = bounds[g + 1];
      const int32_t* cl = cols + (s * 3 + g) * nt;
      lu_solve(Mk, a, b, piv + s * NL + a, v + a);
      for (int i = a; i < b; ++i) {
        double acc = 0.0;
        for (int c = 0; c < ncols[s * 3 + g]; ++c) acc += Mk[i * nt + cl[c]] * v[cl[c]];
        v[i] -= acc;
      }
    }
    std::memcpy(r + s * NL, v, NL * sizeof(double));
    for (int p = 0; p < NC; ++p) xc[p] = inmask[s * NC + p] ? v[inpos[s * NC + p]] : 0.0;
  }
}

}  // extern "C"
