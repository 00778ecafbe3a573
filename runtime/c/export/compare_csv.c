/* compare_csv: the rows of an expected CSV (test vectors recorded from the Python filter) against run_csv's output.
 *
 *     compare_csv EXPECTED ACTUAL TOLERANCE [NIS_TOLERANCE]
 *
 * Both files: a header line, then rows whose first column is the step k. Every row of EXPECTED must appear in
 * ACTUAL (same k, same number of columns); the code column (the second) must be equal, every other number within
 * TOLERANCE * max(1, |expected|), the NIS (the third) within NIS_TOLERANCE * max(1, |expected|) (default
 * TOLERANCE: the NIS inherits the cancellation of z - h(x) between two large numbers); NaN equals NaN. Prints the
 * largest differences; exit 0 when all pass. C99.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define LINE 262144

static char expected_line[LINE], actual_line[LINE];

static int parse(char* text, double* out, int capacity) {
  int count = 0;
  while (*text && *text != '\n' && count < capacity) {
    char* end;
    out[count] = strtod(text, &end);
    if (end == text) return -1;
    ++count;
    text = end;
    if (*text == ',') ++text;
  }
  return count;
}

static int compare(FILE* expected, FILE* actual, char** argv, double tolerance, double nis_tolerance) {
  static double e[LINE / 2], a[LINE / 2];
  double worst = 0.0, worst_nis = 0.0;
  long rows = 0, actual_k = -1, worst_row = -1;
  int worst_column = -1, failures = 0;
  if (!fgets(expected_line, LINE, expected) || !fgets(actual_line, LINE, actual)) {
    fprintf(stderr, "compare_csv: an empty file\n");
    return 2;
  }
  while (fgets(expected_line, LINE, expected)) {
    int ne = parse(expected_line, e, LINE / 2), na = 0, c;
    long k = (long)e[0];
    if (ne < 2) {
      fprintf(stderr, "compare_csv: a malformed row in %s\n", argv[1]);
      return 2;
    }
    while (actual_k < k && fgets(actual_line, LINE, actual)) {
      na = parse(actual_line, a, LINE / 2);
      actual_k = na > 0 ? (long)a[0] : -1;
    }
    if (actual_k != k) {
      fprintf(stderr, "compare_csv: step %ld of %s is not in %s\n", k, argv[1], argv[2]);
      return 1;
    }
    na = parse(actual_line, a, LINE / 2);
    if (na != ne) {
      fprintf(stderr, "compare_csv: step %ld has %d columns in %s and %d in %s\n", k, ne, argv[1], na, argv[2]);
      return 1;
    }
    if (a[1] != e[1]) {
      fprintf(stderr, "compare_csv: step %ld returned %g, expected %g\n", k, a[1], e[1]);
      ++failures;
    }
    for (c = 2; c < ne; ++c) {
      double scale = fabs(e[c]) > 1.0 ? fabs(e[c]) : 1.0;
      double difference = (isnan(e[c]) && isnan(a[c])) ? 0.0 : fabs(a[c] - e[c]) / scale;
      if (c == 2) { /* the NIS */
        if (!(difference <= worst_nis)) worst_nis = isnan(difference) ? INFINITY : difference;
        if (!(difference <= nis_tolerance)) ++failures;
        continue;
      }
      if (!(difference <= worst)) {
        worst = isnan(difference) ? INFINITY : difference;
        worst_row = k;
        worst_column = c;
      }
      if (!(difference <= tolerance)) ++failures;
    }
    ++rows;
  }
  printf("%ld rows compared; largest relative difference of x and P %.3g (step %ld, column %d), of the NIS %.3g; "
         "tolerances %g, %g: %s\n", rows, worst, worst_row, worst_column, worst_nis, tolerance, nis_tolerance,
         failures ? "FAILED" : "passed");
  return failures ? 1 : 0;
}

int main(int argc, char** argv) {
  FILE *expected, *actual;
  int result;
  if (argc != 4 && argc != 5) {
    fprintf(stderr, "usage: compare_csv EXPECTED ACTUAL TOLERANCE [NIS_TOLERANCE]\n");
    return 2;
  }
  expected = fopen(argv[1], "r");
  if (!expected) {
    fprintf(stderr, "compare_csv: cannot open %s\n", argv[1]);
    return 2;
  }
  actual = fopen(argv[2], "r");
  if (!actual) {
    fprintf(stderr, "compare_csv: cannot open %s\n", argv[2]);
    fclose(expected);
    return 2;
  }
  result = compare(expected, actual, argv, strtod(argv[3], 0), argc == 5 ? strtod(argv[4], 0) : strtod(argv[3], 0));
  fclose(expected);
  fclose(actual);
  return result;
}
