/* bench_dls_rays — what the DLS full passes' scaled rays cost in accuracy and save in
 * time. Bakes a level three times: default (rays scaled down where a set's light is faint,
 * bake/dls.h), --dls-full-rays (every kept receiver at the full rays), and a reference
 * with REF times the gather rays at full rays (another seed). Per set, each record's error
 * against the reference: texels and GLG probes, their DC (green), over the receivers of
 * either record (one without the other counts as zero):
 *   L1  = Σ|a − ref| / Σ|ref|;
 *   p99, max = the 99th percentile and the largest |a − ref| over the set's mean |ref|
 *         on its brightest tenth of receivers (how large a receiver's error is next to
 *         the light a player sees where the set shines).
 * The reference's own noise is in both figures, alike for both bakes. Prints; asserts
 * nothing.
 * usage: bench_dls_rays [--quality draft|fast|high] [--bounces N] [--texel-size M]
 *                       [--ref R] [--reuse-ref] [LEVEL.gltf]
 * Default: UB_BUILD/levels/estate_small.gltf, draft, 2 bounces, 0.4 m texels, R = 16. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench/bench_util.h"
#include "tests/report_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"

/* Errors of record a (sorted receivers ia, values va of stride floats) against ref (ib,
 * vb): the DC, green. */
typedef struct rec_err {
  double l1, p99, max_rel;
} rec_err;

static int cmp_desc(const void *x, const void *y)
{
  double a = *(const double *)x, b = *(const double *)y;
  return (a < b) - (a > b);
}

static rec_err record_error(const uint32_t *ia, const float *va, uint32_t na, const uint32_t *ib,
                            const float *vb, uint32_t nb, uint32_t stride)
{
  rec_err e = {0.0, 0.0, 0.0};
  double sum_ref = 0.0, sum_err = 0.0, worst = 0.0;
  double *bright = malloc(((size_t)nb + 1) * sizeof *bright);
  double *errs = malloc(((size_t)na + nb + 1) * sizeof *errs);
  size_t ne = 0;
  uint32_t i = 0, j = 0;
  while (i < na || j < nb) {
    double a = 0.0, r = 0.0;
    if (j >= nb || (i < na && ia[i] < ib[j])) {
      a = va[stride * (size_t)i++ + 1];
    } else if (i >= na || ib[j] < ia[i]) {
      r = vb[stride * (size_t)j++ + 1];
    } else {
      a = va[stride * (size_t)i++ + 1];
      r = vb[stride * (size_t)j++ + 1];
    }
    sum_ref += fabs(r);
    sum_err += fabs(a - r);
    worst = fmax(worst, fabs(a - r));
    if (errs)
      errs[ne++] = fabs(a - r);
  }
  for (uint32_t k = 0; bright && k < nb; k++)
    bright[k] = fabs(vb[stride * (size_t)k + 1]);
  double top = 0.0;
  uint32_t nt = nb / 10 ? nb / 10 : nb;
  if (bright && nb) {
    qsort(bright, nb, sizeof *bright, cmp_desc);
    for (uint32_t k = 0; k < nt; k++)
      top += bright[k];
    top /= nt;
  }
  free(bright);
  double p99 = errs ? ub_bench_percentile(errs, ne, 0.99) : 0.0;
  free(errs);
  e.l1 = sum_ref > 0.0 ? sum_err / sum_ref : 0.0;
  e.p99 = top > 0.0 ? p99 / top : 0.0;
  e.max_rel = top > 0.0 ? worst / top : 0.0;
  return e;
}

int main(int argc, char **argv)
{
  const char *build = getenv("UB_BUILD") ? getenv("UB_BUILD") : "build";
  ub_quality q = UB_QUALITY_DRAFT;
  int bounces = 2;
  float texel = 0.4f;
  uint32_t refm = 16;
  int reuse = 0;
  char level[1024];
  snprintf(level, sizeof level, "%s/levels/estate_small.gltf", build);
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--quality") && i + 1 < argc) {
      q = ub_bench_quality(argv[++i]);
    } else if (!strcmp(argv[i], "--bounces") && i + 1 < argc) {
      bounces = atoi(argv[++i]);
    } else if (!strcmp(argv[i], "--texel-size") && i + 1 < argc) {
      texel = strtof(argv[++i], NULL);
    } else if (!strcmp(argv[i], "--ref") && i + 1 < argc) {
      refm = (uint32_t)strtoul(argv[++i], NULL, 10);
    } else if (!strcmp(argv[i], "--reuse-ref")) {
      reuse = 1;
    } else if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
      printf("usage: bench_dls_rays [--quality draft|fast|high] [--bounces N] [--texel-size M]\n"
             "                      [--ref R] [--reuse-ref] [LEVEL.gltf]\n"
             "Bakes LEVEL (default UB_BUILD/levels/estate_small.gltf, draft, 2 bounces, 0.4 m\n"
             "texels) with the DLS full passes' rays scaled (default) and full\n"
             "(--dls-full-rays), and a reference at R x the gather rays (default 16); prints\n"
             "the DLS stage's seconds and each set's record error against the reference.\n"
             "--reuse-ref: read the reference an earlier run left in UB_BUILD/bench_out.\n");
      return 0;
    } else if (argv[i][0] == '-') {
      fprintf(stderr, "bench_dls_rays: unknown option %s (see --help)\n", argv[i]);
      return 2;
    } else {
      snprintf(level, sizeof level, "%s", argv[i]);
    }
  }
  if (refm < 2)
    refm = 2;
  static const char *names[3] = {"scaled", "full", "reference"};
  ub_bake_stats st[3];
  ub_bakefile *bf[3] = {NULL, NULL, NULL};
  /* the presets' gather rays (bake/plan.c) */
  uint32_t rays = q == UB_QUALITY_HIGH ? 1024 : (q == UB_QUALITY_FAST ? 256 : 64);
  for (int k = 0; k < 3; k++) {
    ub_bake_options o;
    ub_bake_options_default(&o);
    o.quality = q;
    o.bounces = bounces;
    o.texel_size = texel;
    o.dls_full_rays = k > 0;
    if (k == 2) {
      o.gather_rays = refm * rays;
      o.seed = 7;
    }
    char dir[1100];
    snprintf(dir, sizeof dir, "%s/bench_out/dls_rays_%s", build, names[k]);
    o.out_dir = dir;
    if (k == 2 && reuse) {
      const char *b = strrchr(level, '/');
      b = b ? b + 1 : level;
      size_t nb = strlen(b) > 5 && !strcmp(b + strlen(b) - 5, ".gltf") ? strlen(b) - 5 : strlen(b);
      memset(&st[k], 0, sizeof st[k]);
      snprintf(st[k].ubk_path, sizeof st[k].ubk_path, "%.900s/%.*s.ubk", dir, (int)(nb < 100 ? nb : 100), b);
      if (ub_bakefile_read(st[k].ubk_path, NULL, &bf[k]) == UB_OK) {
        printf("reference: %s (an earlier run's)\n", st[k].ubk_path);
        continue;
      }
    }
    printf("baking %s (%s)...\n", level, names[k]);
    fflush(stdout);
    if (ub_bake_level(level, &o, NULL, &st[k]) != UB_OK ||
        ub_bakefile_read(st[k].ubk_path, NULL, &bf[k]) != UB_OK) {
      fprintf(stderr, "bench_dls_rays: the %s bake of %s failed\n", names[k], level);
      return 1;
    }
  }
  if (bf[0]->dls_count == 0 || bf[0]->dls_count != bf[1]->dls_count ||
      bf[0]->dls_count != bf[2]->dls_count) {
    fprintf(stderr, "bench_dls_rays: %s has no sets (or the bakes disagree on them)\n", level);
    return 1;
  }
  printf("bench_dls_rays (%s, %d bounces, %.2f m texels; reference %u x %u rays):\n",
         ub_quality_name(q), bounces, texel, refm, rays);
  printf("  %-16s %17s %17s %17s %17s %17s\n", "set", "texels L1", "texels p99",
         "texels max", "probes L1", "probes p99");
  printf("  %-16s %17s %17s %17s %17s %17s\n", "", "scaled / full", "scaled / full",
         "scaled / full", "scaled / full", "scaled / full");
  double sl1[2][2] = {{0, 0}, {0, 0}}, sp99[2][2] = {{0, 0}, {0, 0}}, smax[2] = {0, 0};
  for (uint32_t d = 0; d < bf[0]->dls_count; d++) {
    const ub_bakefile_record *r[3] = {&bf[0]->dls[d], &bf[1]->dls[d], &bf[2]->dls[d]};
    rec_err te[2], pe[2];
    for (int k = 0; k < 2; k++) {
      te[k] = record_error(r[k]->texel_index, r[k]->texel_sh, r[k]->texel_count,
                           r[2]->texel_index, r[2]->texel_sh, r[2]->texel_count, 12);
      pe[k] = record_error(r[k]->probe_index, r[k]->probe_sh, r[k]->probe_count,
                           r[2]->probe_index, r[2]->probe_sh, r[2]->probe_count, 27);
      sl1[k][0] += te[k].l1;
      sl1[k][1] += pe[k].l1;
      sp99[k][0] += te[k].p99;
      sp99[k][1] += pe[k].p99;
      smax[k] = fmax(smax[k], te[k].max_rel);
    }
    printf("  %-16s %7.2f%% /%6.2f%% %7.2f%% /%6.2f%% %7.1f%% /%6.1f%% %7.2f%% /%6.2f%% %7.2f%% "
           "/%6.2f%%\n",
           r[0]->name, 100 * te[0].l1, 100 * te[1].l1, 100 * te[0].p99, 100 * te[1].p99,
           100 * te[0].max_rel, 100 * te[1].max_rel, 100 * pe[0].l1, 100 * pe[1].l1,
           100 * pe[0].p99, 100 * pe[1].p99);
  }
  uint32_t n = bf[0]->dls_count;
  printf("  %-16s %7.2f%% /%6.2f%% %7.2f%% /%6.2f%% %7.1f%% /%6.1f%% %7.2f%% /%6.2f%% %7.2f%% "
         "/%6.2f%%\n",
         "mean (max: worst)", 100 * sl1[0][0] / n, 100 * sl1[1][0] / n, 100 * sp99[0][0] / n,
         100 * sp99[1][0] / n, 100 * smax[0], 100 * smax[1], 100 * sl1[0][1] / n,
         100 * sl1[1][1] / n, 100 * sp99[0][1] / n, 100 * sp99[1][1] / n);
  const double d0 = ub_bench_stage_seconds(&st[0], "dls");
  const double d1 = ub_bench_stage_seconds(&st[1], "dls");
  double b0 = st[0].total_seconds - d0, b1 = st[1].total_seconds - d1;
  printf("  full passes' gathers: scaled %.1f%% of the full rays\n",
         100 * ub_report_number(st[0].ubk_path, "gather_share"));
  printf("  dls stage: scaled %.2f s, full rays %.2f s (%.2fx); the bake without it %.2f / "
         "%.2f s; bake / bake without the sets' stage: scaled %.2fx, full %.2fx; reference "
         "%.2f s\n",
         d0, d1, d0 > 0 ? d1 / d0 : 0.0, b0,
         b1, b0 > 0 ? st[0].total_seconds / b0 : 0.0, b1 > 0 ? st[1].total_seconds / b1 : 0.0,
         st[2].total_seconds);
  printf("L1 = sum |record - reference| / sum |reference| (DC, green; receivers of either); "
         "p99, max = 99th percentile, largest |record - reference| / mean of the "
         "reference's brightest tenth\n");
  for (int k = 0; k < 3; k++)
    ub_bakefile_free(bf[k]);
  return 0;
}
