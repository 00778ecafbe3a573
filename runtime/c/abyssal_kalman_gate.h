/* abyssal_kalman_gate.h: the innovation gate of every Kalman-type filter of abyssal.
 *
 * After an update, the NIS of the present measurement entries is compared with the chi-square quantile of
 * tail probability `probability` (1e-10: a consistent filter gates a measurement once in 10^10 updates;
 * 0 turns the gate off). When it fails, the entries whose own normalised innovation nu_i^2 / S_ii exceeds
 * the one-degree quantile are left out and the update is redone with the rest, which must pass too; when
 * no single entry is to blame (or all are), the whole measurement is left out. An entry gated in `patience`
 * consecutive updates means the filter, not the sensor, is probably wrong (a jump it cannot follow): each
 * further update that gates it asks for P to be multiplied by `inflation` until the entry passes.
 *
 *     abyssal_gate_init(memory, bytes, m, 1e-10, 5, 4.0, &gate);
 *     round 0: run the update over `present`; abyssal_gate_judge(gate, 0, nu, S, present, gated, &nis, scratch)
 *              -> ACCEPT, or RETRY (rerun over the new `present`, round 1), or REJECT;
 *     then:    if (abyssal_gate_note(gate, gated, present_before)) P *= inflation;
 *
 * The gate lives in caller-provided memory (abyssal_gate_size bytes, 8-byte aligned), holds no pointers (a
 * memcpy of it is a checkpoint) and no global state. The Kalman runtime (abyssal_kalman.c) and Python's
 * InnovationGate (runtime/filters/kalman/gate.py) both call these functions. Hand-written C99.
 *
 * Conventions of the updates: nu is (m,) with 0 on unused entries and S (m x m, column-major) with identity
 * rows there, so the NIS over all rows is the NIS of the present ones. Masks are arrays of m bytes, 1 / 0.
 */
#ifndef ABYSSAL_KALMAN_GATE_H
#define ABYSSAL_KALMAN_GATE_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
  unsigned long long magic;
  int m;                   /* measurement entries */
  int patience;            /* consecutive gated updates of an entry before P is inflated */
  double probability;      /* tail probability of the chi-square test; 0: no gate */
  double inflation;        /* factor on P per further gated update */
  long long gated;         /* measurement entries left out so far */
  long long inflations;    /* inflations asked for so far */
  long long streaking;     /* 1 when some entry's streak is > 0 */
  long long thresholds;    /* byte offset (from the gate) of m + 1 doubles: the quantile per degree of freedom */
  long long streak;        /* byte offset of m long longs: consecutive gated updates of each entry */
  long long bytes;         /* the gate's size (abyssal_gate_size) */
} abyssal_gate;

enum { ABYSSAL_GATE_ACCEPT = 0, ABYSSAL_GATE_RETRY = 1, ABYSSAL_GATE_REJECT = 2 };

/* Bytes of a gate over m entries (a multiple of 8). */
size_t abyssal_gate_size(int m);

/* Build a gate in memory; 0, or -1 (memory NULL, misaligned or smaller than abyssal_gate_size(m), m < 1),
 * -2 (options: 0 <= probability < 1, patience >= 1 and 1 <= inflation < inf are required). *gate (may be
 * NULL) receives the gate, NULL on failure. */
int abyssal_gate_init(void* memory, size_t bytes, int m, double probability, int patience, double inflation,
                      abyssal_gate** gate);

/* The chi-square quantile the NIS over dof entries is compared with (+inf: no gate). */
double abyssal_gate_threshold(const abyssal_gate* gate, int dof);

/* Whether an update over dof entries with this NIS passes (a non-finite NIS never does). */
int abyssal_gate_passes(const abyssal_gate* gate, double nis, int dof);

/* One round of the selection after an update over `present` gave (nu, S); *nis receives its NIS (may be NULL).
 * ACCEPT: it passes. RETRY (round 0 only): the entries to blame are moved from present to gated; rerun the
 * update over the new present. REJECT: nothing usable is left, gated |= present. scratch: m^2 + m doubles. */
int abyssal_gate_judge(const abyssal_gate* gate, int round, const double* nu, const double* S, unsigned char* present,
                       unsigned char* gated, double* nis, double* scratch);

/* Count the gated entries of an update over `present`: streaks of passed entries end, gated ones grow. Returns
 * 1 when P is to be inflated (an entry gated `patience` times in a row; counted in inflations), else 0. */
int abyssal_gate_note(abyssal_gate* gate, const unsigned char* gated, const unsigned char* present);

/* The current run of consecutive gated updates of an entry (0 for an index out of range). */
long long abyssal_gate_streak(const abyssal_gate* gate, int entry);

/* A complete measurement passed: every streak ends. */
void abyssal_gate_accepted_all(abyssal_gate* gate);

/* x with P(X > x) = probability for X chi-square with dof degrees of freedom, 0 < probability < 1, dof >= 1
 * (regularised incomplete gamma function by its series and continued fraction, safeguarded Newton steps on
 * its logarithm: relative error ~1e-14). NaN outside that domain. */
double abyssal_chi2_isf(double probability, int dof);

#ifdef __cplusplus
}
#endif

#endif /* ABYSSAL_KALMAN_GATE_H */
