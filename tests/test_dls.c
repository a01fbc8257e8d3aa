/* Dynamic light sets end to end: bake hallway_low (two sets, one primary lamp), then
 * - linearity: base + sets is exact per receiver (texels along their normal, GLG SH);
 * - an RGB tint scales its set channel-wise;
 * - toggling returns the identical state (no drift);
 * - several states vs the reference path tracer with the same state (3 s.e. + 5%);
 * - `ubake info --json --memory` lists each set (lights, receivers, bytes) and the
 *   run-time memory by part. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bake/lights.h"
#include "bake/reference.h"
#include "bake/rt.h"
#include "test_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/glg.h"
#include "ubake/runtime.h"
#include "ubake/scene.h"
#include "ubake/sh.h"

static char g_build[512];
static char g_level[1024];

static void set2(ub_runtime *rt, float a, float b)
{
  const float wa[3] = {a, a, a}, wb[3] = {b, b, b};
  ASSERT_OK(ub_runtime_set_dls(rt, (uint32_t)ub_runtime_dls_find(rt, "hall_a"), wa));
  ASSERT_OK(ub_runtime_set_dls(rt, (uint32_t)ub_runtime_dls_find(rt, "hall_b"), wb));
  ASSERT_OK(ub_runtime_update(rt, NULL));
}

/* Irradiance along the normal of every covered texel (green), into out (pixel order). */
static size_t texels(const ub_runtime *rt, double *out)
{
  const ub_bakefile *f = ub_runtime_bakefile(rt);
  size_t n = 0;
  for (uint32_t a = 0; a < f->atlas_count; a++)
    for (uint32_t y = 0; y < f->atlases[a].height; y++)
      for (uint32_t x = 0; x < f->atlases[a].width; x++) {
        size_t px = (size_t)y * f->atlases[a].width + x;
        if (f->atlases[a].coverage[px] != 1)
          continue;
        float e[3];
        float nn[3];
        ASSERT_OK(ub_runtime_texel_normal(rt, a, x, y, nn));
        ub_runtime_texel_irradiance(rt, a, x, y, nn, e);
        if (out)
          out[n] = e[1];
        n++;
      }
  return n;
}

static void test_linearity(ub_runtime *rt)
{
  size_t n = texels(rt, NULL);
  double *q11 = malloc(n * sizeof *q11), *q10 = malloc(n * sizeof *q10);
  double *q01 = malloc(n * sizeof *q01), *q00 = malloc(n * sizeof *q00);
  set2(rt, 1, 1);
  texels(rt, q11);
  set2(rt, 1, 0);
  texels(rt, q10);
  set2(rt, 0, 1);
  texels(rt, q01);
  set2(rt, 0, 0);
  texels(rt, q00);
  double worst = 0.0;
  for (size_t i = 0; i < n; i++) {
    double lhs = q11[i], rhs = q10[i] + q01[i] - q00[i];
    double scale = fabs(q10[i]) + fabs(q01[i]) + fabs(q00[i]) + 1e-6;
    double rel = fabs(lhs - rhs) / scale;
    if (rel > worst)
      worst = rel;
  }
  printf("linearity (texels along their normal, %zu texels): worst |q11 - (q10 + q01 - q00)| / "
         "scale = %.2e\n",
         n, worst);
  ASSERT_TRUE(worst < 1e-5);
  /* GLG: every probe's blended SH is linear in the sets (windowing, a non-linear step,
   * comes after the sum, like AHD encoding for texels). */
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  ASSERT_TRUE(bf->glg_probe_count > 0);
  size_t np = (size_t)bf->glg_probe_count * 27;
  float *s11 = malloc(np * sizeof *s11), *s10 = malloc(np * sizeof *s10);
  float *s01 = malloc(np * sizeof *s01), *s00 = malloc(np * sizeof *s00);
  /* A moving object's cursor across updates: the same bits as a plain query with a tet
   * cache on the same points, in every state (the cursor's rows go stale with each update). */
  {
    ub_glg_cursor cur;
    ub_glg_cursor_init(&cur);
    uint32_t pc = UB_GLG_NO_CACHE;
    int same = 1, changed = 0;
    float prev[3] = {0, 0, 0};
    const float nrm[3] = {0.0f, -1.0f, 0.0f};
    for (int st = 0; st < 4; st++) {
      set2(rt, (float)(st & 1), (float)(st >> 1));
      for (int k = 0; k < 40; k++) {
        float p[3] = {-4.0f + 0.05f * (float)k, 1.2f, 0.3f}, a[3], c[3];
        ASSERT_OK(ub_runtime_query_glg(rt, p, nrm, &pc, a));
        ASSERT_OK(ub_runtime_query_glg_cursor(rt, p, nrm, &cur, c));
        same &= !memcmp(a, c, sizeof a);
        if (k == 0) {
          changed += memcmp(a, prev, sizeof a) != 0;
          memcpy(prev, a, sizeof a);
        }
      }
    }
    printf("GLG cursor across 4 states: %s plain queries, first point changed %d of 4 times\n",
           same ? "the same bits as" : "DIFFERS from", changed);
    ASSERT_TRUE(same);
    ASSERT_TRUE(changed >= 3);
  }
  /* A run-time's bake file lacks the GLG arrays the run-time keeps its own way: writing it
   * is refused with an error (no abort, nothing written). */
  {
    char wpath[1200];
    snprintf(wpath, sizeof wpath, "%s/test_out/dls/runtime_copy.ubk", g_build);
    remove(wpath);
    ASSERT_TRUE(ub_bakefile_write(bf, wpath, NULL) == UB_ERR_INVALID_ARGUMENT);
    FILE *f = fopen(wpath, "rb");
    ASSERT_TRUE(f == NULL);
    if (f)
      fclose(f);
  }
  set2(rt, 1, 1);
  ASSERT_OK(ub_runtime_glg_probe_sh(rt, 0, s11));
  set2(rt, 1, 0);
  ASSERT_OK(ub_runtime_glg_probe_sh(rt, 0, s10));
  set2(rt, 0, 1);
  ASSERT_OK(ub_runtime_glg_probe_sh(rt, 0, s01));
  set2(rt, 0, 0);
  ASSERT_OK(ub_runtime_glg_probe_sh(rt, 0, s00));
  /* The store keeps each value in half (unit roundoff 2^-11 of the value itself): the
   * four roundings bound the residual by 2^-11 of the sum of magnitudes. */
  double gworst = 0.0;
  for (size_t c = 0; c < np; c++) {
    double scale = fabs(s11[c]) + fabs(s10[c]) + fabs(s01[c]) + fabs(s00[c]) + 1e-6;
    double rel = fabs(s11[c] - (s10[c] + s01[c] - s00[c])) / scale;
    if (rel > gworst)
      gworst = rel;
  }
  printf("linearity (GLG probe SH in half, %u probes): worst %.2e of the magnitudes (bound "
         "%.2e)\n", bf->glg_probe_count, gworst, ldexp(1.0, -11));
  ASSERT_TRUE(gworst <= ldexp(1.0, -11) * 1.01);
  /* and the windowed probes a query reads never give negative irradiance */
  float *win = s11;
  ASSERT_OK(ub_runtime_glg_probe_sh(rt, 1, win));
  int negative = 0;
  for (uint32_t q = 0; q < bf->glg_probe_count; q++) {
    float mn[3];
    ub_sh2_irradiance_min(win + 27 * (size_t)q, mn);
    negative += mn[0] < -1e-6f || mn[1] < -1e-6f || mn[2] < -1e-6f;
  }
  ASSERT_TRUE(negative == 0);
  free(s11);
  free(s10);
  free(s01);
  free(s00);
  /* Tint: hall_a = (1, 0.25, 0) with hall_b off is hall_a's light scaled per channel. */
  set2(rt, 1, 0);
  float p[3] = {-3.0f, 0.0f, 0.3f}, nrm[3] = {0, 1, 0}, full[3], tinted[3], d;
  ASSERT_OK(ub_runtime_query_lightmap(rt, p, nrm, full, &d));
  const float tint[3] = {1.0f, 0.25f, 0.0f};
  ASSERT_OK(ub_runtime_set_dls(rt, (uint32_t)ub_runtime_dls_find(rt, "hall_a"), tint));
  ASSERT_OK(ub_runtime_update(rt, NULL));
  ASSERT_OK(ub_runtime_query_lightmap(rt, p, nrm, tinted, &d));
  printf("tint (1, 0.25, 0): %.5f %.5f %.5f from %.5f %.5f %.5f\n", tinted[0], tinted[1],
         tinted[2], full[0], full[1], full[2]);
  ASSERT_NEAR(tinted[0], full[0], 1e-6, 1e-4);
  ASSERT_NEAR(tinted[1], 0.25 * full[1], 1e-6, 1e-4);
  ASSERT_NEAR(tinted[2], 0.0, 1e-6, 0.0);
  free(q11);
  free(q10);
  free(q01);
  free(q00);
}

static void test_toggle(ub_runtime *rt)
{
  size_t n = texels(rt, NULL);
  double *a = malloc(n * sizeof *a), *b = malloc(n * sizeof *b);
  set2(rt, 1, 0.5f);
  texels(rt, a);
  for (int i = 0; i < 50; i++)
    set2(rt, (float)(i % 3) * 0.7f, (float)(i % 5) * 0.3f);
  set2(rt, 1, 0.5f);
  texels(rt, b);
  ASSERT_TRUE(memcmp(a, b, n * sizeof *a) == 0);
  printf("toggle: 50 state changes and back: %s\n",
         memcmp(a, b, n * sizeof *a) == 0 ? "bit-identical" : "DRIFTED");
  free(a);
  free(b);
}

static void test_states_vs_reference(ub_runtime *rt)
{
  ub_scene *scene = NULL;
  ub_rt *trace = NULL;
  ub_emitters *em = NULL;
  ASSERT_OK(ub_scene_load(g_level, NULL, &scene));
  ASSERT_OK(ub_rt_create(scene, NULL, NULL, &trace));
  ASSERT_OK(ub_emitters_build(scene, &em));
  if (!scene || !trace || !em)
    return;
  /* states: weights of (hall_a, hall_b) per channel */
  const float states[4][2][3] = {{{1, 1, 1}, {1, 1, 1}},
                                 {{0, 0, 0}, {1, 1, 1}},
                                 {{1, 1, 1}, {0.5f, 0.5f, 0.5f}},
                                 {{1, 0.3f, 0.3f}, {0.2f, 0.2f, 1}}};
  const float pts[5][6] = {{-3, 0, 0.3f, 0, 1, 0},     {-1, 1.2f, -1.5f, 0, 0, 1},
                           {2, 2.5f, 0.5f, 0, -1, 0}, {4.6f, 0.7f, 1.5f, 0, 0, -1},
                           {0.3f, 0, -0.8f, 0, 1, 0}};
  int ia = -1, ib = -1;
  for (uint32_t d = 0; d < scene->dls_count; d++) {
    if (!strcmp(scene->dls_names[d], "hall_a"))
      ia = (int)d;
    if (!strcmp(scene->dls_names[d], "hall_b"))
      ib = (int)d;
  }
  ASSERT_TRUE(ia >= 0 && ib >= 0);
  int fails = 0;
  double worst = 0.0;
  for (int s = 0; s < 4; s++) {
    ub_runtime_set_dls(rt, (uint32_t)ub_runtime_dls_find(rt, "hall_a"), states[s][0]);
    ub_runtime_set_dls(rt, (uint32_t)ub_runtime_dls_find(rt, "hall_b"), states[s][1]);
    ub_runtime_update(rt, NULL);
    float w[6];
    memcpy(w + 3 * ia, states[s][0], 3 * sizeof(float));
    memcpy(w + 3 * ib, states[s][1], 3 * sizeof(float));
    for (int i = 0; i < 5; i++) {
      float e[3], ref[3], se[3], d;
      ASSERT_OK(ub_runtime_query_lightmap(rt, pts[i], pts[i] + 3, e, &d));
      ub_reference_params rp;
      ub_reference_params_init(&rp);
      memcpy(rp.position, pts[i], 3 * sizeof(float));
      memcpy(rp.normal, pts[i] + 3, 3 * sizeof(float));
      rp.spp = 8192;
      rp.seed = 7 + i;
      rp.dls_weight = w;
      ASSERT_OK(ub_reference_irradiance(scene, trace, em, &rp, ref, se, NULL));
      for (int c = 0; c < 3; c++) {
        double err = fabs(e[c] - ref[c]);
        double rel = ref[c] > 0 ? err / ref[c] : 0.0;
        if (rel > worst)
          worst = rel;
        if (!(err <= 3 * se[c] + 0.05 * ref[c] + 1e-4)) {
          fprintf(stderr, "state %d point %d ch %d: bake %.5f ref %.5f ± %.5f\n", s, i, c, e[c],
                  ref[c], se[c]);
          fails++;
        }
      }
    }
  }
  printf("hallway_low: 4 states x 5 points x 3 channels vs reference: worst %.2f%%, %d outside "
         "3 s.e. + 5%%\n",
         100 * worst, fails);
  ASSERT_TRUE(fails == 0);
  ub_emitters_free(em);
  ub_rt_free(trace);
  ub_scene_free(scene);
}

/* `ubake info --json --memory`: each set with its lights and receivers as the bake file
 * holds them and its bytes (28 per texel pixel: index + 12 halves; 58 per probe: index
 * + 27 halves), and the run-time's bytes by part = ub_runtime_memory_usage of rt. */
static void test_info(const char *ubk, const ub_runtime *rt, const char *opts)
{
  char cmd[2300];
  snprintf(cmd, sizeof cmd, "'%s/ubake' info '%s' --json --memory%s", g_build, ubk, opts);
  FILE *p = popen(cmd, "r");
  ASSERT_TRUE(p != NULL);
  if (!p)
    return;
  size_t cap = 1 << 16, n = 0;
  char *out = malloc(cap);
  size_t got;
  while (out && (got = fread(out + n, 1, cap - 1 - n, p)) > 0)
    n += got;
  ASSERT_TRUE(pclose(p) == 0 && out);
  if (!out)
    return;
  out[n] = 0;
  ub_bakefile *bf = NULL;
  ASSERT_OK(ub_bakefile_read(ubk, NULL, &bf));
  int bad = 0;
  for (uint32_t d = 0; bf && d < bf->dls_count; d++) {
    const ub_bakefile_record *rc = &bf->dls[d];
    char key[128];
    snprintf(key, sizeof key, "{\"name\": \"%s\",", rc->name);
    const char *at = strstr(out, key);
    unsigned lights = 0, texels = 0, probes = 0, llg = 0;
    unsigned long long bytes = 0;
    if (!at || sscanf(at + strlen(key), " \"lights\": %u, \"texels\": %u, \"probes\": %u, "
                      "\"llg_probes\": %u, \"bytes\": %llu", &lights, &texels, &probes, &llg,
                      &bytes) != 5) {
      bad++;
      continue;
    }
    bad += lights != rc->light_count || texels != rc->texel_count ||
           probes != rc->probe_count || llg != rc->llg_probe_count ||
           bytes != 28ull * texels + 58ull * (probes + llg) || texels == 0;
  }
  ub_bakefile_free(bf);
  ub_runtime_memory m;
  ub_runtime_memory_usage(rt, &m);
  const char *mj = strstr(out, "\"runtime_memory\": {");
  unsigned long long g = 0, l = 0, gl = 0, ll = 0, rec = 0, bl = 0, tot = 0;
  int nm = mj ? sscanf(mj, "\"runtime_memory\": {\"geometry\": %llu, \"lightmap\": %llu, "
                       "\"glg\": %llu, \"llg\": %llu, \"records\": %llu, \"blend\": %llu, "
                       "\"total\": %llu", &g, &l, &gl, &ll, &rec, &bl, &tot) : 0;
  printf("ubake info --json --memory%s: %d of 2 sets wrong; run-time %llu bytes (here %zu), "
         "records %llu\n", opts, bad, tot, m.total, rec);
  ASSERT_TRUE(bad == 0 && nm == 7);
  ASSERT_TRUE(tot == m.total && g == m.geometry && l == m.lightmap && gl == m.glg &&
              ll == m.llg && rec == m.records && bl == m.blend && rec > 0 &&
              g + l + gl + ll + rec + bl == tot);
  free(out);
}

int main(void)
{
  const char *b = getenv("UB_BUILD");
  snprintf(g_build, sizeof g_build, "%s", b ? b : "build");
  snprintf(g_level, sizeof g_level, "%s/levels/hallway_low.gltf", g_build);
  char dir[1024];
  snprintf(dir, sizeof dir, "%s/test_out/dls", g_build);
  ub_bake_options o;
  ub_bake_options_default(&o);
  o.quality = UB_QUALITY_FAST;
  o.out_dir = dir;
  ub_bake_stats st;
  ub_result r = ub_bake_level(g_level, &o, NULL, &st);
  ASSERT_OK(r);
  if (r != UB_OK)
    TEST_MAIN_END();
  printf("baked hallway_low: %u sets, %.2f s\n", st.dls_sets, st.total_seconds);
  ASSERT_TRUE(st.dls_sets == 2);
  ub_runtime *rt = NULL;
  ASSERT_OK(ub_runtime_load(st.ubk_path, NULL, &rt));
  if (rt) {
    ASSERT_TRUE(ub_runtime_dls_count(rt) == 2);
    ASSERT_TRUE(ub_runtime_dls_find(rt, "nope") == -1);
    const float bad[3] = {NAN, 0, 0}, huge[3] = {1, 1, 1.01f * UB_RUNTIME_MAX_WEIGHT},
                most[3] = {UB_RUNTIME_MAX_WEIGHT, 0, 0}, one[3] = {1, 1, 1};
    ASSERT_TRUE(ub_runtime_set_dls(rt, 0, bad) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(ub_runtime_set_dls(rt, 0, huge) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(ub_runtime_set_dls(rt, 2, one) == UB_ERR_INVALID_ARGUMENT);
    /* the largest weight: the GLG answers its product like the lightmap (the probe store
     * zeroed channels past its range, 1e30 read 0 there) */
    {
      const float p[3] = {0.0f, 1.0f, 0.0f}, n[3] = {0.0f, 1.0f, 0.0f};
      float g1[3], gm[3], l1[3], lm[3];
      ASSERT_OK(ub_runtime_set_dls(rt, 0, one));
      ASSERT_OK(ub_runtime_update(rt, NULL));
      ASSERT_OK(ub_runtime_query_glg(rt, p, n, NULL, g1));
      ASSERT_OK(ub_runtime_query_lightmap(rt, p, n, l1, NULL));
      ASSERT_OK(ub_runtime_set_dls(rt, 0, most));
      ASSERT_OK(ub_runtime_update(rt, NULL));
      ASSERT_OK(ub_runtime_query_glg(rt, p, n, NULL, gm));
      ASSERT_OK(ub_runtime_query_lightmap(rt, p, n, lm, NULL));
      printf("weight 1e6 at (0,1,0): GLG red %.4g (x%.4g), lightmap red %.4g (x%.4g)\n", gm[0],
             gm[0] / g1[0], lm[0], lm[0] / l1[0]);
      ASSERT_TRUE(gm[0] > 1e4 * g1[0] && lm[0] > 1e4 * l1[0]);
      ASSERT_OK(ub_runtime_set_dls(rt, 0, one));
      ASSERT_OK(ub_runtime_update(rt, NULL));
    }
    test_info(st.ubk_path, rt, "");
    test_linearity(rt);
    test_toggle(rt);
    test_states_vs_reference(rt);
    ub_runtime_free(rt);
  }
  /* The same with the records in 8 bits and the load state kept: still linear, still within
   * the reference. */
  rt = NULL;
  ASSERT_OK(ub_runtime_load_ex(st.ubk_path, NULL, UB_RUNTIME_RECORDS_8BIT | UB_RUNTIME_KEEP_STATE,
                               &rt));
  if (rt) {
    printf("-- records in 8 bits, the load state kept --\n");
    test_info(st.ubk_path, rt, " --records 8bit --keep-state");
    test_linearity(rt);
    test_states_vs_reference(rt);
    ub_runtime_free(rt);
  }
  TEST_MAIN_END();
}
