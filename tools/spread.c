/* ubake spread A.ubk B.ubk …: per dynamic element (sets, doors, objects, combinations) and
 * representation (lightmap texel pixels, GLG probes, LLG probes), each receiver's value
 * (luminance of its DC coefficient) in every file against its median over the files, in
 * units of |median| + the record's mean |value|. A record whose worst receiver sits far
 * out in those units holds a sample that outweighed the rest (doors/door.c's portal
 * sample did: sunroom's door record read 13.1 over 6 seeds before it was bounded, 1.3
 * after). The files must be bakes of one level (same atlases, probes and elements). */
#include "tools/spread.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ubake/bakefile.h"

#define SPREAD_MAX_FILES 64

static const char *HELP =
    "usage: ubake spread A.ubk B.ubk [C.ubk ...] [--element NAME] [--bound X]\n"
    "Bakes of one level with different seeds (ubake bake --seed N): for each dynamic\n"
    "element's record and representation (texel pixels, GLG probes, LLG probes), the\n"
    "largest deviation of a receiver's value (DC luminance) from its median over the files,\n"
    "in units of |median| + the record's mean |value|, and how many values lie over 0.5.\n"
    "  --element NAME  only the element (set, door, object or combination) named NAME\n"
    "  --bound X       exit status 1 when any deviation exceeds X (a noise check)\n";

static void quiet_log(void *user, ub_log_level level, const char *msg)
{
  (void)user;
  if (level <= UB_LOG_ERROR)
    fprintf(stderr, "ubake spread: %s\n", msg);
}

static int cmp_float(const void *a, const void *b)
{
  float x = *(const float *)a, y = *(const float *)b;
  return (x > y) - (x < y);
}

static const ub_bakefile_record *element(const ub_bakefile *bf, uint32_t e)
{
  return e < bf->dls_count ? &bf->dls[e] : &bf->elems[e - bf->dls_count];
}

/* Receivers of representation k (0 texel pixels, 1 GLG probes, 2 LLG probes) of record r:
 * count, indices, values and floats per row. */
static uint32_t rows_of(const ub_bakefile_record *r, int k, const uint32_t **idx,
                        const float **val, size_t *stride)
{
  *idx = k == 0 ? r->texel_index : k == 1 ? r->probe_index : r->llg_probe_index;
  *val = k == 0 ? r->texel_sh : k == 1 ? r->probe_sh : r->llg_probe_sh;
  *stride = k == 0 ? UB_SH1_FLOATS : 27;
  return k == 0 ? r->texel_count : k == 1 ? r->probe_count : r->llg_probe_count;
}

/* The files agree on what the receivers and elements are; else a message naming file j. */
static int same_level(ub_bakefile *const *bf, char **path, int j)
{
  const ub_bakefile *a = bf[0], *b = bf[j];
  const char *what = NULL;
  if (ub_bakefile_atlas_pixels(a) != ub_bakefile_atlas_pixels(b))
    what = "atlas pixels";
  else if (a->glg_probe_count != b->glg_probe_count)
    what = "GLG probes";
  else if (ub_bakefile_llg_probes(a) != ub_bakefile_llg_probes(b))
    what = "LLG probes";
  else if (a->dls_count != b->dls_count || a->elem_count != b->elem_count)
    what = "dynamic elements";
  for (uint32_t e = 0; !what && e < a->dls_count + a->elem_count; e++)
    if (strcmp(element(a, e)->name, element(b, e)->name) || element(a, e)->kind != element(b, e)->kind)
      what = "element names";
  if (what)
    fprintf(stderr, "ubake spread: %s: not a bake of the level of %s (its %s differ)\n", path[j],
            path[0], what);
  return !what;
}

int ub_cli_spread(int argc, char **argv)
{
  char *path[SPREAD_MAX_FILES];
  int n = 0;
  const char *only = NULL;
  double bound = INFINITY;
  for (int i = 0; i < argc; i++) {
    const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
    if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
      fputs(HELP, stdout);
      return 0;
    } else if (!strcmp(a, "--element") && v) {
      only = v, i++;
    } else if (!strcmp(a, "--bound") && v) {
      char *end;
      bound = strtod(v, &end);
      if (*end || !(bound >= 0.0)) {
        fprintf(stderr, "ubake spread: --bound %s: not a number >= 0\n", v);
        return 1;
      }
      i++;
    } else if (a[0] == '-') {
      fprintf(stderr, "ubake spread: unknown option or missing value: %s\n%s", a, HELP);
      return 1;
    } else if (n == SPREAD_MAX_FILES) {
      fprintf(stderr, "ubake spread: at most %d files\n", SPREAD_MAX_FILES);
      return 1;
    } else {
      path[n++] = argv[i];
    }
  }
  if (n < 2) {
    fprintf(stderr, "ubake spread: give two or more bake files\n%s", HELP);
    return 1;
  }
  ub_log log = {quiet_log, NULL};
  ub_bakefile *bf[SPREAD_MAX_FILES] = {NULL};
  int status = 0;
  for (int j = 0; j < n && !status; j++) {
    if (ub_bakefile_read(path[j], &log, &bf[j]) != UB_OK || (j && !same_level(bf, path, j)))
      status = 1;
  }
  size_t R = 0;
  float *v = NULL, *srt = malloc(n * sizeof *srt);
  if (!status) {
    size_t rt = ub_bakefile_atlas_pixels(bf[0]), rg = bf[0]->glg_probe_count;
    size_t rl = ub_bakefile_llg_probes(bf[0]);
    R = rt > rg ? (rt > rl ? rt : rl) : (rg > rl ? rg : rl);
    v = malloc((R + 1) * n * sizeof *v);
  }
  uint8_t *seen = !status ? calloc(R + 1, 1) : NULL;
  uint32_t *list = !status ? malloc((R + 1) * sizeof *list) : NULL; /* receivers seen */
  if (!status && (!v || !srt || !seen || !list)) {
    fprintf(stderr, "ubake spread: out of memory\n");
    status = 1;
  }
  uint32_t ne = status ? 0 : bf[0]->dls_count + bf[0]->elem_count, shown = 0;
  for (uint32_t e = 0; only && e < ne; e++)
    shown += !strcmp(only, element(bf[0], e)->name);
  if (!status && only && !shown) {
    fprintf(stderr, "ubake spread: %s: no element named %s\n", path[0], only);
    status = 1;
    ne = 0;
  }
  static const char *kind_name[3] = {"texel pixels", "GLG probes", "LLG probes"};
  if (ne)
    printf("%d files; deviation = |value - median| / (|median| + mean |value|)%s\n", n,
           isfinite(bound) ? ", bound given" : "");
  for (uint32_t e = 0; e < ne; e++) {
    const char *name = element(bf[0], e)->name;
    if (only && strcmp(only, name))
      continue;
    for (int k = 0; k < 3; k++) {
      size_t used = 0;
      for (int j = 0; j < n; j++) {
        const uint32_t *idx;
        const float *val;
        size_t stride;
        uint32_t c = rows_of(element(bf[j], e), k, &idx, &val, &stride);
        for (uint32_t i = 0; i < c; i++) {
          size_t q = idx[i];
          if (q >= R)
            continue;
          if (!seen[q]) {
            seen[q] = 1;
            list[used++] = (uint32_t)q;
            for (int jj = 0; jj < n; jj++)
              v[q * n + jj] = 0.0f;
          }
          const float *s = val + stride * i;
          v[q * n + j] = 0.2126f * s[0] + 0.7152f * s[1] + 0.0722f * s[2];
        }
      }
      if (!used)
        continue;
      double mean = 0.0;
      for (size_t i = 0; i < used; i++)
        for (int j = 0; j < n; j++)
          mean += fabs(v[(size_t)list[i] * n + j]);
      mean /= (double)used * n;
      double worst = 0.0;
      size_t at = 0, over_half = 0, over_bound = 0;
      int at_file = 0;
      for (size_t i = 0; i < used && mean > 0.0; i++) {
        size_t q = list[i];
        memcpy(srt, v + q * n, n * sizeof *srt);
        qsort(srt, n, sizeof *srt, cmp_float);
        double med = n % 2 ? srt[n / 2] : 0.5 * (srt[n / 2 - 1] + srt[n / 2]);
        for (int j = 0; j < n; j++) {
          double d = fabs(v[q * n + j] - med) / (fabs(med) + mean);
          if (d > worst)
            worst = d, at = q, at_file = j;
          over_half += d > 0.5;
          over_bound += d > bound;
        }
      }
      for (size_t i = 0; i < used; i++)
        seen[list[i]] = 0;
      printf("%-24s %-12s %8zu receivers, mean |value| %.4g: worst %.2f (receiver %zu in %s), "
             "%zu over 0.5", name, kind_name[k], used, mean, worst, at, path[at_file], over_half);
      if (isfinite(bound))
        printf(", %zu over %.3g", over_bound, bound);
      printf("\n");
      if (over_bound)
        status = 1;
    }
  }
  if (!status && !ne)
    printf("no dynamic elements\n");
  free(v);
  free(srt);
  free(seen);
  free(list);
  for (int j = 0; j < n; j++)
    ub_bakefile_free(bf[j]);
  return status;
}
