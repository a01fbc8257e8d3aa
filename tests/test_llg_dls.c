/* tests/test_llg_dls.c — LLG probes in dynamic light set records, end to end.
 *
 * Level: `hallway --param lamp_y=1.5 --param llg_prop=1 --param llg_prop_at=-3,0,0.5`
 * (levels/genlevel.c): the 12 m corridor with its two dynamic light sets (hall_a: lamps 1
 * and 2, lamp 2 primary; hall_b: lamps 3 and 4; nothing in the base) and a 0.4 m box
 * tagged `ubake_receiver: "llg"` between lamps 1 and 2. Baked at fast quality.
 * Checks, for the states {hall_a 1, hall_b 0}, {0, 1}, {1, 1} and {0.5, 2}:
 *   - every set's record carries LLG probes (indices in range, ascending);
 *   - the run-time's LLG grid (ub_runtime_query_llg_ex without visibility, after
 *     ub_runtime_update) equals base + Σ wᵢ·recordᵢ summed here from the file's
 *     probes (relative 1e-4);
 *   - `ubake query --source llg --dls …` prints the run-time's value (printed precision);
 *   - the LLG irradiance on the box's top and two side faces matches `reference` with the
 *     same DLS weights (2048 paths) within 3 s.e. + 5% (figures printed). */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "bake/reference.h"
#include "bake/rt.h"
#include "test_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/llg.h"
#include "ubake/runtime.h"
#include "ubake/scene.h"

static void test_log(void *user, ub_log_level level, const char *msg)
{
  (void)user;
  if (level <= UB_LOG_WARNING)
    fprintf(stderr, "%s: %s\n", level == UB_LOG_ERROR ? "error" : "warning", msg);
}
static const ub_log g_log = {test_log, NULL};

static double lum(const float *c) { return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]; }

int main(void)
{
  const char *b = getenv("UB_BUILD");
  char build[512], dir[1024], cmd[4096], level[1200], out[1200];
  snprintf(build, sizeof build, "%s", b ? b : ".");
  snprintf(dir, sizeof dir, "%s/test_out", build);
  mkdir(dir, 0777);
  snprintf(dir, sizeof dir, "%s/test_out/llg_dls", build);
  mkdir(dir, 0777);
  snprintf(cmd, sizeof cmd,
           "'%s/ubake-genlevel' hallway -o '%s' --param lamp_y=1.5 --param llg_prop=1 "
           "--param llg_prop_at=-3,0,0.5 --name hallway_llg",
           build, dir);
  ASSERT_TRUE(system(cmd) == 0);
  snprintf(level, sizeof level, "%s/hallway_llg.gltf", dir);
  snprintf(out, sizeof out, "%s/bake", dir);
  ub_bake_options o;
  ub_bake_options_default(&o);
  o.quality = UB_QUALITY_FAST;
  o.out_dir = out;
  ub_bake_stats st;
  ub_result r = ub_bake_level(level, &o, &g_log, &st);
  ASSERT_OK(r);
  if (r != UB_OK)
    TEST_MAIN_END();
  ub_bakefile *bf = NULL;
  ub_runtime *run = NULL;
  ub_scene *scene = NULL;
  ub_rt *rt = NULL;
  ASSERT_OK(ub_bakefile_read(st.ubk_path, &g_log, &bf));
  ASSERT_OK(ub_runtime_load(st.ubk_path, &g_log, &run));
  ASSERT_OK(ub_scene_load(level, &g_log, &scene));
  if (scene)
    ASSERT_OK(ub_rt_create(scene, NULL, &g_log, &rt));
  if (!bf || !run || !scene || !rt)
    TEST_MAIN_END();
  ASSERT_TRUE(bf->llg_count == 1 && bf->dls_count == 2);
  if (bf->llg_count != 1 || bf->dls_count != 2)
    TEST_MAIN_END();
  const ub_bakefile_llg *m = &bf->llgs[0];
  uint32_t np = m->dims[0] * m->dims[1] * m->dims[2];
  int32_t set_of[2];
  for (uint32_t d = 0; d < 2; d++) {
    const ub_bakefile_record *rec = &bf->dls[d];
    int sorted = 1;
    for (uint32_t i = 0; i < rec->llg_probe_count; i++)
      sorted &= rec->llg_probe_index[i] < np && (i == 0 || rec->llg_probe_index[i] >
                                                               rec->llg_probe_index[i - 1]);
    printf("  record %s: %u of %u LLG probes\n", rec->name, rec->llg_probe_count, np);
    ASSERT_TRUE(rec->llg_probe_count > 0 && sorted);
    set_of[d] = ub_runtime_dls_find(run, rec->name);
    ASSERT_TRUE(set_of[d] >= 0);
  }
  int32_t scene_set[2] = {-1, -1}; /* record d → scene dls index (reference weights) */
  for (uint32_t d = 0; d < 2; d++)
    for (uint32_t k = 0; k < scene->dls_count; k++)
      if (!strcmp(scene->dls_names[k], bf->dls[d].name))
        scene_set[d] = (int32_t)k;
  ASSERT_TRUE(scene_set[0] >= 0 && scene_set[1] >= 0 && scene->dls_count == 2);
  static const float states[4][2] = {{1, 0}, {0, 1}, {1, 1}, {0.5f, 2}};
  static const float pts[3][6] = {{-3.0f, 0.403f, 0.5f, 0, 1, 0},
                                  {-2.797f, 0.2f, 0.5f, 1, 0, 0},
                                  {-3.0f, 0.2f, 0.297f, 0, 0, -1}};
  float *sum = malloc((size_t)np * 27 * sizeof *sum);
  double worst_grid = 0.0;
  for (int s = 0; s < 4; s++) {
    for (int d = 0; d < 2; d++) {
      float w[3] = {states[s][d], states[s][d], states[s][d]};
      ASSERT_OK(ub_runtime_set_dls(run, (uint32_t)set_of[d], w));
    }
    ASSERT_OK(ub_runtime_update(run, NULL));
    /* base + Σ w·record, from the file */
    memcpy(sum, m->probe_sh, (size_t)np * 27 * sizeof *sum);
    for (int d = 0; d < 2; d++) {
      const ub_bakefile_record *rec = &bf->dls[d];
      for (uint32_t i = 0; i < rec->llg_probe_count; i++)
        for (int k = 0; k < 27; k++)
          sum[27 * (size_t)rec->llg_probe_index[i] + k] +=
              states[s][d] * rec->llg_probe_sh[27 * (size_t)i + k];
    }
    for (int i = 0; i < 3; i++) {
      const float *p = pts[i], *n = pts[i] + 3;
      float grid_rt[3], grid_sum[3], L[27], e[3], ref[3], se[3];
      ASSERT_OK(ub_runtime_query_llg_ex(run, p, n, UB_LLG_QUERY_NO_VISIBILITY, grid_rt, NULL));
      ub_llg_grid_sample(m->center, m->axes, m->half, m->dims, sum, p, L);
      ub_llg_irradiance(L, NULL, NULL, n, grid_sum);
      for (int c = 0; c < 3; c++) {
        double den = fmax(fabs(grid_sum[c]), 1e-3);
        worst_grid = fmax(worst_grid, fabs(grid_rt[c] - grid_sum[c]) / den);
        ASSERT_NEAR(grid_rt[c], grid_sum[c], 1e-5, 1e-4);
      }
      ASSERT_OK(ub_runtime_query_llg(run, p, n, e));
      ub_reference_params rp;
      ub_reference_params_init(&rp);
      memcpy(rp.position, p, sizeof rp.position);
      memcpy(rp.normal, n, sizeof rp.normal);
      rp.spp = 2048;
      rp.seed = 101 + (uint32_t)(3 * s + i);
      float wref[6];
      for (int d = 0; d < 2; d++)
        for (int c = 0; c < 3; c++)
          wref[3 * scene_set[d] + c] = states[s][d];
      rp.dls_weight = wref;
      ASSERT_OK(ub_reference_irradiance(scene, rt, NULL, &rp, ref, se, &g_log));
      double a = lum(e), rr = lum(ref), sd = lum(se);
      printf("  hall_a %.1f hall_b %.1f, face %d: LLG %.4f, reference %.4f ± %.4f W/m² "
             "(%+.1f%%)\n",
             states[s][0], states[s][1], i, a, rr, sd, rr > 0 ? 100.0 * (a - rr) / rr : 0.0);
      ASSERT_NEAR(a, rr, 3.0 * sd, 0.05);
      if (s == 0 && i == 0) { /* the command line answers the same */
        char q[4096];
        snprintf(q, sizeof q,
                 "'%s/ubake' query '%s' --at %.4f,%.4f,%.4f --normal %g,%g,%g --source llg "
                 "--dls %s=%g --dls %s=%g",
                 build, st.ubk_path, p[0], p[1], p[2], n[0], n[1], n[2], bf->dls[0].name,
                 states[s][0], bf->dls[1].name, states[s][1]);
        FILE *f = popen(q, "r");
        float c3[3] = {-1, -1, -1};
        int got = f ? fscanf(f, "%f %f %f", &c3[0], &c3[1], &c3[2]) : 0;
        if (f)
          pclose(f);
        printf("  ubake query --source llg: %.6g %.6g %.6g (run-time %.6g %.6g %.6g)\n", c3[0],
               c3[1], c3[2], e[0], e[1], e[2]);
        ASSERT_TRUE(got == 3);
        for (int c = 0; c < 3; c++)
          ASSERT_NEAR(c3[c], e[c], 1e-6, 1e-4);
      }
    }
  }
  printf("  run-time LLG grid vs base + Σ w·record: worst relative difference %.2e\n",
         worst_grid);
  free(sum);
  ub_rt_free(rt);
  ub_scene_free(scene);
  ub_runtime_free(run);
  ub_bakefile_free(bf);
  TEST_MAIN_END();
}
