// Compiled Riccati factorisation + solve of the synthetic stage data of bench_riccati_floor.py,
// and a plain block-tridiagonal Cholesky factorisation, as XLA FFI handlers and plain C entry
// points (ctypes). Built by bench_riccati_compiled.py:
//
//   g++ -std=c++17 -O3 -march=native -shared -fPIC -I$(jax.ffi.include_dir())
//       -DNX=10 -DNU=5 -DNF=6 -DNI=7 -DNB=44 riccati_floor.cc -o libriccati_floor.so
//
// The block sizes are compile-time constants (the shapes are checked at run time); N is not.
// Arrays are row-major (C order), F64, as JAX lays them out.
//
// Per interval k, z = (x_k [NX], u_k [NU], f_k [NF], x_{k+1} [NX]), "other" = z without f_k:
//   Ht = H_k + G_k^T diag(Sig_k) G_k
//   T1 : z = T1 w + t1, w = z_other, f_k = F_k w + e_k      (forces substituted)
//   H1 = T1^T Ht T1,  D1 = D_k T1,  E = D1[:, x_{k+1}] (LU, partial pivoting)
//   X  = -E^{-1} D1[:, (x_k, u_k)],  c = E^{-1} (d_k - D_k[:, f] e_k)   x_{k+1} = X v + c
//   H2 = [I; X]^T (H1 + diag(0, P_{k+1})) [I; X],  L L^T = H2_uu,  K = L^{-1} H2_ux,
//   P_k = H2_xx - K^T K   (symmetrised), P_N = 0.
// Factorisation flags ok[k] = 1 if H2_uu (k < N), P_0 (k = N) is positive definite, else 0.
// The solve minimises sum_k 1/2 z_k^T Ht_k z_k + g_k^T z_k subject to D_k z_k = d_k and
// f_k = F_k z_other,k + e_k over all x_0..x_N, u, f (x_0 free: x_0 = -P_0^{-1} p_0): a backward
// pass for the linear terms (p_k), then a forward roll-out.
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

#ifndef NX
#define NX 10
#endif
#ifndef NU
#define NU 5
#endif
#ifndef NF
#define NF 6
#endif
#ifndef NI
#define NI 7
#endif
#ifndef NB
#define NB 44
#endif

namespace {

constexpr int nx = NX, nu = NU, nf = NF, ni = NI, nb = NB;
constexpr int nxu = nx + nu, nz = 2 * nx + nu + nf, no = nz - nf, f0 = nxu;

// index in z of the o-th "other" unknown
constexpr int zo(int o) { return o < nxu ? o : o + nf; }

// what the solve needs of one interval's factorisation
struct Stage {
  double X[nx][nxu];
  double LU[nx][nx];
  int piv[nx];
  double Pn[nx][nx];   // P_{k+1}
  double H1x[no][nx];  // H1[:, x_{k+1}]
  double Htf[nz][nf];  // Ht[:, f]
  double kv[nu];
  double c[nx];
};

// Cholesky in place (lower, row-major, n x n with leading dimension ld); false if not PD
template <int n>
bool cholesky(double* A, int ld) {
  bool ok = true;
  for (int j = 0; j < n; ++j) {
    double d = A[j * ld + j];
    for (int r = 0; r < j; ++r) d -= A[j * ld + r] * A[j * ld + r];
    if (!(d > 0.0)) ok = false;
    d = std::sqrt(d);
    A[j * ld + j] = d;
    const double inv = 1.0 / d;
    for (int i = j + 1; i < n; ++i) {
      double s = A[i * ld + j];
      for (int r = 0; r < j; ++r) s -= A[i * ld + r] * A[j * ld + r];
      A[i * ld + j] = s * inv;
    }
    for (int i = 0; i < j; ++i) A[i * ld + j] = 0.0;
  }
  return ok;
}

void lu_factor(double (&A)[nx][nx], int (&piv)[nx]) {
  for (int j = 0; j < nx; ++j) {
    int p = j;
    for (int i = j + 1; i < nx; ++i)
      if (std::fabs(A[i][j]) > std::fabs(A[p][j])) p = i;
    piv[j] = p;
    if (p != j)
      for (int c = 0; c < nx; ++c) std::swap(A[j][c], A[p][c]);
    const double inv = 1.0 / A[j][j];
    for (int i = j + 1; i < nx; ++i) {
      const double l = A[i][j] * inv;
      A[i][j] = l;
      for (int c = j + 1; c < nx; ++c) A[i][c] -= l * A[j][c];
    }
  }
}

// B (nx x m, leading dimension ld) <- A^{-1} B with A's LU
template <int m>
void lu_solve(const double (&A)[nx][nx], const int (&piv)[nx], double* B, int ld) {
  for (int j = 0; j < nx; ++j)
    if (piv[j] != j)
      for (int c = 0; c < m; ++c) std::swap(B[j * ld + c], B[piv[j] * ld + c]);
  for (int i = 0; i < nx; ++i)
    for (int r = 0; r < i; ++r)
      for (int c = 0; c < m; ++c) B[i * ld + c] -= A[i][r] * B[r * ld + c];
  for (int i = nx - 1; i >= 0; --i) {
    for (int r = i + 1; r < nx; ++r)
      for (int c = 0; c < m; ++c) B[i * ld + c] -= A[i][r] * B[r * ld + c];
    const double inv = 1.0 / A[i][i];
    for (int c = 0; c < m; ++c) B[i * ld + c] *= inv;
  }
}

// M T1 for rows M (m, nz): the columns "other" of M plus its force columns times F (f = F z_other)
template <int m>
void substitute_forces(const double (*M)[nz], const double (*F)[no], double (*out)[no]) {
  for (int i = 0; i < m; ++i) {
    for (int b = 0; b < no; ++b) out[i][b] = M[i][zo(b)];
    for (int q = 0; q < nf; ++q) {
      const double a = M[i][f0 + q];
      for (int b = 0; b < no; ++b) out[i][b] += a * F[q][b];
    }
  }
}

// factorisation of all N intervals (backward), storing in st what the solve needs
void riccati_factor(int64_t N, const double* Hs, const double* Gs, const double* Ss, const double* Fs,
                    const double* Ds, Stage* st, double* P0, double* Ls, double* Ks, int32_t* ok) {
  double P[nx][nx] = {};
  for (int64_t k = N - 1; k >= 0; --k) {
    const double(*H)[nz] = reinterpret_cast<const double(*)[nz]>(Hs + k * nz * nz);
    const double(*G)[nz] = reinterpret_cast<const double(*)[nz]>(Gs + k * ni * nz);
    const double* S = Ss + k * ni;
    const double(*F)[no] = reinterpret_cast<const double(*)[no]>(Fs + k * nf * no);
    const double(*D)[nz] = reinterpret_cast<const double(*)[nz]>(Ds + k * nx * nz);
    Stage& s = st[k];
    // Ht = H + G^T S G
    double Ht[nz][nz];
    std::memcpy(Ht, H, sizeof(Ht));
    for (int r = 0; r < ni; ++r)
      for (int i = 0; i < nz; ++i) {
        const double a = S[r] * G[r][i];
        for (int j = 0; j < nz; ++j) Ht[i][j] += a * G[r][j];
      }
    for (int i = 0; i < nz; ++i)
      for (int q = 0; q < nf; ++q) s.Htf[i][q] = Ht[i][f0 + q];
    // R = Ht T1 = Ht[:, o] + Ht[:, f] F ;  H1 = R[o, :] + F^T R[f, :]
    double R[nz][no];
    substitute_forces<nz>(Ht, F, R);
    double H1[no][no];
    for (int a = 0; a < no; ++a) {
      for (int b = 0; b < no; ++b) H1[a][b] = R[zo(a)][b];
      for (int q = 0; q < nf; ++q) {
        const double fa = F[q][a];
        for (int b = 0; b < no; ++b) H1[a][b] += fa * R[f0 + q][b];
      }
    }
    for (int a = 0; a < no; ++a)
      for (int j = 0; j < nx; ++j) s.H1x[a][j] = H1[a][nxu + j];
    // D1 = D[:, o] + D[:, f] F ;  E = D1[:, x'] ;  X = -E^{-1} D1[:, v]
    double D1[nx][no];
    substitute_forces<nx>(D, F, D1);
    for (int i = 0; i < nx; ++i) {
      for (int j = 0; j < nx; ++j) s.LU[i][j] = D1[i][nxu + j];
      for (int m = 0; m < nxu; ++m) s.X[i][m] = -D1[i][m];
    }
    lu_factor(s.LU, s.piv);
    lu_solve<nxu>(s.LU, s.piv, &s.X[0][0], nxu);
    // recursion: C = H1_x'x' + P ; Z = H1_vx'^T + C X ; H2 = H1_vv + H1_vx' X + X^T Z
    std::memcpy(s.Pn, P, sizeof(P));
    double C[nx][nx], Z[nx][nxu], H2[nxu][nxu];
    for (int i = 0; i < nx; ++i)
      for (int j = 0; j < nx; ++j) C[i][j] = H1[nxu + i][nxu + j] + P[i][j];
    for (int i = 0; i < nx; ++i) {
      for (int m = 0; m < nxu; ++m) Z[i][m] = H1[nxu + i][m];
      for (int j = 0; j < nx; ++j) {
        const double a = C[i][j];
        for (int m = 0; m < nxu; ++m) Z[i][m] += a * s.X[j][m];
      }
    }
    for (int a = 0; a < nxu; ++a) {
      for (int b = 0; b < nxu; ++b) H2[a][b] = H1[a][b];
      for (int j = 0; j < nx; ++j) {
        const double h = H1[a][nxu + j], xj = s.X[j][a];
        for (int b = 0; b < nxu; ++b) H2[a][b] += h * s.X[j][b] + xj * Z[j][b];
      }
    }
    double* L = Ls + k * nu * nu;
    double* K = Ks + k * nu * nx;
    for (int i = 0; i < nu; ++i)
      for (int j = 0; j < nu; ++j) L[i * nu + j] = H2[nx + i][nx + j];
    ok[k] = cholesky<nu>(L, nu) ? 1 : 0;
    // K = L^{-1} H2_ux
    for (int i = 0; i < nu; ++i) {
      for (int j = 0; j < nx; ++j) K[i * nx + j] = H2[nx + i][j];
      for (int r = 0; r < i; ++r) {
        const double l = L[i * nu + r];
        for (int j = 0; j < nx; ++j) K[i * nx + j] -= l * K[r * nx + j];
      }
      const double inv = 1.0 / L[i * nu + i];
      for (int j = 0; j < nx; ++j) K[i * nx + j] *= inv;
    }
    // P = H2_xx - K^T K, symmetrised
    double Pt[nx][nx];
    for (int i = 0; i < nx; ++i)
      for (int j = 0; j < nx; ++j) Pt[i][j] = H2[i][j];
    for (int r = 0; r < nu; ++r)
      for (int i = 0; i < nx; ++i) {
        const double a = K[r * nx + i];
        for (int j = 0; j < nx; ++j) Pt[i][j] -= a * K[r * nx + j];
      }
    for (int i = 0; i < nx; ++i)
      for (int j = 0; j < nx; ++j) P[i][j] = 0.5 * (Pt[i][j] + Pt[j][i]);
  }
  std::memcpy(P0, P, sizeof(P));
}

void riccati_solve(int64_t N, const double* Fs, const double* Ds, const double* gs, const double* ds,
                   const double* es, Stage* st, const double* P0, const double* Ls, const double* Ks, int32_t* ok,
                   double* xs, double* us, double* fs) {
  double p[nx] = {};
  for (int64_t k = N - 1; k >= 0; --k) {
    const double(*F)[no] = reinterpret_cast<const double(*)[no]>(Fs + k * nf * no);
    const double(*D)[nz] = reinterpret_cast<const double(*)[nz]>(Ds + k * nx * nz);
    const double* g = gs + k * nz;
    const double* e = es + k * nf;
    Stage& s = st[k];
    // y = Ht t1 + g = Ht[:, f] e + g ;  g1 = y[o] + F^T y[f]
    double y[nz], g1[no];
    for (int i = 0; i < nz; ++i) {
      double a = g[i];
      for (int q = 0; q < nf; ++q) a += s.Htf[i][q] * e[q];
      y[i] = a;
    }
    for (int b = 0; b < no; ++b) g1[b] = y[zo(b)];
    for (int q = 0; q < nf; ++q)
      for (int b = 0; b < no; ++b) g1[b] += F[q][b] * y[f0 + q];
    // c = E^{-1} (d - D[:, f] e)
    for (int i = 0; i < nx; ++i) {
      double a = ds[k * nx + i];
      for (int q = 0; q < nf; ++q) a -= D[i][f0 + q] * e[q];
      s.c[i] = a;
    }
    lu_solve<1>(s.LU, s.piv, s.c, 1);
    // w = H1[:, x'] c + g1 + (0, P c + p) ;  h = w[v] + X^T w[x']
    double w[no], h[nxu];
    for (int a = 0; a < no; ++a) {
      double t = g1[a];
      for (int j = 0; j < nx; ++j) t += s.H1x[a][j] * s.c[j];
      w[a] = t;
    }
    for (int i = 0; i < nx; ++i) {
      double t = p[i];
      for (int j = 0; j < nx; ++j) t += s.Pn[i][j] * s.c[j];
      w[nxu + i] += t;
    }
    for (int m = 0; m < nxu; ++m) h[m] = w[m];
    for (int j = 0; j < nx; ++j)
      for (int m = 0; m < nxu; ++m) h[m] += s.X[j][m] * w[nxu + j];
    // kv = L^{-1} h_u ;  p = h_x - K^T kv
    const double* L = Ls + k * nu * nu;
    const double* K = Ks + k * nu * nx;
    for (int i = 0; i < nu; ++i) {
      double t = h[nx + i];
      for (int r = 0; r < i; ++r) t -= L[i * nu + r] * s.kv[r];
      s.kv[i] = t / L[i * nu + i];
    }
    for (int i = 0; i < nx; ++i) {
      double t = h[i];
      for (int r = 0; r < nu; ++r) t -= K[r * nx + i] * s.kv[r];
      p[i] = t;
    }
  }
  // x_0 = -P_0^{-1} p_0
  double LP[nx * nx];
  std::memcpy(LP, P0, sizeof(LP));
  ok[N] = cholesky<nx>(LP, nx) ? 1 : 0;
  double* x = xs;
  for (int i = 0; i < nx; ++i) {
    double t = -p[i];
    for (int r = 0; r < i; ++r) t -= LP[i * nx + r] * x[r];
    x[i] = t / LP[i * nx + i];
  }
  for (int i = nx - 1; i >= 0; --i) {
    double t = x[i];
    for (int r = i + 1; r < nx; ++r) t -= LP[r * nx + i] * x[r];
    x[i] = t / LP[i * nx + i];
  }
  for (int64_t k = 0; k < N; ++k) {
    const double(*F)[no] = reinterpret_cast<const double(*)[no]>(Fs + k * nf * no);
    const double* L = Ls + k * nu * nu;
    const double* K = Ks + k * nu * nx;
    const Stage& s = st[k];
    const double* xk = xs + k * nx;
    double* xn = xs + (k + 1) * nx;
    double* u = us + k * nu;
    // u = -L^{-T} (K x + kv)
    double t[nu];
    for (int i = 0; i < nu; ++i) {
      double a = s.kv[i];
      for (int j = 0; j < nx; ++j) a += K[i * nx + j] * xk[j];
      t[i] = -a;
    }
    for (int i = nu - 1; i >= 0; --i) {
      double a = t[i];
      for (int r = i + 1; r < nu; ++r) a -= L[r * nu + i] * u[r];
      u[i] = a / L[i * nu + i];
    }
    // x' = X (x, u) + c ;  f = F (x, u, x') + e
    for (int i = 0; i < nx; ++i) {
      double a = s.c[i];
      for (int m = 0; m < nx; ++m) a += s.X[i][m] * xk[m];
      for (int m = 0; m < nu; ++m) a += s.X[i][nx + m] * u[m];
      xn[i] = a;
    }
    for (int q = 0; q < nf; ++q) {
      double a = es[k * nf + q];
      for (int m = 0; m < nx; ++m) a += F[q][m] * xk[m];
      for (int m = 0; m < nu; ++m) a += F[q][nx + m] * u[m];
      for (int m = 0; m < nx; ++m) a += F[q][nxu + m] * xn[m];
      fs[k * nf + q] = a;
    }
  }
}

std::vector<Stage>& workspace(int64_t N) {
  thread_local std::vector<Stage> ws;
  if (static_cast<int64_t>(ws.size()) < N) ws.resize(N);
  return ws;
}

// plain block-tridiagonal Cholesky: L_0 = chol(A_0), W = L_{k-1}^{-1} B_k^T, L_k = chol(A_k - W^T W)
bool block_cholesky(int64_t N1, const double* As, const double* Bs, double* Ls) {
  bool ok = true;
  std::memcpy(Ls, As, sizeof(double) * nb * nb);
  ok &= cholesky<nb>(Ls, nb);
  for (int64_t k = 1; k < N1; ++k) {
    const double* Lp = Ls + (k - 1) * nb * nb;
    const double* B = Bs + k * nb * nb;
    double* Lk = Ls + k * nb * nb;
    double W[nb][nb];
    for (int i = 0; i < nb; ++i) {
      for (int j = 0; j < nb; ++j) W[i][j] = B[j * nb + i];
      for (int r = 0; r < i; ++r) {
        const double l = Lp[i * nb + r];
        for (int j = 0; j < nb; ++j) W[i][j] -= l * W[r][j];
      }
      const double inv = 1.0 / Lp[i * nb + i];
      for (int j = 0; j < nb; ++j) W[i][j] *= inv;
    }
    std::memcpy(Lk, As + k * nb * nb, sizeof(double) * nb * nb);
    for (int r = 0; r < nb; ++r)
      for (int i = 0; i < nb; ++i) {
        const double a = W[r][i];
        for (int j = 0; j <= i; ++j) Lk[i * nb + j] -= a * W[r][j];
      }
    ok &= cholesky<nb>(Lk, nb);
  }
  return ok;
}

}  // namespace

// ---- plain C entry points (ctypes) ----

extern "C" int riccati_sizes(int* out) {
  out[0] = nx, out[1] = nu, out[2] = nf, out[3] = ni, out[4] = nb;
  return 0;
}

extern "C" int riccati_c(int64_t N, const double* H, const double* G, const double* S, const double* F,
                         const double* D, const double* g, const double* d, const double* e, double* P0, double* L,
                         double* K, int32_t* ok, double* xs, double* us, double* fs, int do_solve) {
  Stage* st = workspace(N).data();
  riccati_factor(N, H, G, S, F, D, st, P0, L, K, ok);
  if (do_solve) riccati_solve(N, F, D, g, d, e, st, P0, L, K, ok, xs, us, fs);
  return 0;
}

extern "C" int block_cholesky_c(int64_t N1, const double* A, const double* B, double* L) {
  return block_cholesky(N1, A, B, L) ? 0 : 1;
}

// ---- XLA FFI handlers ----

namespace {

using B64 = ffi::Buffer<ffi::F64>;
using R64 = ffi::ResultBuffer<ffi::F64>;

bool shape_is(const B64& b, std::initializer_list<int64_t> dims) {
  auto d = b.dimensions();
  if (d.size() != dims.size()) return false;
  size_t i = 0;
  for (int64_t v : dims)
    if (d[i++] != v) return false;
  return true;
}

ffi::Error RiccatiImpl(B64 H, B64 G, B64 S, B64 F, B64 D, B64 g, B64 d, B64 e, R64 P0, R64 L, R64 K,
                       ffi::ResultBuffer<ffi::S32> ok, R64 xs, R64 us, R64 fs, int64_t do_solve) {
  const int64_t N = H.dimensions().size() == 3 ? H.dimensions()[0] : -1;
  if (!(shape_is(H, {N, nz, nz}) && shape_is(G, {N, ni, nz}) && shape_is(S, {N, ni}) && shape_is(F, {N, nf, no}) &&
        shape_is(D, {N, nx, nz}) && shape_is(g, {N, nz}) && shape_is(d, {N, nx}) && shape_is(e, {N, nf})))
    return ffi::Error::InvalidArgument("riccati: shapes differ from the compiled sizes NX, NU, NF, NI");
  riccati_c(N, H.typed_data(), G.typed_data(), S.typed_data(), F.typed_data(), D.typed_data(), g.typed_data(),
            d.typed_data(), e.typed_data(), P0->typed_data(), L->typed_data(), K->typed_data(), ok->typed_data(),
            xs->typed_data(), us->typed_data(), fs->typed_data(), static_cast<int>(do_solve));
  return ffi::Error::Success();
}

ffi::Error BlockCholeskyImpl(B64 A, B64 B, R64 L) {
  const int64_t N1 = A.dimensions().size() == 3 ? A.dimensions()[0] : -1;
  if (!(shape_is(A, {N1, nb, nb}) && shape_is(B, {N1, nb, nb})))
    return ffi::Error::InvalidArgument("block_cholesky: shapes differ from the compiled NB");
  block_cholesky(N1, A.typed_data(), B.typed_data(), L->typed_data());
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(Riccati, RiccatiImpl,
                              ffi::Ffi::Bind()
                                  .Arg<B64>()
                                  .Arg<B64>()
                                  .Arg<B64>()
                                  .Arg<B64>()
                                  .Arg<B64>()
                                  .Arg<B64>()
                                  .Arg<B64>()
                                  .Arg<B64>()
                                  .Ret<B64>()
                                  .Ret<B64>()
                                  .Ret<B64>()
                                  .Ret<ffi::Buffer<ffi::S32>>()
                                  .Ret<B64>()
                                  .Ret<B64>()
                                  .Ret<B64>()
                                  .Attr<int64_t>("do_solve"));

XLA_FFI_DEFINE_HANDLER_SYMBOL(BlockCholesky, BlockCholeskyImpl,
                              ffi::Ffi::Bind().Arg<B64>().Arg<B64>().Ret<B64>());
