/* tests/test_llg_auto.c — LLG by default for small props (probes/llg_auto.c).
 *
 * Level: `room --param props=1` (levels/genlevel.c): a closed 4 × 3 × 4 m room, a point
 * light, and three untagged-or-tagged boxes: prop_stool (0.15 m, untagged), prop_crate
 * (0.8 m, untagged), prop_tagged (0.15 m, `ubake_receiver: "lightmap"`).
 * Checks:
 *   - at the level's 0.25 m texels the stool's charts are poor (measured texels per chart
 *     printed) and it becomes an LLG receiver (receiver_source UB_RECEIVER_AUTO); the crate
 *     (good charts), the tagged stool (the tag wins) and the walls (too large) do not;
 *   - at 0.02 m texels (--param texel_size=0.02) the stool's charts are fine: nothing
 *     switches (the criterion follows the texel size, not the mesh alone);
 *   - a draft bake: the report lists exactly prop_stool under llg.auto_nodes, the .ubk
 *     has one LLG model named prop_stool, the lightmap has no texel on it, and the LLG
 *     irradiance on the stool's top and side faces matches `reference` (2048 paths)
 *     within 3 s.e. + 10%. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "bake/reference.h"
#include "bake/rt.h"
#include "lightmaps/lightmap.h"
#include "probes/llg.h"
#include "test_util.h"
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

static int32_t node_named(const ub_scene *s, const char *name)
{
  for (uint32_t n = 0; n < s->node_count; n++)
    if (!strcmp(s->nodes[n].name, name))
      return (int32_t)n;
  return -1;
}

/* Covered texels / charts of node n in lm (the quantity the criterion thresholds). */
static double texels_per_chart(const ub_scene *s, const ub_lightmap *lm, uint32_t n)
{
  uint8_t *seen = calloc(lm->chart_count + 1, 1);
  uint32_t charts = 0, texels = 0;
  const ub_node *nd = &s->nodes[n];
  for (uint32_t t = nd->first_triangle; t < nd->first_triangle + nd->triangle_count; t++) {
    int32_t c = lm->tri_chart[t];
    if (c >= 0 && !seen[c]) {
      seen[c] = 1;
      charts++;
    }
  }
  for (uint32_t x = 0; x < lm->texel_count; x++)
    texels += s->tri_node[lm->texel_tri[x]] == n;
  free(seen);
  return charts ? (double)texels / charts : 0.0;
}

/* Loads level, lays out its lightmap, runs the selection. Returns switched count. */
static uint32_t select_on(const char *level, const char *label, int expect_stool)
{
  ub_scene *s = NULL;
  ub_rt *rt = NULL;
  ub_lightmap *lm = NULL;
  ASSERT_OK(ub_scene_load(level, &g_log, &s));
  if (!s)
    return 0;
  ASSERT_OK(ub_rt_create(s, NULL, &g_log, &rt));
  ASSERT_OK(ub_lightmap_build(s, rt, s->texel_size, &g_log, &lm));
  int32_t stool = node_named(s, "prop_stool"), crate = node_named(s, "prop_crate"),
          tagged = node_named(s, "prop_tagged");
  ASSERT_TRUE(stool >= 0 && crate >= 0 && tagged >= 0);
  ub_llg_auto_stats st;
  memset(&st, 0, sizeof st);
  if (lm && stool >= 0 && crate >= 0 && tagged >= 0) {
    printf("  %s (texel %.3g m): texels per chart: stool %.2f, crate %.2f, tagged stool %.2f "
           "(threshold %.1f)\n",
           label, (double)s->texel_size, texels_per_chart(s, lm, (uint32_t)stool),
           texels_per_chart(s, lm, (uint32_t)crate), texels_per_chart(s, lm, (uint32_t)tagged),
           UB_LLG_AUTO_TEXELS_PER_CHART);
    ASSERT_TRUE(s->nodes[tagged].receiver_source == UB_RECEIVER_TAGGED);
    ASSERT_OK(ub_llg_auto_select(s, lm, &st));
    printf("  %s: %u considered, %u switched\n", label, st.considered, st.switched);
    ASSERT_TRUE(st.switched == (expect_stool ? 1u : 0u));
    ASSERT_TRUE((s->nodes[stool].receiver == UB_RECEIVER_LLG) == !!expect_stool);
    ASSERT_TRUE((s->nodes[stool].receiver_source == UB_RECEIVER_AUTO) == !!expect_stool);
    ASSERT_TRUE(s->nodes[crate].receiver == UB_RECEIVER_LIGHTMAP);
    ASSERT_TRUE(s->nodes[tagged].receiver == UB_RECEIVER_LIGHTMAP);
    for (uint32_t n = 0; n < s->node_count; n++)
      if (strncmp(s->nodes[n].name, "room_", 5) == 0)
        ASSERT_TRUE(s->nodes[n].receiver == UB_RECEIVER_LIGHTMAP);
  }
  ub_lightmap_free(lm);
  ub_rt_free(rt);
  ub_scene_free(s);
  return st.switched;
}

static double lum(const float *c) { return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]; }

static void test_bake(const char *level, const char *dir)
{
  char out[1100];
  snprintf(out, sizeof out, "%s/bake", dir);
  ub_bake_options o;
  ub_bake_options_default(&o);
  o.quality = UB_QUALITY_DRAFT;
  o.out_dir = out;
  ub_bake_stats st;
  ASSERT_OK(ub_bake_level(level, &o, &g_log, &st));
  ASSERT_TRUE(st.llg_auto_nodes == 1);
  /* the report names it */
  char rep[1200];
  snprintf(rep, sizeof rep, "%s/room_props.report.json", out);
  FILE *f = fopen(rep, "rb");
  ASSERT_TRUE(f != NULL);
  if (f) {
    static char buf[1 << 16];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    buf[n] = 0;
    fclose(f);
    ASSERT_TRUE(strstr(buf, "\"auto\": 1, \"auto_nodes\": [\"prop_stool\"]") != NULL);
  }
  ub_bakefile *bf = NULL;
  ASSERT_OK(ub_bakefile_read(st.ubk_path, &g_log, &bf));
  ub_runtime *run = NULL;
  ASSERT_OK(ub_runtime_load(st.ubk_path, &g_log, &run));
  ub_scene *s = NULL;
  ub_rt *rt = NULL;
  ASSERT_OK(ub_scene_load(level, &g_log, &s));
  if (s)
    ASSERT_OK(ub_rt_create(s, NULL, &g_log, &rt));
  if (!bf || !run || !s || !rt)
    goto done;
  ASSERT_TRUE(bf->llg_count == 1 && !strcmp(bf->llgs[0].name, "prop_stool"));
  /* no lightmapped triangle on the stool: its triangles are in GEOM with atlas -1, or
   * absent */
  {
    int32_t sn = node_named(s, "prop_stool");
    uint32_t lit = 0;
    for (uint32_t t = 0; t < bf->triangle_count && sn >= 0; t++) {
      if (bf->tri_atlas[t] < 0)
        continue;
      const float *p = bf->positions + 3 * (size_t)bf->indices[3 * (size_t)t];
      lit += p[0] > 0.89f && p[0] < 1.06f && p[2] > 0.89f && p[2] < 1.06f && p[1] > 0.001f;
    }
    printf("  lightmapped triangles on the stool: %u\n", lit);
    ASSERT_TRUE(lit == 0);
  }
  /* LLG vs reference on the stool's faces */
  static const float pts[3][6] = {
      {0.975f, 0.153f, 0.975f, 0, 1, 0},   /* top */
      {0.897f, 0.075f, 0.975f, -1, 0, 0},  /* side facing -x */
      {0.975f, 0.075f, 1.053f, 0, 0, 1}};  /* side facing +z */
  for (int i = 0; i < 3; i++) {
    float e[3], ref[3], se[3];
    ASSERT_OK(ub_runtime_query_llg(run, pts[i], pts[i] + 3, e));
    ub_reference_params rp;
    ub_reference_params_init(&rp);
    memcpy(rp.position, pts[i], sizeof rp.position);
    memcpy(rp.normal, pts[i] + 3, sizeof rp.normal);
    rp.spp = 2048;
    rp.seed = 11 + (uint32_t)i;
    ASSERT_OK(ub_reference_irradiance(s, rt, NULL, &rp, ref, se, &g_log));
    double a = lum(e), r = lum(ref), sd = lum(se);
    printf("  stool face %d: LLG %.4f, reference %.4f ± %.4f W/m² (%+.1f%%)\n", i, a, r, sd,
           r > 0 ? 100.0 * (a - r) / r : 0.0);
    ASSERT_NEAR(a, r, 3.0 * sd, 0.10);
  }
done:
  ub_rt_free(rt);
  ub_scene_free(s);
  ub_runtime_free(run);
  ub_bakefile_free(bf);
}

int main(void)
{
  const char *b = getenv("UB_BUILD");
  char build[512], dir[1024], cmd[4096], level[1200], level_fine[1200];
  snprintf(build, sizeof build, "%s", b ? b : ".");
  snprintf(dir, sizeof dir, "%s/test_out", build);
  mkdir(dir, 0777);
  snprintf(dir, sizeof dir, "%s/test_out/llg_auto", build);
  mkdir(dir, 0777);
  snprintf(cmd, sizeof cmd,
           "'%s/ubake-genlevel' room -o '%s' --param props=1 --name room_props && "
           "'%s/ubake-genlevel' room -o '%s' --param props=1 --param texel_size=0.02 "
           "--name room_props_fine",
           build, dir, build, dir);
  ASSERT_TRUE(system(cmd) == 0);
  snprintf(level, sizeof level, "%s/room_props.gltf", dir);
  snprintf(level_fine, sizeof level_fine, "%s/room_props_fine.gltf", dir);
  select_on(level, "room_props", 1);
  select_on(level_fine, "room_props_fine", 0);
  test_bake(level, dir);
  TEST_MAIN_END();
}
