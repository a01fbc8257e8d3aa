/* bench_bounces — what the automatic bounce count buys, and what stopping earlier costs.
 * Bakes a level with fixed bounce counts, with the automatic stop (the default: a bounce
 * adds < 0.5% of the light so far over the level, and at most 1% of the lit texels gain
 * more than 0.5% of their own light, bake/pass.c) and with a reference of many bounces,
 * all with one seed. Bounces 1..k trace the same rays whatever the count (the random
 * numbers are keyed by bounce), so a bake's difference from the reference is exactly the
 * light of the bounces it left out, without noise. Per bake: the base pass's and the sets'
 * seconds, and per texel |L − L_ref| / L_ref of the DC luminance over the lit texels (the
 * stop rule's: above 0.1% of the level's mean) for the base lightmap and, over the texels
 * both records hold, every set's record (above 0.1% of the set's mean): p50, p90, p99,
 * max, and the share of texels off by more than 1%. Prints; asserts nothing.
 * usage: bench_bounces [--quality draft|fast|high] [--ref-bounces N] [LEVEL.gltf]
 * Default: UB_BUILD/levels/estate_small.gltf, draft, reference 40 bounces. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench/bench_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"

static double dc_lum(const float *sh)
{
  return 0.2126 * sh[0] + 0.7152 * sh[1] + 0.0722 * sh[2];
}

/* Per-texel relative errors, appended to e (capacity checked by the caller). */
typedef struct errs {
  double *v;
  size_t n;
} errs;

static void base_errors(const ub_bakefile *a, const ub_bakefile *r, errs *e)
{
  double mean = 0.0;
  size_t covered = 0;
  for (uint32_t k = 0; k < r->atlas_count; k++) {
    const ub_bakefile_atlas *R = &r->atlases[k];
    for (size_t i = 0; i < (size_t)R->width * R->height; i++)
      if (R->coverage[i] == 1) {
        mean += dc_lum(R->sh + 12 * i);
        covered++;
      }
  }
  mean /= covered ? (double)covered : 1.0;
  for (uint32_t k = 0; k < r->atlas_count && k < a->atlas_count; k++) {
    const ub_bakefile_atlas *A = &a->atlases[k], *R = &r->atlases[k];
    for (size_t i = 0; i < (size_t)R->width * R->height; i++) {
      double y = dc_lum(R->sh + 12 * i);
      if (R->coverage[i] == 1 && y > 1e-3 * mean)
        e->v[e->n++] = fabs(dc_lum(A->sh + 12 * i) - y) / y;
    }
  }
}

static void set_errors(const ub_bakefile *a, const ub_bakefile *r, errs *e)
{
  for (uint32_t d = 0; d < a->dls_count && d < r->dls_count; d++) {
    const ub_bakefile_record *A = &a->dls[d], *R = &r->dls[d];
    double mean = 0.0;
    for (uint32_t j = 0; j < R->texel_count; j++)
      mean += dc_lum(R->texel_sh + 12 * (size_t)j);
    mean /= R->texel_count ? (double)R->texel_count : 1.0;
    uint32_t j = 0;
    for (uint32_t i = 0; i < A->texel_count; i++) {
      while (j < R->texel_count && R->texel_index[j] < A->texel_index[i])
        j++;
      if (j >= R->texel_count || R->texel_index[j] != A->texel_index[i])
        continue;
      double y = dc_lum(R->texel_sh + 12 * (size_t)j);
      if (y > 1e-3 * mean)
        e->v[e->n++] = fabs(dc_lum(A->texel_sh + 12 * (size_t)i) - y) / y;
    }
  }
}

static void print_errs(errs *e)
{
  if (!e->n) {
    printf(" %44s", "-");
    return;
  }
  size_t over = 0;
  for (size_t i = 0; i < e->n; i++)
    over += e->v[i] > 0.01;
  double share = (double)over / (double)e->n;
  double p50 = ub_bench_percentile(e->v, e->n, 0.5), p90 = ub_bench_percentile(e->v, e->n, 0.9);
  double p99 = ub_bench_percentile(e->v, e->n, 0.99), mx = ub_bench_percentile(e->v, e->n, 1.0);
  printf(" %6.2f %6.2f %6.2f %7.2f %7.2f%%", 100 * p50, 100 * p90, 100 * p99, 100 * mx,
         100 * share);
}

int main(int argc, char **argv)
{
  const char *build = getenv("UB_BUILD") ? getenv("UB_BUILD") : "build";
  ub_quality q = UB_QUALITY_DRAFT;
  int ref_bounces = 40;
  char level[1024];
  snprintf(level, sizeof level, "%s/levels/estate_small.gltf", build);
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--quality") && i + 1 < argc) {
      q = ub_bench_quality(argv[++i]);
    } else if (!strcmp(argv[i], "--ref-bounces") && i + 1 < argc) {
      ref_bounces = atoi(argv[++i]);
    } else if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
      printf("usage: bench_bounces [--quality draft|fast|high] [--ref-bounces N] [LEVEL.gltf]\n"
             "Bakes LEVEL (default UB_BUILD/levels/estate_small.gltf, draft) with 4, 8 and\n"
             "12 bounces, the automatic stop, and N bounces (default 40) as the reference,\n"
             "one seed: prints each bake's seconds and its per-texel error against the\n"
             "reference (the light of the bounces it left out), base lightmap and sets.\n");
      return 0;
    } else if (argv[i][0] == '-') {
      fprintf(stderr, "bench_bounces: unknown option %s (see --help)\n", argv[i]);
      return 2;
    } else {
      snprintf(level, sizeof level, "%s", argv[i]);
    }
  }
  if (ref_bounces < 2 || ref_bounces > UB_BAKE_MAX_BOUNCES) {
    fprintf(stderr, "bench_bounces: --ref-bounces %d is outside 2..%d\n", ref_bounces,
            UB_BAKE_MAX_BOUNCES);
    return 2;
  }
  /* the reference first, then the others against it; -1: automatic */
  int counts[5] = {ref_bounces, 4, 8, 12, -1};
  ub_bake_stats st[5];
  ub_bakefile *bf[5] = {NULL, NULL, NULL, NULL, NULL};
  for (int k = 0; k < 5; k++) {
    if (counts[k] >= ref_bounces && k > 0)
      continue;
    ub_bake_options o;
    ub_bake_options_default(&o);
    o.quality = q;
    o.bounces = counts[k];
    char dir[1100];
    if (counts[k] < 0)
      snprintf(dir, sizeof dir, "%s/bench_out/bounces_auto", build);
    else
      snprintf(dir, sizeof dir, "%s/bench_out/bounces_%d", build, counts[k]);
    o.out_dir = dir;
    printf("baking %s (%s)...\n", level, dir);
    fflush(stdout);
    if (ub_bake_level(level, &o, NULL, &st[k]) != UB_OK ||
        ub_bakefile_read(st[k].ubk_path, NULL, &bf[k]) != UB_OK) {
      fprintf(stderr, "bench_bounces: the bake of %s into %s failed\n", level, dir);
      return 1;
    }
  }
  printf("bench_bounces (%s, %s; per-texel |L - L_ref| / L_ref against %d bounces, same seed):\n",
         level, ub_quality_name(q), ref_bounces);
  printf("  %-9s %7s %8s %8s | %-44s | %-44s\n", "bounces", "run", "base s", "sets s",
         "base texels: p50 p90 p99 max, share > 1%", "set records: p50 p90 p99 max, > 1%");
  for (int k = 1; k < 5; k++) {
    if (!bf[k])
      continue;
    size_t cap = 1 + ub_bakefile_atlas_pixels(bf[0]);
    size_t scap = 1;
    for (uint32_t d = 0; d < bf[k]->dls_count; d++)
      scap += bf[k]->dls[d].texel_count;
    errs eb = {malloc(cap * sizeof(double)), 0}, es = {malloc(scap * sizeof(double)), 0};
    if (!eb.v || !es.v) {
      fprintf(stderr, "bench_bounces: out of memory\n");
      return 1;
    }
    base_errors(bf[k], bf[0], &eb);
    set_errors(bf[k], bf[0], &es);
    char name[16];
    if (counts[k] < 0)
      snprintf(name, sizeof name, "auto");
    else
      snprintf(name, sizeof name, "%d", counts[k]);
    printf("  %-9s %7u %8.2f %8.2f |", name, st[k].bounces,
           ub_bench_stage_seconds(&st[k], "base pass"), ub_bench_stage_seconds(&st[k], "dls"));
    print_errs(&eb);
    printf(" |");
    print_errs(&es);
    printf("\n");
    free(eb.v);
    free(es.v);
  }
  printf("  %-9s %7u %8.2f %8.2f | (reference)\n", "ref", st[0].bounces,
         ub_bench_stage_seconds(&st[0], "base pass"), ub_bench_stage_seconds(&st[0], "dls"));
  for (int k = 0; k < 5; k++)
    ub_bakefile_free(bf[k]);
  return 0;
}
