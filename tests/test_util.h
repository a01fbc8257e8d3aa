/* tests/test_util.h — tiny assertion helpers: each failure prints file and line. */
#ifndef UBAKE_TEST_UTIL_H
#define UBAKE_TEST_UTIL_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

static int ub_test_failures = 0;

#define ASSERT_TRUE(cond)                                                               \
  do {                                                                                  \
    if (!(cond)) {                                                                      \
      fprintf(stderr, "%s:%d: assertion failed: %s\n", __FILE__, __LINE__, #cond);      \
      ub_test_failures++;                                                               \
    }                                                                                   \
  } while (0)

/* |a - b| <= abs_tol + rel_tol * |b| */
#define ASSERT_NEAR(a, b, abs_tol, rel_tol)                                             \
  do {                                                                                  \
    double ua_ = (double)(a), ub_ = (double)(b);                                        \
    double tol_ = (double)(abs_tol) + (double)(rel_tol) * fabs(ub_);                    \
    if (!(fabs(ua_ - ub_) <= tol_)) {                                                   \
      fprintf(stderr, "%s:%d: %s = %.9g, expected %s = %.9g (tol %.3g)\n", __FILE__,    \
              __LINE__, #a, ua_, #b, ub_, tol_);                                        \
      ub_test_failures++;                                                               \
    }                                                                                   \
  } while (0)

#define ASSERT_OK(expr)                                                                 \
  do {                                                                                  \
    int r_ = (int)(expr);                                                               \
    if (r_ != 0) {                                                                      \
      fprintf(stderr, "%s:%d: %s returned %d\n", __FILE__, __LINE__, #expr, r_);        \
      ub_test_failures++;                                                               \
    }                                                                                   \
  } while (0)

#define TEST_MAIN_END()                                                                 \
  do {                                                                                  \
    if (ub_test_failures) {                                                             \
      fprintf(stderr, "%d assertion(s) failed\n", ub_test_failures);                    \
      return 1;                                                                         \
    }                                                                                   \
    printf("all assertions passed\n");                                                  \
    return 0;                                                                           \
  } while (0)

#endif
