/* Counter-based random numbers of abyssal's particle-filter runtime (C99, header only).
 *
 * Philox4x32-10 (Salmon, Moraes, Dror & Shaw, "Parallel random numbers: as easy as 1, 2, 3", SC 2011):
 * 128 random bits are a pure function of a 128-bit counter and a 64-bit key, so a draw never depends on
 * which thread or block computed it, nor on what was drawn before. A particle filter keys it with a seed
 * from the user's numpy Generator and counts steps in the counter: its whole random state is two words.
 * Checked against the published known-answer vectors (Random123's kat_vectors) in the tests.
 *
 * The round is a macro so that a loop over particles calling it vectorises. Its variables may be uint32_t or
 * uint64_t holding 32-bit values: in 64-bit lanes each product is one 32 x 32 -> 64-bit vector multiply
 * (vpmuludq), where 32-bit lanes need their odd and even halves shuffled apart (1.7x slower with AVX-512).
 */
#ifndef ABYSSAL_RNG_H
#define ABYSSAL_RNG_H

#include <stdint.h>

#define ABYSSAL_PHILOX_M0 UINT32_C(0xD2511F53)
#define ABYSSAL_PHILOX_M1 UINT32_C(0xCD9E8D57)
#define ABYSSAL_PHILOX_W0 UINT32_C(0x9E3779B9)
#define ABYSSAL_PHILOX_W1 UINT32_C(0xBB67AE85)
#define ABYSSAL_LOW32 UINT64_C(0xFFFFFFFF)

/* One Philox4x32 round on the counter words c0..c3 under key words k0, k1 (lvalues, 32-bit values). */
#define ABYSSAL_PHILOX_ROUND(c0, c1, c2, c3, k0, k1)                     \
  do {                                                                   \
    const uint64_t abyssal_p0_ = (uint64_t)ABYSSAL_PHILOX_M0 * (c0);     \
    const uint64_t abyssal_p1_ = (uint64_t)ABYSSAL_PHILOX_M1 * (c2);     \
    (c0) = (abyssal_p1_ >> 32) ^ (c1) ^ (k0);                            \
    (c1) = abyssal_p1_ & ABYSSAL_LOW32;                                  \
    (c2) = (abyssal_p0_ >> 32) ^ (c3) ^ (k1);                            \
    (c3) = abyssal_p0_ & ABYSSAL_LOW32;                                  \
  } while (0)

/* Ten rounds; the key (k0, k1: variables, modified) is bumped by the Weyl constants between rounds. */
#define ABYSSAL_PHILOX_10(c0, c1, c2, c3, k0, k1)                                       \
  do {                                                                                  \
    ABYSSAL_PHILOX_ROUND(c0, c1, c2, c3, k0, k1);                                       \
    for (int abyssal_r_ = 1; abyssal_r_ < 10; ++abyssal_r_) {                           \
      (k0) = ((k0) + ABYSSAL_PHILOX_W0) & ABYSSAL_LOW32;                                \
      (k1) = ((k1) + ABYSSAL_PHILOX_W1) & ABYSSAL_LOW32;                                \
      ABYSSAL_PHILOX_ROUND(c0, c1, c2, c3, k0, k1);                                     \
    }                                                                                   \
  } while (0)

/* Philox4x32-10 of counter[4] under key[2] into out[4] (scalar form). */
static inline void abyssal_philox4x32_10(const uint32_t counter[4], const uint32_t key[2], uint32_t out[4]) {
  uint32_t c0 = counter[0], c1 = counter[1], c2 = counter[2], c3 = counter[3], k0 = key[0], k1 = key[1];
  ABYSSAL_PHILOX_10(c0, c1, c2, c3, k0, k1);
  out[0] = c0;
  out[1] = c1;
  out[2] = c2;
  out[3] = c3;
}

/* A uniform in the open interval (0, 1) from 32 random bits: (bits + 1/2) 2^-32, exact in double. */
static inline double abyssal_uniform(uint32_t bits) { return ((double)bits + 0.5) * 0x1p-32; }

#endif /* ABYSSAL_RNG_H */
