/* The reach bound of dynamic light sets (bake/dls.h) drops nothing that matters: per set,
 * the influence pass run over every texel (what ub_dls_bake did before the bound) and the
 * same pass over the bound's candidate texels only, with the kept-receiver rule of
 * ub_dls_bake before full passes of INF_BOUNCES fixed bounces (influence pass and photons
 * of that many bounces, no tail: lit directly, or indirect above
 * UB_DLS_INFLUENCE_FRACTION_EXACT of the mean indirect of the directly lit texels)
 * applied to each. Checked, per set:
 * - the texels kept without the bound that lie outside it carry < 1% of the light
 *   (direct + indirect of the unbounded influence pass) of the texels kept without it;
 * - the texels kept without the bound but not with it (outside it, or inside it but now
 *   below the threshold, e.g. missing bounce light from outside) carry < 1% more than
 *   the rule's own noise: the same unbounded pass with other random numbers;
 * - the candidate list through the per-texel cell table (ub_dls_texel_cells) is the
 *   point-by-point one;
 * - and the bound is reported: candidates and kept texels vs the level.
 * Levels: hallway and estate_small (sets of their own), inn and two_rooms with every
 * light in one set (genlevel's common parameter lights_dls=1). Texels only: probes follow
 * the same photons with a looser test (any crossed voxel), and tests/test_plan.c checks
 * the records against --plan all. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bake/dls.h"
#include "bake/geomstate.h"
#include "bake/pass.h"
#include "test_util.h"
#include "ubake/bake.h"
#include "ubake/scene.h"

#define MAX_DROPPED 0.01 /* of the light of the receivers the unbounded pass keeps */
#define INF_BOUNCES 2     /* ub_dls_bake's influence pass at --bounces 2 */

static char g_build[512];

static void keep_rule(const ub_pass_result *inf, uint32_t T, uint8_t *out_kept)
{
  double ind = 0.0;
  uint64_t lit = 0;
  for (uint32_t t = 0; t < T; t++)
    if (inf->texel_direct[t] > 0.0f) {
      ind += inf->texel_indirect[t];
      lit++;
    }
  double thr = lit ? UB_DLS_INFLUENCE_FRACTION_EXACT * ind / lit : 0.0;
  for (uint32_t t = 0; t < T; t++)
    out_kept[t] = inf->texel_direct[t] > 0.0f || inf->texel_indirect[t] > thr;
}

static void check_level(const char *path, const char *name)
{
  ub_scene *s = NULL;
  ASSERT_OK(ub_scene_load(path, NULL, &s));
  if (!s)
    return;
  ASSERT_TRUE(s->dls_count > 0);
  uint8_t *mask = ub_geom_mask(s, NULL);
  ub_rt *rt = NULL;
  ub_lightmap *lm = NULL;
  ASSERT_OK(ub_rt_create(s, mask, NULL, &rt));
  if (rt)
    ASSERT_OK(ub_lightmap_build(s, rt, s->texel_size, NULL, &lm));
  if (!rt || !lm) {
    free(mask);
    ub_rt_free(rt);
    ub_scene_free(s);
    return;
  }
  ub_bake_options o;
  ub_bake_options_default(&o);
  uint32_t T = lm->texel_count;
  uint8_t *en = calloc(s->light_count + 1, 1);
  uint8_t *ka = malloc((size_t)T + 1), *kb = malloc((size_t)T + 1);
  uint8_t *kn = malloc((size_t)T + 1), *ic = malloc((size_t)T + 1);
  uint32_t *cand = malloc(((size_t)T + 1) * sizeof *cand);
  float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (uint32_t t = 0; t < T; t++)
    ub_dls_bounds_add(lm->texel_pos + 3 * (size_t)t, lo, hi);
  for (uint32_t l = 0; l < s->light_count; l++)
    if (s->lights[l].dls >= 0 && s->lights[l].type != UB_LIGHT_DIRECTIONAL)
      ub_dls_bounds_add(s->lights[l].position, lo, hi);
  double worst = 0.0;
  uint64_t sum_cand = 0, sum_ka = 0, sum_kb = 0;
  for (uint32_t d = 0; d < s->dls_count && en && ka && kb && kn && ic && cand; d++) {
    for (uint32_t l = 0; l < s->light_count; l++)
      en[l] = s->lights[l].dls == (int32_t)d;
    ub_dls_reach rb;
    ASSERT_OK(ub_dls_reach_build(s, rt, en, lo, hi, o.seed, d,
                                 ub_dls_influence_bounces(INF_BOUNCES) + 1u, &rb));
    uint32_t nc = 0;
    for (uint32_t t = 0; t < T; t++)
      if (ub_dls_reach_texel(&rb, lm, t))
        cand[nc++] = t;
    {
      ub_dls_texel_cells tc;
      uint32_t *c2 = malloc(((size_t)T + 1) * sizeof *c2);
      int built = ub_dls_texel_cells_build(&rb, lm, &tc);
      ASSERT_TRUE(built || rb.unbounded);
      uint32_t n2 = c2 ? ub_dls_reach_texels(&rb, &tc, lm, c2) : 0;
      ASSERT_TRUE(c2 && n2 == nc && memcmp(c2, cand, (size_t)nc * sizeof *c2) == 0);
      ASSERT_TRUE(ub_dls_reach_texels(&rb, NULL, lm, NULL) == nc);
      ub_dls_texel_cells_free(&tc);
      free(c2);
    }
    ub_dls_reach_free(&rb);
    /* An influence pass of ub_dls_bake at --bounces INF_BOUNCES (16 gather rays). */
    ub_pass_desc pd;
    memset(&pd, 0, sizeof pd);
    pd.scene = s;
    pd.rt = rt;
    pd.lightmap = lm;
    pd.light_enabled = en;
    pd.gather_rays = 16;
    pd.shadow_samples = 1;
    pd.bounces = INF_BOUNCES;
    pd.seed = o.seed;
    pd.pass_id = 2 + 2 * d;
    ub_pass_result all, sub, again;
    ASSERT_OK(ub_pass_run(&pd, NULL, &all));
    pd.pass_id = 1000 + d; /* the same pass with other random numbers: the rule's noise */
    ASSERT_OK(ub_pass_run(&pd, NULL, &again));
    pd.pass_id = 2 + 2 * d;
    pd.texel_subset = cand;
    pd.texel_subset_count = nc;
    ASSERT_OK(ub_pass_run(&pd, NULL, &sub));
    keep_rule(&all, T, ka);
    keep_rule(&sub, T, kb);
    keep_rule(&again, T, kn);
    memset(ic, 0, T);
    for (uint32_t i = 0; i < nc; i++)
      ic[cand[i]] = 1;
    double total = 0.0, dropped = 0.0, outside = 0.0, noise = 0.0;
    uint32_t na = 0, nb = 0, lost = 0, nout = 0;
    for (uint32_t t = 0; t < T; t++) {
      na += ka[t];
      nb += kb[t];
      if (!ka[t])
        continue;
      double v = (double)all.texel_direct[t] + all.texel_indirect[t];
      total += v;
      if (!kb[t]) {
        dropped += v;
        lost++;
      }
      if (!ic[t]) {
        outside += v;
        nout++;
      }
      if (!kn[t])
        noise += v;
    }
    double share = total > 0 ? outside / total : 0.0;
    double kshare = total > 0 ? dropped / total : 0.0, nshare = total > 0 ? noise / total : 0.0;
    worst = share > worst ? share : worst;
    sum_cand += nc;
    sum_ka += na;
    sum_kb += nb;
    printf("  %s set %s: reach bound %u of %u texels (%.1f%%); kept %u unbounded, %u bounded; "
           "outside the bound %u kept texels, %.3f%% of the light; kept only unbounded %u, "
           "%.3f%% (rule's own noise: %.3f%%)\n",
           name, s->dls_names[d], nc, T, 100.0 * nc / (T ? T : 1), na, nb, nout, 100 * share,
           lost, 100 * kshare, 100 * nshare);
    ASSERT_TRUE(share < MAX_DROPPED);
    ASSERT_TRUE(kshare < nshare + MAX_DROPPED);
    ub_pass_result_free(&all);
    ub_pass_result_free(&sub);
    ub_pass_result_free(&again);
  }
  printf("%s: %u sets, the influence passes see %.1f%% of sets x texels; kept %llu unbounded "
         "vs %llu bounded; worst set drops %.4f%% of its light\n",
         name, s->dls_count, 100.0 * sum_cand / ((double)s->dls_count * (T ? T : 1)),
         (unsigned long long)sum_ka, (unsigned long long)sum_kb, 100 * worst);
  free(en);
  free(ka);
  free(kb);
  free(kn);
  free(ic);
  free(cand);
  free(mask);
  ub_lightmap_free(lm);
  ub_rt_free(rt);
  ub_scene_free(s);
}

int main(void)
{
  const char *b = getenv("UB_BUILD");
  snprintf(g_build, sizeof g_build, "%s", b ? b : "build");
  char path[1024], cmd[4096];
  snprintf(path, sizeof path, "%s/levels/hallway.gltf", g_build);
  check_level(path, "hallway");
  snprintf(path, sizeof path, "%s/levels/estate_small.gltf", g_build);
  check_level(path, "estate_small");
  static const char *gen[] = {"inn", "two_rooms"};
  for (int i = 0; i < 2; i++) {
    snprintf(cmd, sizeof cmd,
             "'%s/ubake-genlevel' %s -o '%s/test_out/plan_reach' --param lights_dls=1 "
             "--name %s_dls > /dev/null",
             g_build, gen[i], g_build, gen[i]);
    ASSERT_TRUE(system(cmd) == 0);
    snprintf(path, sizeof path, "%s/test_out/plan_reach/%s_dls.gltf", g_build, gen[i]);
    check_level(path, gen[i]);
  }
  TEST_MAIN_END();
}
