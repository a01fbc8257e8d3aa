/* bench/bench_util.h — helpers the benchmarks share (header-only, static inline).
 *
 * - ub_bench_now(): monotonic seconds;
 * - ub_bench_percentile(): a percentile of a sample (sorts it in place);
 * - ub_bench_ceiling(): the ray-tracing ceiling of a scene — random incoherent
 *   closest-hit and shadow rays from area-uniform surface points in uniform directions,
 *   through the same Embree wrapper the baker uses, on all OpenMP threads — so a bake's
 *   rays/s can be compared with what the machine does on that scene in the same run;
 * - ub_bench_rss_kb(): current resident set size (VmRSS), for memory deltas;
 * - ub_bench_load_average(): 1-minute load average (the machine is shared);
 * - ub_bench_genlevel(): runs ubake-genlevel for a generated benchmark level;
 * - ub_bench_stage_seconds(): a bake's seconds in the stages of one name;
 * - ub_bench_quality(): a --quality argument (draft, fast, high; anything else: draft);
 * - ub_bench_make_texels(): deterministic texel rows and normals for the AHD encode.
 * Benchmarks print figures and assert nothing. */
#ifndef UBAKE_BENCH_UTIL_H
#define UBAKE_BENCH_UTIL_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bake/lights.h"
#include "bake/output.h"
#include "bake/rt.h"
#include "ubake/bake.h"
#include "ubake/scene.h"

#define UB_BENCH_CHUNK 4096

static inline double ub_bench_now(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static inline int ub_bench_cmp_double(const void *a, const void *b)
{
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

/* The seconds a bake spent in the stages called name (0 when none ran). */
static inline double ub_bench_stage_seconds(const ub_bake_stats *st, const char *name)
{
  double s = 0.0;
  for (uint32_t i = 0; i < st->stage_count; i++)
    if (!strcmp(st->stage_name[i], name))
      s += st->stage_seconds[i];
  return s;
}

/* A --quality argument: "high", "fast", anything else draft. */
static inline ub_quality ub_bench_quality(const char *arg)
{
  return !strcmp(arg, "high") ? UB_QUALITY_HIGH
                              : (!strcmp(arg, "fast") ? UB_QUALITY_FAST : UB_QUALITY_DRAFT);
}

/* p in [0,1]: the value at rank floor(p·(n−1)) of v sorted (v is sorted in place). */
/* n deterministic texels as a blend gives them (rows: 12 floats each, the SH with I_z in
 * the first three; nrm: a unit normal each): I_z > 0 mostly, linear terms within ±I_z. */
static inline void ub_bench_make_texels(size_t n, float *rows, float *nrm)
{
  uint32_t h = 12345u;
  for (size_t i = 0; i < n; i++) {
    float u[4];
    for (int k = 0; k < 4; k++) {
      h = h * 1664525u + 1013904223u;
      u[k] = (float)(h >> 8) * (1.0f / 16777216.0f);
    }
    float z = 2.0f * u[0] - 1.0f, r = sqrtf(fmaxf(0.0f, 1.0f - z * z)), ph = 6.2831853f * u[1];
    nrm[3 * i] = r * cosf(ph);
    nrm[3 * i + 1] = r * sinf(ph);
    nrm[3 * i + 2] = z;
    for (int c = 0; c < 3; c++)
      rows[12 * i + c] = 0.1f + 4.0f * u[2] * (1.0f + 0.1f * (float)c);
    for (int k = 3; k < 12; k++) {
      h = h * 1664525u + 1013904223u;
      rows[12 * i + k] = ((float)(h >> 8) * (1.0f / 16777216.0f) - 0.4f) * u[3] * 2.0f;
    }
  }
}

static inline double ub_bench_percentile(double *v, size_t n, double p)
{
  if (n == 0)
    return 0.0;
  qsort(v, n, sizeof *v, ub_bench_cmp_double);
  size_t k = (size_t)(p * (double)(n - 1));
  return v[k < n ? k : n - 1];
}

static inline void ub_bench_random_ray(const ub_scene *s, const ub_rt *rt, const float *cdf,
                                       uint32_t i, ub_ray *r)
{
  uint32_t h = ub_hash4(99, i, 0, 0);
  float u0 = ub_u01(h);
  uint32_t lo = ub_cdf_pick(cdf, s->triangle_count, u0);
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

/* Closest-hit and shadow rays per second (all threads) on scene s traced with rt. */
static inline void ub_bench_ceiling(const ub_scene *s, const ub_rt *rt, double *out_hit,
                                    double *out_shadow)
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
  double t0 = ub_bench_now();
#pragma omp parallel
  {
    ub_ray *rays = malloc(UB_BENCH_CHUNK * sizeof *rays);
    ub_hit *hits = malloc(UB_BENCH_CHUNK * sizeof *hits);
#pragma omp for schedule(dynamic, 1)
    for (uint32_t c = 0; c < N / UB_BENCH_CHUNK; c++) {
      for (uint32_t i = 0; i < UB_BENCH_CHUNK; i++)
        ub_bench_random_ray(s, rt, cdf, c * UB_BENCH_CHUNK + i, &rays[i]);
      ub_rt_intersect(rt, rays, UB_BENCH_CHUNK, hits);
    }
    free(rays);
    free(hits);
  }
  *out_hit = N / (ub_bench_now() - t0);
  t0 = ub_bench_now();
#pragma omp parallel
  {
    ub_ray *rays = malloc(UB_BENCH_CHUNK * sizeof *rays);
    uint8_t *occ = malloc(UB_BENCH_CHUNK);
#pragma omp for schedule(dynamic, 1)
    for (uint32_t c = 0; c < N / UB_BENCH_CHUNK; c++) {
      for (uint32_t i = 0; i < UB_BENCH_CHUNK; i++) {
        ub_bench_random_ray(s, rt, cdf, c * UB_BENCH_CHUNK + i, &rays[i]);
        rays[i].tfar = 0.5f * ub_scene_extent(s) * ub_u01(ub_hash4(c, i, 5, 0));
      }
      ub_rt_occluded(rt, rays, UB_BENCH_CHUNK, occ);
    }
    free(rays);
    free(occ);
  }
  *out_shadow = N / (ub_bench_now() - t0);
  free(cdf);
}

/* A bake's gather + shadow rays per second against the ceiling for the same mix. */
static inline double ub_bench_ceiling_ratio(double rays_gather, double rays_shadow,
                                            double seconds, double hit, double shadow)
{
  double mix = (rays_gather + rays_shadow) / (rays_gather / hit + rays_shadow / shadow + 1e-30);
  return (rays_gather + rays_shadow) / (seconds + 1e-30) / mix;
}

static inline long ub_bench_rss_kb(void)
{
  return ub_proc_status_kb("VmRSS:");
}

static inline double ub_bench_load_average(void)
{
  double l = -1.0;
  FILE *f = fopen("/proc/loadavg", "r");
  if (f) {
    if (fscanf(f, "%lf", &l) != 1)
      l = -1.0;
    fclose(f);
  }
  return l;
}

/* Runs `BUILD/ubake-genlevel KIND -o DIR --name NAME --param scale=S (when S > 0)
 * --param P...`; echo: its output indented on stdout (else dropped). Returns the number of
 * dynamic light sets it reports ("…, N sets"; 0 when it names none), −1 when it fails. */
static inline int ub_bench_genlevel(const char *build, const char *kind, const char *dir,
                                    const char *name, double scale, const char *const *params,
                                    int nparams, int echo)
{
  char cmd[8192];
  int n = snprintf(cmd, sizeof cmd, "'%s/ubake-genlevel' %s -o '%s' --name %s", build, kind,
                   dir, name);
  if (scale > 0.0)
    n += snprintf(cmd + n, sizeof cmd - (size_t)n, " --param scale=%.17g", scale);
  for (int i = 0; i < nparams && n < (int)sizeof cmd - 512; i++)
    n += snprintf(cmd + n, sizeof cmd - (size_t)n, " --param '%s'", params[i]);
  FILE *p = popen(cmd, "r");
  if (!p)
    return -1;
  char line[1024];
  int sets = 0;
  while (fgets(line, sizeof line, p)) {
    if (echo)
      printf("  %s", line);
    const char *q = strstr(line, "doorways), ");
    if (q)
      sscanf(q, "doorways), %d sets", &sets);
  }
  if (pclose(p) != 0) {
    fprintf(stderr, "bench: %s failed\n", cmd);
    return -1;
  }
  return sets;
}

#endif
