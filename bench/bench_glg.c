/* bench_glg — global light grid queries per second on a baked level, one core.
 *
 * Bakes the level (draft) unless a .ubk is given, then times ub_glg_query for a coherent
 * walk (a moving object: consecutive points 1 cm apart, one tet cache) and for random
 * points in the level's bounds, single thread; prints tets, probes, bytes per probe, the
 * run-time GLG memory and the bake seconds spent on probes vs lightmaps. Asserts nothing.
 * The run-time's GLG is the compact store (half SH, per-probe exponent and window, 58 B
 * per probe). Also: random points through ub_glg_query_batch, the same GLG over float SH
 * windowed per probe (the 108 B/probe store before it: speed and the irradiance
 * difference), a byte breakdown per probe, and the per-update
 * windowing cost (ub_sh2_window vs the reference search on every probe's raw SH).
 * Baselines in the same run: a plain 27-float SH evaluation loop (the cost floor of the
 * irradiance step alone), a dependent random read over an array the size of the GLG's
 * tet records (ns per cache miss: a random query is a chain of such misses) and memcpy
 * bandwidth. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bake/lights.h"
#include "runtime/half.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/glg.h"
#include "ubake/runtime.h"
#include "ubake/sh.h"
#include "bench/bench_util.h"

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

/* The coherent path: from the bounds' centre, 1 cm per step, bouncing inside them. */
typedef struct walk {
  float p[3], v[3];
} walk;

static void walk_init(walk *w, const float lo[3], const float hi[3])
{
  for (int a = 0; a < 3; a++)
    w->p[a] = 0.5f * (lo[a] + hi[a]);
  w->v[0] = 0.0062f, w->v[1] = 0.0041f, w->v[2] = 0.0066f; /* |v| ≈ 1 cm */
}

static void walk_step(walk *w, const float lo[3], const float hi[3])
{
  for (int a = 0; a < 3; a++) {
    w->p[a] += w->v[a];
    if (w->p[a] < lo[a] || w->p[a] > hi[a])
      w->v[a] = -w->v[a];
  }
}

/* Queries per second along N steps of the path: with a tet cache, or a cursor. */
static double coherent_rate(const ub_glg *g, int with_cursor, const float lo[3],
                            const float hi[3], uint32_t N, double *sink)
{
  walk w;
  walk_init(&w, lo, hi);
  uint32_t cache = UB_GLG_NO_CACHE;
  ub_glg_cursor cur;
  ub_glg_cursor_init(&cur);
  double t0 = ub_bench_now();
  for (uint32_t i = 0; i < N; i++) {
    walk_step(&w, lo, hi);
    float n[3] = {0, 1, 0}, e[3];
    if (with_cursor)
      ub_glg_query_cursor(g, w.p, n, &cur, e);
    else
      ub_glg_query(g, w.p, n, &cache, e);
    *sink += e[1];
  }
  return N / (ub_bench_now() - t0);
}

/* Queries per second at the M points pts (normal +y): one by one with one tet cache
 * (*one), and as one ub_glg_query_batch (*batch; nrm: the normals, rgb: its output). */
static void random_rates(const ub_glg *g, const float *pts, const float *nrm, float *rgb,
                         uint32_t M, double *one, double *batch, double *sink)
{
  uint32_t cache = UB_GLG_NO_CACHE;
  double t0 = ub_bench_now();
  for (uint32_t i = 0; i < M; i++) {
    float n[3] = {0, 1, 0}, e[3];
    ub_glg_query(g, pts + 3 * i, n, &cache, e);
    *sink += e[1];
  }
  *one = M / (ub_bench_now() - t0);
  t0 = ub_bench_now();
  ub_glg_query_batch(g, M, pts, nrm, NULL, rgb);
  *batch = M / (ub_bench_now() - t0);
  *sink += rgb[1];
}

/* The largest irradiance difference between two GLGs at the M points, relative to the
 * point's mean irradiance in a (E for a normal and its opposite, summed). */
static double query_diff(const ub_glg *a, const ub_glg *b, const float *pts, uint32_t M)
{
  double worst = 0.0;
  for (uint32_t i = 0; i < M; i++) {
    float n[3] = {0.48f, 0.6f, 0.64f}, m[3] = {-0.48f, -0.6f, -0.64f}, ea[3], eb[3], ea2[3],
          eb2[3];
    uint32_t c1 = UB_GLG_NO_CACHE, c2 = UB_GLG_NO_CACHE;
    ub_glg_query(a, pts + 3 * i, n, &c1, ea);
    ub_glg_query(b, pts + 3 * i, n, &c2, eb);
    ub_glg_query(a, pts + 3 * i, m, &c1, ea2);
    ub_glg_query(b, pts + 3 * i, m, &c2, eb2);
    for (int c = 0; c < 3; c++) {
      double ref = ea[c] + ea2[c];
      if (ref > 0.0)
        worst = fmax(worst, fmax(fabs(ea[c] - eb[c]), fabs(ea2[c] - eb2[c])) / ref);
    }
  }
  return worst;
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
  /* The same file with the small walk (UB_RUNTIME_GLG_SMALL_WALK): its price, same run. */
  ub_runtime *rts = NULL;
  if (ub_runtime_load_ex(ubk, NULL, UB_RUNTIME_GLG_SMALL_WALK, &rts) != UB_OK) {
    fprintf(stderr, "bench_glg: %s: load with the small walk failed\n", ubk);
    return 1;
  }
  const ub_glg *gs = ub_runtime_glg(rts);
  /* The file as written (the run-time's copy has no positions, neighbours or float SH). */
  ub_bakefile *nbf = NULL;
  if (ub_bakefile_read(ubk, NULL, &nbf) != UB_OK) {
    fprintf(stderr, "bench_glg: cannot read %s\n", ubk);
    return 1;
  }
  float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (uint32_t i = 0; i < nbf->glg_probe_count; i++)
    for (int a = 0; a < 3; a++) {
      lo[a] = fminf(lo[a], nbf->glg_positions[3 * i + a]);
      hi[a] = fmaxf(hi[a], nbf->glg_positions[3 * i + a]);
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
  /* The same GLG over float SH, every probe windowed by ub_sh2_window (the store before
   * the compact one: 108 B of SH per probe). */
  float *sh_win = malloc((size_t)nbf->glg_probe_count * 27 * sizeof *sh_win);
  memcpy(sh_win, nbf->glg_sh, (size_t)nbf->glg_probe_count * 27 * sizeof *sh_win);
  for (uint32_t q = 0; q < nbf->glg_probe_count; q++)
    ub_sh2_window(sh_win + 27 * (size_t)q);
  ub_glg gh;
  {
    ub_glg_desc d;
    memset(&d, 0, sizeof d);
    d.probe_count = nbf->glg_probe_count;
    d.positions = nbf->glg_positions;
    d.sh = sh_win;
    d.tet_count = nbf->glg_tet_count;
    d.tets = nbf->glg_tets;
    d.neigh = nbf->glg_neigh;
    d.leak_plane_count = nbf->glg_plane_count;
    d.leak_planes = nbf->glg_planes;
    d.leak_plane_of = nbf->glg_plane_of;
    d.sh_windowed = 1;
    if (ub_glg_init(&gh, &d, NULL) != UB_OK) {
      fprintf(stderr, "bench_glg: float-SH GLG init failed\n");
      return 1;
    }
  }
  float *nrm = malloc((size_t)M * 3 * sizeof *nrm), *rgb = malloc((size_t)M * 3 * sizeof *rgb);
  for (uint32_t i = 0; i < M; i++)
    nrm[3 * i] = 0.0f, nrm[3 * i + 1] = 1.0f, nrm[3 * i + 2] = 0.0f;
  /* Dependent random reads (a pointer chase through a random cycle) over an array the
   * size of the tet records: the latency of one miss where the GLG lives. */
  size_t chase_n = (size_t)bf->glg_tet_count * 64 / sizeof(uint32_t) / 16; /* one per line */
  uint32_t *chase = malloc(chase_n * 16 * sizeof *chase);
  {
    uint32_t *perm = malloc(chase_n * sizeof *perm);
    for (size_t i = 0; i < chase_n; i++)
      perm[i] = (uint32_t)i;
    for (size_t i = chase_n - 1; i > 0; i--) {
      size_t j = ub_hash4(9, (uint32_t)i, 0, 0) % (i + 1);
      uint32_t t = perm[i];
      perm[i] = perm[j];
      perm[j] = t;
    }
    for (size_t i = 0; i < chase_n; i++)
      chase[16 * (size_t)perm[i]] = perm[(i + 1) % chase_n];
    free(perm);
  }
  size_t mc_bytes = (size_t)64 << 20;
  char *mc_a = malloc(mc_bytes), *mc_b = malloc(mc_bytes);
  memset(mc_a, 1, mc_bytes);
  memset(mc_b, 2, mc_bytes);
  double cohf_r[ROUNDS], cohc_r[ROUNDS], bat_r[ROUNDS], half_r[ROUNDS], halfb_r[ROUNDS], lat_r[ROUNDS], mc_r[ROUNDS];
  double scoh_r[ROUNDS], scohc_r[ROUNDS], srnd_r[ROUNDS], sbat_r[ROUNDS]; /* small walk */
  for (int round = 0; round < ROUNDS; round++) {
    /* Coherent: the walk (the same path each round) with a tet cache, with a cursor, and
     * over the float store. */
    coh_r[round] = coherent_rate(g, 0, lo, hi, N, &sink);
    cohc_r[round] = coherent_rate(g, 1, lo, hi, N, &sink);
    cohf_r[round] = coherent_rate(&gh, 0, lo, hi, N, &sink);
    scoh_r[round] = coherent_rate(gs, 0, lo, hi, N, &sink);
    scohc_r[round] = coherent_rate(gs, 1, lo, hi, N, &sink);
    if (getenv("UB_BENCH_COHERENT_ONLY")) { /* for profiling the coherent path */
      rnd_r[round] = base_r[round] = bat_r[round] = half_r[round] = halfb_r[round] = 0.0;
      lat_r[round] = mc_r[round] = srnd_r[round] = sbat_r[round] = 0.0;
      continue;
    }
    /* Random points in the level's bounds: one by one (one cache) and as one batch (no
     * caches); then the same with the small walk and over the float store. */
    random_rates(g, pts, nrm, rgb, M, &rnd_r[round], &bat_r[round], &sink);
    random_rates(gs, pts, nrm, rgb, M, &srnd_r[round], &sbat_r[round], &sink);
    random_rates(&gh, pts, nrm, rgb, M, &half_r[round], &halfb_r[round], &sink);
    double t0;
    /* Miss latency: 2M dependent reads. */
    {
      uint32_t at = 0;
      const uint32_t steps = 2000000;
      t0 = ub_bench_now();
      for (uint32_t i = 0; i < steps; i++)
        at = chase[16 * (size_t)at];
      lat_r[round] = (ub_bench_now() - t0) / steps;
      sink += at;
    }
    t0 = ub_bench_now();
    memcpy(mc_b, mc_a, mc_bytes);
    mc_r[round] = mc_bytes / (ub_bench_now() - t0);
    sink += mc_b[round];
    /* Baseline: SH irradiance alone over probe SH (no location, no interpolation). */
    t0 = ub_bench_now();
    for (uint32_t i = 0, q = 0; i < N; i++) {
      float e[3], n[3] = {0, 1, 0};
      ub_sh2_irradiance(sh_win + 27 * (size_t)q, n, e);
      q = q + 1 == bf->glg_probe_count ? 0 : q + 1;
      sink += e[1];
    }
    base_r[round] = N / (ub_bench_now() - t0);
  }
  double coherent = median(coh_r, ROUNDS), random = median(rnd_r, ROUNDS),
         baseline = median(base_r, ROUNDS), batch = median(bat_r, ROUNDS),
         half1 = median(half_r, ROUNDS), cohf = median(cohf_r, ROUNDS),
         cohc = median(cohc_r, ROUNDS), halfb = median(halfb_r, ROUNDS),
         lat = median(lat_r, ROUNDS), mcbw = median(mc_r, ROUNDS);
  /* Compact vs float SH, and small walk vs walk records: irradiance differences at the
   * random points (query_diff). */
  const double half_err = query_diff(g, &gh, pts, M), small_err = query_diff(g, gs, pts, M);
  /* Windowing every probe's raw SH (what a re-blend costs per touched probe). */
  double win_fast = 0.0, win_ref = 0.0;
  unsigned win_count = 0;
  {
    const float *raw = nbf->glg_sh;
    float sh[27];
    uint32_t np = bf->glg_probe_count;
    double t0 = ub_bench_now();
    for (uint32_t q = 0; q < np; q++) {
      memcpy(sh, raw + 27 * (size_t)q, sizeof sh);
      win_count += ub_sh2_window(sh) != 0;
      sink += sh[3];
    }
    win_fast = (ub_bench_now() - t0) / np;
    t0 = ub_bench_now();
    for (uint32_t q = 0; q < np; q++) {
      memcpy(sh, raw + 27 * (size_t)q, sizeof sh);
      ub_sh2_window_reference(sh);
      sink += sh[3];
    }
    win_ref = (ub_bench_now() - t0) / np;
  }
  /* The coherent walk's locate statistics (one pass of the same path). */
  double csteps = 0.0, cgrid = 0.0, cnew = 0.0;
  {
    walk w;
    walk_init(&w, lo, hi);
    uint32_t prev = UB_GLG_NO_CACHE;
    cache = UB_GLG_NO_CACHE;
    for (uint32_t i = 0; i < N; i++) {
      walk_step(&w, lo, hi);
      ub_glg_locate_info li;
      float bary[4];
      ub_glg_locate_ex(g, w.p, &cache, bary, &li);
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
  printf("bench_glg %s: %u probes, %u tets (%.2f per probe), %u leak planes\n", ubk,
         bf->glg_probe_count, bf->glg_tet_count, (double)bf->glg_tet_count / bf->glg_probe_count,
         bf->glg_plane_count);
  printf("  coherent walk (1 cm steps): %.2f M queries/s per core (target >= 20); median of %d "
         "rounds, range %.2f..%.2f\n", coherent * 1e-6, ROUNDS, coh_r[0] * 1e-6,
         coh_r[ROUNDS - 1] * 1e-6);
  printf("  coherent walk with a cursor (ub_glg_query_cursor: the tet's 4 windowed rows held "
         "by the caller): %.2f M queries/s per core (target >= 20); range %.2f..%.2f\n",
         cohc * 1e-6, cohc_r[0] * 1e-6, cohc_r[ROUNDS - 1] * 1e-6);
  printf("  random points:              %.2f M queries/s per core (target >= 3); range "
         "%.2f..%.2f\n", random * 1e-6, rnd_r[0] * 1e-6, rnd_r[ROUNDS - 1] * 1e-6);
  printf("  coherent walk: %.3f walk steps per query, a new tet every %.1f queries, %.3f%% "
         "restarted from the start grid\n", csteps / N, N / (cnew > 0 ? cnew : 1),
         100.0 * cgrid / N);
  printf("  random points: %.2f walk steps, %.2f hull steps per query; %.1f%% outside the "
         "hull, %.3f%% brute-force fallbacks\n", steps / M, hull_steps / M, 100.0 * outside / M,
         100.0 * fallback / M);
  printf("  random points, batched (ub_glg_query_batch, no caches): %.2f M queries/s (x%.2f "
         "the one-by-one rate)\n", batch * 1e-6, batch / random);
  printf("  the same GLG over float SH windowed per probe (108 B/probe): coherent %.2f M/s, "
         "random %.2f M/s one by one, %.2f M/s batched; compact vs float: max |E_compact - "
         "E_float| = %.1e x (E(n) + E(-n))\n", cohf * 1e-6, half1 * 1e-6, halfb * 1e-6,
         half_err);
  printf("  baseline SH irradiance only: %.2f M/s; coherent/baseline = %.2f\n", baseline * 1e-6,
         coherent / baseline);
  printf("  baseline dependent miss over %.1f MB: %.0f ns; random query = %.1f misses' time "
         "(batched %.1f); memcpy %.2f GB/s\n", chase_n * 64.0 / 1e6, lat * 1e9,
         1.0 / (random * lat), 1.0 / (batch * lat), mcbw * 1e-9);
  printf("  windowing every probe's raw SH: %.2f us/probe (reference search %.2f us, x%.2f); "
         "%u of %u probes windowed\n", win_fast * 1e6, win_ref * 1e6, win_ref / win_fast,
         win_count, bf->glg_probe_count);
  {
    ub_glg_memory gm, hm;
    ub_glg_memory_usage(g, &gm);
    ub_glg_memory_usage(&gh, &hm);
    double np = bf->glg_probe_count, nt = bf->glg_tet_count;
    double tets = gm.walk_records + gm.tet_corners + gm.tet_flags + gm.leak + gm.hull +
                  gm.start_grid;
    printf("  bytes per GLG probe at query time, compact store: probe %.1f (SH half 54 + a "
           "32-bit word: exponent, window, stale) + kept positions %.1f (hull faces' and %u "
           "badly shaped tets' corners) = %.1f (target <= 64); float store %.1f + %.1f\n",
           gm.sh / np, gm.positions / np, g->ill_tet_count, (gm.sh + gm.positions) / np,
           hm.sh / np, hm.positions / np);
    printf("  tet structure per probe: walk records %.1f (64 B x %.2f tets), tet corners "
           "%.1f, flags %.1f, leak planes %.1f, hull %.1f, start grid %.1f = %.1f; all "
           "together %.1f B/probe (float store %.1f)\n",
           gm.walk_records / np, nt / np, gm.tet_corners / np, gm.tet_flags / np,
           gm.leak / np, gm.hull / np, gm.start_grid / np, tets / np, gm.total / np,
           hm.total / np);
    ub_runtime_memory rm;
    ub_runtime_memory_usage(rt, &rm);
    printf("  run-time GLG total (ub_runtime_memory_usage .glg, compact store + walk data; "
           "tets and leak planes are in .geometry): %.1f B/probe\n", rm.glg / np);
    ub_runtime_memory sm;
    ub_runtime_memory_usage(rts, &sm);
    double scoh = median(scoh_r, ROUNDS), scohc = median(scohc_r, ROUNDS),
           srnd = median(srnd_r, ROUNDS), sbat = median(sbat_r, ROUNDS);
    printf("  small walk (UB_RUNTIME_GLG_SMALL_WALK: links 16 B a tet + positions 12 B a probe "
           "instead of 64-B walk records): run-time GLG %.1f B/probe (%.2f MiB less); coherent "
           "%.2f M/s (x%.2f of the records'), with a cursor %.2f (x%.2f), random %.2f (x%.2f), "
           "batched %.2f (x%.2f); largest difference from the records' irradiance %.1e of "
           "E(n) + E(-n)\n",
           sm.glg / np, ((double)rm.glg - (double)sm.glg) / 1048576.0, scoh * 1e-6,
           scoh / coherent, scohc * 1e-6, scohc / cohc, srnd * 1e-6, srnd / random,
           sbat * 1e-6, sbat / batch, small_err);
  }
  if (st.stage_count) {
    double probes = ub_bench_stage_seconds(&st, "probes") + ub_bench_stage_seconds(&st, "leak");
    double lm = ub_bench_stage_seconds(&st, "receivers");
    printf("  bake: probe placement + TetGen + leak planes %.2f s vs lightmap receivers %.2f s; "
           "whole draft bake %.2f s (probes are gathered inside the same passes)\n",
           probes, lm, st.total_seconds);
  }
  /* Optional second argument, a .ubk with dynamic light sets (e.g. estate_small): how much
   * the re-windowing of the GLG probes a one-set toggle (set off + update, set on +
   * update) changes would add to it (queries do it, see ubake/glg.h), with ub_sh2_window
   * and with the reference search (timed on the same probes' raw SH right after the
   * update). */
  if (argc > 2) {
    ub_runtime *rs = NULL;
    if (ub_runtime_load(argv[2], NULL, &rs) == UB_OK && ub_runtime_glg(rs) &&
        ub_runtime_dls_count(rs)) {
      const ub_bakefile *bs = ub_runtime_bakefile(rs);
      uint32_t np = bs->glg_probe_count, sets = ub_runtime_dls_count(rs);
      float *before = malloc((size_t)np * 27 * sizeof *before), sh[27];
      float *cur = malloc((size_t)np * 27 * sizeof *cur);
      double t_upd = 0.0, t_fast = 0.0, t_ref = 0.0;
      uint64_t probes = 0;
      for (int rep = 0; rep < 3; rep++)
        for (uint32_t e = 0; e < sets; e++)
          for (int on = 0; on < 2; on++) {
            const float w[3] = {(float)on, (float)on, (float)on};
            ub_runtime_glg_probe_sh(rs, 0, before);
            ub_runtime_set_dls(rs, e, w);
            ub_runtime_update_stats us;
            double t0 = ub_bench_now();
            ub_runtime_update(rs, &us);
            t_upd += ub_bench_now() - t0;
            /* the touched probes are those whose raw SH changed */
            ub_runtime_glg_probe_sh(rs, 0, cur);
            for (uint32_t q = 0; q < np; q++) {
              if (!memcmp(before + 27 * (size_t)q, cur + 27 * (size_t)q, sizeof sh))
                continue;
              probes++;
              memcpy(sh, cur + 27 * (size_t)q, sizeof sh);
              t0 = ub_bench_now();
              ub_sh2_window(sh);
              t_fast += ub_bench_now() - t0;
              memcpy(sh, cur + 27 * (size_t)q, sizeof sh);
              t0 = ub_bench_now();
              ub_sh2_window_reference(sh);
              t_ref += ub_bench_now() - t0;
              sink += sh[3];
            }
          }
      printf("  %s: %u sets toggled off/on x3: update %.3f ms per toggle (GLG probes only "
             "marked: blended and windowed by the queries that read them); windowing the "
             "probes it changed ~%.3f ms (%.0f%% of the update's time; %.1f probes/toggle); "
             "the reference windowing would take %.3f ms (%.0f%% of an update doing it)\n",
             argv[2], sets, 1e3 * t_upd / (6.0 * sets), 1e3 * t_fast / (6.0 * sets),
             100.0 * t_fast / t_upd, probes / (6.0 * sets), 1e3 * t_ref / (6.0 * sets),
             100.0 * t_ref / (t_upd - t_fast + t_ref));
      free(before);
      free(cur);
    } else {
      printf("  %s: no GLG with dynamic light sets, toggle figures skipped\n", argv[2]);
    }
    ub_runtime_free(rs);
  }
  printf("  (checksum %.3g)\n", sink);
  ub_glg_release(&gh);
  ub_bakefile_free(nbf);
  free(sh_win);
  free(nrm);
  free(rgb);
  free(chase);
  free(mc_a);
  free(mc_b);
  free(pts);
  ub_runtime_free(rts);
  ub_runtime_free(rt);
  return 0;
}
