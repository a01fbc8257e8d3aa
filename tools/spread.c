/* ubake spread A.ubk B.ubk …: per dynamic element (sets, doors, objects, combinations) and
 * representation (lightmap texel pixels, GLG probes, LLG probes), each receiver's value
 * (luminance of its DC coefficient; --along-normal: of a texel's irradiance along its
 * normal) in every file against its median over the files, in
 * units of |median| + the record's mean |value|. A record whose worst receiver sits far
 * out in those units holds a sample that outweighed the rest (doors/door.c's portal
 * sample did: sunroom's door record read 13.1 over 6 seeds before it was bounded, 1.3
 * after). --base adds the base bake as one more element, "(base)". The files must be
 * bakes of one level (same atlases, probes and elements). */
#include "tools/spread.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "runtime/texel_sh.h"
#include "ubake/bakefile.h"

#define SPREAD_MAX_FILES 64

static const char *HELP =
    "usage: ubake spread A.ubk B.ubk [C.ubk ...] [--element NAME] [--bound X] [--base]\n"
    "                    [--along-normal]\n"
    "Bakes of one level with different seeds (ubake bake --seed N): for each dynamic\n"
    "element's record and representation (texel pixels, GLG probes, LLG probes), the\n"
    "largest deviation of a receiver's value (DC luminance) from its median over the files,\n"
    "in units of |median| + the record's mean |value|, and how many values lie over 0.5.\n"
    "  --element NAME  only the element (set, door, object or combination) named NAME\n"
    "                  ((base) with --base: the base bake)\n"
    "  --bound X       exit status 1 when any deviation exceeds X (a noise check)\n"
    "  --base          also the base bake, as an element named (base): every covered\n"
    "                  texel pixel, GLG probe and LLG probe\n"
    "  --along-normal  texel pixels: the luminance of the irradiance along the pixel's\n"
    "                  normal (what a flat surface shows) instead of the DC (which also\n"
    "                  carries the light a normal map sees); pixels without a normal\n"
    "                  (padding) are left out\n";

#define SPREAD_BASE_NAME "(base)"

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

/* The base bake of bf as a record (--base): its covered texel pixels (global pixel
 * indices, SH copied), its GLG probes (glg_sh borrowed, not copied) and its LLG probes
 * (copied in the global order). 0 when out of memory; base_free frees what it made. */
static int base_record(const ub_bakefile *bf, ub_bakefile_record *r)
{
  memset(r, 0, sizeof *r);
  snprintf(r->name, sizeof r->name, "%s", SPREAD_BASE_NAME);
  r->kind = UINT32_MAX;
  size_t covered = 0, off = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    for (size_t p = 0; p < (size_t)at->width * at->height; p++)
      covered += at->coverage[p] == 1;
  }
  size_t ng = bf->glg_probe_count, nl = ub_bakefile_llg_probes(bf);
  r->texel_index = malloc((covered + 1) * sizeof *r->texel_index);
  r->texel_sh = malloc((covered + 1) * UB_SH1_FLOATS * sizeof *r->texel_sh);
  r->probe_index = malloc((ng + 1) * sizeof *r->probe_index);
  r->llg_probe_index = malloc((nl + 1) * sizeof *r->llg_probe_index);
  r->llg_probe_sh = malloc((nl + 1) * 27 * sizeof *r->llg_probe_sh);
  if (!r->texel_index || !r->texel_sh || !r->probe_index || !r->llg_probe_index ||
      !r->llg_probe_sh)
    return 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    for (size_t p = 0; p < (size_t)at->width * at->height; p++)
      if (at->coverage[p] == 1) {
        r->texel_index[r->texel_count] = (uint32_t)(off + p);
        memcpy(r->texel_sh + (size_t)r->texel_count * UB_SH1_FLOATS,
               at->sh + p * UB_SH1_FLOATS, UB_SH1_FLOATS * sizeof *r->texel_sh);
        r->texel_count++;
      }
    off += (size_t)at->width * at->height;
  }
  r->probe_count = (uint32_t)ng;
  for (size_t i = 0; i < ng; i++)
    r->probe_index[i] = (uint32_t)i;
  r->probe_sh = bf->glg_sh;
  for (uint32_t m = 0; m < bf->llg_count; m++) {
    const ub_bakefile_llg *g = &bf->llgs[m];
    size_t np = (size_t)g->dims[0] * g->dims[1] * g->dims[2];
    memcpy(r->llg_probe_sh + (size_t)r->llg_probe_count * 27, g->probe_sh,
           np * 27 * sizeof *r->llg_probe_sh);
    for (size_t i = 0; i < np; i++, r->llg_probe_count++)
      r->llg_probe_index[r->llg_probe_count] = r->llg_probe_count;
  }
  return 1;
}

static void base_free(ub_bakefile_record *r)
{
  free(r->texel_index);
  free(r->texel_sh);
  free(r->probe_index); /* probe_sh is the file's */
  free(r->llg_probe_index);
  free(r->llg_probe_sh);
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
  int with_base = 0, along_normal = 0;
  for (int i = 0; i < argc; i++) {
    const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
    if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
      fputs(HELP, stdout);
      return 0;
    } else if (!strcmp(a, "--base")) {
      with_base = 1;
    } else if (!strcmp(a, "--along-normal")) {
      along_normal = 1;
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
  /* --base: the base bake as one more element, after the files' own */
  ub_bakefile_record base[SPREAD_MAX_FILES];
  int nbase = 0;
  for (; with_base && !status && nbase < n; nbase++)
    if (!base_record(bf[nbase], &base[nbase])) {
      fprintf(stderr, "ubake spread: out of memory\n");
      status = 1;
      nbase++; /* base_free frees what it made */
      break;
    }
  uint32_t nf = status ? 0 : bf[0]->dls_count + bf[0]->elem_count; /* the files' elements */
  uint32_t ne = nf + (status ? 0 : (uint32_t)with_base), shown = 0;
#define ELEM(j, e) ((e) < nf ? element(bf[j], (e)) : &base[j])
  for (uint32_t e = 0; only && e < ne; e++)
    shown += !strcmp(only, ELEM(0, e)->name);
  if (!status && only && !shown) {
    fprintf(stderr, "ubake spread: %s: no element named %s\n", path[0], only);
    status = 1;
    ne = 0;
  }
  static const char *kind_name[3] = {"texel pixels", "GLG probes", "LLG probes"};
  if (ne)
    printf("%d files; deviation = |value - median| / (|median| + mean |value|)%s%s\n", n,
           isfinite(bound) ? ", bound given" : "",
           along_normal ? "; texel values along the normal" : "");
  for (uint32_t e = 0; e < ne; e++) {
    const char *name = ELEM(0, e)->name;
    if (only && strcmp(only, name))
      continue;
    for (int k = 0; k < 3; k++) {
      size_t used = 0;
      for (int j = 0; j < n; j++) {
        const uint32_t *idx;
        const float *val;
        size_t stride;
        uint32_t c = rows_of(ELEM(j, e), k, &idx, &val, &stride);
        for (uint32_t i = 0; i < c; i++) {
          size_t q = idx[i];
          float un[3];
          const float *sn = k == 0 && along_normal ? ub_bakefile_pixel_normal(bf[j], q) : NULL;
          int has_n = sn && ub_texel_normal(sn, un); /* padding pixels: normal 0 */
          if (q >= R || (k == 0 && along_normal && !has_n))
            continue;
          if (!seen[q]) {
            seen[q] = 1;
            list[used++] = (uint32_t)q;
            for (int jj = 0; jj < n; jj++)
              v[q * n + jj] = 0.0f;
          }
          const float *s = val + stride * i;
          float iz[UB_SH1_FLOATS]; /* the file's I_z form: I_z in place of L00 */
          if (has_n) {
            memcpy(iz, s, sizeof iz);
            ub_texel_sh_pack(iz, un);
            s = iz;
          }
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
#undef ELEM
  if (!status && !ne)
    printf("no dynamic elements\n");
  for (int j = 0; j < nbase; j++)
    base_free(&base[j]);
  free(v);
  free(srt);
  free(seen);
  free(list);
  for (int j = 0; j < n; j++)
    ub_bakefile_free(bf[j]);
  return status;
}
