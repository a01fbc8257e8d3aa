/* Bake plan: which effects this level calls for (see plan.h). */
#include "bake/plan.h"

#include "bake/dls.h"
#include "bake/geomstate.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

const char *ub_light_skip_reason(ub_light_skip s)
{
  switch (s) {
  case UB_SKIP_NONE: return "baked";
  case UB_SKIP_DARK: return "zero intensity";
  case UB_SKIP_OUT_OF_RANGE: return "reaches no receiver (range, cone or facing)";
  case UB_SKIP_IN_DLS: return "baked in its dynamic light set's pass";
  }
  return "?";
}

/* Fraction of receivers where the light can shine (range sphere, spot cone, front side),
 * ignoring occlusion: an upper bound of what the light reaches. */
static double light_reach_fraction(const ub_light *L, const ub_lightmap *lm, int any)
{
  uint64_t n = 0;
  for (uint32_t t = 0; t < lm->texel_count; t++) {
    const float *p = lm->texel_pos + 3 * (size_t)t;
    const float *nn = lm->texel_normal + 3 * (size_t)t;
    float dir[3], dist, e[3];
    if (!ub_light_incident(L, p, dir, &dist, e))
      continue;
    if (dir[0] * nn[0] + dir[1] * nn[1] + dir[2] * nn[2] > 0.0f) {
      n++;
      if (any)
        break;
    }
  }
  return lm->texel_count ? (double)n / lm->texel_count : 0.0;
}

static double now_s(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Rays per second of this level's scene on this machine: a short burst of cosine rays
 * from texel sample points, all threads. Used only to turn planned rays into seconds. */
static double measure_ray_rate(const ub_rt *rt, const ub_lightmap *lm)
{
  if (lm->texel_count == 0)
    return 1e6;
  const uint32_t per = 4096, chunks = 16;
  double t0 = now_s();
#pragma omp parallel for schedule(dynamic, 1)
  for (uint32_t c = 0; c < chunks; c++) {
    ub_ray *rays = malloc(per * sizeof *rays);
    ub_hit *hits = malloc(per * sizeof *hits);
    if (rays && hits) {
      for (uint32_t i = 0; i < per; i++) {
        uint32_t h = ub_hash4(0x51a7, c, i, 0);
        uint32_t t = h % lm->texel_count;
        memcpy(rays[i].org, lm->sample_pos + ((size_t)t * UB_TEXEL_SAMPLES) * 3,
               3 * sizeof(float));
        ub_sample_cosine(lm->texel_normal + 3 * (size_t)t, ub_u01(ub_hash4(h, 1, 0, 0)),
                         ub_u01(ub_hash4(h, 2, 0, 0)), rays[i].dir);
        rays[i].tnear = 0.0f;
        rays[i].tfar = INFINITY;
      }
      ub_rt_intersect(rt, rays, per, hits);
    }
    free(rays);
    free(hits);
  }
  double dt = now_s() - t0;
  return dt > 0 ? (double)per * chunks / dt : 1e6;
}

/* Combinations the level tags: `ubake_combine: "A,B"` on a door's closed leaf names sets
 * (or doors) combined with it. A name that is a set becomes a candidate (the door pass
 * stage bakes it when the influence regions overlap); any other name is listed as
 * skipped with the reason. */
static ub_result plan_combos(const ub_scene *s, const uint8_t *set_reaches, ub_plan *out)
{
  for (uint32_t n = 0; n < s->node_count; n++) {
    const ub_node *nd = &s->nodes[n];
    if (nd->door < 0 || !nd->combine)
      continue;
    const char *p = nd->combine;
    while (*p) {
      while (*p == ',' || *p == ' ')
        p++;
      size_t len = strcspn(p, ",");
      while (len && p[len - 1] == ' ')
        len--;
      if (!len)
        break;
      char name[64];
      snprintf(name, sizeof name, "%.*s", (int)(len < 63 ? len : 63), p);
      p += len;
      while (*p && *p != ',')
        p++;
      int dup = 0;
      for (uint32_t k = 0; k < out->combo_count; k++)
        dup |= out->combos[k].door == (uint32_t)nd->door && !strcmp(out->combos[k].name, name);
      if (dup)
        continue;
      ub_plan_combo *c = realloc(out->combos, (out->combo_count + 1) * sizeof *c);
      if (!c)
        return UB_ERR_OUT_OF_MEMORY;
      out->combos = c;
      c += out->combo_count++;
      memset(c, 0, sizeof *c);
      c->door = (uint32_t)nd->door;
      c->set = c->other = -1;
      snprintf(c->name, sizeof c->name, "%s", name);
      for (uint32_t d = 0; d < s->dls_count; d++)
        if (!strcmp(s->dls_names[d], name))
          c->set = (int32_t)d;
      for (uint32_t d = 0; c->set < 0 && d < s->door_count; d++)
        if (!strcmp(s->door_names[d], name))
          c->other = (int32_t)d;
      int listed = 0; /* the same pair tagged on the other door */
      for (uint32_t k = 0; c->other >= 0 && k + 1 < out->combo_count; k++)
        listed |= out->combos[k].door == (uint32_t)c->other &&
                  out->combos[k].other == nd->door;
      if (c->set >= 0 && !set_reaches[c->set])
        snprintf(c->why, sizeof c->why, "skipped: set %s reaches no receiver", name);
      else if (c->set >= 0)
        snprintf(c->why, sizeof c->why, "tagged: baked if the influence regions overlap");
      else if (c->other == nd->door)
        c->other = -1, snprintf(c->why, sizeof c->why, "skipped: a door with itself");
      else if (listed)
        c->other = -1, snprintf(c->why, sizeof c->why, "skipped: already listed as door %s "
                                "x %s", name, s->door_names[nd->door]);
      else if (c->other >= 0)
        snprintf(c->why, sizeof c->why, "tagged: baked if the influence regions overlap");
      else
        snprintf(c->why, sizeof c->why, "skipped: %s is not a dynamic light set or a door",
                 name);
    }
  }
  return UB_OK;
}

ub_result ub_plan_build(const ub_scene *scene, const ub_rt *rt, const ub_emitters *em,
                        const ub_lightmap *lm, uint32_t probe_count,
                        const ub_bake_options *opt, const ub_log *log, ub_plan *out)
{
  (void)log; /* the plan is printed by ub_plan_print */
  memset(out, 0, sizeof *out);
  int all = opt->plan_all;
  out->forced = all;
  size_t nl = scene->light_count ? scene->light_count : 1;
  out->base_light_enabled = calloc(nl, 1);
  out->light_skip = calloc(nl, 1);
  out->dls_light_reaches = calloc(nl, 1);
  out->light_reach = calloc(nl, sizeof *out->light_reach);
  uint8_t *set_reaches = calloc(scene->dls_count ? scene->dls_count : 1, 1);
  out->dls_est_rays = calloc(scene->dls_count ? scene->dls_count : 1, sizeof(double));
  out->dls_candidates = calloc(scene->dls_count ? scene->dls_count : 1, sizeof(double));
  if (!out->base_light_enabled || !out->light_skip || !out->dls_light_reaches ||
      !out->light_reach || !set_reaches || !out->dls_est_rays || !out->dls_candidates) {
    free(set_reaches);
    ub_plan_free(out);
    return UB_ERR_OUT_OF_MEMORY;
  }
  switch (opt->quality) {
  case UB_QUALITY_DRAFT:
    /* 4 shadow and 32 emissive samples like fast: with 1 and 8 draft cost at most 9% less
     * but had 3× the texel noise on sunroom, 1.3× on oa_dm4 (README, Accuracy vs time). */
    out->gather_rays = 64;
    out->emissive_samples = 32;
    out->shadow_samples = 4;
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

  for (uint32_t l = 0; l < scene->light_count; l++) {
    const ub_light *L = &scene->lights[l];
    ub_light_skip skip = UB_SKIP_NONE;
    int dark = !(L->intensity[0] > 0.0f || L->intensity[1] > 0.0f || L->intensity[2] > 0.0f);
    out->light_reach[l] = dark ? 0.0f : (float)light_reach_fraction(L, lm, 0);
    if (!all && dark)
      skip = UB_SKIP_DARK;
    else if (!all && out->light_reach[l] <= 0.0f)
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
      out->skipped_lights++;
    }
  }
  for (uint32_t d = 0; d < scene->dls_count; d++)
    out->dls_passes += set_reaches[d];
  out->sky = all || (scene->has_sky && (scene->sky[0] > 0 || scene->sky[1] > 0 || scene->sky[2] > 0));
  out->emissive = em && em->count > 0;
  if (!out->emissive)
    out->emissive_samples = 0;
  out->stop_fraction = all ? 0.0005 : 0.005;
  out->influence_culling = !all;
  out->doors = scene->door_count;
  for (uint32_t d = 0; d < scene->door_count; d++)
    out->door_passes += ub_geom_door_triangles(scene, d, 0) > 0;
  out->door_rays = opt->door_rays ? opt->door_rays : out->gather_rays;
  out->door_influence_rays = out->influence_culling ? out->influence_rays : 0;
  out->door_photons = 8192;
  if (plan_combos(scene, set_reaches, out) != UB_OK) {
    free(set_reaches);
    ub_plan_free(out);
    return UB_ERR_OUT_OF_MEMORY;
  }
  out->pass_count = 1 + out->dls_passes + out->door_passes;

  /* Estimates: rays per pass, and seconds from this machine's measured ray rate. */
  double T = lm->texel_count, P = probe_count;
  int b = opt->bounces < 0 ? 4 : opt->bounces;
  double direct = T * ((double)out->base_lights * out->shadow_samples + out->emissive_samples +
                       ((out->sky || out->emissive) ? out->gather_rays : 0)) +
                  P * ((double)out->base_lights + out->emissive_samples +
                       ((out->sky || out->emissive) ? out->probe_rays : 0));
  /* A base pass with nothing emitting traces nothing (no bounce has a source). */
  int base_emits = out->base_lights || out->sky || out->emissive;
  out->est_rays = base_emits ? direct + (T * out->gather_rays + P * out->probe_rays) * b : 0.0;
  /* Sets: the reach bound of each (the photons dls.c traces before its influence pass,
   * over a grid spanning the texels and the sets' lights: probes lie among them) gives
   * the receivers its influence pass sees; the full pass sees at most those, and at most
   * the share its lights can shine on (range, cone, facing). */
  uint8_t *en = calloc(nl, 1);
  if (out->influence_culling && scene->dls_count) {
    out->dls_reach = calloc(scene->dls_count, sizeof *out->dls_reach);
    out->dls_reach_count = out->dls_reach ? scene->dls_count : 0;
    for (uint32_t d = 0; d < out->dls_reach_count; d++)
      out->dls_reach[d].unbounded = 1; /* sets skipped: no bound */
  }
  if (out->influence_culling && scene->dls_count && !out->dls_reach) {
    free(en);
    en = NULL;
  }
  float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  if (!en) {
    free(set_reaches);
    ub_plan_free(out);
    return UB_ERR_OUT_OF_MEMORY;
  }
  for (uint32_t t = 0; t < lm->texel_count; t++)
    ub_dls_bounds_add(lm->texel_pos + 3 * (size_t)t, lo, hi);
  for (uint32_t l = 0; l < scene->light_count; l++)
    if (scene->lights[l].dls >= 0 && scene->lights[l].type != UB_LIGHT_DIRECTIONAL)
      ub_dls_bounds_add(scene->lights[l].position, lo, hi);
  for (uint32_t d = 0; d < scene->dls_count; d++) {
    if (!set_reaches[d])
      continue;
    double reach = 0.0;
    uint32_t nlight = 0;
    for (uint32_t l = 0; l < scene->light_count; l++) {
      en[l] = scene->lights[l].dls == (int32_t)d && out->dls_light_reaches[l];
      if (en[l]) {
        reach = fmax(reach, out->light_reach[l]);
        nlight++;
      }
    }
    double cand = 1.0, photon_rays = 0.0;
    if (out->influence_culling && out->dls_reach) {
      ub_dls_reach *rbp = &out->dls_reach[d], rb;
      ub_result rr = ub_dls_reach_build(scene, rt, en, lo, hi, opt->seed, d, &rb);
      if (rr != UB_OK) {
        free(en);
        free(set_reaches);
        ub_plan_free(out);
        return rr;
      }
      if (!rb.unbounded && lm->texel_count) {
        uint64_t n = 0;
        for (uint32_t t = 0; t < lm->texel_count; t++)
          n += ub_dls_reach_texel(&rb, lm->texel_pos + 3 * (size_t)t,
                                  lm->texel_normal + 3 * (size_t)t);
        cand = (double)n / lm->texel_count;
      }
      photon_rays = (double)rb.rays;
      *rbp = rb; /* kept for the set's pass */
    }
    out->dls_candidates[d] = cand;
    double Tc = cand * T, Pc = cand * P;
    /* influence: direct + 2 bounces on the candidates; full: the reachable share. */
    double inf = photon_rays + (Tc + Pc) * nlight +
                 2.0 * (Tc * out->influence_rays + Pc * 2 * out->influence_rays);
    double frac = out->influence_culling ? fmin(cand, 1.2 * reach) : 1.0;
    double full = frac * ((T * out->shadow_samples + P) * nlight +
                          (T * out->gather_rays + P * out->probe_rays) * b);
    out->dls_est_rays[d] = (out->influence_culling ? inf : 0.0) + full;
  }
  free(en);
  out->ray_rate = measure_ray_rate(rt, lm);
  free(set_reaches);
  return UB_OK;
}

void ub_plan_print(const ub_plan *plan, const ub_scene *scene, const ub_log *log)
{
  ub_log_printf(log, UB_LOG_INFO, "plan%s: sky %s, emissive triangles %s, %u static + %u "
                "primary lights in the base pass, %u skipped, %u dynamic light set pass(es)",
                plan->forced ? " (--plan all: every effect forced on)" : "",
                plan->sky ? "yes" : "no (no sky rays)",
                plan->emissive ? "yes" : "no (no emissive sampling)", plan->static_lights,
                plan->primary_lights, plan->skipped_lights, plan->dls_passes);
  ub_log_printf(log, UB_LOG_INFO, "  samples: %u gather rays/texel, %u/probe, %u emissive, %u "
                "shadow; bounces until < %.2f%% energy",
                plan->gather_rays, plan->probe_rays, plan->emissive_samples,
                plan->shadow_samples, 100 * plan->stop_fraction);
  if (plan->door_passes == 0)
    ub_log_printf(log, UB_LOG_INFO, "  doors: %u, no door pass", plan->doors);
  for (uint32_t d = 0; d < scene->door_count; d++)
    if (ub_geom_door_triangles(scene, d, 0))
      ub_log_printf(log, UB_LOG_INFO, "  pass door %s: %u guided rays/texel, %u photons, "
                    "influence %s", scene->door_names[d], plan->door_rays, plan->door_photons,
                    plan->door_influence_rays ? "culled" : "all receivers");
    else
      ub_log_printf(log, UB_LOG_INFO, "  pass door %s: skipped, no closed leaf",
                    scene->door_names[d]);
  for (uint32_t k = 0; k < plan->combo_count; k++)
    ub_log_printf(log, UB_LOG_INFO, "  combination door %s x %s: %s",
                  scene->door_names[plan->combos[k].door], plan->combos[k].name,
                  plan->combos[k].why);
  ub_log_printf(log, UB_LOG_INFO, "  pass base: est. %.1f M rays, %.1f s at %.2f M rays/s",
                plan->est_rays * 1e-6, plan->est_rays / plan->ray_rate, plan->ray_rate * 1e-6);
  for (uint32_t d = 0; d < scene->dls_count; d++)
    if (plan->dls_est_rays[d] > 0) {
      if (plan->influence_culling)
        ub_log_printf(log, UB_LOG_INFO, "  pass dls %s: est. %.1f M rays, %.1f s "
                      "(influence-culled; reach bound %.1f%% of texels)",
                      scene->dls_names[d], plan->dls_est_rays[d] * 1e-6,
                      plan->dls_est_rays[d] / plan->ray_rate, 100.0 * plan->dls_candidates[d]);
      else
        ub_log_printf(log, UB_LOG_INFO, "  pass dls %s: est. %.1f M rays, %.1f s",
                      scene->dls_names[d], plan->dls_est_rays[d] * 1e-6,
                      plan->dls_est_rays[d] / plan->ray_rate);
    } else {
      ub_log_printf(log, UB_LOG_INFO, "  pass dls %s: skipped, its lights reach no receiver",
                    scene->dls_names[d]);
    }
  for (uint32_t l = 0; l < scene->light_count; l++)
    if (plan->light_skip[l] != UB_SKIP_NONE && plan->light_skip[l] != UB_SKIP_IN_DLS)
      ub_log_printf(log, UB_LOG_INFO, "  light %u (%s): skipped: %s", l,
                    scene->nodes[scene->lights[l].node].name,
                    ub_light_skip_reason((ub_light_skip)plan->light_skip[l]));
}

void ub_plan_free(ub_plan *plan)
{
  if (!plan)
    return;
  free(plan->base_light_enabled);
  free(plan->light_skip);
  free(plan->dls_light_reaches);
  free(plan->light_reach);
  free(plan->dls_est_rays);
  free(plan->combos);
  plan->combos = NULL;
  plan->combo_count = 0;
  free(plan->dls_candidates);
  plan->dls_candidates = NULL;
  for (uint32_t d = 0; plan->dls_reach && d < plan->dls_reach_count; d++)
    ub_dls_reach_free(&plan->dls_reach[d]);
  free(plan->dls_reach);
  plan->dls_reach = NULL;
  plan->dls_reach_count = 0;
  plan->base_light_enabled = NULL;
  plan->light_skip = NULL;
  plan->dls_light_reaches = NULL;
  plan->light_reach = NULL;
  plan->dls_est_rays = NULL;
}
