/* bench_plan — what the bake plan saves: planned vs --plan all (every effect forced on, no
 * culling) seconds per level, with the planned estimate and the difference in the
 * level's mean lightmap irradiance. Prints; asserts nothing.
 * usage: bench_plan [--quality draft|fast|high] [--estate-scale S] LEVEL...
 * Default levels: every shipped level — the synthetic levels in UB_BUILD/levels, the real
 * levels in UB_SHARED (default ../shared/levels/real) — and the ESTATE-scale level
 * generated at scale S (default 0.05, as bench_estate; 0 leaves it out). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <dirent.h>

#include "bench/bench_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/runtime.h"

static double mean_irradiance(const char *ubk)
{
  ub_runtime *rt = NULL;
  if (ub_runtime_load(ubk, NULL, &rt) != UB_OK)
    return NAN;
  const ub_bakefile *f = ub_runtime_bakefile(rt);
  double s = 0.0;
  size_t n = 0;
  for (uint32_t a = 0; a < f->atlas_count; a++)
    for (size_t px = 0; px < (size_t)f->atlases[a].width * f->atlases[a].height; px++)
      if (f->atlases[a].coverage[px] == 1) {
        float e[3], nn[3];
        uint32_t x = (uint32_t)(px % f->atlases[a].width), y = (uint32_t)(px / f->atlases[a].width);
        ub_runtime_texel_normal(rt, a, x, y, nn);
        ub_runtime_texel_irradiance(rt, a, x, y, nn, e);
        s += e[1];
        n++;
      }
  ub_runtime_free(rt);
  return n ? s / n : 0.0;
}

int main(int argc, char **argv)
{
  const char *build = getenv("UB_BUILD") ? getenv("UB_BUILD") : "build";
  ub_quality q = UB_QUALITY_DRAFT;
  enum { MAXL = 64 };
  const char *levels[MAXL];
  static char def[MAXL][1024];
  int nl = 0, nd = 0;
  double estate_scale = 0.05;
  for (int i = 1; i < argc && nl < MAXL; i++) {
    if (!strcmp(argv[i], "--quality") && i + 1 < argc) {
      q = ub_bench_quality(argv[++i]);
    } else if (!strcmp(argv[i], "--estate-scale") && i + 1 < argc) {
      estate_scale = strtod(argv[++i], NULL);
    } else if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
      printf("usage: bench_plan [--quality draft|fast|high] [--estate-scale S] [LEVEL...]\n"
             "Bakes each level planned and with --plan all; prints seconds, their ratio and\n"
             "the difference of the mean lightmap irradiance. Default: every level in\n"
             "UB_BUILD/levels, the real levels in UB_SHARED, and the ESTATE-scale level at\n"
             "scale S (default 0.05; 0: left out).\n");
      return 0;
    } else {
      levels[nl++] = argv[i];
    }
  }
  if (nl == 0) {
    /* the synthetic levels, sorted by name */
    char dirp[768];
    snprintf(dirp, sizeof dirp, "%s/levels", build);
    DIR *dd = opendir(dirp);
    for (struct dirent *e; dd && (e = readdir(dd)) != NULL && nd < MAXL - 8;) {
      size_t n = strlen(e->d_name);
      if (n > 5 && !strcmp(e->d_name + n - 5, ".gltf"))
        snprintf(def[nd++], sizeof def[0], "%s/%.250s", dirp, e->d_name);
    }
    if (dd)
      closedir(dd);
    qsort(def, (size_t)nd, sizeof def[0], (int (*)(const void *, const void *))strcmp);
    const char *shared = getenv("UB_SHARED") ? getenv("UB_SHARED") : "../shared/levels/real";
    static const char *real[] = {"oa_dm4", "q3dm6ish", "kaos"};
    for (int r = 0; r < 3; r++) {
      snprintf(def[nd], sizeof def[0], "%s/%s/%s.gltf", shared, real[r], real[r]);
      FILE *f = fopen(def[nd], "rb");
      if (f) {
        fclose(f);
        nd++;
      } else {
        printf("  (%s not found: left out)\n", def[nd]);
      }
    }
    if (estate_scale > 0) {
      char out[4096];
      snprintf(out, sizeof out, "%s/bench_out", build);
      if (ub_bench_genlevel(build, "estate", out, "estate_plan", estate_scale, NULL, 0, 0) >= 0)
        snprintf(def[nd++], sizeof def[0], "%s/bench_out/estate_plan.gltf", build);
      else
        fprintf(stderr, "bench_plan: could not generate the ESTATE-scale level\n");
    }
    for (int i = 0; i < nd; i++)
      levels[nl++] = def[i];
  }
  double sum_p = 0.0, sum_a = 0.0;
  printf("bench_plan (%s): planned bake vs --plan all\n", ub_quality_name(q));
  printf("  %-44s %9s %9s %7s %10s\n", "level", "planned s", "all s", "ratio", "mean diff");
  for (int l = 0; l < nl; l++) {
    ub_bake_stats st[2];
    int ok = 1;
    for (int all = 0; all < 2 && ok; all++) {
      ub_bake_options o;
      ub_bake_options_default(&o);
      o.quality = q;
      o.plan_all = all;
      char dir[1100];
      snprintf(dir, sizeof dir, "%s/bench_out/plan_%d_%d", build, l, all);
      o.out_dir = dir;
      ok = ub_bake_level(levels[l], &o, NULL, &st[all]) == UB_OK;
    }
    if (!ok) {
      fprintf(stderr, "bench_plan: bake of %s failed\n", levels[l]);
      continue;
    }
    fflush(stdout);
    double ma = mean_irradiance(st[0].ubk_path), mb = mean_irradiance(st[1].ubk_path);
    sum_p += st[0].total_seconds;
    sum_a += st[1].total_seconds;
    const char *base = strrchr(levels[l], '/');
    printf("  %-44s %9.2f %9.2f %7.2f %9.3f%%\n", base ? base + 1 : levels[l], st[0].total_seconds,
           st[1].total_seconds, st[0].total_seconds / st[1].total_seconds,
           mb > 0 ? 100.0 * (mb - ma) / mb : 0.0);
  }
  printf("  %-44s %9.2f %9.2f %7.2f\n", "all levels", sum_p, sum_a, sum_a > 0 ? sum_p / sum_a : 0.0);
  printf("ratio = planned / forced seconds; mean diff = relative difference of the mean "
         "lightmap irradiance (forced - planned) / forced\n");
  return 0;
}
