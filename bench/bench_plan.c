/* bench_plan — what the bake plan saves: planned vs --plan all (every effect forced on, no
 * culling) seconds per level, with the planned estimate and the difference in the
 * level's mean lightmap irradiance. Prints; asserts nothing.
 * usage: bench_plan [--quality draft|fast|high] LEVEL...   (default: the synthetic hallway
 * and sunroom from UB_BUILD/levels) */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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
        float e[3];
        ub_runtime_texel_irradiance(rt, a, (uint32_t)(px % f->atlases[a].width),
                                    (uint32_t)(px / f->atlases[a].width),
                                    f->atlases[a].normal + 3 * px, e);
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
  const char *levels[32];
  char def[2][1024];
  int nl = 0;
  for (int i = 1; i < argc && nl < 32; i++) {
    if (!strcmp(argv[i], "--quality") && i + 1 < argc) {
      i++;
      q = !strcmp(argv[i], "high") ? UB_QUALITY_HIGH
                                   : (!strcmp(argv[i], "fast") ? UB_QUALITY_FAST : UB_QUALITY_DRAFT);
    } else {
      levels[nl++] = argv[i];
    }
  }
  if (nl == 0) {
    snprintf(def[0], sizeof def[0], "%s/levels/hallway.gltf", build);
    snprintf(def[1], sizeof def[1], "%s/levels/sunroom.gltf", build);
    levels[nl++] = def[0];
    levels[nl++] = def[1];
  }
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
      return 1;
    }
    double ma = mean_irradiance(st[0].ubk_path), mb = mean_irradiance(st[1].ubk_path);
    printf("  %-44s %9.2f %9.2f %7.2f %9.3f%%\n", levels[l], st[0].total_seconds,
           st[1].total_seconds, st[0].total_seconds / st[1].total_seconds,
           mb > 0 ? 100.0 * (mb - ma) / mb : 0.0);
  }
  printf("ratio = planned / forced seconds; mean diff = relative difference of the mean "
         "lightmap irradiance (forced - planned) / forced\n");
  return 0;
}
