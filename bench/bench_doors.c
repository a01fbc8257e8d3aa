/* bench_doors — the door pass's cost and accuracy on a level with doors (default sunroom):
 * base pass seconds, then the door pass (full stage) at 8..512 rays per texel with guiding
 * + MIS and cosine-only: seconds (faster of two runs) and mean |error| over the door's
 * influence texels against a converged door pass (guided, 2048 rays; the same estimator, so the bias the pass shares
 * with both is not in these figures — test_door measures against the reference tracer).
 * Also: seconds of cosine-only for the error each guided rung reaches (log-log interpolated)
 * and their ratio (issue 5's target: <= 1/3 on sunroom).
 * Prints; asserts nothing.   usage: bench_doors [LEVEL.gltf] */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bake/dls.h"
#include "bake/geomstate.h"
#include "bake/lights.h"
#include "bake/pass.h"
#include "bake/rt.h"
#include "doors/door.h"
#include "lightmaps/lightmap.h"
#include "ubake/scene.h"
#include "bench/bench_util.h"

static double lum3(const float *v) { return 0.2126 * v[0] + 0.7152 * v[1] + 0.0722 * v[2]; }

static void err_log(void *u, ub_log_level l, const char *m)
{
  (void)u;
  if (l == UB_LOG_ERROR)
    fprintf(stderr, "%s\n", m);
}

static double door_run(ub_door_desc *dd, uint32_t rays, int guiding, float *iz)
{
  ub_log lg = {err_log, NULL};
  ub_door_stats ds;
  ub_bakefile_record *rec = NULL;
  dd->rays = rays;
  dd->guiding = guiding;
  dd->debug_texel_iz = iz;
  if (ub_door_bake(dd, &lg, &rec, &ds) != UB_OK)
    return NAN;
  ub_dls_records_free(rec, dd->base->scene->door_count);
  return ds.seconds_full;
}

int main(int argc, char **argv)
{
  char level[1024];
  const char *b = getenv("UB_BUILD");
  if (argc > 1)
    snprintf(level, sizeof level, "%s", argv[1]);
  else
    snprintf(level, sizeof level, "%s/levels/sunroom.gltf", b ? b : "build");
  ub_log lg = {err_log, NULL};
  ub_scene *s = NULL;
  if (ub_scene_load(level, &lg, &s) != UB_OK || ub_geom_prepare(s, &lg, NULL) != UB_OK)
    return 1;
  if (!s->door_count) {
    printf("%s: no door\n", level);
    return 0;
  }
  uint8_t *mask = ub_geom_mask(s, NULL);
  ub_rt *rt = NULL;
  ub_emitters *em = NULL;
  ub_lightmap *lm = NULL;
  if (ub_rt_create(s, mask, &lg, &rt) != UB_OK || ub_emitters_build(s, &em) != UB_OK ||
      ub_lightmap_build(s, rt, s->texel_size, &lg, &lm) != UB_OK)
    return 1;
  uint8_t *enabled = calloc(s->light_count + 1, 1);
  for (uint32_t l = 0; l < s->light_count; l++)
    enabled[l] = s->lights[l].dls < 0;
  ub_pass_desc pd;
  memset(&pd, 0, sizeof pd);
  pd.scene = s, pd.rt = rt, pd.emitters = em, pd.lightmap = lm, pd.light_enabled = enabled;
  pd.sky = s->has_sky, pd.emissive = em->count > 0;
  pd.gather_rays = 64, pd.emissive_samples = 4, pd.shadow_samples = 1;
  pd.bounces = -1, pd.stop_fraction = 0.005, pd.seed = 1;
  ub_pass_result base;
  double t0 = ub_bench_now();
  if (ub_pass_run(&pd, NULL, &base) != UB_OK)
    return 1;
  double t_base = ub_bench_now() - t0;
  size_t T3 = (size_t)lm->texel_count * 3;
  float *conv = calloc(T3, sizeof(float)), *iz = calloc(T3, sizeof(float));
  ub_door_desc dd;
  memset(&dd, 0, sizeof dd);
  dd.base = &pd, dd.base_result = &base, dd.influence_rays = 16, dd.photons = 8192;
  double t_conv = door_run(&dd, 2048, 1, conv);
  double csum = 0.0;
  uint32_t nk = 0;
  for (uint32_t t = 0; t < lm->texel_count; t++)
    if (conv[3 * t] != 0.0f || conv[3 * t + 1] != 0.0f)
      csum += lum3(conv + 3 * t), nk++;
  printf("%s: %u texels, base pass (64 rays, draft-like) %.2f s; converged door pass (2048 "
         "rays) %.2f s over %u influence texels, mean %.4g W/m²\n",
         level, lm->texel_count, t_base, t_conv, nk, nk ? csum / nk : 0.0);
  printf("%6s | %10s %12s | %10s %12s\n", "rays", "guided s", "guided err", "cosine s",
         "cosine err");
  /* both ladders to 512 rays, so cosine-only reaches the errors guiding reaches early;
   * seconds are the faster of two runs (the machine is shared) */
  enum { NR = 7 };
  static const uint32_t R[NR] = {8, 16, 32, 64, 128, 256, 512};
  double sec[2][NR], err[2][NR];
  for (int i = 0; i < NR; i++) {
    for (int g = 1; g >= 0; g--) {
      sec[g][i] = door_run(&dd, R[i], g, iz);
      double again = door_run(&dd, R[i], g, iz);
      sec[g][i] = again < sec[g][i] ? again : sec[g][i];
      double e = 0.0;
      for (uint32_t t = 0; t < lm->texel_count; t++)
        if (conv[3 * t] != 0.0f || conv[3 * t + 1] != 0.0f)
          e += fabs(lum3(iz + 3 * t) - lum3(conv + 3 * t));
      err[g][i] = nk ? e / nk / (csum / nk) : NAN; /* relative to the mean */
    }
    printf("%6u | %10.3f %12.4f | %10.3f %12.4f\n", R[i], sec[1][i], err[1][i], sec[0][i],
           err[0][i]);
  }
  /* Cosine seconds at each guided rung's error: log-log interpolation along the cosine
   * curve (the target: guided + MIS at <= 1/3 of cosine-only's seconds). */
  for (int k = 1; k < NR - 1; k++) {
    double target = err[1][k], cos_sec = NAN;
    for (int i = 0; i + 1 < NR; i++)
      if (err[0][i] >= target && err[0][i + 1] <= target) {
        double f = log(err[0][i] / target) / log(err[0][i] / err[0][i + 1]);
        cos_sec = exp(log(sec[0][i]) + f * (log(sec[0][i + 1]) - log(sec[0][i])));
      }
    if (isfinite(cos_sec))
      printf("equal error %.4f: guided %u rays %.3f s, cosine-only %.3f s (ratio %.2f)\n", target,
             R[k], sec[1][k], cos_sec, sec[1][k] / cos_sec);
    else
      printf("equal error %.4f: guided %u rays %.3f s; cosine-only does not reach it by %u rays "
             "(%.3f s, error %.4f)\n", target, R[k], sec[1][k], R[NR - 1], sec[0][NR - 1],
             err[0][NR - 1]);
  }
  printf("door pass (64 rays, guided) / base pass: %.2f\n", sec[1][3] / t_base);
  free(conv), free(iz), free(enabled), free(mask);
  ub_pass_result_free(&base);
  ub_lightmap_free(lm);
  ub_emitters_free(em);
  ub_rt_free(rt);
  ub_scene_free(s);
  return 0;
}
