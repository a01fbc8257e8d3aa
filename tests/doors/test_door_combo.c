/* tests/doors/test_door_combo.c — closed-door bounce S_C, door × set combinations and
 * LLG probes in door records (issue 5 items 3(ii), 4 and 5; issue 6 item 1), end to end
 * on variants of levels/genlevel.c's door_combo (door_rooms: rooms A x<0 and B x>0, a
 * 1x2 m leaf at x=0 whose open pose swings into B, static lamp A in room A).
 * Bakes at fast quality (at draft the bake's own noise, which the tolerance does not
 * cover, reached 7% at a ceiling point lit by the bright leaf; the black-leaf bake,
 * which only has to be wrong, at draft). Points: the regression suite's (tools/regress.c): floor and ceiling 1, 2 and 4 m from
 * the leaf on both sides, plus the floor 0.5 m from it in room A. A point passes when
 * |bake − reference| ≤ 3 s.e. + 5%, + LEAK where the reference is below LEAK = 1% of the
 * mean reference over the lamp room's points: the floor texels straddling the shared wall
 * leak the lamp room's light into a sealed dark room (tests/hard/README.md bug 8, still
 * open) where the reference is 0.
 *
 * 1. S_C: light leaf (albedo 0.85) with lamp A 0.6 m from it. Baked as now (the leaf keeps
 *    its albedo in the base, record S_O − S_C) and with the leaf tagged
 *    `ubake_receiver: none` (the black leaf of UberBake §4.1, the bake before S_C).
 *    Closed and open vs reference (leaf closed / open pose): the new bake within tolerance
 *    everywhere; the black leaf's closed error summed over room A ≥ 2× the new one and
 *    outside tolerance next to the leaf. Both printed. Door open: room A's summed error
 *    also within 3 s.e. + 2% of the reference per point (the door pass's light that goes
 *    into room B and comes back).
 * 2. Combination: DLS lamp_b in room B, the door tagged `ubake_combine: lamp_b`. The file
 *    has one COMBO record (parents lamp_b, the door), the report lists the combination as
 *    baked; door open + lamp_b on within tolerance, and the same file without the COMBO
 *    record has a larger summed error (printed). Also closed + lamp_b and open alone.
 * 3. LLG: the same level with an LLG prop in room B by the doorway: the door and
 *    combination records carry LLG probes; LLG irradiance on the prop's faces vs
 *    reference with the door closed and open (lamp_b off) within tolerance.
 * 4. Door × door on door_chain (see test_pair). With lamp_b
 *    on, printed only: the set's own LLG record misses ~30% on the prop's lit faces even
 *    with the door closed (no door record involved; a DLS / LLG matter). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "bake/geomstate.h"
#include "bake/reference.h"
#include "bake/rt.h"
#include "test_util.h"
#include "test_rt_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/runtime.h"
#include "ubake/scene.h"

static void test_log(void *user, ub_log_level level, const char *msg)
{
  (void)user;
  if (level <= UB_LOG_WARNING)
    fprintf(stderr, "%s: %s\n", level == UB_LOG_ERROR ? "error" : "warning", msg);
}
static const ub_log g_log = {test_log, NULL};
static char g_build[512], g_dir[1024];

static double lum(const float *c) { return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]; }

typedef struct pt {
  const char *name;
  float p[3], n[3];
} pt;

#define NPTS 13
static const pt g_pts[NPTS] = {
    {"A 0.5m floor", {-0.5f, 0.0f, 0.3f}, {0, 1, 0}}, {"A 1m floor", {-1, 0, 0}, {0, 1, 0}},
    {"A 1m ceiling", {-1, 3, 0}, {0, -1, 0}},          {"A 2m floor", {-2, 0, 0}, {0, 1, 0}},
    {"A 2m ceiling", {-2, 3, 0}, {0, -1, 0}},          {"A 4m floor", {-4, 0, 0}, {0, 1, 0}},
    {"A 4m ceiling", {-4, 3, 0}, {0, -1, 0}},          {"B 1m floor", {1, 0, 0}, {0, 1, 0}},
    {"B 1m ceiling", {1, 3, 0}, {0, -1, 0}},           {"B 2m floor", {2, 0, 0}, {0, 1, 0}},
    {"B 2m ceiling", {2, 3, 0}, {0, -1, 0}},           {"B 4m floor", {4, 0, 0}, {0, 1, 0}},
    {"B 4m ceiling", {4, 3, 0}, {0, -1, 0}}};

/* Generates a door_combo variant (name, extra --param list) and bakes it. */
/* The options every bake of this test uses: the defaults at `quality` into out_dir. */
static ub_bake_options bake_options(ub_quality quality, const char *out_dir)
{
  ub_bake_options o;
  ub_bake_options_default(&o);
  o.quality = quality;
  o.out_dir = out_dir;
  return o;
}

static int make(const char *name, const char *params, ub_quality quality, char *out_level,
                size_t cap, ub_bake_stats *st)
{
  char cmd[4096], out[1400];
  snprintf(cmd, sizeof cmd, "'%s/ubake-genlevel' door_combo -o '%s' --name %s %s > /dev/null",
           g_build, g_dir, name, params);
  if (system(cmd) != 0)
    return 0;
  snprintf(out_level, cap, "%s/%s.gltf", g_dir, name);
  snprintf(out, sizeof out, "%s/%s", g_dir, name);
  ub_bake_options o = bake_options(quality, out);
  return ub_bake_level(out_level, &o, &g_log, st) == UB_OK;
}

/* The level made by make() baked again with another seed into DIR/NAME_seedN; its run-time
 * and (ubk, cap) its bake file's path. */
static ub_runtime *bake_seed(const char *level, const char *name, ub_quality quality,
                             uint32_t seed, char *ubk, size_t cap)
{
  char out[1400];
  snprintf(out, sizeof out, "%s/%s_seed%u", g_dir, name, seed);
  ub_bake_options o = bake_options(quality, out);
  o.seed = seed;
  ub_bake_stats st;
  ub_runtime *rt = NULL;
  if (ub_bake_level(level, &o, &g_log, &st) == UB_OK) {
    ASSERT_OK(ub_runtime_load(st.ubk_path, &g_log, &rt));
    snprintf(ubk, cap, "%s", st.ubk_path);
  }
  return rt;
}

/* Writes bf to path without element ci (the same bake, the combination record left out). */
static void write_without(ub_bakefile *bf, int32_t ci, const char *path)
{
  ub_bakefile_record *keep = bf->elems;
  uint32_t kc = bf->elem_count, m = 0;
  ub_bakefile_record *el = malloc((kc ? kc : 1) * sizeof *el);
  ASSERT_TRUE(el != NULL);
  if (!el)
    return;
  for (uint32_t e = 0; e < kc; e++)
    if ((int32_t)e != ci)
      el[m++] = keep[e];
  bf->elems = el;
  bf->elem_count = m;
  ASSERT_OK(ub_bakefile_write(bf, path, &g_log));
  bf->elems = keep;
  bf->elem_count = kc;
  free(el);
}

/* Reference E (luminance) and its s.e. at p for the door open or not and lamp_b's weight. */
static void reference(const ub_scene *s, int open, float set_w, const float p[3],
                      const float n[3], double *out_e, double *out_se)
{
  uint8_t op[4] = {(uint8_t)open, 0, 0, 0};
  ub_geom_state gs = {op, NULL};
  uint8_t *mask = ub_geom_mask(s, &gs);
  ub_rt *rt = NULL;
  ub_emitters *em = NULL;
  float w[3 * 4], rgb[3] = {NAN, NAN, NAN}, se[3] = {NAN, NAN, NAN};
  for (int i = 0; i < 12; i++)
    w[i] = set_w;
  ub_reference_params rp;
  ub_reference_params_init(&rp);
  memcpy(rp.position, p, sizeof rp.position);
  memcpy(rp.normal, n, sizeof rp.normal);
  rp.spp = 4096;
  rp.seed = 5;
  rp.dls_weight = s->dls_count ? w : NULL;
  if (mask && ub_rt_create(s, mask, NULL, &rt) == UB_OK && ub_emitters_build(s, &em) == UB_OK)
    ub_reference_irradiance(s, rt, em, &rp, rgb, se, NULL);
  ub_emitters_free(em);
  ub_rt_free(rt);
  free(mask);
  *out_e = lum(rgb);
  *out_se = lum(se);
}

static void set_state(ub_runtime *run, float t, float set_w)
{
  int32_t e = ub_runtime_element_find(run, UB_ELEMENT_DOOR, "middle");
  ASSERT_TRUE(e >= 0);
  if (e >= 0)
    ASSERT_OK(ub_runtime_set_element(run, (uint32_t)e, t));
  int32_t d = ub_runtime_dls_find(run, "lamp_b");
  if (d >= 0) {
    const float w[3] = {set_w, set_w, set_w};
    ASSERT_OK(ub_runtime_set_dls(run, (uint32_t)d, w));
  }
  ASSERT_OK(ub_runtime_update(run, NULL));
}

static double query(ub_runtime *run, const pt *q)
{
  float rgb[3] = {NAN, NAN, NAN};
  ASSERT_OK(ub_runtime_query_lightmap(run, q->p, q->n, rgb, NULL));
  return lum(rgb);
}

/* Reference at every point for one state; returns the LEAK floor (1% of room A's mean). */
static double refs(const ub_scene *s, int open, float set_w, double *e, double *se)
{
  double a = 0.0;
  int na = 0;
  for (int i = 0; i < NPTS; i++) {
    reference(s, open, set_w, g_pts[i].p, g_pts[i].n, &e[i], &se[i]);
    if (g_pts[i].p[0] < 0)
      a += e[i], na++;
  }
  return 0.01 * a / na;
}

/* LEAK only counts where the reference is below it (a sealed, dark room). */
static int within(double q, double e, double se, double leak)
{
  return fabs(q - e) <= 3.0 * se + 0.05 * fabs(e) + (fabs(e) < leak ? leak : 0.0);
}

/* 1. S_C: new vs black leaf, closed and open. */
static void test_leaf_bounce(void)
{
  const char *lit = "--param lamp_b=0 --param combine=0 --param leaf_albedo=0.85 "
                    "--param lamp_a_at=-0.6,1.0,0";
  char lv_new[1400], lv_old[1400], params[512];
  ub_bake_stats st_new, st_old;
  ASSERT_TRUE(make("door_lit", lit, UB_QUALITY_FAST, lv_new, sizeof lv_new, &st_new));
  snprintf(params, sizeof params, "%s --param black_leaf=1", lit);
  ASSERT_TRUE(make("door_lit_black", params, UB_QUALITY_DRAFT, lv_old, sizeof lv_old,
                   &st_old));
  ub_scene *s = NULL;
  ub_runtime *rn = NULL, *ro = NULL;
  ASSERT_OK(ub_scene_load(lv_new, &g_log, &s));
  ASSERT_OK(ub_runtime_load(st_new.ubk_path, &g_log, &rn));
  ASSERT_OK(ub_runtime_load(st_old.ubk_path, &g_log, &ro));
  if (!s || !rn || !ro)
    goto done;
  for (int open = 0; open < 2; open++) {
    double e[NPTS], se[NPTS];
    double leak = refs(s, open, 1.0f, e, se);
    set_state(rn, (float)open, 1.0f);
    set_state(ro, (float)open, 1.0f);
    double sum_new = 0.0, sum_old = 0.0, sum_ref = 0.0, sum_se = 0.0;
    int near_old_out = 0;
    printf("S_C, door %s (leak floor %.4f W/m²):\n", open ? "open" : "closed", leak);
    for (int i = 0; i < NPTS; i++) {
      double qn = query(rn, &g_pts[i]), qo = query(ro, &g_pts[i]);
      int okn = within(qn, e[i], se[i], leak), oko = within(qo, e[i], se[i], leak);
      printf("  %-13s ref %9.4f (se %.4f)  new %9.4f err %+7.2f%% %s  black leaf %9.4f err "
             "%+7.2f%% %s\n", g_pts[i].name, e[i], se[i], qn,
             e[i] > 0 ? 100 * (qn - e[i]) / e[i] : 0.0, okn ? "ok" : "OUT", qo,
             e[i] > 0 ? 100 * (qo - e[i]) / e[i] : 0.0, oko ? "ok" : "OUT");
      ASSERT_TRUE(okn);
      if (g_pts[i].p[0] < 0) {
        sum_new += fabs(qn - e[i]);
        sum_old += fabs(qo - e[i]);
        sum_ref += e[i];
        sum_se += se[i];
      }
      if (i == 0)
        near_old_out = !oko;
    }
    printf("  room A summed |error|: new %.4f, black leaf %.4f W/m²\n", sum_new, sum_old);
    /* Door open: room A as a whole within 3 s.e. + 2% per point on average. The door pass
     * once left out the light that crosses the doorway into room B and comes back (0.0 for
     * rays through the doorway at every bounce) and the open leaf's own direct light:
     * 2.78 W/m² here, against 1.73 since (bound 2.47). */
    if (open) {
      printf("  room A door open: summed |error| %.4f W/m², bound %.4f\n", sum_new,
             3.0 * sum_se + 0.02 * sum_ref);
      ASSERT_TRUE(sum_new <= 3.0 * sum_se + 0.02 * sum_ref);
    }
    if (!open) {
      ASSERT_TRUE(sum_old >= 2.0 * sum_new);
      ASSERT_TRUE(near_old_out);
    }
  }
done:
  ub_runtime_free(rn);
  ub_runtime_free(ro);
  ub_scene_free(s);
}

/* Index of the COMBO record with parents (set, dls_count + door), or -1. */
static int32_t combo_index(const ub_bakefile *bf)
{
  for (uint32_t e = 0; e < bf->elem_count; e++)
    if (bf->elems[e].kind == UB_ELEMENT_COMBO && bf->elems[e].parent[0] == 0 &&
        bf->elems[e].parent[1] == (int32_t)bf->dls_count)
      return (int32_t)e;
  return -1;
}

/* Noise of the door record's LLG probes over n bakes with different seeds (ubk[j]; bf is
 * ubk[0] read): every probe's value (L00 luminance) in every bake lies within 25% of its
 * median over the bakes, plus 1% of the record's mean probe value. The door pass's
 * estimate is bounded per sample (π × the radiance it sees, doors/door.c
 * door_irradiance); over 12 seeds on one machine the largest ratio to the median was 1.11.
 * Before it was bounded, a gather hit a few centimetres from the doorway took a portal
 * sample of tiny pdf: 5 of those 12 seeds had a probe at 1.3-2.2 times its median. */
static void door_llg_noise(const ub_bakefile *bf, char ubk[][1600], int n)
{
  const uint32_t L = bf->elems[0].llg_probe_count ? bf->llgs[0].dims[0] * bf->llgs[0].dims[1] *
                                                        bf->llgs[0].dims[2]
                                                  : 0;
  float *v = malloc(((size_t)L * n + 1) * sizeof *v);
  ASSERT_TRUE(v != NULL && bf->llg_count == 1 && L > 0);
  if (!v || bf->llg_count != 1 || !L) {
    free(v);
    return;
  }
  for (size_t i = 0; i < (size_t)L * n; i++)
    v[i] = NAN;
  for (int j = 0; j < n; j++) {
    ub_bakefile *b = NULL;
    if (j)
      ASSERT_OK(ub_bakefile_read(ubk[j], &g_log, &b));
    const ub_bakefile *bj = j ? b : bf;
    if (bj && bj->elem_count && bj->elems[0].kind == UB_ELEMENT_DOOR) {
      const ub_bakefile_record *r = &bj->elems[0];
      for (uint32_t i = 0; i < r->llg_probe_count; i++)
        if (r->llg_probe_index[i] < L) {
          const float *sh = r->llg_probe_sh + 27 * (size_t)i;
          v[(size_t)r->llg_probe_index[i] * n + j] = lum(sh);
        }
    }
    ub_bakefile_free(b);
  }
  double mean = 0.0, worst = 0.0;
  uint32_t common = 0, out = 0;
  for (uint32_t q = 0; q < L; q++) {
    int all = 1;
    for (int j = 0; j < n; j++)
      all &= isfinite(v[(size_t)q * n + j]);
    for (int j = 0; j < n && all; j++)
      mean += fabs(v[(size_t)q * n + j]) / n;
    common += all;
  }
  mean = common ? mean / common : 0.0;
  for (uint32_t q = 0; q < L; q++) {
    float *x = v + (size_t)q * n, srt[8];
    int all = n <= 8;
    for (int j = 0; j < n && all; j++)
      all &= isfinite(x[j]);
    if (!all)
      continue;
    memcpy(srt, x, (size_t)n * sizeof *srt);
    for (int a = 1; a < n; a++) /* insertion sort */
      for (int b = a; b > 0 && srt[b - 1] > srt[b]; b--) {
        float t = srt[b];
        srt[b] = srt[b - 1];
        srt[b - 1] = t;
      }
    double med = n % 2 ? srt[n / 2] : 0.5 * (srt[n / 2 - 1] + srt[n / 2]);
    for (int j = 0; j < n; j++) {
      double dev = fabs(x[j] - med);
      if (fabs(med) > 0.0 && dev / fabs(med) > worst)
        worst = dev / fabs(med);
      out += dev > 0.25 * fabs(med) + 0.01 * mean;
    }
  }
  printf("door record LLG noise over %d seeds: %u probes in every record, largest deviation "
         "from a probe's median %.1f%%, %u values outside 25%% + 1%% of the mean (want 0)\n",
         n, common, 100 * worst, out);
  ASSERT_TRUE(common > 0 && out == 0);
  free(v);
}

/* 2 and 3: combination and LLG, on one level. */
static void test_combo_llg(void)
{
  char lv[1400], path[1600];
  ub_bake_stats st;
  ASSERT_TRUE(make("door_combo_llg", "--param llg_prop=1 --param llg_prop_at=1.3,0,0.9",
                   UB_QUALITY_FAST, lv, sizeof lv, &st));
  ub_scene *s = NULL;
  ub_bakefile *bf = NULL;
  ub_runtime *run = NULL, *naive = NULL;
  ASSERT_OK(ub_scene_load(lv, &g_log, &s));
  ASSERT_OK(ub_bakefile_read(st.ubk_path, &g_log, &bf));
  if (!s || !bf)
    goto done;
  ASSERT_TRUE(bf->dls_count == 1 && bf->llg_count == 1);
  int32_t ci = combo_index(bf);
  ASSERT_TRUE(ci >= 0 && bf->elems[0].kind == UB_ELEMENT_DOOR);
  if (ci < 0 || bf->elem_count < 1 || bf->dls_count != 1)
    goto done;
  printf("records: door %s %u pixels %u probes %u LLG probes; combination %s %u pixels %u "
         "probes %u LLG probes\n", bf->elems[0].name, bf->elems[0].texel_count,
         bf->elems[0].probe_count, bf->elems[0].llg_probe_count, bf->elems[ci].name,
         bf->elems[ci].texel_count, bf->elems[ci].probe_count, bf->elems[ci].llg_probe_count);
  ASSERT_TRUE(bf->elems[0].llg_probe_count > 0 && bf->elems[ci].llg_probe_count > 0);
  /* the report lists it, baked, with the reason */
  snprintf(path, sizeof path, "%s/door_combo_llg/door_combo_llg.report.json", g_dir);
  FILE *f = fopen(path, "r");
  ASSERT_TRUE(f != NULL);
  if (f) {
    static char buf[1 << 20];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    buf[n] = 0;
    fclose(f);
    const char *c = strstr(buf, "\"combination door middle x lamp_b\", \"baked\": true");
    ASSERT_TRUE(c != NULL && strstr(c, "overlap") != NULL);
  }
  /* the same file without the combination: the door and the set summed */
  snprintf(path, sizeof path, "%s/door_combo_llg/naive.ubk", g_dir);
  write_without(bf, ci, path);
  ASSERT_OK(ub_runtime_load(st.ubk_path, &g_log, &run));
  ASSERT_OK(ub_runtime_load(path, &g_log, &naive));
  if (!run || !naive)
    goto done;
  /* the packed AHD at load (door closed, lamp_b on): the door's own groups are recomputed
   * only once it opens, so back in this state after the states below they must give the
   * same bits as the load encoded */
  ub_ahd_packed *ahd0 = ahd_snapshot(run, ub_runtime_bakefile(run));
  static const struct {
    float t, w;
    const char *name;
  } states[3] = {{1, 1, "open + lamp_b"}, {0, 1, "closed + lamp_b"}, {1, 0, "open, lamp_b off"}};
  double e_room_a = 0.0;
  for (int k = 0; k < 3; k++) {
    double e[NPTS], se[NPTS];
    double leak = refs(s, (int)states[k].t, states[k].w, e, se);
    if (k == 0)
      e_room_a = 100.0 * leak;
    set_state(run, states[k].t, states[k].w);
    set_state(naive, states[k].t, states[k].w);
    double sum_c = 0.0, sum_n = 0.0;
    printf("%s (leak floor %.4f W/m²):\n", states[k].name, leak);
    for (int i = 0; i < NPTS; i++) {
      double qc = query(run, &g_pts[i]), qn = query(naive, &g_pts[i]);
      int ok = within(qc, e[i], se[i], leak);
      printf("  %-13s ref %9.4f (se %.4f)  bake %9.4f err %+7.2f%% %s  without combination "
             "%9.4f err %+7.2f%%\n", g_pts[i].name, e[i], se[i], qc,
             e[i] > 0 ? 100 * (qc - e[i]) / e[i] : 0.0, ok ? "ok" : "OUT", qn,
             e[i] > 0 ? 100 * (qn - e[i]) / e[i] : 0.0);
      ASSERT_TRUE(ok);
      sum_c += fabs(qc - e[i]);
      sum_n += fabs(qn - e[i]);
    }
    printf("  summed |error|: with combination %.4f, without %.4f W/m²\n", sum_c, sum_n);
    if (k == 0)
      ASSERT_TRUE(sum_n > 2.0 * sum_c);
  }
  {
    set_state(run, 0, 1);
    const ub_bakefile *rb = ub_runtime_bakefile(run);
    ub_ahd_packed *ahd1 = ahd_snapshot(run, rb);
    const size_t np = atlas_pixels(rb, rb->atlas_count);
    size_t differ = 0;
    for (size_t i = 0; i < np; i++)
      differ += memcmp(&ahd0[i], &ahd1[i], sizeof *ahd1) != 0;
    printf("back to the load's state: %zu of %zu packed AHD texels differ from the load's "
           "(want 0)\n", differ, np);
    ASSERT_TRUE(differ == 0);
    free(ahd1);
    free(ahd0);
  }
  /* 3. LLG irradiance on the prop (box 0.4 m, bottom centre (1.3, 0, 0.9)): top, the face
   * toward the doorway (-x) and toward room A's light through it (-z). The bake's own
   * noise there is above the reference's (door open, -z face, seeds 1-12 on one machine:
   * 0.67-0.82 W/m², se 0.025 for the reference's 0.86; 0.69-1.26 before door_irradiance
   * was bounded), so the check is on the mean of LLG_SEEDS bakes with their spread in the
   * tolerance: |mean - ref| <= 3·sqrt(se_ref² + s²/n) + 5%, plus the LLG's own error at
   * that point (below); door_llg_noise bounds the spread itself. */
  enum { LLG_SEEDS = 4 };
  _Static_assert(LLG_SEEDS == 4, "the LLG rows print four seeds' values");
  ub_runtime *seeds[LLG_SEEDS] = {run};
  char seed_ubk[LLG_SEEDS][1600];
  snprintf(seed_ubk[0], sizeof seed_ubk[0], "%s", st.ubk_path);
  for (uint32_t j = 1; j < LLG_SEEDS; j++) {
    seeds[j] = bake_seed(lv, "door_combo_llg", UB_QUALITY_FAST, 1 + j, seed_ubk[j],
                         sizeof seed_ubk[j]);
    ASSERT_TRUE(seeds[j] != NULL);
    if (!seeds[j])
      goto seeds_done;
  }
  door_llg_noise(bf, seed_ubk, LLG_SEEDS);
  static const pt lp[3] = {{"prop top", {1.3f, 0.403f, 0.9f}, {0, 1, 0}},
                           {"prop -x face", {1.097f, 0.2f, 0.9f}, {-1, 0, 0}},
                           {"prop -z face", {1.3f, 0.2f, 0.697f}, {0, 0, -1}}};
  static const struct {
    float t, w;
    int must;
    const char *name;
  } ls[4] = {{0, 0, 1, "closed"}, {1, 0, 1, "open"}, {0, 1, 0, "closed + lamp_b"},
             {1, 1, 0, "open + lamp_b"}};
  double m[4][3], e[4][3], se[4][3], sd[4][3], q[4][3][LLG_SEEDS], qn[4][3];
  for (int k = 0; k < 4; k++) {
    for (int j = 0; j < LLG_SEEDS; j++)
      set_state(seeds[j], ls[k].t, ls[k].w);
    set_state(naive, ls[k].t, ls[k].w);
    for (int i = 0; i < 3; i++) {
      double v = 0.0;
      reference(s, (int)ls[k].t, ls[k].w, lp[i].p, lp[i].n, &e[k][i], &se[k][i]);
      m[k][i] = 0.0;
      for (int j = 0; j < LLG_SEEDS; j++) {
        float rgb[3] = {NAN, NAN, NAN};
        ASSERT_OK(ub_runtime_query_llg(seeds[j], lp[i].p, lp[i].n, rgb));
        q[k][i][j] = lum(rgb);
        m[k][i] += q[k][i][j] / LLG_SEEDS;
      }
      for (int j = 0; j < LLG_SEEDS; j++)
        v += (q[k][i][j] - m[k][i]) * (q[k][i][j] - m[k][i]) / (LLG_SEEDS - 1);
      sd[k][i] = sqrt(v);
      float rgbn[3] = {NAN, NAN, NAN};
      ASSERT_OK(ub_runtime_query_llg(naive, lp[i].p, lp[i].n, rgbn));
      qn[k][i] = lum(rgbn);
    }
  }
  /* What the LLG itself misses at each point, door aside: closed + lamp_b, lit by the lamp
   * in room B (the grid's L2 SH around a 0.4 m box; -z face -10.8% here with a spread
   * of 0.1%). A door record reaching the prop is held to that plus 3 s.e. + 5%. */
  for (int k = 0; k < 4; k++)
    for (int i = 0; i < 3; i++) {
      const double own = e[2][i] > 0 ? fabs(m[2][i] - e[2][i]) / e[2][i] : 0.0;
      const double se_all = sqrt(se[k][i] * se[k][i] + sd[k][i] * sd[k][i] / LLG_SEEDS);
      int ok = within(m[k][i], e[k][i], se_all, 0.01 * e_room_a) ||
               fabs(m[k][i] - e[k][i]) <= 3.0 * se_all + (0.05 + own) * fabs(e[k][i]);
      printf("  LLG %-16s %-13s ref %8.4f (se %.4f)  bake mean %8.4f (seeds %.4f %.4f %.4f "
             "%.4f, se %.4f) err %+7.2f%% (LLG's own %.1f%%) %s  without combination (seed 1) "
             "%8.4f\n", ls[k].name, lp[i].name, e[k][i], se[k][i], m[k][i], q[k][i][0],
             q[k][i][1], q[k][i][2], q[k][i][3], sd[k][i] / sqrt(LLG_SEEDS),
             e[k][i] > 0 ? 100 * (m[k][i] - e[k][i]) / e[k][i] : 0.0, 100 * own,
             ok ? "ok" : (ls[k].must ? "OUT" : "off"), qn[k][i]);
      if (ls[k].must)
        ASSERT_TRUE(ok);
    }
seeds_done:
  for (int j = 1; j < LLG_SEEDS; j++)
    ub_runtime_free(seeds[j]);
done:
  ub_runtime_free(run);
  ub_runtime_free(naive);
  ub_bakefile_free(bf);
  ub_scene_free(s);
}

/* 4. Door × door: door_chain (rooms A | B | C, doors ab and bc in line, lamp in A; bc
 * tagged `ubake_combine: ab`). Both open: room C (lit only through both doorways) and
 * room B within tolerance; without the COMBO record room C stays dark (summed error
 * larger, printed). One door open: the record does not apply. */
static void test_pair(void)
{
  char cmd[4096], lv[1400], out[1400], path[1600];
  snprintf(cmd, sizeof cmd, "'%s/ubake-genlevel' door_chain -o '%s' > /dev/null", g_build,
           g_dir);
  ASSERT_TRUE(system(cmd) == 0);
  snprintf(lv, sizeof lv, "%s/door_chain.gltf", g_dir);
  snprintf(out, sizeof out, "%s/door_chain", g_dir);
  ub_bake_options o = bake_options(UB_QUALITY_FAST, out);
  ub_bake_stats st;
  ub_scene *s = NULL;
  ub_bakefile *bf = NULL;
  ub_runtime *run = NULL, *naive = NULL;
  ASSERT_OK(ub_bake_level(lv, &o, &g_log, &st));
  ASSERT_OK(ub_scene_load(lv, &g_log, &s));
  ASSERT_OK(ub_bakefile_read(st.ubk_path, &g_log, &bf));
  if (!s || !bf)
    goto done;
  int32_t ci = -1;
  for (uint32_t e = 0; e < bf->elem_count; e++)
    if (bf->elems[e].kind == UB_ELEMENT_COMBO && bf->elems[e].parent[0] == (int32_t)bf->dls_count + 1 &&
        bf->elems[e].parent[1] == (int32_t)bf->dls_count)
      ci = (int32_t)e;
  ASSERT_TRUE(ci >= 0 && s->door_count == 2 && !strcmp(s->door_names[0], "ab"));
  if (ci < 0)
    goto done;
  printf("door x door record %s: %u pixels %u probes\n", bf->elems[ci].name,
         bf->elems[ci].texel_count, bf->elems[ci].probe_count);
  snprintf(path, sizeof path, "%s/naive.ubk", out);
  write_without(bf, ci, path);
  ASSERT_OK(ub_runtime_load(st.ubk_path, &g_log, &run));
  ASSERT_OK(ub_runtime_load(path, &g_log, &naive));
  if (!run || !naive)
    goto done;
  static const pt cp[8] = {{"C 1m floor", {2.5f, 0, 0}, {0, 1, 0}},
                           {"C 2m floor", {3.5f, 0, 0}, {0, 1, 0}},
                           {"C 1m ceiling", {2.5f, 3, 0}, {0, -1, 0}},
                           {"C 2m ceiling", {3.5f, 3, 0}, {0, -1, 0}},
                           {"B floor", {0.5f, 0, 0}, {0, 1, 0}},
                           {"B ceiling", {-0.5f, 3, 0}, {0, -1, 0}},
                           {"A floor", {-3.0f, 0, -1.0f}, {0, 1, 0}},
                           {"A ceiling", {-3.5f, 3, 0}, {0, -1, 0}}};
  static const uint8_t states[3][2] = {{1, 1}, {1, 0}, {0, 1}};
  for (int k = 0; k < 3; k++) {
    for (int rr = 0; rr < 2; rr++) {
      ub_runtime *x = rr ? naive : run;
      for (uint32_t d = 0; d < 2; d++)
        ASSERT_OK(ub_runtime_set_element(x, (uint32_t)ub_runtime_element_find(
                                                x, UB_ELEMENT_DOOR, s->door_names[d]),
                                         (float)states[k][d]));
      ASSERT_OK(ub_runtime_update(x, NULL));
    }
    uint8_t op[2] = {states[k][0], states[k][1]};
    ub_geom_state gs = {op, NULL};
    uint8_t *mask = ub_geom_mask(s, &gs);
    ub_rt *rt = NULL;
    ub_emitters *em = NULL;
    ASSERT_TRUE(mask && ub_rt_create(s, mask, NULL, &rt) == UB_OK &&
                ub_emitters_build(s, &em) == UB_OK);
    double e[8], se[8], room_a = 0.0, sum_c = 0.0, sum_n = 0.0;
    for (int i = 0; i < 8 && rt && em; i++) {
      float rgb[3] = {NAN, NAN, NAN}, sev[3] = {NAN, NAN, NAN};
      ub_reference_params rp;
      ub_reference_params_init(&rp);
      memcpy(rp.position, cp[i].p, sizeof rp.position);
      memcpy(rp.normal, cp[i].n, sizeof rp.normal);
      rp.spp = 4096;
      rp.seed = 9;
      ub_reference_irradiance(s, rt, em, &rp, rgb, sev, NULL);
      e[i] = lum(rgb);
      se[i] = lum(sev);
      if (i >= 6)
        room_a += 0.5 * e[i];
    }
    printf("doors ab=%u bc=%u (leak floor %.4f W/m²):\n", states[k][0], states[k][1],
           0.01 * room_a);
    for (int i = 0; i < 8; i++) {
      double qc = query(run, &cp[i]), qn = query(naive, &cp[i]);
      int ok = within(qc, e[i], se[i], 0.01 * room_a);
      printf("  %-13s ref %8.4f (se %.4f)  bake %8.4f err %+7.2f%% %s  without combination "
             "%8.4f err %+7.2f%%\n", cp[i].name, e[i], se[i], qc,
             e[i] > 0 ? 100 * (qc - e[i]) / e[i] : 0.0, ok ? "ok" : "OUT", qn,
             e[i] > 0 ? 100 * (qn - e[i]) / e[i] : 0.0);
      ASSERT_TRUE(ok);
      if (i < 4) {
        sum_c += fabs(qc - e[i]);
        sum_n += fabs(qn - e[i]);
      }
    }
    printf("  room C summed |error|: with combination %.4f, without %.4f W/m²\n", sum_c,
           sum_n);
    if (k == 0)
      ASSERT_TRUE(sum_n > 2.0 * sum_c);
    ub_emitters_free(em);
    ub_rt_free(rt);
    free(mask);
  }
done:
  ub_runtime_free(run);
  ub_runtime_free(naive);
  ub_bakefile_free(bf);
  ub_scene_free(s);
}

int main(int argc, char **argv)
{
  const char *b = getenv("UB_BUILD");
  snprintf(g_build, sizeof g_build, "%s", b ? b : ".");
  snprintf(g_dir, sizeof g_dir, "%s/test_out", g_build);
  mkdir(g_dir, 0777);
  snprintf(g_dir, sizeof g_dir, "%s/test_out/door_combo", g_build);
  mkdir(g_dir, 0777);
  const char *only = argc > 1 ? argv[1] : "";
  if (!*only || !strcmp(only, "bounce"))
    test_leaf_bounce();
  if (!*only || !strcmp(only, "combo"))
    test_combo_llg();
  if (!*only || !strcmp(only, "pair"))
    test_pair();
  TEST_MAIN_END();
}
