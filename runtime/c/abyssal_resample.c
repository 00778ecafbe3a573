/* abyssal_resample.c: see abyssal_resample.h. Hand-written C99. */
#include "abyssal_resample.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

typedef abyssal_count idx;

/* cdf = cumulative sums of w in order, divided by the last (numpy's cumsum, then /= cdf[-1]) */
static void cumulative(idx n, const double* w, double* cdf) {
  double total = 0.0, last;
  idx i;
  for (i = 0; i < n; ++i) {
    total += w[i];
    cdf[i] = total;
  }
  last = cdf[n - 1];
  for (i = 0; i < n; ++i) cdf[i] /= last;
}

/* the last particle of positive weight (0 when there is none) */
static idx last_positive(idx n, const double* w) {
  idx i;
  for (i = n - 1; i > 0; --i)
    if (w[i] > 0.0) return i;
  return 0;
}

/* inverse CDF of sorted uniforms against a cdf (a merge of the two sorted sequences) */
static void walk(idx n, const double* w, const double* cdf, idx m, const double* u, idx* anc) {
  idx i = 0, k, beyond = -1;
  for (k = 0; k < m; ++k) {
    while (i < n && cdf[i] <= u[k]) ++i;
    if (i < n) {
      anc[k] = i;
    } else {
      if (beyond < 0) beyond = last_positive(n, w);
      anc[k] = beyond;
    }
  }
}

void abyssal_resample_inverse_cdf(idx n, const double* w, idx m, const double* u, idx* ancestors, double* cdf) {
  if (n < 1 || m < 1) return;
  cumulative(n, w, cdf);
  walk(n, w, cdf, m, u, ancestors);
}

void abyssal_resample_systematic(idx n, const double* w, idx m, double u0, idx* ancestors, double* cdf) {
  idx i = 0, k, beyond = -1;
  if (n < 1 || m < 1) return;
  cumulative(n, w, cdf);
  for (k = 0; k < m; ++k) {
    const double u = ((double)k + u0) / (double)m;
    while (i < n && cdf[i] <= u) ++i;
    if (i < n) {
      ancestors[k] = i;
    } else {
      if (beyond < 0) beyond = last_positive(n, w);
      ancestors[k] = beyond;
    }
  }
}

/* u (m, in [0, 1)) sorted in place: a bucket sort on floor(u m) (expected O(m) for uniforms), insertion within buckets;
 * order: m + 1 counts of scratch, cdf's first m doubles a copy */
static void sort_uniforms(idx m, double* u, idx* order, double* copy) {
  idx k, b;
  for (b = 0; b <= m; ++b) order[b] = 0;
  for (k = 0; k < m; ++k) {
    idx bucket = (idx)(u[k] * (double)m);
    bucket = bucket < 0 ? 0 : bucket >= m ? m - 1 : bucket;
    ++order[bucket + 1];
  }
  for (b = 0; b < m; ++b) order[b + 1] += order[b];
  for (k = 0; k < m; ++k) {
    idx bucket = (idx)(u[k] * (double)m);
    bucket = bucket < 0 ? 0 : bucket >= m ? m - 1 : bucket;
    copy[order[bucket]++] = u[k];
  }
  for (k = 1; k < m; ++k) { /* the buckets are in order: one insertion pass sorts within them */
    const double v = copy[k];
    idx j = k;
    while (j > 0 && copy[j - 1] > v) {
      copy[j] = copy[j - 1];
      --j;
    }
    copy[j] = v;
  }
  memcpy(u, copy, sizeof(double) * (size_t)m);
}

void abyssal_resample_multinomial(idx n, const double* w, idx m, double* u, idx* ancestors, double* cdf, idx* order) {
  if (n < 1 || m < 1) return;
  sort_uniforms(m, u, order, cdf); /* (cdf as the copy: it is computed after) */
  cumulative(n, w, cdf);
  walk(n, w, cdf, m, u, ancestors);
}

/* ------------------------------------------------------------------------------------------ KLD */

#define KLD_MAGIC 0x6b6c642d73657431ULL
#define MAX_DIMS 16

typedef struct {
  unsigned long long magic;
  idx n, n_max, slots, drawn, k, ld;
  double stamp; /* this resampling's mark of an occupied slot */
  int dims, stopped;
  const double* states;
  const long long* limit;
  double low[MAX_DIMS], width[MAX_DIMS];
} kld_head;

static idx slots_for(idx n_max) {
  idx slots = 16;
  while (slots < 2 * (n_max + 1)) slots *= 2;
  return slots;
}

static size_t head_bytes(void) { return (sizeof(kld_head) + 7) & ~(size_t)7; }

size_t abyssal_kld_bytes(idx n, idx n_max, int dims) {
  return head_bytes() + sizeof(double) * ((size_t)n + (size_t)slots_for(n_max) * (size_t)(dims + 1));
}

static double* kld_cdf(kld_head* h) { return (double*)(void*)((char*)h + head_bytes()); }
static double* kld_table(kld_head* h) { return kld_cdf(h) + h->n; }

/* the bin index of a state along one binned row: floor(clip(x / width)) */
static double bin_index(double x, double width) {
  double v = x / width;
  v = v < -1e300 ? -1e300 : v > 1e300 ? 1e300 : v;
  return floor(v);
}

int abyssal_kld_start(void* memory, size_t bytes, idx n, const double* w, const double* states, idx ld, int dims,
                      const double* widths, idx n_max, const long long* limit) {
  kld_head* h = (kld_head*)memory;
  double stamp;
  idx j;
  int d;
  if (!memory || n < 1 || n_max < 1 || dims < 1 || dims > MAX_DIMS || ld < n || !w || !states || !widths || !limit ||
      bytes < abyssal_kld_bytes(n, n_max, dims))
    return -2;
  stamp = h->magic == KLD_MAGIC ? h->stamp + 1.0 : 1.0; /* (a new buffer is zero: no slot carries stamp 1) */
  if (h->magic == KLD_MAGIC && (h->slots != slots_for(n_max) || h->dims != dims)) { /* another layout: clear it */
    memset(memory, 0, bytes);
    stamp = 1.0;
  }
  h->magic = KLD_MAGIC;
  h->stamp = stamp;
  h->n = n;
  h->n_max = n_max;
  h->slots = slots_for(n_max);
  h->dims = dims;
  h->ld = ld;
  h->states = states;
  h->limit = limit;
  h->drawn = h->k = 0;
  h->stopped = 0;
  for (d = 0; d < dims; ++d) { /* the cloud's lowest bin along each row (floor and clip keep the order of x) */
    const double* row = states + (idx)d * ld;
    double low = row[0];
    for (j = 0; j < n; ++j) {
      if (!isfinite(row[j])) return -1;
      low = row[j] < low ? row[j] : low;
    }
    if (!(widths[d] > 0.0)) return -2;
    h->width[d] = widths[d];
    h->low[d] = bin_index(low, widths[d]);
  }
  cumulative(n, w, kld_cdf(h));
  return 0;
}

static uint64_t mix(uint64_t x) { /* splitmix64's finaliser */
  x ^= x >> 30;
  x *= 0xbf58476d1ce4e5b9ULL;
  x ^= x >> 27;
  x *= 0x94d049bb133111ebULL;
  x ^= x >> 31;
  return x;
}

/* whether particle j's bin was empty (it is occupied after the call) */
static int occupy(kld_head* h, idx j) {
  double key[MAX_DIMS];
  double* table = kld_table(h);
  const int D = h->dims, width = D + 1;
  uint64_t hash = 0x9e3779b97f4a7c15ULL;
  idx slot;
  int d;
  for (d = 0; d < D; ++d) {
    uint64_t bits;
    key[d] = (bin_index(h->states[(idx)d * h->ld + j], h->width[d]) - h->low[d]) + 0.0; /* (+0.0: no -0.0 key) */
    memcpy(&bits, &key[d], sizeof bits);
    hash = mix(hash ^ bits);
  }
  for (slot = (idx)(hash & (uint64_t)(h->slots - 1));; slot = (slot + 1) & (h->slots - 1)) {
    double* entry = table + slot * width;
    int same = 1;
    if (entry[0] != h->stamp) { /* empty in this resampling: the bin is new */
      entry[0] = h->stamp;
      for (d = 0; d < D; ++d) entry[1 + d] = key[d];
      return 1;
    }
    for (d = 0; d < D && same; ++d) same = entry[1 + d] == key[d];
    if (same) return 0;
  }
}

/* the first i with cdf[i] > u, at most n - 1 (numpy's searchsorted side "right", then minimum(., n - 1)) */
static idx search(const double* cdf, idx n, double u) {
  idx lo = 0, hi = n;
  while (lo < hi) {
    const idx mid = lo + (hi - lo) / 2;
    if (cdf[mid] <= u)
      lo = mid + 1;
    else
      hi = mid;
  }
  return lo < n ? lo : n - 1;
}

idx abyssal_kld_draw(void* memory, const double* u, idx count, idx* ancestors) {
  kld_head* h = (kld_head*)memory;
  const double* cdf = kld_cdf(h);
  idx t;
  if (h->magic != KLD_MAGIC || h->stopped) return h->stopped ? h->drawn : 0;
  for (t = 0; t < count && h->drawn < h->n_max; ++t) {
    const idx j = search(cdf, h->n, u[t]);
    ancestors[h->drawn++] = j;
    h->k += occupy(h, j);
    if (h->drawn >= h->limit[h->k]) {
      h->stopped = 1;
      return h->drawn;
    }
  }
  if (h->drawn >= h->n_max) {
    h->stopped = 1;
    return h->drawn;
  }
  return 0;
}

/* ------------------------------------------------------------------------------------------ gathers */

void abyssal_gather_rows(int rows, idx m, const idx* ancestors, const double* src, idx ld_src, double* dst,
                         idx ld_dst) {
  int r;
  idx k;
  for (r = 0; r < rows; ++r) {
    const double* s = src + (idx)r * ld_src;
    double* d = dst + (idx)r * ld_dst;
    for (k = 0; k < m; ++k) d[k] = s[ancestors[k]];
  }
}

void abyssal_gather_items(idx m, const idx* ancestors, idx size, const double* src, double* dst) {
  idx k;
  for (k = 0; k < m; ++k) memcpy(dst + k * size, src + ancestors[k] * size, sizeof(double) * (size_t)size);
}
