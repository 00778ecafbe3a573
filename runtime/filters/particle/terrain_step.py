"""One compiled call per step of the terrain-aided navigation SIR (seed 003, Fig. 5).

The step of ``TerrainParticleFilter`` -- body and environment noise draws, the generated arc step
``tan3dof_f`` (its SIMD kernel, called through a function pointer), the compiled map lookup, the
Gaussian altimeter likelihood, normalisation, ESS, the weighted moments, the weighted slope the
fuzzy logic needs, and systematic resampling -- is one C function of the runtime
(``terrain_sir_step``), built through the same cache as the generated models. Python keeps the
contract checks and the fuzzy inputs' window (a few scalars per step).

Random numbers. The step draws its own: 8 independent xoshiro256++ streams (Blackman & Vigna,
2018), one per SIMD lane, seeded once from the filter's numpy Generator (4 x 8 words; an all-zero
lane, probability 2^-256, is refused). Uniforms in [0, 1) take the top 52 bits; normals come from
the Box-Muller transform of pairs (sqrt(-2 log(1 - u1)) cos/sin(2 pi u2), |n| <= 8.5), evaluated in
single precision (each normal to ~1e-6 relative: far below any noise model's own uncertainty). NumPy's
generator costs ~10 ns per normal from Python, the 4 N normals of a step more than the whole rest of
it. ``normals()`` below exposes the stream for the statistical tests.

Memory. The first phase (draws, move, compass, lookup, log-likelihood) runs in blocks of 2048
particles, so its intermediates stay in cache; the later passes (normalisation, moments,
resampling) stream the whole cloud. At 10^6 particles the step is bound by memory bandwidth.

Transactions. Every buffer the step writes is scratch or belongs to the "next" side of a pair:
particles, log-weights, weights, moments and the random state exist twice, the step reads side s
and writes side 1 - s, and a committed step flips s. A refused step leaves side s untouched.

Test hook: with ``draw = False`` the step uses the caller's noise (4, N) and resampling uniform
instead of drawing, so it can be compared with an independent NumPy implementation.
"""
from __future__ import annotations

import ctypes
import math
from functools import lru_cache

import numpy as np

from ...terrain.kernel import lookup_address

#: SIMD lanes = independent random streams
LANES = 8

SOURCE = r"""
/* Fused SIR step of terrain-aided navigation (abyssal.runtime.filters.particle.terrain_step). */
#include <math.h>
#include <stdint.h>
#include <string.h>
#if defined(__x86_64__) && defined(__GLIBC__) && !defined(ABYSSAL_NO_LIBMVEC)
#pragma omp declare simd notinbranch
extern double sin(double) __attribute__((const));
#pragma omp declare simd notinbranch
extern double cos(double) __attribute__((const));
#pragma omp declare simd notinbranch
extern double log(double) __attribute__((const));
#pragma omp declare simd notinbranch
extern double exp(double) __attribute__((const));
#pragma omp declare simd notinbranch
extern float logf(float) __attribute__((const));
#pragma omp declare simd notinbranch
extern float sinf(float) __attribute__((const));
#pragma omp declare simd notinbranch
extern float cosf(float) __attribute__((const));
#endif

/* 512-bit vectors where the CPU has them: the transcendental loops (Box-Muller, weights) run ~1.3x faster */
#if defined(__AVX512F__) && defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#pragma GCC target("prefer-vector-width=512")
#endif
#define LANES 8
#define BLOCK 2048  /* particles per block of the step's first phase (~300 kB of intermediates: in L2) */
typedef long long idx;
typedef int (*soa_fn)(idx n, idx ld, const double** arg, double** res);

/* abyssal.runtime.terrain.kernel's terrain_bilinear, called through a pointer (its own library) */
typedef void (*bilinear_fn)(idx n, const double* px, const double* py, const double* grid, idx nx, idx ny,
                            double x0, double y0, double inv_res, double* depth, double* gx, double* gy,
                            double* inside);

/* scalars[]: inputs of one step */
enum { S_V, S_OMEGA, S_DT, S_SIGMA, S_Z_DEPTH, S_Z_HEADING, S_MOVE, S_DEPTH, S_HEADING, S_SLOPE, S_DRAW, S_UNIFORM,
       S_A1, S_A2, S_A3, S_A4, S_INV_ALTIMETER_SIGMA, S_OUT_OF_MAP_LOG_LIKELIHOOD, S_RESAMPLE_BELOW, S_COUNT };
/* moments[]: outputs */
enum { M_X = 0, M_P = 3, M_ESS = 12, M_SLOPE = 13, M_RESAMPLED = 14, M_COUNT = 15 };

typedef struct {
  idx n;
  soa_fn f;                               /* tan3dof_f_soa */
  bilinear_fn lookup;                     /* terrain_bilinear */
  const double* p;                        /* model parameters (current) */
  const double* grid; idx nx, ny; double x0, y0, inv_res;
  double* u;                              /* (2, n) scratch: per-particle [v, omega] */
  double* noise;                          /* (4, n): n_v, n_omega, e_x, e_y */
  double* uniforms;                       /* (>= 2 n, padded) scratch: a block's uniforms, the CDF */
  double* proposed;                       /* (3, n) scratch: the proposals resampling gathers from */
  double* depth; double* gx; double* gy; double* inside;   /* (n) each */
  const double* dt;                       /* the model's dt buffer (1) */
  /* side read -> side written */
  const double* particles; double* particles_next;     /* (3, n) */
  const double* log_w; double* log_w_next;             /* (n) */
  double* w_next;                                      /* (n) */
  double* moments_next;                                /* (M_COUNT) */
  const uint64_t* rng; uint64_t* rng_next;             /* (4 * LANES) */
} terrain_step_t;

static inline uint64_t rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

/* n (a multiple of LANES) uniforms in [0, 1) from LANES xoshiro256++ streams, state s[4][LANES] advanced. */
static void uniforms(uint64_t* restrict s, idx n, double* restrict out) {
  uint64_t s0[LANES], s1[LANES], s2[LANES], s3[LANES];
  memcpy(s0, s, sizeof s0); memcpy(s1, s + LANES, sizeof s1);
  memcpy(s2, s + 2 * LANES, sizeof s2); memcpy(s3, s + 3 * LANES, sizeof s3);
  for (idx i = 0; i < n; i += LANES) {
#pragma omp simd
    for (int l = 0; l < LANES; ++l) {
      uint64_t r = rotl(s0[l] + s3[l], 23) + s0[l];
      uint64_t t = s1[l] << 17;
      s2[l] ^= s0[l]; s3[l] ^= s1[l]; s1[l] ^= s2[l]; s0[l] ^= s3[l];
      s2[l] ^= t; s3[l] = rotl(s3[l], 45);
      uint64_t bits = (r >> 12) | UINT64_C(0x3FF0000000000000);  /* 1 + 52 random bits of mantissa */
      double d;
      memcpy(&d, &bits, sizeof d);
      out[i + l] = d - 1.0;
    }
  }
  memcpy(s, s0, sizeof s0); memcpy(s + LANES, s1, sizeof s1);
  memcpy(s + 2 * LANES, s2, sizeof s2); memcpy(s + 3 * LANES, s3, sizeof s3);
}

/* 2 * pairs standard normals (Box-Muller) into a[0..pairs) and b[0..pairs); scratch u of >= 2 pairs, padded.
 * log, sqrt, sin and cos in single precision (16 lanes per 512-bit vector, twice the double rate): each
 * normal to ~1e-6 relative, the tail still reaching sqrt(-2 log 2^-52) = 8.5 (1 - u is rounded to float
 * after the double subtraction, and float holds 2^-52). */
static void normals(uint64_t* restrict s, idx pairs, double* restrict u, double* restrict a, double* restrict b) {
  idx n = (2 * pairs + LANES - 1) / LANES * LANES;
  uniforms(s, n, u);
  const double* restrict u2 = u + pairs;
#pragma omp simd
  for (idx k = 0; k < pairs; ++k) {
    float r = sqrtf(-2.0f * logf((float)(1.0 - u[k])));
    float angle = (float)(6.283185307179586 * u2[k]);
    a[k] = (double)(r * cosf(angle));
    b[k] = (double)(r * sinf(angle));
  }
}

/* The exported stream, for tests: 2 * pairs normals into out (pairs first halves, then second halves). */
void terrain_normals(uint64_t* s, idx pairs, double* scratch, double* out) { normals(s, pairs, scratch, out, out + pairs); }

/* One SIR step. Returns 0, 1 when a particle is not finite, 2 when no weight is left. */
int terrain_sir_step(const terrain_step_t* t, const double* restrict sc) {
  const idx n = t->n;
  /* the proposals are written straight into the next side (resampling gathers them from a scratch copy) */
  double* x = t->particles_next;
  double* y = t->particles_next + n;
  double* th = t->particles_next + 2 * n;
  double* restrict noise = t->noise;
  uint64_t state[4 * LANES];
  memcpy(state, t->rng, sizeof state);
  const int move = sc[S_MOVE] != 0.0, draw = sc[S_DRAW] != 0.0, heading_present = sc[S_HEADING] != 0.0;
  const int depth_present = sc[S_DEPTH] != 0.0, slope = sc[S_SLOPE] != 0.0;
  const double v = sc[S_V], om = sc[S_OMEGA], sigma = sc[S_SIGMA];
  const double sd_v = sqrt(sc[S_A1] * v * v + sc[S_A2] * om * om);     /* eq. 2 */
  const double sd_om = sqrt(sc[S_A3] * v * v + sc[S_A4] * om * om);
  const double z = sc[S_Z_DEPTH], inv_sd = sc[S_INV_ALTIMETER_SIGMA], out_ll = sc[S_OUT_OF_MAP_LOG_LIKELIHOOD];
  const double* restrict lw = t->log_w;
  double* restrict lw_next = t->log_w_next;
  double* restrict w = t->w_next;
  double peak = -INFINITY;
  /* Phase 1 -- draws, move, compass, lookup, log-likelihood -- in blocks of BLOCK particles, so its
   * intermediates (uniforms, noise, inputs, lookups) stay in cache for large n. */
  for (idx b0 = 0; b0 < n; b0 += BLOCK) {
    const idx nb = n - b0 < BLOCK ? n - b0 : BLOCK;
    double* xb = x + b0;
    double* yb = y + b0;
    double* thb = th + b0;
    if (move) {
      double* restrict nv = noise + b0;
      double* restrict nom = noise + n + b0;
      double* restrict ex = noise + 2 * n + b0;
      double* restrict ey = noise + 3 * n + b0;
      if (draw) {
        normals(state, nb, t->uniforms, nv, nom);
        normals(state, nb, t->uniforms, ex, ey);
      }
      double* restrict uv = t->u + b0;
      double* restrict uo = t->u + n + b0;
#pragma omp simd
      for (idx j = 0; j < nb; ++j) {
        uv[j] = v + sd_v * nv[j];
        uo[j] = om + sd_om * nom[j];
      }
      const double* arg[4] = {t->particles + b0, t->u + b0, t->p, t->dt};
      double* res[1] = {xb};
      t->f(nb, n, arg, res);                                             /* rows of length n: ld = n */
      if (sigma > 0.0) {                                                 /* eq. 3 */
#pragma omp simd
        for (idx j = 0; j < nb; ++j) {
          xb[j] += sigma * ex[j];
          yb[j] += sigma * ey[j];
        }
      }
    } else {
      for (int r = 0; r < 3; ++r) memcpy(t->particles_next + r * n + b0, t->particles + r * n + b0, nb * sizeof(double));
    }
    if (heading_present) {
      const double heading = sc[S_Z_HEADING];
      for (idx j = 0; j < nb; ++j) thb[j] = heading;
    }
    if (depth_present || slope)
      t->lookup(nb, xb, yb, t->grid, t->nx, t->ny, t->x0, t->y0, t->inv_res, t->depth + b0, t->gx + b0,
                       t->gy + b0, t->inside + b0);
    /* weights: log w += log N(z; map(x, y), sigma^2) up to a constant; outside the map: a fixed residual */
    const double* restrict lwb = lw + b0;
    double* restrict lwnb = lw_next + b0;
    if (depth_present) {
      const double* restrict depth = t->depth + b0;
      const double* restrict inside = t->inside + b0;
#pragma omp simd reduction(max:peak)
      for (idx j = 0; j < nb; ++j) {
        double r = (z - depth[j]) * inv_sd;
        double value = lwb[j] + (inside[j] > 0.0 ? -0.5 * r * r : out_ll);
        lwnb[j] = value;
        peak = value > peak ? value : peak;
      }
    } else {
#pragma omp simd reduction(max:peak)
      for (idx j = 0; j < nb; ++j) {
        lwnb[j] = lwb[j];
        peak = lwb[j] > peak ? lwb[j] : peak;
      }
    }
  }
  if (!(peak > -INFINITY && peak < INFINITY)) return 2;
  double total = 0.0;
#pragma omp simd reduction(+:total)
  for (idx j = 0; j < n; ++j) {
    w[j] = exp(lw_next[j] - peak);
    total += w[j];
  }
  const double shift = peak + log(total);
  double sum_sq = 0.0, mx = 0.0, my = 0.0, mt = 0.0, check = 0.0;  /* x - x is NaN exactly when x is inf or NaN */
#pragma omp simd reduction(+:sum_sq, mx, my, mt, check)
  for (idx j = 0; j < n; ++j) {
    w[j] /= total;
    lw_next[j] -= shift;
    sum_sq += w[j] * w[j];
    mx += w[j] * x[j];
    my += w[j] * y[j];
    mt += w[j] * th[j];
    check += (x[j] - x[j]) + (y[j] - y[j]) + (th[j] - th[j]);
  }
  if (check != 0.0) return 1;  /* (the lookup clamps a non-finite point, so the weights above stay finite) */
  double pxx = 0.0, pxy = 0.0, pxt = 0.0, pyy = 0.0, pyt = 0.0, ptt = 0.0, sl = 0.0;
  if (slope && !heading_present) {
    const double* restrict gx = t->gx;
    const double* restrict gy = t->gy;
#pragma omp simd reduction(+:pxx, pxy, pxt, pyy, pyt, ptt, sl)
    for (idx j = 0; j < n; ++j) {
      double dx = x[j] - mx, dy = y[j] - my, dt_ = th[j] - mt;
      pxx += w[j] * dx * dx; pxy += w[j] * dx * dy; pxt += w[j] * dx * dt_;
      pyy += w[j] * dy * dy; pyt += w[j] * dy * dt_; ptt += w[j] * dt_ * dt_;
      sl += w[j] * (gx[j] * cos(th[j]) + gy[j] * sin(th[j]));
    }
  } else if (slope) {  /* every particle has the compass heading: its cos and sin once */
    const double* restrict gx = t->gx;
    const double* restrict gy = t->gy;
    double sx = 0.0, sy = 0.0;
#pragma omp simd reduction(+:pxx, pxy, pxt, pyy, pyt, ptt, sx, sy)
    for (idx j = 0; j < n; ++j) {
      double dx = x[j] - mx, dy = y[j] - my, dt_ = th[j] - mt;
      pxx += w[j] * dx * dx; pxy += w[j] * dx * dy; pxt += w[j] * dx * dt_;
      pyy += w[j] * dy * dy; pyt += w[j] * dy * dt_; ptt += w[j] * dt_ * dt_;
      sx += w[j] * gx[j];
      sy += w[j] * gy[j];
    }
    sl = sx * cos(sc[S_Z_HEADING]) + sy * sin(sc[S_Z_HEADING]);
  } else {
#pragma omp simd reduction(+:pxx, pxy, pxt, pyy, pyt, ptt)
    for (idx j = 0; j < n; ++j) {
      double dx = x[j] - mx, dy = y[j] - my, dt_ = th[j] - mt;
      pxx += w[j] * dx * dx; pxy += w[j] * dx * dy; pxt += w[j] * dx * dt_;
      pyy += w[j] * dy * dy; pyt += w[j] * dy * dt_; ptt += w[j] * dt_ * dt_;
    }
  }
  double* m = t->moments_next;
  const double ess = 1.0 / sum_sq;
  m[M_X] = mx; m[M_X + 1] = my; m[M_X + 2] = mt;
  m[M_P] = pxx; m[M_P + 1] = pxy; m[M_P + 2] = pxt;
  m[M_P + 3] = pxy; m[M_P + 4] = pyy; m[M_P + 5] = pyt;
  m[M_P + 6] = pxt; m[M_P + 7] = pyt; m[M_P + 8] = ptt;
  m[M_ESS] = ess;
  m[M_SLOPE] = sl;
  if (ess < sc[S_RESAMPLE_BELOW]) {
    /* systematic: u_k = (k + u0) / n against the normalised cumulative weights; ancestor = first i with cdf[i] > u_k */
    double u0;
    if (sc[S_DRAW] != 0.0) {
      double block[LANES];
      uniforms(state, LANES, block);
      u0 = block[0];
    } else {
      u0 = sc[S_UNIFORM];
    }
    double* restrict cdf = t->uniforms;
    double c = 0.0;
    for (idx j = 0; j < n; ++j) { c += w[j]; cdf[j] = c; }
#pragma omp simd
    for (idx j = 0; j < n; ++j) cdf[j] /= c;
    double* restrict from = t->proposed;
    memcpy(from, t->particles_next, 3 * n * sizeof(double));
    double* restrict out = t->particles_next;
    idx i = 0;
    const double log_uniform = -log((double)n);
    for (idx k = 0; k < n; ++k) {
      const double target = ((double)k + u0) / (double)n;
      while (i < n - 1 && cdf[i] <= target) ++i;
      out[k] = from[i]; out[n + k] = from[n + i]; out[2 * n + k] = from[2 * n + i];
      lw_next[k] = log_uniform;
    }
    m[M_RESAMPLED] = 1.0;
  } else {
    m[M_RESAMPLED] = 0.0;
  }
  memcpy(t->rng_next, state, sizeof state);
  return 0;
}
"""


@lru_cache(maxsize=1)
def _library() -> ctypes.CDLL:
    from abyssal.generated.build import build

    lib = ctypes.CDLL(str(build("terrain_sir", {"terrain_sir_soa.c": SOURCE})))
    lib.terrain_sir_step.restype = ctypes.c_int
    lib.terrain_sir_step.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    lib.terrain_normals.restype = None
    return lib


# indices of the scalars and moments arrays (the enums of the C source)
(S_V, S_OMEGA, S_DT, S_SIGMA, S_Z_DEPTH, S_Z_HEADING, S_MOVE, S_DEPTH, S_HEADING, S_SLOPE, S_DRAW, S_UNIFORM,
 S_A1, S_A2, S_A3, S_A4, S_INV_ALTIMETER_SIGMA, S_OUT_OF_MAP_LOG_LIKELIHOOD, S_RESAMPLE_BELOW, S_COUNT) = range(20)
M_X, M_P, M_ESS, M_SLOPE, M_RESAMPLED, M_COUNT = 0, 3, 12, 13, 14, 15


class _Step(ctypes.Structure):
    _fields_ = [("n", ctypes.c_longlong), ("f", ctypes.c_void_p), ("lookup", ctypes.c_void_p), ("p", ctypes.c_void_p),
                ("grid", ctypes.c_void_p),
                ("nx", ctypes.c_longlong), ("ny", ctypes.c_longlong), ("x0", ctypes.c_double), ("y0", ctypes.c_double),
                ("inv_res", ctypes.c_double)] + [(name, ctypes.c_void_p) for name in (
                    "u", "noise", "uniforms", "proposed", "depth", "gx", "gy", "inside", "dt", "particles",
                    "particles_next", "log_w", "log_w_next", "w_next", "moments_next", "rng", "rng_next")]


def seed_streams(rng: np.random.Generator) -> np.ndarray:
    """(4 * LANES,) uint64 xoshiro256++ state drawn from a numpy Generator (lane-major: word k of lane l at k * LANES + l)."""
    state = rng.integers(0, 2 ** 64, size=4 * LANES, dtype=np.uint64, endpoint=False)
    if (state.reshape(4, LANES) == 0).all(axis=0).any():
        raise ValueError("an all-zero xoshiro256++ lane was drawn (probability 2^-256): use another seed")
    return state


def normals(state: np.ndarray, count: int) -> np.ndarray:
    """`count` (even) standard normals from the step's stream, advancing `state` in place (for tests)."""
    if count % 2 or count < 0:
        raise ValueError(f"count must be even and non-negative, got {count}")
    if not (isinstance(state, np.ndarray) and state.dtype == np.uint64 and state.shape == (4 * LANES,)
            and state.flags.c_contiguous and state.flags.writeable):
        raise ValueError(f"state must be a writeable contiguous uint64 array of shape ({4 * LANES},)")
    pairs = count // 2
    out = np.empty(count)
    scratch = np.empty((2 * pairs + LANES - 1) // LANES * LANES + LANES)
    _library().terrain_normals(state.ctypes.data_as(ctypes.c_void_p), ctypes.c_longlong(pairs),
                               scratch.ctypes.data_as(ctypes.c_void_p), out.ctypes.data_as(ctypes.c_void_p))
    return out


class TerrainStep:
    """The compiled step bound to one filter's buffers (both sides of every state buffer).

    ``step(side)`` reads side ``side`` and writes side ``1 - side``; returns the C status
    (0 ok, 1 non-finite particle, 2 no weight left). Fill ``scalars`` first (S_* indices, then p).
    """

    def __init__(self, f_soa_address: int, n_p: int, terrain, n: int, body_noise, altimeter_sigma: float,
                 out_of_map_log_likelihood: float, resample_below: float):
        self.n = n
        #: the step's inputs: scalars[:S_COUNT] (S_* indices), then the model parameters p (n_p); the
        #: model's dt is scalars[S_DT]. Everything a step takes is written with two slice assignments.
        self.scalars = np.zeros(S_COUNT + n_p)
        self.p = self.scalars[S_COUNT:]
        self.scalars[[S_A1, S_A2, S_A3, S_A4]] = body_noise
        self.scalars[S_INV_ALTIMETER_SIGMA] = 1.0 / altimeter_sigma
        self.scalars[S_OUT_OF_MAP_LOG_LIKELIHOOD] = out_of_map_log_likelihood
        self.scalars[S_RESAMPLE_BELOW] = resample_below
        self.scalars[S_DRAW] = 1.0
        # scratch
        self.u, self.noise = np.zeros((2, n)), np.zeros((4, n))
        # a block's uniforms (2 per particle of a block of <= n) and the resampling CDF (n): 2 n, padded
        self.uniforms = np.zeros((2 * n + LANES - 1) // LANES * LANES + LANES)
        self.proposed = np.zeros((3, n))
        self.depth, self.gx, self.gy, self.inside = (np.zeros(n) for _ in range(4))
        # both sides of the state
        self.particles = (np.zeros((3, n)), np.zeros((3, n)))
        self.log_w = (np.full(n, -math.log(n)), np.full(n, -math.log(n)))
        self.w = (np.full(n, 1.0 / n), np.full(n, 1.0 / n))
        self.moments = (np.zeros(M_COUNT), np.zeros(M_COUNT))
        self.rng = (np.zeros(4 * LANES, dtype=np.uint64), np.zeros(4 * LANES, dtype=np.uint64))
        self._keep = (terrain.depth,)

        def address(a):
            return a.ctypes.data

        ny, nx = terrain.depth.shape
        self._structs = []
        for side in (0, 1):
            other = 1 - side
            s = _Step(n=n, f=f_soa_address, lookup=lookup_address(), p=address(self.scalars) + 8 * S_COUNT,
                      grid=address(terrain.depth), nx=nx, ny=ny,
                      x0=terrain.origin[0], y0=terrain.origin[1], inv_res=1.0 / terrain.resolution,
                      u=address(self.u), noise=address(self.noise), uniforms=address(self.uniforms),
                      proposed=address(self.proposed), depth=address(self.depth), gx=address(self.gx),
                      gy=address(self.gy), inside=address(self.inside), dt=address(self.scalars) + 8 * S_DT,
                      particles=address(self.particles[side]), particles_next=address(self.particles[other]),
                      log_w=address(self.log_w[side]), log_w_next=address(self.log_w[other]),
                      w_next=address(self.w[other]), moments_next=address(self.moments[other]),
                      rng=address(self.rng[side]), rng_next=address(self.rng[other]))
            self._structs.append(ctypes.addressof(s))
            self._keep += (s,)
        self._fn = _library().terrain_sir_step
        self._scalars_address = self.scalars.ctypes.data

    def step(self, side: int) -> int:
        return self._fn(self._structs[side], self._scalars_address)
