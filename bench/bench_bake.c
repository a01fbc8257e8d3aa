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

#include "bake/lights.h"
#include "bake/output.h"
#include "bake/rt.h"
#include "ubake/bake.h"
#include "ubake/scene.h"

#define CHUNK 4096

static double now_s(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void random_ray(const ub_scene *s, const ub_rt *rt, const float *cdf, uint32_t i,
                       ub_ray *r)
{
  uint32_t h = ub_hash4(99, i, 0, 0);
  float u0 = ub_u01(h);
  uint32_t lo = 0, hi = s->triangle_count - 1;
  while (lo < hi) {
    uint32_t mid = (lo + hi) / 2;
    if (cdf[mid] > u0)
      hi = mid;
    else
      lo = mid + 1;
  }
  const float *a = s->positions + 3 * s->indices[3 * lo];
  const float *b = s->positions + 3 * s->indices[3 * lo + 1];
  const float *c = s->positions + 3 * s->indices[3 * lo + 2];
  float u1 = sqrtf(ub_u01(ub_hash4(h, 1, 0, 0))), u2 = ub_u01(ub_hash4(h, 2, 0, 0));
  float p[3], nz = 2.0f * ub_u01(ub_hash4(h, 3, 0, 0)) - 1.0f;
  float phi = 6.2831853f * ub_u01(ub_hash4(h, 4, 0, 0)), rr = sqrtf(fmaxf(0.0f, 1 - nz * nz));
  for (int k = 0; k < 3; k++)
    p[k] = (1 - u1) * a[k] + u1 * (1 - u2) * b[k] + u1 * u2 * c[k];
  r->dir[0] = rr * cosf(phi);
  r->dir[1] = nz;
  r->dir[2] = rr * sinf(phi);
  ub_rt_offset_point(rt, p, r->dir, r->org);
  r->tnear = 0.0f;
  r->tfar = INFINITY;
}

static void ceiling(const ub_scene *s, const ub_rt *rt, double *out_hit, double *out_shadow)
{
  float *cdf = malloc(s->triangle_count * sizeof *cdf);
  double acc = 0.0;
  for (uint32_t t = 0; t < s->triangle_count; t++) {
    const float *a = s->positions + 3 * s->indices[3 * t];
    const float *b = s->positions + 3 * s->indices[3 * t + 1];
    const float *c = s->positions + 3 * s->indices[3 * t + 2];
    float e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    float e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    float x = e1[1] * e2[2] - e1[2] * e2[1], y = e1[2] * e2[0] - e1[0] * e2[2],
          z = e1[0] * e2[1] - e1[1] * e2[0];
    acc += 0.5 * sqrt(x * x + y * y + z * z);
    cdf[t] = (float)acc;
  }
  for (uint32_t t = 0; t < s->triangle_count; t++)
    cdf[t] /= (float)acc;
  const uint32_t N = 4u << 20;
  double t0 = now_s();
#pragma omp parallel
  {
    ub_ray *rays = malloc(CHUNK * sizeof *rays);
    ub_hit *hits = malloc(CHUNK * sizeof *hits);
#pragma omp for schedule(dynamic, 1)
    for (uint32_t c = 0; c < N / CHUNK; c++) {
      for (uint32_t i = 0; i < CHUNK; i++)
        random_ray(s, rt, cdf, c * CHUNK + i, &rays[i]);
      ub_rt_intersect(rt, rays, CHUNK, hits);
    }
    free(rays);
    free(hits);
  }
  *out_hit = N / (now_s() - t0);
  t0 = now_s();
#pragma omp parallel
  {
    ub_ray *rays = malloc(CHUNK * sizeof *rays);
    uint8_t *occ = malloc(CHUNK);
#pragma omp for schedule(dynamic, 1)
    for (uint32_t c = 0; c < N / CHUNK; c++) {
      for (uint32_t i = 0; i < CHUNK; i++) {
        random_ray(s, rt, cdf, c * CHUNK + i, &rays[i]);
        rays[i].tfar = 0.5f * ub_scene_extent(s) * ub_u01(ub_hash4(c, i, 5, 0));
      }
      ub_rt_occluded(rt, rays, CHUNK, occ);
    }
    free(rays);
    free(occ);
  }
  *out_shadow = N / (now_s() - t0);
  free(cdf);
}

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
    ceiling(s, rt, &hit, &shadow);
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
      double mix_ceiling = (st.rays_gather + st.rays_shadow) /
                           (st.rays_gather / hit + st.rays_shadow / shadow + 1e-30);
      double ratio = (st.rays_gather + st.rays_shadow) / (st.gather_seconds + 1e-30) / mix_ceiling;
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
