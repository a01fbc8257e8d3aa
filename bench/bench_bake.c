/* bench_bake — bake throughput against the ray-tracing ceiling measured in the same run.
 *
 * For each level: the ceiling is random incoherent closest-hit (and shadow) rays from
 * random surface points in uniformly random directions, traced through the same Embree
 * scene and wrapper the baker uses, on all threads. Then the level is baked at draft, fast
 * and high: gather+shadow rays/s of the passes, their ratio to the ceiling, core-seconds
 * per texel, and peak RSS. Prints figures; asserts nothing. */
#include <math.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bake/output.h"
#include "bench/bench_util.h"
#include "ubake/bake.h"
#include "ubake/scene.h"

int main(int argc, char **argv)
{
  const char *build = getenv("UB_BUILD") ? getenv("UB_BUILD") : "build";
  char def[3][1024];
  const char *levels[16];
  int nl = 0;
  for (int i = 1; i < argc && nl < 16; i++)
    levels[nl++] = argv[i];
  if (nl == 0) {
    snprintf(def[0], sizeof def[0], "%s/levels/cornell.gltf", build);
    snprintf(def[1], sizeof def[1], "%s/levels/sunroom.gltf", build);
    levels[nl++] = def[0];
    levels[nl++] = def[1];
  }
  int threads = omp_get_max_threads();
  printf("bench_bake: %d threads\n", threads);
  for (int l = 0; l < nl; l++) {
    ub_scene *s = NULL;
    ub_rt *rt = NULL;
    if (ub_scene_load(levels[l], NULL, &s) != UB_OK || ub_rt_create(s, NULL, NULL, &rt) != UB_OK) {
      fprintf(stderr, "bench_bake: cannot load %s\n", levels[l]);
      return 1;
    }
    double hit, shadow;
    ub_bench_ceiling(s, rt, &hit, &shadow);
    printf("\n%s: %u triangles\n", levels[l], s->triangle_count);
    printf("  ceiling (random incoherent, same scene, %d threads): %.2f M closest-hit rays/s, "
           "%.2f M shadow rays/s\n",
           threads, hit * 1e-6, shadow * 1e-6);
    ub_rt_free(rt);
    ub_scene_free(s);
    printf("  %-6s %9s %7s %8s %10s %10s %8s %12s %9s\n", "preset", "texels", "bounce", "seconds",
           "gatherM/s", "shadowM/s", "ratio", "core-us/tex", "peakMB");
    for (int q = UB_QUALITY_DRAFT; q <= UB_QUALITY_HIGH; q++) {
      ub_bake_options o;
      ub_bake_options_default(&o);
      o.quality = (ub_quality)q;
      char dir[1100];
      snprintf(dir, sizeof dir, "%s/bench_out", build);
      o.out_dir = dir;
      ub_bake_stats st;
      if (ub_bake_level(levels[l], &o, NULL, &st) != UB_OK) {
        fprintf(stderr, "bench_bake: bake of %s failed\n", levels[l]);
        return 1;
      }
      double g = st.gather_seconds > 0 ? st.rays_gather / st.gather_seconds : 0;
      double sh = st.gather_seconds > 0 ? st.rays_shadow / st.gather_seconds : 0;
      /* Ratio: the pass's mixed ray rate against the ceiling for the same ray mix. */
      double ratio = ub_bench_ceiling_ratio((double)st.rays_gather, (double)st.rays_shadow,
                                            st.gather_seconds, hit, shadow);
      printf("  %-6s %9u %7u %8.2f %10.2f %10.2f %8.2f %12.2f %9.1f\n", ub_quality_name(o.quality),
             st.texels, st.bounces, st.total_seconds, g * 1e-6, sh * 1e-6, ratio,
             1e6 * st.total_seconds * threads / (st.texels ? st.texels : 1),
             st.peak_rss_kb / 1024.0);
    }
  }
  printf("\nratio = (gather+shadow rays / pass seconds) / (ceiling rate for the same mix of "
         "closest-hit and shadow rays); target >= 0.7\n");
  return 0;
}
