/* Bake plan: which effects this level calls for (see plan.h). */
#include "bake/plan.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

const char *ub_light_skip_reason(ub_light_skip s)
{
  switch (s) {
  case UB_SKIP_NONE: return "baked";
  case UB_SKIP_DARK: return "zero intensity";
  case UB_SKIP_OUT_OF_RANGE: return "reaches no receiver (range/cone)";
  case UB_SKIP_IN_DLS: return "baked in its dynamic light set's pass";
  }
  return "?";
}

/* Does any receiver lie where the light can shine (range sphere, spot cone, front side)? */
static int light_reaches(const ub_light *L, const ub_lightmap *lm)
{
  for (uint32_t t = 0; t < lm->texel_count; t++) {
    const float *p = lm->texel_pos + 3 * (size_t)t;
    const float *n = lm->texel_normal + 3 * (size_t)t;
    float dir[3], dist, e[3];
    if (!ub_light_incident(L, p, dir, &dist, e))
      continue;
    if (dir[0] * n[0] + dir[1] * n[1] + dir[2] * n[2] > 0.0f)
      return 1;
  }
  return 0;
}

ub_result ub_plan_build(const ub_scene *scene, const ub_rt *rt, const ub_emitters *em,
                        const ub_lightmap *lm, const ub_bake_options *opt, const ub_log *log,
                        ub_plan *out)
{
  (void)rt;
  memset(out, 0, sizeof *out);
  size_t nl = scene->light_count ? scene->light_count : 1;
  out->base_light_enabled = calloc(nl, 1);
  out->light_skip = calloc(nl, 1);
  out->dls_light_reaches = calloc(nl, 1);
  uint8_t *set_reaches = calloc(scene->dls_count ? scene->dls_count : 1, 1);
  if (!out->base_light_enabled || !out->light_skip || !out->dls_light_reaches || !set_reaches) {
    free(set_reaches);
    ub_plan_free(out);
    return UB_ERR_OUT_OF_MEMORY;
  }
  for (uint32_t l = 0; l < scene->light_count; l++) {
    const ub_light *L = &scene->lights[l];
    ub_light_skip skip = UB_SKIP_NONE;
    if (!(L->intensity[0] > 0.0f || L->intensity[1] > 0.0f || L->intensity[2] > 0.0f))
      skip = UB_SKIP_DARK;
    else if (!light_reaches(L, lm))
      skip = UB_SKIP_OUT_OF_RANGE;
    else if (L->dls >= 0)
      skip = UB_SKIP_IN_DLS;
    if (L->dls >= 0) {
      out->dls_lights++;
      if (skip == UB_SKIP_IN_DLS) {
        out->dls_light_reaches[l] = 1;
        set_reaches[L->dls] = 1;
      }
    }
    out->light_skip[l] = (uint8_t)skip;
    if (skip == UB_SKIP_NONE) {
      out->base_light_enabled[l] = 1;
      out->base_lights++;
      if (L->cls == UB_LIGHT_PRIMARY)
        out->primary_lights++;
      else
        out->static_lights++;
    } else if (skip != UB_SKIP_IN_DLS) {
      ub_log_printf(log, UB_LOG_INFO, "  plan: light %u (node %d) skipped: %s", l, L->node,
                    ub_light_skip_reason(skip));
    }
  }
  for (uint32_t d = 0; d < scene->dls_count; d++)
    out->dls_passes += set_reaches[d];
  free(set_reaches);
  out->sky = scene->has_sky && (scene->sky[0] > 0 || scene->sky[1] > 0 || scene->sky[2] > 0);
  out->emissive = em && em->count > 0;
  switch (opt->quality) {
  case UB_QUALITY_DRAFT:
    out->gather_rays = 64;
    out->emissive_samples = 8;
    out->shadow_samples = 1;
    break;
  case UB_QUALITY_FAST:
    out->gather_rays = 256;
    out->emissive_samples = 32;
    out->shadow_samples = 4;
    break;
  case UB_QUALITY_HIGH:
    out->gather_rays = 1024;
    out->emissive_samples = 128;
    out->shadow_samples = 4;
    break;
  }
  if (opt->gather_rays)
    out->gather_rays = opt->gather_rays;
  /* A probe sees the whole sphere: twice the rays of a texel's hemisphere. */
  out->probe_rays = 2 * out->gather_rays;
  /* Influence passes only decide who is reached: an eighth of the rays, at least 16. */
  out->influence_rays = out->gather_rays / 8 < 16 ? 16 : out->gather_rays / 8;
  if (!out->emissive || getenv("UB_DEBUG_NOEM"))
    out->emissive_samples = 0;
  out->pass_count = 1 + out->dls_passes;
  double T = lm->texel_count;
  double direct = T * ((double)out->base_lights * out->shadow_samples + out->emissive_samples +
                       ((out->sky || out->emissive) ? out->gather_rays : 0));
  int b = opt->bounces < 0 ? 3 : opt->bounces;
  out->est_rays = direct + T * out->gather_rays * b;
  return UB_OK;
}

void ub_plan_free(ub_plan *plan)
{
  if (!plan)
    return;
  free(plan->base_light_enabled);
  free(plan->light_skip);
  free(plan->dls_light_reaches);
  plan->base_light_enabled = NULL;
  plan->light_skip = NULL;
  plan->dls_light_reaches = NULL;
}
