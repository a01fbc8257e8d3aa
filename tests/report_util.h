/* tests/report_util.h — a number from the report.json a bake writes next to its .ubk
 * (bake/output.c), for the tests and benchmarks that read one (header-only). */
#ifndef UBAKE_TESTS_REPORT_UTIL_H
#define UBAKE_TESTS_REPORT_UTIL_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The number after "key": in DIR/NAME.report.json for ubk_path DIR/NAME.ubk (the first
 * occurrence; the report's first MiB), NaN when the report or the key is absent. */
static inline double ub_report_number(const char *ubk_path, const char *key)
{
  char path[1100], needle[128];
  snprintf(path, sizeof path, "%s", ubk_path);
  char *dot = strrchr(path, '.');
  if (!dot)
    return NAN;
  snprintf(dot, sizeof path - (size_t)(dot - path), ".report.json");
  FILE *f = fopen(path, "rb");
  if (!f)
    return NAN;
  static char buf[1 << 20];
  size_t n = fread(buf, 1, sizeof buf - 1, f);
  fclose(f);
  buf[n] = 0;
  snprintf(needle, sizeof needle, "\"%s\": ", key);
  const char *at = strstr(buf, needle);
  return at ? strtod(at + strlen(needle), NULL) : NAN;
}

#endif
