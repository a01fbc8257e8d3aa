/* End-to-end bake tests: closed forms (furnace, point over plane, sky over plane),
 * bake vs the reference path tracer on cornell, determinism across thread counts.
 * Levels come from the generator (UB_BUILD/levels). On failure each case prints the
 * measured numbers; the baked outputs stay in UB_BUILD/test_out/ for inspection. */
#include <math.h>
#include <omp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "bake/lights.h"
#include "bake/reference.h"
#include "bake/rt.h"
#include "test_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/glg.h"
#include "ubake/runtime.h"
#include "ubake/scene.h"

static char g_build[512];

static void test_log(void *user, ub_log_level level, const char *msg)
{
  (void)user;
  if (level <= UB_LOG_WARNING)
    fprintf(stderr, "%s: %s\n", level == UB_LOG_ERROR ? "error" : "warning", msg);
}
static const ub_log g_log = {test_log, NULL};

static void level_path(const char *name, char *out, size_t cap)
{
  snprintf(out, cap, "%s/levels/%s.gltf", g_build, name);
}

static float g_glg_spacing = 0.0f; /* override for the next bake (0 = level default) */
static int g_bounce_full_rays = 0;  /* ub_bake_options.bounce_full_rays for the next bake */
static ub_bake_stats g_last;        /* the last bake's stats */

static ub_runtime *bake(const char *level, const char *tag, ub_quality q, int bounces,
                        int threads, float texel, char *out_ubk, size_t cap)
{
  char path[1024], dir[1024];
  level_path(level, path, sizeof path);
  snprintf(dir, sizeof dir, "%s/test_out/bake_%s", g_build, tag);
  ub_bake_options o;
  ub_bake_options_default(&o);
  o.quality = q;
  o.bounces = bounces;
  o.threads = threads;
  o.out_dir = dir;
  o.texel_size = texel;
  o.glg_spacing = g_glg_spacing;
  o.bounce_full_rays = g_bounce_full_rays;
  ub_bake_stats st;
  ub_result r = ub_bake_level(path, &o, &g_log, &st);
  g_last = st;
  if (r != UB_OK) {
    fprintf(stderr, "bake %s failed: %s\n", path, ub_result_string(r));
    return NULL;
  }
  printf("  baked %-12s %-14s %7u texels %2u bounces %.2f s\n", level, tag, st.texels,
         st.bounces, st.total_seconds);
  if (out_ubk)
    snprintf(out_ubk, cap, "%s", st.ubk_path);
  ub_runtime *rt = NULL;
  if (ub_runtime_load(st.ubk_path, NULL, &rt) != UB_OK) {
    fprintf(stderr, "cannot load %s\n", st.ubk_path);
    return NULL;
  }
  return rt;
}

/* Irradiance along the normal at every covered texel of every atlas: mean and worst. */
static void texel_stats(const ub_runtime *rt, double *out_mean, double *out_p95_dev,
                        double expect)
{
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  double sum = 0.0;
  size_t n = 0, cap = 0;
  double *dev = NULL;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    for (uint32_t y = 0; y < at->height; y++)
      for (uint32_t x = 0; x < at->width; x++) {
        size_t px = (size_t)y * at->width + x;
        if (at->coverage[px] != 1)
          continue;
        float rgb[3], nn[3];
        ASSERT_OK(ub_runtime_texel_normal(rt, a, x, y, nn));
        ub_runtime_texel_irradiance(rt, a, x, y, nn, rgb);
        sum += rgb[1];
        if (n == cap) {
          cap = cap ? 2 * cap : 1024;
          dev = realloc(dev, cap * sizeof *dev);
        }
        dev[n++] = fabs(rgb[1] - expect) / expect;
      }
  }
  *out_mean = n ? sum / n : 0.0;
  /* 95th percentile of the relative deviation (partial selection by sorting). */
  for (size_t i = 1; i < n; i++) {
    double v = dev[i];
    size_t j = i;
    while (j > 0 && dev[j - 1] > v) {
      dev[j] = dev[j - 1];
      j--;
    }
    dev[j] = v;
  }
  *out_p95_dev = n ? dev[(size_t)(0.95 * (n - 1))] : 1e9;
  free(dev);
}

static void test_furnace(void)
{
  /* Closed cube, uniform emission Le = 1 and albedo rho = 0.5 (generator defaults):
   * E = π Le Σ_{k≤N} ρ^k at every point of every wall.
   * N = 8 runs twice, with later bounces at fewer rays (bake/pass.c bounce_shifts, the
   * default) and with every bounce at full rays: every bounce brings half the last, so
   * bounce 3 gathers with 1/2 of the rays, bounces 4..8 with 1/4 (the most,
   * UB_BOUNCE_RAY_SHIFT_MAX). With bounce 0's gathers (they see the emitting walls, full
   * rays) that is (1 + 2 + 1/2 + 5/4) / 9 = 53% of the gathers, 61% if rounding puts a
   * bounce a hair above half the last (one step less shift). The furnace's radiance is
   * the same in every direction, so any ray count gives the exact bounce: a mean off by a
   * power of two would be a receiver weighed with the wrong count. */
  const double Le = 1.0, rho = 0.5;
  const int Ns[] = {0, 1, 3, 8, 8}, full_rays[] = {0, 0, 0, 0, 1};
  uint64_t gathers[2] = {0, 0}; /* N = 8: default, full rays */
  for (int i = 0; i < 5; i++) {
    char tag[32];
    snprintf(tag, sizeof tag, "furnace_b%d%s", Ns[i], full_rays[i] ? "_full" : "");
    g_bounce_full_rays = full_rays[i];
    ub_runtime *rt = bake("furnace", tag, UB_QUALITY_FAST, Ns[i], 0, 0.0f, NULL, 0);
    g_bounce_full_rays = 0;
    ASSERT_TRUE(rt != NULL);
    if (!rt)
      continue;
    if (Ns[i] == 8)
      gathers[full_rays[i]] = g_last.rays_gather;
    double expect = 0.0;
    for (int k = 0; k <= Ns[i]; k++)
      expect += M_PI * Le * pow(rho, k);
    double mean, p95;
    texel_stats(rt, &mean, &p95, expect);
    printf("furnace N=%d%s: mean E = %.5f, closed form %.5f (%.3f%%), p95 texel deviation "
           "%.2f%%, %.1f M gather rays\n",
           Ns[i], full_rays[i] ? " (every bounce at full rays)" : "", mean, expect,
           100 * (mean - expect) / expect, 100 * p95, 1e-6 * (double)g_last.rays_gather);
    ASSERT_NEAR(mean, expect, 0.0, 0.01);
    ASSERT_TRUE(p95 < 0.05);
    ub_runtime_free(rt);
  }
  printf("furnace N=8: later bounces' fewer rays trace %.1f%% of the gathers\n",
         gathers[1] ? 100.0 * (double)gathers[0] / (double)gathers[1] : 0.0);
  ASSERT_TRUE(gathers[1] > 0 && (double)gathers[0] < 0.7 * (double)gathers[1] &&
              (double)gathers[0] > 0.45 * (double)gathers[1]);
}

static void test_plane_point(void)
{
  /* Point light I = 10 W/sr at height h = 1 over an albedo-0 plane: E = I h/(h²+r²)^{3/2}. */
  const double I = 10.0, h = 1.0;
  ub_runtime *rt = bake("plane_point", "plane_point", UB_QUALITY_FAST, -1, 0, 0.1f, NULL, 0);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return;
  const float rs[] = {0.0f, 0.3f, 0.7f, 1.0f, 2.0f, 4.0f, 7.0f};
  const float az[] = {0.0f, 1.1f, 2.3f, 3.7f, 4.4f, 5.5f, 0.6f};
  for (int i = 0; i < 7; i++) {
    float p[3] = {rs[i] * cosf(az[i]) + 0.013f, 0.0f, rs[i] * sinf(az[i]) + 0.007f};
    float r2 = p[0] * p[0] + p[2] * p[2];
    float n[3] = {0, 1, 0}, rgb[3], dist;
    ASSERT_OK(ub_runtime_query_lightmap(rt, p, n, rgb, &dist));
    double expect = I * h / pow(h * h + r2, 1.5);
    printf("plane_point r=%.2f (%.1f deg): E = %.5f, closed form %.5f (%.3f%%)\n", sqrt(r2),
           atan(sqrt(r2) / h) * 180 / M_PI, rgb[1], expect, 100 * (rgb[1] - expect) / expect);
    ASSERT_NEAR(rgb[1], expect, 0.0, 0.01);
  }
  ub_runtime_free(rt);
}

static void test_sky_plane(void)
{
  ub_runtime *rt = bake("sky_plane", "sky_plane", UB_QUALITY_FAST, -1, 0, 0.5f, NULL, 0);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return;
  const float sky[3] = {0.5f, 0.7f, 1.0f};
  for (int i = 0; i < 5; i++) {
    float p[3] = {-6.0f + 3.0f * i + 0.11f, 0.0f, 2.0f - 1.3f * i}, n[3] = {0, 1, 0}, rgb[3], d;
    ASSERT_OK(ub_runtime_query_lightmap(rt, p, n, rgb, &d));
    for (int c = 0; c < 3; c++)
      ASSERT_NEAR(rgb[c], M_PI * sky[c], 0.0, 0.01);
    if (i == 0)
      printf("sky_plane: E = %.5f %.5f %.5f, closed form %.5f %.5f %.5f\n", rgb[0], rgb[1],
             rgb[2], M_PI * sky[0], M_PI * sky[1], M_PI * sky[2]);
  }
  ub_runtime_free(rt);
}

static void test_cornell_vs_reference(void)
{
  ub_runtime *rt = bake("cornell", "cornell", UB_QUALITY_HIGH, -1, 0, 0.1f, NULL, 0);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return;
  char path[1024];
  level_path("cornell", path, sizeof path);
  ub_scene *scene = NULL;
  ub_rt *trace = NULL;
  ub_emitters *em = NULL;
  ASSERT_OK(ub_scene_load(path, NULL, &scene));
  ASSERT_OK(ub_rt_create(scene, NULL, NULL, &trace));
  ASSERT_OK(ub_emitters_build(scene, &em));
  /* Points on the walls and ceiling of the 2 m box (x,z in [-1,1], y in [0,2]), away from
   * edges and from the two inner boxes. */
  typedef struct { float p[3], n[3]; } pt;
  pt pts[24];
  int np = 0;
  for (int i = 0; i < 4; i++)
    for (int j = 0; j < 2; j++) {
      float y = 0.35f + 0.4f * i, z = -0.5f + 1.0f * j;
      pts[np++] = (pt){{-1.0f, y, z}, {1, 0, 0}};
      pts[np++] = (pt){{1.0f, y, z}, {-1, 0, 0}};
      pts[np++] = (pt){{-0.5f + 1.0f * j, y, -1.0f}, {0, 0, 1}};
    }
  int fails = 0;
  double worst = 0.0;
  for (int i = 0; i < np; i++) {
    float rgb[3], d, ref[3], se[3];
    ASSERT_OK(ub_runtime_query_lightmap(rt, pts[i].p, pts[i].n, rgb, &d));
    ub_reference_params rp;
    ub_reference_params_init(&rp);
    memcpy(rp.position, pts[i].p, sizeof rp.position);
    memcpy(rp.normal, pts[i].n, sizeof rp.normal);
    rp.spp = 8192;
    rp.seed = 1234 + i;
    ASSERT_OK(ub_reference_irradiance(scene, trace, em, &rp, ref, se, NULL));
    for (int c = 0; c < 3; c++) {
      double tol = 3.0 * se[c] + 0.03 * ref[c];
      double err = fabs(rgb[c] - ref[c]);
      double rel = ref[c] > 0 ? err / ref[c] : 0;
      if (rel > worst)
        worst = rel;
      if (!(err <= tol)) {
        fprintf(stderr, "cornell point %d (%.2f %.2f %.2f) ch %d: bake %.5f ref %.5f ± %.5f\n",
                i, pts[i].p[0], pts[i].p[1], pts[i].p[2], c, rgb[c], ref[c], se[c]);
        fails++;
      }
    }
  }
  printf("cornell: %d points x 3 channels vs reference, worst relative difference %.2f%%, %d "
         "outside 3 s.e. + 3%%\n",
         np, 100 * worst, fails);
  ASSERT_TRUE(np >= 20);
  ASSERT_TRUE(fails == 0);
  ub_emitters_free(em);
  ub_rt_free(trace);
  ub_scene_free(scene);
  ub_runtime_free(rt);
}


static void test_two_rooms_leak(void)
{
  /* Shared wall x in [-0.025, 0.025]; light in room A (x < 0). Dark-room (B) texels within
   * one texel of the wall must stay below 1% of the mirrored lit-side texels. */
  const float texel = 0.1f;
  ub_runtime *rt = bake("two_rooms", "two_rooms", UB_QUALITY_DRAFT, -1, 0, texel, NULL, 0);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return;
  struct { float p[3], n[3]; } pts[] = {
      {{0.025f + 0.5f * texel, 0.0f, 0.3f}, {0, 1, 0}},   /* floor at the wall */
      {{0.025f + 0.5f * texel, 3.0f, -0.7f}, {0, -1, 0}}, /* ceiling at the wall */
      {{0.025f, 0.02f, 1.1f}, {1, 0, 0}},                 /* wall face at the floor */
      {{0.025f, 1.5f, 0.0f}, {1, 0, 0}},                  /* wall face, middle */
      {{0.025f, 2.98f, -1.2f}, {1, 0, 0}},                /* wall face at the ceiling */
  };
  double worst = 0.0;
  for (size_t i = 0; i < sizeof pts / sizeof pts[0]; i++) {
    float b[3], a[3], d;
    float pa[3] = {-pts[i].p[0], pts[i].p[1], pts[i].p[2]};
    float na[3] = {-pts[i].n[0], pts[i].n[1], pts[i].n[2]};
    ASSERT_OK(ub_runtime_query_lightmap(rt, pts[i].p, pts[i].n, b, &d));
    ASSERT_OK(ub_runtime_query_lightmap(rt, pa, na, a, &d));
    double ratio = a[1] > 0 ? b[1] / a[1] : 1.0;
    if (ratio > worst)
      worst = ratio;
    if (!(ratio < 0.01))
      fprintf(stderr, "two_rooms leak at (%.3f %.3f %.3f): dark %.5g lit %.5g\n", pts[i].p[0],
              pts[i].p[1], pts[i].p[2], b[1], a[1]);
    ASSERT_TRUE(a[1] > 0.0f);
    ASSERT_TRUE(ratio < 0.01);
  }
  printf("two_rooms: worst dark/lit ratio next to the 5 cm wall = %.2e\n", worst);
  ub_runtime_free(rt);
}

/* ---- GLG probes ----------------------------------------------------------------- */

static void test_glg_furnace(void)
{
  /* Inside the closed furnace the radiance is the same from every direction at every
   * point: the GLG must give E = π Le Σ_{k≤N} ρ^k for any point and normal. */
  ub_runtime *rt = bake("furnace", "glg_furnace", UB_QUALITY_HIGH, 3, 0, 0.0f, NULL, 0);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return;
  double expect = M_PI * (1.0 + 0.5 + 0.25 + 0.125);
  double worst = 0.0, sum = 0.0;
  uint32_t cache = UB_GLG_NO_CACHE;
  for (int i = 0; i < 50; i++) {
    uint32_t h = ub_hash4(77, i, 0, 0);
    float p[3] = {-0.9f + 1.8f * ub_u01(h), 0.1f + 1.8f * ub_u01(ub_hash4(h, 1, 0, 0)),
                  -0.9f + 1.8f * ub_u01(ub_hash4(h, 2, 0, 0))};
    float n[3];
    ub_sample_cosine((const float[3]){0, 1, 0}, ub_u01(ub_hash4(h, 3, 0, 0)),
                     ub_u01(ub_hash4(h, 4, 0, 0)), n);
    if (i % 2)
      n[1] = -n[1];
    float rgb[3];
    ASSERT_OK(ub_runtime_query_glg(rt, p, n, &cache, rgb));
    double rel = fabs(rgb[1] - expect) / expect;
    if (rel > worst)
      worst = rel;
    sum += rel;
  }
  /* The probes' noise: 400 random points of this bake at seeds 1-3 gave a mean |deviation|
   * of 0.23-0.29% and a worst of 0.9-1.4% with emitters picked per receiver, 0.22-0.27%
   * and 1.0-1.1% by power alone (no bias either way: mean deviations within ±0.03%). */
  printf("glg furnace: 50 interior points, closed form %.5f, mean deviation %.3f%%, worst "
         "%.3f%%\n",
         expect, 100 * sum / 50, 100 * worst);
  ASSERT_TRUE(sum / 50 < 0.005);
  ASSERT_TRUE(worst < 0.02);
  /* Points far outside the grid (finite, beyond any integer cell index) or at infinity: a
   * finite answer or INVALID_ARGUMENT, never undefined behaviour (the sanitizer build's
   * float-cast-overflow check ran into the cell index's conversion). */
  const float far[4][3] = {{1e19f, 0, 0}, {0, -1e20f, 0}, {3e38f, 1, 1}, {INFINITY, 0, 0}};
  for (int i = 0; i < 4; i++) {
    float rgb[3] = {0, 0, 0}, n[3] = {0, 1, 0};
    ub_result r = ub_runtime_query_glg(rt, far[i], n, &cache, rgb);
    ASSERT_TRUE(i < 3 ? r == UB_OK : r == UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(isfinite(rgb[0]) && isfinite(rgb[1]) && isfinite(rgb[2]));
  }
  /* A level without dynamic elements: an update changes nothing, and listing the changed
   * texels gives none (it read a run table that such a level never allocates). */
  ub_runtime_texel_change chg[4];
  ASSERT_OK(ub_runtime_update(rt, NULL));
  ASSERT_TRUE(ub_runtime_changed_texel_count(rt) == 0);
  ASSERT_TRUE(ub_runtime_changed_texels(rt, 0, 4, chg) == 0);
  ub_runtime_free(rt);
}

/* Copies BUILD/levels/NAME.{gltf,bin} to BUILD/levels/OUT.{gltf,bin} with the first
 * occurrence of `from` in the JSON replaced by `to`. */
static int level_variant(const char *name, const char *out, const char *from, const char *to)
{
  char src[1024], dst[1024];
  level_path(name, src, sizeof src);
  level_path(out, dst, sizeof dst);
  FILE *f = fopen(src, "rb");
  if (!f)
    return 0;
  static char buf[1 << 20];
  size_t n = fread(buf, 1, sizeof buf - 1, f);
  fclose(f);
  buf[n] = 0;
  char *at = strstr(buf, from);
  if (!at)
    return 0;
  f = fopen(dst, "wb");
  if (!f)
    return 0;
  fwrite(buf, 1, (size_t)(at - buf), f);
  fputs(to, f);
  fputs(at + strlen(from), f);
  fclose(f);
  /* the .bin is referenced by its original name, which sits beside the copy */
  return 1;
}

static void test_glg_cornell(void)
{
  /* The GLG stores what UberBake stores in it: with the ceiling light `primary`, its direct
   * light is the run-time's job and the probes hold the (smooth) indirect light, which SH
   * L2 represents well. The reference computes the same path classes. */
  ASSERT_TRUE(level_variant("cornell", "cornell_primary", "\"ubake_light\": \"static\"",
                            "\"ubake_light\": \"primary\""));
  g_glg_spacing = 0.5f;
  ub_runtime *rt = bake("cornell_primary", "glg_cornell", UB_QUALITY_HIGH, -1, 0, 0.0f, NULL, 0);
  g_glg_spacing = 0.0f;
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return;
  char path[1024];
  level_path("cornell_primary", path, sizeof path);
  ub_scene *scene = NULL;
  ub_rt *trace = NULL;
  ub_emitters *em = NULL;
  ASSERT_OK(ub_scene_load(path, NULL, &scene));
  ASSERT_OK(ub_rt_create(scene, NULL, NULL, &trace));
  ASSERT_OK(ub_emitters_build(scene, &em));
  int fails = 0, np = 0;
  double worst = 0.0, sum_rel = 0.0;
  uint32_t cache = UB_GLG_NO_CACHE;
  for (int i = 0; np < 30 && i < 1000; i++) {
    /* Random points in the air of the box, away from walls and outside the two boxes. */
    uint32_t h = ub_hash4(4242, i, 0, 0);
    float p[3] = {-0.8f + 1.6f * ub_u01(h), 0.2f + 1.6f * ub_u01(ub_hash4(h, 1, 0, 0)),
                  -0.8f + 1.6f * ub_u01(ub_hash4(h, 2, 0, 0))};
    if (p[1] < 1.35f && fabsf(p[0] + 0.33f) < 0.55f && fabsf(p[2] + 0.27f) < 0.55f)
      continue; /* tall box */
    if (p[1] < 0.75f && fabsf(p[0] - 0.33f) < 0.55f && fabsf(p[2] - 0.39f) < 0.55f)
      continue; /* short box */
    float n[3];
    ub_sample_cosine((const float[3]){0, 1, 0}, ub_u01(ub_hash4(h, 3, 0, 0)),
                     ub_u01(ub_hash4(h, 4, 0, 0)), n);
    if (i % 3 == 1)
      n[1] = -n[1];
    float rgb[3], ref[3], se[3];
    ASSERT_OK(ub_runtime_query_glg(rt, p, n, &cache, rgb));
    ub_reference_params rp;
    ub_reference_params_init(&rp);
    memcpy(rp.position, p, sizeof p);
    memcpy(rp.normal, n, sizeof n);
    rp.spp = 8192;
    rp.seed = 99 + i;
    ASSERT_OK(ub_reference_irradiance(scene, trace, em, &rp, ref, se, NULL));
    np++;
    for (int c = 0; c < 3; c++) {
      double err = fabs(rgb[c] - ref[c]), rel = ref[c] > 0 ? err / ref[c] : 0.0;
      if (c == 1) {
        sum_rel += rel;
        if (rel > worst)
          worst = rel;
      }
      if (!(err <= 3.0 * se[c] + 0.10 * ref[c])) {
        fprintf(stderr, "glg cornell (%.2f %.2f %.2f) n (%.2f %.2f %.2f) ch %d: glg %.4f ref %.4f ± %.4f\n",
                p[0], p[1], p[2], n[0], n[1], n[2], c, rgb[c], ref[c], se[c]);
        fails++;
      }
    }
  }
  printf("glg cornell: %d points vs reference: mean |rel err| %.2f%%, worst %.2f%% (green), %d "
         "outside 3 s.e. + 10%%\n",
         np, 100 * sum_rel / np, 100 * worst, fails);
  ASSERT_TRUE(np == 30);
  ASSERT_TRUE(fails == 0);
  ub_emitters_free(em);
  ub_rt_free(trace);
  ub_scene_free(scene);
  ub_runtime_free(rt);
}

static void test_glg_two_rooms_leak(void)
{
  /* GLG irradiance in the dark room 10 cm from the shared 5 cm wall < 1% of the lit side. */
  ub_runtime *rt = bake("two_rooms", "glg_two_rooms", UB_QUALITY_DRAFT, -1, 0, 0.0f, NULL, 0);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return;
  double worst = 0.0;
  for (int i = 0; i < 12; i++) {
    float y = 0.3f + 0.22f * i, z = -1.7f + 0.3f * i;
    const float normals[3][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}};
    for (int k = 0; k < 3; k++) {
      float pb[3] = {0.025f + 0.1f, y, z}, pa[3] = {-0.025f - 0.1f, y, z};
      float nb[3] = {normals[k][0], normals[k][1], normals[k][2]};
      float na[3] = {-nb[0], nb[1], nb[2]};
      float b[3], a[3];
      ASSERT_OK(ub_runtime_query_glg(rt, pb, nb, NULL, b));
      ASSERT_OK(ub_runtime_query_glg(rt, pa, na, NULL, a));
      double ratio = a[1] > 0 ? b[1] / a[1] : 1.0;
      if (ratio > worst)
        worst = ratio;
      if (!(ratio < 0.01))
        fprintf(stderr, "glg leak at (%.3f %.3f %.3f): dark %.4g lit %.4g\n", pb[0], pb[1], pb[2],
                b[1], a[1]);
      ASSERT_TRUE(ratio < 0.01);
    }
  }
  printf("glg two_rooms: worst dark/lit ratio 10 cm from the 5 cm wall = %.2e\n", worst);
  ub_runtime_free(rt);
}

static int read_all(const char *path, unsigned char **out, size_t *out_n)
{
  FILE *f = fopen(path, "rb");
  if (!f)
    return 0;
  fseek(f, 0, SEEK_END);
  long n = ftell(f);
  fseek(f, 0, SEEK_SET);
  *out = malloc(n > 0 ? (size_t)n : 1);
  *out_n = fread(*out, 1, (size_t)n, f);
  fclose(f);
  return *out_n == (size_t)n;
}

static void test_determinism(void)
{
  char a[1024], b[1024];
  const int threads0 = omp_get_max_threads();
  ub_runtime *r1 = bake("cornell", "det_t1", UB_QUALITY_DRAFT, 2, 1, 0.0f, a, sizeof a);
  /* a bake's thread count is its own: the caller's default comes back */
  ASSERT_TRUE(omp_get_max_threads() == threads0);
  ub_runtime *r2 = bake("cornell", "det_t2", UB_QUALITY_DRAFT, 2, 2, 0.0f, b, sizeof b);
  ASSERT_TRUE(r1 && r2);
  unsigned char *da = NULL, *db = NULL;
  size_t na = 0, nb = 0;
  ASSERT_TRUE(read_all(a, &da, &na));
  ASSERT_TRUE(read_all(b, &db, &nb));
  int same = na == nb && na > 0 && memcmp(da, db, na) == 0;
  printf("determinism: --threads 1 vs 2: %zu vs %zu bytes, %s\n", na, nb,
         same ? "identical" : "DIFFERENT");
  ASSERT_TRUE(same);
  free(da);
  free(db);
  ub_runtime_free(r1);
  ub_runtime_free(r2);
}

int main(int argc, char **argv)
{
  const char *b = getenv("UB_BUILD");
  snprintf(g_build, sizeof g_build, "%s", b ? b : "build");
  const char *only = argc > 1 ? argv[1] : NULL;
  if (!only || !strcmp(only, "furnace"))
    test_furnace();
  if (!only || !strcmp(only, "plane_point"))
    test_plane_point();
  if (!only || !strcmp(only, "sky_plane"))
    test_sky_plane();
  if (!only || !strcmp(only, "cornell"))
    test_cornell_vs_reference();
  if (!only || !strcmp(only, "two_rooms"))
    test_two_rooms_leak();
  if (!only || !strcmp(only, "glg_furnace"))
    test_glg_furnace();
  if (!only || !strcmp(only, "glg_cornell"))
    test_glg_cornell();
  if (!only || !strcmp(only, "glg_two_rooms"))
    test_glg_two_rooms_leak();
  if (!only || !strcmp(only, "determinism"))
    test_determinism();
  TEST_MAIN_END();
}
