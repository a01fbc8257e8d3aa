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
 * ignoring occlusion: an upper bound of what the light reaches. Over the texels in
 * parallel (an integer count: the same for any thread count; at ESTATE full scale 297
 * lights × 1.57 M texels took 7.2 s on one thread). */
static double light_reach_fraction(const ub_light *L, const ub_lightmap *lm)
{
  uint64_t n = 0;
  const int64_t T = lm->texel_count;
#pragma omp parallel for schedule(static, 16384) reduction(+ : n)
  for (int64_t t = 0; t < T; t++) {
    const float *p = lm->texel_pos + 3 * (size_t)t;
    const float *nn = lm->texel_normal + 3 * (size_t)t;
    float dir[3], dist, e[3];
    if (!ub_light_incident(L, p, dir, &dist, e))
      continue;
    if (dir[0] * nn[0] + dir[1] * nn[1] + dir[2] * nn[2] > 0.0f)
      n++;
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
 * from texel sample points, all threads. Used only to turn planned rays into seconds.
 * The same burst, continued as random walks for UB_PLAN_WALK segments, gives the level's
 * bounce ratio: W_k = mean product of the luminance albedos met along the first k
 * segments (an escaped ray ends its walk), each walk weighted by the direct light of the
 * base pass's punctual lights at its start texel (one light picked per walk, shadow ray;
 * uniform weights when the pass has none), ratio = W_k / W_(k-1) of the last segment —
 * the share of a bounce's light the next bounce brings back once the light has spread
 * (the dominant eigenvalue of the transport, which a plain mean albedo underestimates in
 * closed rooms), for the bounce count of ub_plan_bounces. */
#define UB_PLAN_WALK 4
static double measure_ray_rate(const ub_scene *s, const ub_rt *rt, const ub_lightmap *lm,
                               const uint8_t *light_on, double *out_ratio)
{
  uint32_t lit_lights[64], nll = 0;
  for (uint32_t l = 0; l < s->light_count && nll < 64; l++)
    if (light_on[l])
      lit_lights[nll++] = l;
  *out_ratio = 0.0;
  if (lm->texel_count == 0)
    return 1e6;
  enum { PER = 4096, CHUNKS = 16 };
  double w_sum[CHUNKS][UB_PLAN_WALK + 1];
  memset(w_sum, 0, sizeof w_sum);
  double t0 = now_s();
  uint64_t traced = 0;
#pragma omp parallel for schedule(dynamic, 1) reduction(+ : traced)
  for (uint32_t c = 0; c < CHUNKS; c++) {
    ub_ray *rays = malloc(PER * sizeof *rays);
    ub_hit *hits = malloc(PER * sizeof *hits);
    float *w = malloc(PER * sizeof *w);
    uint32_t *alive = malloc(PER * sizeof *alive);
    ub_ray *shadow = nll ? malloc(PER * sizeof *shadow) : NULL;
    uint8_t *occl = nll ? malloc(PER) : NULL;
    if (rays && hits && w && alive && (!nll || (shadow && occl))) {
      uint32_t n = PER;
      for (uint32_t i = 0; i < PER; i++) {
        uint32_t h = ub_hash4(0x51a7, c, i, 0);
        uint32_t t = h % lm->texel_count;
        memcpy(rays[i].org, lm->sample_pos + ((size_t)t * UB_TEXEL_SAMPLES) * 3,
               3 * sizeof(float));
        ub_sample_cosine(lm->texel_normal + 3 * (size_t)t, ub_u01(ub_hash4(h, 1, 0, 0)),
                         ub_u01(ub_hash4(h, 2, 0, 0)), rays[i].dir);
        rays[i].tnear = 0.0f;
        rays[i].tfar = INFINITY;
        w[i] = 1.0f;
        alive[i] = i;
        if (nll) {
          /* the walk's weight: direct light of one base light at the start (× nll) */
          const ub_light *L = &s->lights[lit_lights[ub_hash4(h, 3, 0, 0) % nll]];
          float dir[3], dist, e[3];
          const float *n = lm->texel_normal + 3 * (size_t)t;
          float cs = 0.0f;
          if (ub_light_incident(L, rays[i].org, dir, &dist, e))
            cs = n[0] * dir[0] + n[1] * dir[1] + n[2] * dir[2];
          w[i] = cs > 0.0f ? (float)nll * cs * (0.2126f * e[0] + 0.7152f * e[1] + 0.0722f * e[2])
                           : 0.0f;
          memcpy(shadow[i].org, rays[i].org, sizeof shadow[i].org);
          memcpy(shadow[i].dir, dir, sizeof shadow[i].dir);
          shadow[i].tnear = 0.0f;
          shadow[i].tfar = cs > 0.0f && isfinite(dist) ? dist * 0.999f : INFINITY;
        }
      }
      if (nll) {
        ub_rt_occluded(rt, shadow, PER, occl);
        traced += PER;
        for (uint32_t i = 0; i < PER; i++)
          if (occl[i] || !isfinite(w[i]))
            w[i] = 0.0f;
      }
      for (uint32_t i = 0; i < PER; i++)
        w_sum[c][0] += w[i];
      for (int k = 1; k <= UB_PLAN_WALK && n; k++) {
        ub_rt_intersect(rt, rays, n, hits);
        traced += n;
        uint32_t m = 0;
        for (uint32_t i = 0; i < n; i++) {
          const ub_hit *hh = &hits[i];
          if (hh->tri == UB_RT_MISS || hh->tri >= s->triangle_count || !(w[i] > 0.0f))
            continue;
          const float *a = s->materials[s->tri_material[hh->tri]].albedo;
          float wi = w[i] * (0.2126f * a[0] + 0.7152f * a[1] + 0.0722f * a[2]);
          if (!(wi > 0.0f))
            continue;
          w_sum[c][k] += wi;
          /* continue from the hit, on the side the ray came from */
          float ng[3], len = sqrtf(hh->ng[0] * hh->ng[0] + hh->ng[1] * hh->ng[1] +
                                   hh->ng[2] * hh->ng[2]);
          if (!(len > 0.0f))
            continue;
          float side = (hh->ng[0] * rays[i].dir[0] + hh->ng[1] * rays[i].dir[1] +
                        hh->ng[2] * rays[i].dir[2]) < 0.0f ? 1.0f : -1.0f;
          for (int j = 0; j < 3; j++)
            ng[j] = side * hh->ng[j] / len;
          float p[3];
          for (int j = 0; j < 3; j++)
            p[j] = rays[i].org[j] + rays[i].dir[j] * hh->t;
          ub_ray *r = &rays[m];
          ub_rt_offset_point(rt, p, ng, r->org);
          uint32_t hsh = ub_hash4(0x51a7, c, alive[i], (uint32_t)k);
          ub_sample_cosine(ng, ub_u01(ub_hash4(hsh, 1, 0, 0)), ub_u01(ub_hash4(hsh, 2, 0, 0)),
                           r->dir);
          r->tnear = 0.0f;
          r->tfar = INFINITY;
          w[m] = wi;
          alive[m] = alive[i];
          m++;
        }
        n = m;
      }
    }
    free(rays);
    free(hits);
    free(w);
    free(alive);
    free(shadow);
    free(occl);
  }
  double dt = now_s() - t0, W[UB_PLAN_WALK + 1] = {0};
  for (int c = 0; c < CHUNKS; c++)
    for (int k = 0; k <= UB_PLAN_WALK; k++)
      W[k] += w_sum[c][k];
  *out_ratio = W[UB_PLAN_WALK - 1] > 0.0 ? W[UB_PLAN_WALK] / W[UB_PLAN_WALK - 1] : 0.0;
  return dt > 0 ? (double)traced / dt : 1e6;
}

uint32_t ub_plan_bounces(double ratio, double stop_fraction, uint32_t cap)
{
  /* Bounce k ≥ 1 carries e1·r^(k−1); the pass stops after the first k with
   * e_k ≤ stop·(e_1 + … + e_k) (bake/pass.c, over the level). */
  if (!(ratio > 0.0))
    return 1;
  double ek = 1.0, sum = 0.0;
  for (uint32_t k = 1; k <= cap; k++) {
    sum += ek;
    if (ek <= stop_fraction * sum)
      return k;
    ek *= ratio;
  }
  return cap;
}

double ub_plan_gather_bounces(double ratio, uint32_t bounces, int full_rays)
{
  if (full_rays)
    return (double)bounces;
  double step = ratio > 0.0 && ratio < 1.0 ? 0.5 * log2(1.0 / ratio) : (ratio >= 1.0 ? 0.0 : 1.5);
  double sum = 0.0;
  for (uint32_t k = 1; k <= bounces; k++) {
    double s = k < 3 ? 0.0 : floor((double)(k - 2) * step);
    sum += ldexp(1.0, -(int)(s < UB_BOUNCE_RAY_SHIFT_MAX ? s : UB_BOUNCE_RAY_SHIFT_MAX));
  }
  return sum;
}

/* Rays/s of a set's influence and full passes as shares of the plan's measured rate (a
 * burst of bare rays): the influence pass does per-candidate work besides its rays
 * (donors, sparse fills, the threshold), the full pass shades every ray (bounce-1 NEE at
 * the hits, lightmap and LLG lookups). Measured, --bounces 2, draft, against the rate
 * ub_plan_build takes: ESTATE full scale 0.39 and 0.74, ESTATE scale 0.3 0.45 and 0.83.
 * The sets' seconds over the base pass's then come out 2.25x and 3.36x where the bakes
 * took 2.2-2.4x and 3.37x; at rays / rate they read 1.60x and 2.39x. */
#define UB_PLAN_INFLUENCE_RATE 0.42
#define UB_PLAN_FULL_RATE 0.8

/* The share of a set's reach-bound candidates its influence pass keeps (dls.c), for the
 * full pass's estimate: --bounces 2, draft, estate_small 0.61, ESTATE full scale 0.43. */
#define UB_PLAN_KEPT_SHARE 0.5

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
    size_t pos = 0, at, len;
    while (ub_combine_next(nd->combine, &pos, &at, &len)) {
      char name[64];
      snprintf(name, sizeof name, "%.*s", (int)(len < 63 ? len : 63), nd->combine + at);
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
  out->dls_est_seconds = calloc(scene->dls_count ? scene->dls_count : 1, sizeof(double));
  out->dls_candidates = calloc(scene->dls_count ? scene->dls_count : 1, sizeof(double));
  if (!out->base_light_enabled || !out->light_skip || !out->dls_light_reaches ||
      !out->light_reach || !set_reaches || !out->dls_est_rays || !out->dls_est_seconds ||
      !out->dls_candidates) {
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
    out->near_samples = 16;
    break;
  case UB_QUALITY_FAST:
    out->gather_rays = 256;
    out->emissive_samples = 32;
    out->shadow_samples = 4;
    /* 64 and 256 lamp footprint samples: at 16 they were the texel noise floor near
     * point lights (cornell texels vs converged 7.1% at 256 gather rays, 2.9% with 64;
     * README, Accuracy vs time) */
    out->near_samples = 64;
    break;
  case UB_QUALITY_HIGH:
    out->gather_rays = 1024;
    out->emissive_samples = 128;
    out->shadow_samples = 4;
    out->near_samples = 256;
    break;
  }
  if (opt->gather_rays)
    out->gather_rays = opt->gather_rays;
  /* A probe sees the whole sphere: twice the rays of a texel's hemisphere. */
  out->probe_rays = 2 * out->gather_rays;
  /* Influence passes only decide who is reached: an eighth of the rays, at least 8 (16
   * before 2026-11-27: draft's sets then took a quarter). */
  out->influence_rays = out->gather_rays / 8 < 8 ? 8 : out->gather_rays / 8;

  for (uint32_t l = 0; l < scene->light_count; l++) {
    const ub_light *L = &scene->lights[l];
    ub_light_skip skip = UB_SKIP_NONE;
    int dark = !(L->intensity[0] > 0.0f || L->intensity[1] > 0.0f || L->intensity[2] > 0.0f);
    double tl0 = now_s();
    out->light_reach[l] = dark ? 0.0f : (float)light_reach_fraction(L, lm);
    if (L->dls >= 0) /* a set's work, done here */
      out->dls_reach_seconds += now_s() - tl0;
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
  out->influence_sparse = out->influence_culling && !opt->influence_dense;
  out->dls_scaled_rays = out->influence_culling && !opt->dls_full_rays;
  out->doors = scene->door_count;
  for (uint32_t d = 0; d < scene->door_count; d++)
    out->door_passes += ub_geom_door_triangles(scene, d, 0) > 0;
  out->door_rays = opt->door_rays ? opt->door_rays : out->gather_rays;
  /* door influence passes keep at least 16 (their culling was measured with 16 at draft) */
  out->door_influence_rays =
      out->influence_culling ? (out->influence_rays < 16 ? 16 : out->influence_rays) : 0;
  out->door_photons = 8192;
  if (plan_combos(scene, set_reaches, out) != UB_OK) {
    free(set_reaches);
    ub_plan_free(out);
    return UB_ERR_OUT_OF_MEMORY;
  }
  out->pass_count = 1 + out->dls_passes + out->door_passes;

  /* Estimates: rays per pass, and seconds from this machine's measured ray rate. */
  double T = lm->texel_count, P = probe_count;
  /* The first burst runs cold (threads, pages, BVH out of cache) and read 10-25% below
   * the next ones in one process; of those after it the median (bursts in one process
   * differ by +-7%). A burst is ~0.3 M rays. This VM also swings between runs: full
   * ESTATE 5.5-6.9 M rays/s over 5 runs, scale 0.3 6.4-8.8; the seconds move with it, the
   * sets' seconds over the base pass's (printed) do not. */
  double rates[4], rr;
  rates[0] = measure_ray_rate(scene, rt, lm, out->base_light_enabled, &out->bounce_ratio);
  for (int i = 1; i < 4; i++)
    rates[i] = measure_ray_rate(scene, rt, lm, out->base_light_enabled, &rr);
  out->ray_rate = fmax(fmin(rates[1], rates[2]), fmin(fmax(rates[1], rates[2]), rates[3]));
  out->est_bounces = opt->bounces < 0 ? ub_plan_bounces(out->bounce_ratio, out->stop_fraction,
                                                         UB_BAKE_MAX_BOUNCES)
                                      : (uint32_t)opt->bounces;
  double b = ub_plan_gather_bounces(out->bounce_ratio, out->est_bounces, opt->bounce_full_rays);
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
  ub_dls_texel_cells cells;
  memset(&cells, 0, sizeof cells);
  double t_reach = now_s();
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
      ub_result rr = ub_dls_reach_build(scene, rt, en, lo, hi, opt->seed, d,
                                        ub_dls_influence_bounces(opt->bounces) + 1u, &rb);
      if (rr != UB_OK) {
        ub_dls_texel_cells_free(&cells);
        free(en);
        free(set_reaches);
        ub_plan_free(out);
        return rr;
      }
      if (!rb.unbounded && lm->texel_count) {
        if (!cells.idx) /* every set's bound is on this grid (failing: point by point) */
          ub_dls_texel_cells_build(&rb, lm, &cells);
        uint64_t n = ub_dls_reach_texels(&rb, &cells, lm, NULL);
        cand = (double)n / lm->texel_count;
      }
      photon_rays = (double)rb.rays;
      *rbp = rb; /* kept for the set's pass */
    }
    out->dls_candidates[d] = cand;
    double Tc = cand * T, Pc = cand * P;
    /* influence: direct + ub_dls_influence_bounces bounces on the candidates; full: the
     * reachable share. */
    /* sparse gathers (dls.c): under a third of the candidate texels and a fifth of the
     * candidate probes gather (estate_small draft: 29% and 19%) */
    double gt = out->influence_sparse ? 0.3 : 1.0, gp = out->influence_sparse ? 0.2 : 1.0;
    double inf = photon_rays + (Tc + Pc) * nlight +
                 (double)ub_dls_influence_bounces(opt->bounces) *
                     (gt * Tc * out->influence_rays + gp * Pc * 2 * out->influence_rays);
    double frac = out->influence_culling ? fmin(UB_PLAN_KEPT_SHARE * cand, 1.2 * reach) : 1.0;
    /* scaled rays (dls.c): the full passes' gathers at about half the rays (estate_small
     * and ESTATE full scale, draft: 47.9% and 46.9%), plus the texel lights' shadow rays
     * of the sets' passes (texel_lights_everywhere: +3% of the full passes' rays at ESTATE
     * full scale, 2 bounces; all sets est. 819 M rays, 811 M traced) */
    double gs = out->dls_scaled_rays ? 0.55 : 1.0;
    double full = frac * ((T * out->shadow_samples + P) * nlight +
                          gs * (T * out->gather_rays + P * out->probe_rays) * b);
    out->dls_est_rays[d] = (out->influence_culling ? inf : 0.0) + full;
    out->dls_est_seconds[d] =
        ((out->influence_culling ? (inf - photon_rays) / UB_PLAN_INFLUENCE_RATE : 0.0) +
         full / UB_PLAN_FULL_RATE) / out->ray_rate;
  }
  ub_dls_texel_cells_free(&cells);
  if (out->dls_reach)
    out->dls_reach_seconds += now_s() - t_reach;
  free(en);
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
                "shadow, %u near a lamp; bounces until < %.2f%% energy (estimated %u: a "
                "gather ray brings back %.2f of the light)",
                plan->gather_rays, plan->probe_rays, plan->emissive_samples,
                plan->shadow_samples, plan->near_samples, 100 * plan->stop_fraction,
                plan->est_bounces,
                plan->bounce_ratio);
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
                      plan->dls_est_seconds[d], 100.0 * plan->dls_candidates[d]);
      else
        ub_log_printf(log, UB_LOG_INFO, "  pass dls %s: est. %.1f M rays, %.1f s",
                      scene->dls_names[d], plan->dls_est_rays[d] * 1e-6,
                      plan->dls_est_seconds[d]);
    } else {
      ub_log_printf(log, UB_LOG_INFO, "  pass dls %s: skipped, its lights reach no receiver",
                    scene->dls_names[d]);
    }
  double sets = 0.0, sets_s = 0.0;
  for (uint32_t d = 0; d < scene->dls_count; d++)
    if (plan->dls_est_rays[d] > 0) {
      sets += plan->dls_est_rays[d];
      sets_s += plan->dls_est_seconds[d];
    }
  if (sets > 0 && plan->est_rays > 0)
    ub_log_printf(log, UB_LOG_INFO, "  all sets: est. %.1f M rays, %.1f s (%.2fx the base "
                  "pass's rays, %.2fx its seconds)", sets * 1e-6, sets_s, sets / plan->est_rays,
                  sets_s * plan->ray_rate / plan->est_rays);
  else if (sets > 0)
    ub_log_printf(log, UB_LOG_INFO, "  all sets: est. %.1f M rays, %.1f s (the base pass "
                  "traces nothing)", sets * 1e-6, sets_s);
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
  free(plan->dls_est_seconds);
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
  plan->dls_est_seconds = NULL;
}
