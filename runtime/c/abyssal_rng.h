/* Counter-based random numbers of abyssal's particle-filter runtime (C99, header only).
 *
 * Philox4x32-10 (Salmon, Moraes, Dror & Shaw, "Parallel random numbers: as easy as 1, 2, 3", SC 2011):
 * 128 random bits are a pure function of a 128-bit counter and a 64-bit key, so a draw never depends on
 * which thread or block computed it, nor on what was drawn before. A particle filter keys it with a seed
 * from the user's numpy Generator and counts steps in the counter: its whole random state is two words.
 * Checked against the published known-answer vectors (Random123's kat_vectors) in the tests.
 *
 * The round is a macro so that a loop over particles calling it vectorises (uint64_t variables holding 32-bit
 * values; 32-bit lanes need their odd and even halves shuffled apart, 1.7x slower with AVX-512). gcc still
 * multiplies such lanes as full 64-bit numbers (vpmullq with AVX-512, shifts and adds without), so the runs of
 * counters a step draws go through abyssal_philox_run, which uses the 32 x 32 -> 64-bit vpmuludq itself on AVX2.
 */
#ifndef ABYSSAL_RNG_H
#define ABYSSAL_RNG_H

#include <stdint.h>
#if defined(__AVX2__) && !defined(ABYSSAL_NO_INTRINSICS)
#include <immintrin.h>
#define ABYSSAL_PHILOX_AVX2 1
#endif

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

#ifdef ABYSSAL_PHILOX_AVX2
/* The words of counters j..j+3 (the low halves of x's four 64-bit lanes) and of j+4..j+7 (y's, those below n)
 * into out[j..]; nothing when out is NULL. */
static inline void abyssal_philox_store4(uint32_t* out, long long j, __m256i x, __m256i y, long long n) {
  const __m256i even = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
  if (!out) return;
  _mm_storeu_si128((__m128i*)(out + j), _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(x, even)));
  if (j + 8 <= n) _mm_storeu_si128((__m128i*)(out + j + 4), _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(y, even)));
}
#endif

/* Philox4x32-10 of the counters (c0 + j mod 2^32, c1, c2, c3) under the key (k0, k1), j = 0..n-1: word w into
 * out_w[j] (out1..out3 may be NULL: not stored). The same bits as abyssal_philox4x32_10 counter by counter.
 * With AVX2, four counters per vector: gcc vectorises the macro's 32 x 32 -> 64-bit products in 64-bit lanes as
 * a full 64 x 64-bit multiply (emulated with shifts and adds without AVX-512, vpmullq with it), where one
 * vpmuludq suffices; written with the intrinsic, with the round keys computed once.
 * Two vectors go through the ten rounds side by side: a round's multiply waits on the one before it, and the
 * other vector's work fills that wait. Only the low half of each 64-bit lane is a Philox word: vpmuludq reads
 * the low halves, the stores take them, and the xors never carry a high half down, so the high halves are left as
 * the products made them instead of being masked in every round (the same bits; benchmarks/README.md). */
static inline void abyssal_philox_run(uint32_t c0, uint32_t c1, uint32_t c2, uint32_t c3, uint32_t k0, uint32_t k1,
                                      long long n, uint32_t* out0, uint32_t* out1, uint32_t* out2, uint32_t* out3) {
  long long j = 0;
#ifdef ABYSSAL_PHILOX_AVX2
  __m256i key0[10], key1[10];
  uint64_t a = k0, b = k1;
  for (int r = 0; r < 10; ++r) {
    key0[r] = _mm256_set1_epi64x((long long)a);
    key1[r] = _mm256_set1_epi64x((long long)b);
    a = (a + ABYSSAL_PHILOX_W0) & ABYSSAL_LOW32;
    b = (b + ABYSSAL_PHILOX_W1) & ABYSSAL_LOW32;
  }
  const __m256i m0 = _mm256_set1_epi64x(ABYSSAL_PHILOX_M0), m1 = _mm256_set1_epi64x(ABYSSAL_PHILOX_M1);
  const __m256i low = _mm256_set1_epi64x((long long)ABYSSAL_LOW32);
  const __m256i w1 = _mm256_set1_epi64x(c1), w2 = _mm256_set1_epi64x(c2), w3 = _mm256_set1_epi64x(c3);
  const __m256i eight = _mm256_set1_epi64x(8);
  __m256i ctr_x = _mm256_setr_epi64x(c0, (long long)(uint32_t)(c0 + 1u), (long long)(uint32_t)(c0 + 2u),
                                     (long long)(uint32_t)(c0 + 3u));
  __m256i ctr_y = _mm256_and_si256(_mm256_add_epi64(ctr_x, _mm256_set1_epi64x(4)), low);
  for (; j + 4 <= n;) { /* counters j..j+3 in x, j+4..j+7 in y (y not stored past n) */
    __m256i x0 = ctr_x, x1 = w1, x2 = w2, x3 = w3, y0 = ctr_y, y1 = w1, y2 = w2, y3 = w3;
    for (int r = 0; r < 10; ++r) {
      const __m256i p0 = _mm256_mul_epu32(x0, m0), p1 = _mm256_mul_epu32(x2, m1);
      const __m256i q0 = _mm256_mul_epu32(y0, m0), q1 = _mm256_mul_epu32(y2, m1);
      x0 = _mm256_xor_si256(_mm256_xor_si256(_mm256_srli_epi64(p1, 32), x1), key0[r]);
      y0 = _mm256_xor_si256(_mm256_xor_si256(_mm256_srli_epi64(q1, 32), y1), key0[r]);
      x1 = p1;
      y1 = q1;
      x2 = _mm256_xor_si256(_mm256_xor_si256(_mm256_srli_epi64(p0, 32), x3), key1[r]);
      y2 = _mm256_xor_si256(_mm256_xor_si256(_mm256_srli_epi64(q0, 32), y3), key1[r]);
      x3 = p0;
      y3 = q0;
    }
    abyssal_philox_store4(out0, j, x0, y0, n);
    abyssal_philox_store4(out1, j, x1, y1, n);
    abyssal_philox_store4(out2, j, x2, y2, n);
    abyssal_philox_store4(out3, j, x3, y3, n);
    j += j + 8 <= n ? 8 : 4;
    ctr_x = _mm256_and_si256(_mm256_add_epi64(ctr_x, eight), low);
    ctr_y = _mm256_and_si256(_mm256_add_epi64(ctr_y, eight), low);
  }
#endif
  for (; j < n; ++j) {
    uint64_t x0 = (uint32_t)(c0 + (uint32_t)j), x1 = c1, x2 = c2, x3 = c3, a0 = k0, a1 = k1; /* 64-bit lanes */
    ABYSSAL_PHILOX_10(x0, x1, x2, x3, a0, a1);
    out0[j] = (uint32_t)x0;
    if (out1) out1[j] = (uint32_t)x1;
    if (out2) out2[j] = (uint32_t)x2;
    if (out3) out3[j] = (uint32_t)x3;
  }
}

/* A uniform in the open interval (0, 1) from 32 random bits: (bits + 1/2) 2^-32, exact in double. */
static inline double abyssal_uniform(uint32_t bits) { return ((double)bits + 0.5) * 0x1p-32; }

#endif /* ABYSSAL_RNG_H */
