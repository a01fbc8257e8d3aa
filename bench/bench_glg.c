/* bench_glg — global light grid queries per second on a baked level, one core.
 *
 * Bakes the level (draft) unless a .ubk is given, then times ub_glg_query for a coherent
 * walk (a moving object: consecutive points 1 cm apart, one tet cache) and for random
 * points in the level's bounds, single thread; prints tets, probes, bytes per probe, the
 * run-time GLG memory and the bake seconds spent on probes vs lightmaps. Asserts nothing.
 * Baseline in the same run: a plain 27-float SH evaluation loop (the cost floor of the
 * irradiance step alone). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bake/lights.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/glg.h"
#include "ubake/runtime.h"
#include "ubake/sh.h"

static int cmp_double(const void *a, const void *b)
{
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}
static double median(double *v, int n)
{
  qsort(v, (size_t)n, sizeof *v, cmp_double);
  return v[n / 2];
}

static double now_s(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

int main(int argc, char **argv)
{
  const char *build = getenv("UB_BUILD") ? getenv("UB_BUILD") : "build";
  char level[1024], ubk[1100];
  snprintf(level, sizeof level, "%s", argc > 1 ? argv[1] : "../shared/levels/real/kaos/kaos.gltf");
  ub_bake_stats st;
  memset(&st, 0, sizeof st);
  size_t len = strlen(level);
  if (len > 4 && !strcmp(level + len - 4, ".ubk")) {
    snprintf(ubk, sizeof ubk, "%s", level);
  } else {
    ub_bake_options o;
    ub_bake_options_default(&o);
    o.quality = UB_QUALITY_DRAFT;
    o.bounces = 1;
    char dir[1100];
    snprintf(dir, sizeof dir, "%s/bench_out/glg", build);
    o.out_dir = dir;
    if (ub_bake_level(level, &o, NULL, &st) != UB_OK) {
      fprintf(stderr, "bench_glg: bake of %s failed\n", level);
      return 1;
    }
    snprintf(ubk, sizeof ubk, "%s", st.ubk_path);
  }
  ub_runtime *rt = NULL;
  if (ub_runtime_load(ubk, NULL, &rt) != UB_OK || !ub_runtime_glg(rt)) {
    fprintf(stderr, "bench_glg: %s has no GLG\n", ubk);
    return 1;
  }
  const ub_glg *g = ub_runtime_glg(rt);
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (uint32_t i = 0; i < bf->glg_probe_count; i++)
    for (int a = 0; a < 3; a++) {
      lo[a] = fminf(lo[a], bf->glg_positions[3 * i + a]);
      hi[a] = fmaxf(hi[a], bf->glg_positions[3 * i + a]);
    }
  /* Rounds of (coherent, random, baseline), each figure the median over the rounds: the
   * machine is shared, so one round can be disturbed. */
  enum { ROUNDS = 7 };
  const uint32_t N = 500000, M = 200000;
  double coh_r[ROUNDS], rnd_r[ROUNDS], base_r[ROUNDS];
  double sink = 0.0;
  float *pts = malloc((size_t)M * 3 * sizeof *pts);
  for (uint32_t i = 0; i < M; i++)
    for (int a = 0; a < 3; a++)
      pts[3 * i + a] = lo[a] + (hi[a] - lo[a]) * ub_u01(ub_hash4(5, i, a, 0));
  uint32_t cache;
  for (int round = 0; round < ROUNDS; round++) {
    /* Coherent: a walk 1 cm per step, bouncing inside the bounds (the same path each
     * round). */
    float p[3] = {0.5f * (lo[0] + hi[0]), 0.5f * (lo[1] + hi[1]), 0.5f * (lo[2] + hi[2])};
    float v[3] = {0.0062f, 0.0041f, 0.0066f}; /* |v| ≈ 1 cm */
    cache = UB_GLG_NO_CACHE;
    double t0 = now_s();
    for (uint32_t i = 0; i < N; i++) {
      for (int a = 0; a < 3; a++) {
        p[a] += v[a];
        if (p[a] < lo[a] || p[a] > hi[a])
          v[a] = -v[a];
      }
      float n[3] = {0, 1, 0}, e[3];
      ub_glg_query(g, p, n, &cache, e);
      sink += e[1];
    }
    coh_r[round] = N / (now_s() - t0);
    if (getenv("UB_BENCH_COHERENT_ONLY")) { /* for profiling the coherent path */
      rnd_r[round] = base_r[round] = 0.0;
      continue;
    }
    /* Random points in the level's bounds, one cache. */
    cache = UB_GLG_NO_CACHE;
    t0 = now_s();
    for (uint32_t i = 0; i < M; i++) {
      float n[3] = {0, 1, 0}, e[3];
      ub_glg_query(g, pts + 3 * i, n, &cache, e);
      sink += e[1];
    }
    rnd_r[round] = M / (now_s() - t0);
    /* Baseline: SH irradiance alone over probe SH (no location, no interpolation). */
    t0 = now_s();
    for (uint32_t i = 0, q = 0; i < N; i++) {
      float e[3], n[3] = {0, 1, 0};
      ub_sh2_irradiance(bf->glg_sh + 27 * (size_t)q, n, e);
      q = q + 1 == bf->glg_probe_count ? 0 : q + 1;
      sink += e[1];
    }
    base_r[round] = N / (now_s() - t0);
  }
  double coherent = median(coh_r, ROUNDS), random = median(rnd_r, ROUNDS),
         baseline = median(base_r, ROUNDS);
  /* The coherent walk's locate statistics (one pass of the same path). */
  double csteps = 0.0, cgrid = 0.0, cnew = 0.0;
  {
    float p[3] = {0.5f * (lo[0] + hi[0]), 0.5f * (lo[1] + hi[1]), 0.5f * (lo[2] + hi[2])};
    float v[3] = {0.0062f, 0.0041f, 0.0066f};
    uint32_t prev = UB_GLG_NO_CACHE;
    cache = UB_GLG_NO_CACHE;
    for (uint32_t i = 0; i < N; i++) {
      for (int a = 0; a < 3; a++) {
        p[a] += v[a];
        if (p[a] < lo[a] || p[a] > hi[a])
          v[a] = -v[a];
      }
      ub_glg_locate_info li;
      float bary[4];
      ub_glg_locate_ex(g, p, &cache, bary, &li);
      csteps += li.steps;
      cgrid += li.from_grid;
      cnew += cache != prev;
      prev = cache;
    }
  }
  /* Where the random queries spend their time: walk steps, outside the hull, fallbacks. */
  double steps = 0.0, hull_steps = 0.0, outside = 0.0, fallback = 0.0;
  cache = UB_GLG_NO_CACHE;
  for (uint32_t i = 0; i < M; i++) {
    ub_glg_locate_info li;
    float bary[4];
    ub_glg_locate_ex(g, pts + 3 * i, &cache, bary, &li);
    steps += li.steps;
    hull_steps += li.hull_steps;
    outside += li.outside;
    fallback += li.fallback;
  }
  size_t owned = ub_glg_owned_bytes(g);
  double file_bytes = (double)bf->glg_probe_count * (12 + 54) + (double)bf->glg_tet_count * 36 +
                      (double)bf->glg_plane_count * 16;
  printf("bench_glg %s: %u probes, %u tets (%.2f per probe), %u leak planes\n", ubk,
         bf->glg_probe_count, bf->glg_tet_count, (double)bf->glg_tet_count / bf->glg_probe_count,
         bf->glg_plane_count);
  printf("  coherent walk (1 cm steps): %.2f M queries/s per core (target >= 20); median of %d "
         "rounds, range %.2f..%.2f\n", coherent * 1e-6, ROUNDS, coh_r[0] * 1e-6,
         coh_r[ROUNDS - 1] * 1e-6);
  printf("  random points:              %.2f M queries/s per core (target >= 3); range "
         "%.2f..%.2f\n", random * 1e-6, rnd_r[0] * 1e-6, rnd_r[ROUNDS - 1] * 1e-6);
  printf("  coherent walk: %.3f walk steps per query, a new tet every %.1f queries, %.3f%% "
         "restarted from the start grid\n", csteps / N, N / (cnew > 0 ? cnew : 1),
         100.0 * cgrid / N);
  printf("  random points: %.2f walk steps, %.2f hull steps per query; %.1f%% outside the "
         "hull, %.3f%% brute-force fallbacks\n", steps / M, hull_steps / M, 100.0 * outside / M,
         100.0 * fallback / M);
  printf("  baseline SH irradiance only: %.2f M/s; coherent/baseline = %.2f\n", baseline * 1e-6,
         coherent / baseline);
  printf("  bytes per probe: %.1f in the file (positions f32, SH L2 half, tets, neighbours, "
         "planes), %.1f in the run-time (+ walk tables %.1f; SH as float %d)\n",
         file_bytes / bf->glg_probe_count,
         (owned + (double)bf->glg_probe_count * (12 + 108) + (double)bf->glg_tet_count * 36) /
             bf->glg_probe_count,
         (double)owned / bf->glg_probe_count, 108);
  /* A compact layout, computed from the counts (a proposal, not what the run-time does). */
  double compact = (double)bf->glg_tet_count * (32 + 4 + 1) +
                   (double)bf->glg_probe_count * (12 + 54 + 2) + (double)bf->glg_plane_count * 16;
  printf("  compact layout (proposal): 32 B/tet (corners + neighbours, barycentrics from "
         "positions) + 4 B/tet plane index + 1 B/tet plane sides + planes + positions f32 + "
         "windowed SH once in half = %.1f B/probe (%.2f tets per probe are %.1f B of it); "
         "probe payload alone (position + SH half) 66 B (target <= 64)\n",
         compact / bf->glg_probe_count, (double)bf->glg_tet_count / bf->glg_probe_count,
         (double)bf->glg_tet_count * 37 / bf->glg_probe_count);
  if (st.stage_count) {
    double probes = 0, lm = 0;
    for (uint32_t s = 0; s < st.stage_count; s++) {
      if (!strcmp(st.stage_name[s], "probes") || !strcmp(st.stage_name[s], "leak"))
        probes += st.stage_seconds[s];
      if (!strcmp(st.stage_name[s], "receivers"))
        lm += st.stage_seconds[s];
    }
    printf("  bake: probe placement + TetGen + leak planes %.2f s vs lightmap receivers %.2f s; "
           "whole draft bake %.2f s (probes are gathered inside the same passes)\n",
           probes, lm, st.total_seconds);
  }
  printf("  (checksum %.3g)\n", sink);
  free(pts);
  ub_runtime_free(rt);
  return 0;
}
