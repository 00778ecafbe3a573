/* abyssal_kalman_gate.c: see abyssal_kalman_gate.h. Hand-written C99. */
#include "abyssal_kalman_gate.h"

#include <float.h>
#include <math.h>
#include <string.h>

#include "abyssal_kalman_covariance.h"

#define GATE_MAGIC 0x6761746561627973ULL /* "gateabys" */
#define ROUND8(b) (((b) + 7u) & ~(size_t)7u)

static double* thresholds(const abyssal_gate* g) { return (double*)(void*)((char*)g + g->thresholds); }
static long long* streaks(const abyssal_gate* g) { return (long long*)(void*)((char*)g + g->streak); }

size_t abyssal_gate_size(int m) {
  if (m < 1) return 0;
  return ROUND8(sizeof(abyssal_gate)) + sizeof(double) * (size_t)(m + 1) + sizeof(long long) * (size_t)m;
}

int abyssal_gate_init(void* memory, size_t bytes, int m, double probability, int patience, double inflation,
                      abyssal_gate** gate) {
  abyssal_gate* g = (abyssal_gate*)memory;
  double* t;
  int k;
  if (gate) *gate = 0;
  if (!memory || ((size_t)memory & 7u) || m < 1 || bytes < abyssal_gate_size(m)) return -1;
  if (!(probability >= 0.0 && probability < 1.0) || patience < 1 || !(inflation >= 1.0 && inflation < INFINITY))
    return -2;
  memset(memory, 0, abyssal_gate_size(m));
  g->magic = GATE_MAGIC;
  g->m = m;
  g->patience = patience;
  g->probability = probability;
  g->inflation = inflation;
  g->thresholds = (long long)ROUND8(sizeof(abyssal_gate));
  g->streak = g->thresholds + (long long)(sizeof(double) * (size_t)(m + 1));
  g->bytes = (long long)abyssal_gate_size(m);
  t = thresholds(g);
  t[0] = INFINITY;
  for (k = 1; k <= m; ++k) t[k] = probability == 0.0 ? INFINITY : abyssal_chi2_isf(probability, k);
  if (gate) *gate = g;
  return 0;
}

double abyssal_gate_threshold(const abyssal_gate* gate, int dof) {
  if (dof < 0 || dof > gate->m) return NAN;
  return thresholds(gate)[dof];
}

int abyssal_gate_passes(const abyssal_gate* gate, double nis, int dof) {
  double threshold = abyssal_gate_threshold(gate, dof);
  if (threshold == INFINITY) return 1;
  return isfinite(nis) && nis <= threshold;
}

int abyssal_gate_judge(const abyssal_gate* gate, int round, const double* nu, const double* S, unsigned char* present,
                       unsigned char* gated, double* nis, double* scratch) {
  int m = gate->m, dof = 0, outliers = 0, i;
  double value, one = thresholds(gate)[1];
  for (i = 0; i < m; ++i) dof += present[i] != 0;
  value = abyssal_nis(m, nu, S, scratch);
  if (nis) *nis = value;
  if (abyssal_gate_passes(gate, value, dof)) return ABYSSAL_GATE_ACCEPT;
  if (round == 0) {
    for (i = 0; i < m; ++i) /* an entry whose own normalised innovation fails (NaN or inf fails too) */
      outliers += present[i] && !(nu[i] * nu[i] <= one * S[i + i * m]);
    if (outliers > 0 && outliers < dof) {
      for (i = 0; i < m; ++i)
        if (present[i] && !(nu[i] * nu[i] <= one * S[i + i * m])) {
          present[i] = 0;
          gated[i] = 1;
        }
      return ABYSSAL_GATE_RETRY;
    }
  }
  for (i = 0; i < m; ++i)
    if (present[i]) gated[i] = 1;
  return ABYSSAL_GATE_REJECT;
}

int abyssal_gate_note(abyssal_gate* gate, const unsigned char* gated, const unsigned char* present) {
  long long* streak = streaks(gate);
  long long longest = 0;
  int m = gate->m, any = 0, i;
  gate->streaking = 0;
  for (i = 0; i < m; ++i) {
    if (gated[i]) {
      gate->gated += 1;
      streak[i] += 1;
      any = 1;
    } else if (present[i]) {
      streak[i] = 0;
    }
    if (streak[i] > 0) gate->streaking = 1;
    if (streak[i] > longest) longest = streak[i];
  }
  if (any && longest >= gate->patience) {
    gate->inflations += 1;
    return 1;
  }
  return 0;
}

long long abyssal_gate_streak(const abyssal_gate* gate, int entry) {
  return entry >= 0 && entry < gate->m ? streaks(gate)[entry] : 0;
}

void abyssal_gate_accepted_all(abyssal_gate* gate) {
  if (gate->streaking) {
    memset(streaks(gate), 0, sizeof(long long) * (size_t)gate->m);
    gate->streaking = 0;
  }
}

/* ------------------------------------------------------------------ the chi-square quantile */

/* log P(a, x), the regularised lower incomplete gamma function, by its series (x < a + 1). */
static double log_lower_series(double a, double x) {
  double term = 1.0 / a, sum = term;
  int k;
  for (k = 1; k < 1000; ++k) {
    term *= x / (a + k);
    sum += term;
    if (fabs(term) < fabs(sum) * DBL_EPSILON) break;
  }
  return log(sum) - x + a * log(x) - lgamma(a);
}

/* log Q(a, x), the regularised upper incomplete gamma function, by its continued fraction (modified Lentz,
 * x >= a + 1). */
static double log_upper_fraction(double a, double x) {
  double b = x + 1.0 - a, c = 1.0 / DBL_MIN, d = 1.0 / b, h = d;
  int k;
  for (k = 1; k < 1000; ++k) {
    double an = -k * (k - a), delta;
    b += 2.0;
    d = an * d + b;
    if (fabs(d) < DBL_MIN) d = DBL_MIN;
    c = b + an / c;
    if (fabs(c) < DBL_MIN) c = DBL_MIN;
    d = 1.0 / d;
    delta = d * c;
    h *= delta;
    if (fabs(delta - 1.0) < DBL_EPSILON) break;
  }
  return log(h) - x + a * log(x) - lgamma(a);
}

static double log_upper(double a, double x) {
  if (x <= 0.0) return 0.0;
  if (x < a + 1.0) return log1p(-exp(log_lower_series(a, x)));
  return log_upper_fraction(a, x);
}

double abyssal_chi2_isf(double probability, int dof) {
  double a = 0.5 * dof, target, lo = 0.0, hi, x;
  int k;
  if (!(probability > 0.0 && probability < 1.0) || dof < 1) return NAN;
  target = log(probability);
  hi = a + 1.0;
  while (log_upper(a, hi) > target) hi *= 2.0; /* Q(a, 0) = 1 > probability: the root is in (0, hi] */
  lo = 0.5 * hi;
  if (log_upper(a, lo) <= target) lo = 0.0;
  x = 0.5 * (lo + hi);
  for (k = 0; k < 200; ++k) {
    double g = log_upper(a, x) - target, slope, next;
    if (g > 0.0) lo = x; else hi = x;
    /* d/dx log Q = -x^(a-1) e^-x / (Gamma(a) Q) */
    slope = -exp((a - 1.0) * log(x) - x - lgamma(a) - log_upper(a, x));
    next = x - g / slope;
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi); /* outside the bracket: bisect */
    if (fabs(next - x) <= 4.0 * DBL_EPSILON * x) {
      x = next;
      break;
    }
    x = next;
  }
  return 2.0 * x;
}
