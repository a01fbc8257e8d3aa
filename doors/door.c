/* The door pass (see door.h): portal sampling, clustered shadow photons, guided gather
 * with MIS, per-box light lists, influence culling, sparse records. */
#include "doors/door.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bake/dls.h"
#include "bake/geomstate.h"
#include "doors/object.h"
#include "probes/llg.h"
#include "ubake/sh.h"

#define PROBE_ID_BASE 0x40000000u
#define LLG_ID_BASE 0x80000000u
#define KMEANS_ITERS 10
#define UB_DOOR_MAX_BOUNCES 16 /* receiver-side bounces when the pass's count is automatic */

static const double Y0 = 0.282094792;
static const double Y1 = 0.488602512;

static double now_s(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static inline float dot3(const float a[3], const float b[3])
{
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static inline double lum(const double v[3])
{
  return 0.2126 * v[0] + 0.7152 * v[1] + 0.0722 * v[2];
}

typedef struct door_ctx {
  const ub_scene *s;
  const ub_lightmap *lm;
  const ub_rt *rt_open, *rt_leaf;
  const ub_rt *rt_base;      /* the base geometry (closed leaf present): S_C's primary NEE */
  float **img;               /* per atlas: w×h×4, base stored irradiance + coverage */
  ub_obb portal;
  ub_guide guide;
  ub_guide cosine;           /* cosine/sphere only: further bounces */
  uint32_t nbox;
  ub_obb box[UB_DOOR_MAX_BOXES]; /* photon boxes inflated by UB_DOOR_BOX_MARGIN */
  uint8_t *box_lights;       /* nbox × light_count */
  uint8_t *portal_lights;    /* light_count: base lights whose light reaches the portal */
  const uint8_t *enabled;    /* light_count: base lights */
  int sky, emissive;         /* this pass's sky and emissive triangles emit */
  const float *sky_rgb;
  uint32_t seed, pass_id;
} door_ctx;

static inline float rnd(const door_ctx *c, uint32_t rid, uint32_t s, uint32_t dim)
{
  return ub_u01(ub_hash4(c->seed, c->pass_id * 64u + dim, rid, s));
}

static void trace(const ub_rt *rt, const float o[3], const float w[3], float tfar, ub_hit *h)
{
  ub_ray r = {{o[0], o[1], o[2]}, 0.0f, {w[0], w[1], w[2]}, tfar};
  ub_rt_intersect(rt, &r, 1, h);
}

static int occluded(const ub_rt *rt, const float o[3], const float w[3], float tfar)
{
  ub_ray r = {{o[0], o[1], o[2]}, 0.0f, {w[0], w[1], w[2]}, tfar};
  uint8_t occ = 0;
  ub_rt_occluded(rt, &r, 1, &occ);
  return occ;
}

/* Unit geometric normal of a hit, facing the side the ray came from; *front = 1 when that
 * is the triangle's front side. */
static void hit_normal(const ub_hit *h, const float w[3], float out_n[3], int *front)
{
  float l = sqrtf(dot3(h->ng, h->ng));
  for (int i = 0; i < 3; i++)
    out_n[i] = l > 0.0f ? h->ng[i] / l : 0.0f;
  *front = dot3(out_n, w) < 0.0f;
  if (!*front)
    for (int i = 0; i < 3; i++)
      out_n[i] = -out_n[i];
}

/* Irradiance (W/m²) stored in per-atlas images (w×h×4, rgb + coverage weight) at
 * barycentrics (u, v) of a lightmapped triangle, bilinear over covered texels. */
static void image_lookup(const ub_lightmap *lm, float *const *imgs, uint32_t tri, float bu,
                         float bv, float out[3])
{
  out[0] = out[1] = out[2] = 0.0f;
  int32_t a = lm->tri_atlas[tri];
  if (a < 0)
    return;
  const float *uv = lm->tri_uv + 6 * (size_t)tri;
  float u = (1.0f - bu - bv) * uv[0] + bu * uv[2] + bv * uv[4];
  float v = (1.0f - bu - bv) * uv[1] + bu * uv[3] + bv * uv[5];
  ub_lightmap_image_sample(lm, imgs[a], (uint32_t)a, u, v, out);
}

/* Direct light of one punctual light at p (offset), cosine about n applied (n NULL: none),
 * counted only when its shadow ray crosses the closed leaf and the open geometry is clear.
 * need_cross = 0: any unoccluded light counts (direct light beyond the door). */
static int light_through(const door_ctx *c, const ub_light *L, const float p[3],
                         const float *n, int need_cross, float out_e[3], float out_dir[3])
{
  float dist, e[3];
  if (!ub_light_incident(L, p, out_dir, &dist, e))
    return 0;
  float cs = n ? dot3(n, out_dir) : 1.0f;
  if (!(cs > 0.0f))
    return 0;
  float tfar = isfinite(dist) ? dist * (1.0f - 1e-4f) : INFINITY;
  if (need_cross && !occluded(c->rt_leaf, p, out_dir, tfar))
    return 0;
  if (occluded(c->rt_open, p, out_dir, tfar))
    return 0;
  for (int k = 0; k < 3; k++)
    out_e[k] = e[k] * cs;
  return 1;
}

/* Whether beyond_radiance already takes light l's direct light at a hit (stored: the hit
 * has a lightmap): primary lights everywhere, every portal light where nothing is stored.
 * The door's light at such a hit must then leave it out. */
static int beyond_counts(const door_ctx *c, uint32_t l, int stored)
{
  return c->portal_lights[l] && (!stored || c->s->lights[l].cls == UB_LIGHT_PRIMARY);
}

/* Outgoing radiance toward the ray at an open-geometry hit beyond the door (or the sky on a
 * miss): the base's stored lighting + primary direct light + emission. A surface without a
 * lightmap (the open leaf itself, a prop) has no stored lighting: it takes the direct light
 * of every light that reaches the portal instead (door_combo's open leaf, lit through the
 * doorway by room A's lamp, was black to room A). */
static void beyond_radiance(const door_ctx *c, const float x[3], const float w[3],
                            const ub_hit *h, float out[3])
{
  out[0] = out[1] = out[2] = 0.0f;
  if (h->tri == UB_RT_MISS) {
    if (c->sky)
      memcpy(out, c->sky_rgb, 3 * sizeof(float));
    return;
  }
  const ub_scene *s = c->s;
  const ub_material *m = &s->materials[s->tri_material[h->tri]];
  float n[3];
  int front;
  hit_normal(h, w, n, &front);
  if (front && c->emissive)
    for (int k = 0; k < 3; k++)
      out[k] = m->emission[k];
  if (m->albedo[0] + m->albedo[1] + m->albedo[2] <= 0.0f)
    return;
  float E[3] = {0, 0, 0};
  if (front)
    image_lookup(c->lm, c->img, h->tri, h->u, h->v, E);
  int stored = c->lm->tri_atlas[h->tri] >= 0;
  float p[3] = {x[0] + w[0] * h->t, x[1] + w[1] * h->t, x[2] + w[2] * h->t}, po[3];
  ub_rt_offset_point(c->rt_open, p, n, po);
  for (uint32_t l = 0; l < s->light_count; l++) {
    if (!beyond_counts(c, l, stored))
      continue;
    float e[3], dir[3];
    if (light_through(c, &s->lights[l], po, n, 0, e, dir))
      for (int k = 0; k < 3; k++)
        E[k] += e[k];
  }
  for (int k = 0; k < 3; k++)
    out[k] += m->albedo[k] / (float)M_PI * E[k];
}

/* Outgoing radiance toward the ray at a hit hl on the closed leaf, as the base stored it
 * (S_C, bake/geomstate.h): emission + albedo/π × (the leaf's stored irradiance + primary
 * lights' direct light, which the base's gather adds at its hits and never stores). */
static void leaf_radiance(const door_ctx *c, const float x[3], const float w[3],
                          const ub_hit *hl, float out[3])
{
  out[0] = out[1] = out[2] = 0.0f;
  const ub_scene *s = c->s;
  float n[3];
  int front;
  hit_normal(hl, w, n, &front);
  if (!front)
    return;
  const ub_material *m = &s->materials[s->tri_material[hl->tri]];
  if (c->emissive)
    for (int k = 0; k < 3; k++)
      out[k] = m->emission[k];
  if (m->albedo[0] + m->albedo[1] + m->albedo[2] <= 0.0f || c->lm->tri_atlas[hl->tri] < 0)
    return;
  float E[3];
  image_lookup(c->lm, c->img, hl->tri, hl->u, hl->v, E);
  float p[3] = {x[0] + w[0] * hl->t, x[1] + w[1] * hl->t, x[2] + w[2] * hl->t}, po[3];
  ub_rt_offset_point(c->rt_base, p, n, po);
  for (uint32_t l = 0; l < s->light_count; l++) {
    const ub_light *L = &s->lights[l];
    if (!c->enabled[l] || L->cls != UB_LIGHT_PRIMARY)
      continue;
    float dir[3], dist, e[3];
    if (!ub_light_incident(L, po, dir, &dist, e))
      continue;
    float cs = dot3(n, dir);
    if (!(cs > 0.0f) || occluded(c->rt_base, po, dir, isfinite(dist) ? dist * (1.0f - 1e-4f)
                                                                      : INFINITY))
      continue;
    for (int k = 0; k < 3; k++)
      E[k] += e[k] * cs;
  }
  for (int k = 0; k < 3; k++)
    out[k] += m->albedo[k] / (float)M_PI * E[k];
}

/* A ray from x along w whose first open-geometry hit is h: does it cross the door (the
 * closed leaf lies before h)? If so, out = what it sees when the door opens minus what
 * it saw with the leaf closed: beyond_radiance − leaf_radiance. */
static int crossing_delta(const door_ctx *c, const float x[3], const float w[3],
                          const ub_hit *h, float out[3])
{
  ub_hit hl;
  trace(c->rt_leaf, x, w, h->tri == UB_RT_MISS ? INFINITY : h->t, &hl);
  if (hl.tri == UB_RT_MISS)
    return 0;
  float Lb[3], Ll[3];
  beyond_radiance(c, x, w, h, Lb);
  leaf_radiance(c, x, w, &hl, Ll);
  for (int k = 0; k < 3; k++)
    out[k] = Lb[k] - Ll[k];
  return 1;
}

/* E_P(D): irradiance at surface point p (normal n, facing the arriving ray) from light that
 * crosses the door: punctual lights of the box p is in (else of the portal list) and one
 * portal sample of what lies beyond. beyond ≥ 0: p is a crossing ray's hit beyond the door
 * (1: with a lightmap), whose direct light beyond_radiance took: those lights are left
 * out here; -1: all count. */
static void door_irradiance(const door_ctx *c, const float p[3], const float n[3],
                            uint32_t rid, uint32_t smp, int beyond, float out[3])
{
  const ub_scene *s = c->s;
  float po[3];
  ub_rt_offset_point(c->rt_open, p, n, po);
  double E[3] = {0, 0, 0};
  const uint8_t *list = c->portal_lights;
  uint8_t any_box = 0;
  for (uint32_t j = 0; j < c->nbox; j++)
    if (ub_obb_contains(&c->box[j], p)) {
      any_box = 1;
      break;
    }
  for (uint32_t l = 0; l < s->light_count; l++) {
    int on = list[l];
    if (any_box) {
      on = 0;
      for (uint32_t j = 0; j < c->nbox && !on; j++)
        on = c->box_lights[(size_t)j * s->light_count + l] && ub_obb_contains(&c->box[j], p);
    }
    if (!on || (beyond >= 0 && beyond_counts(c, l, beyond)))
      continue;
    float e[3], dir[3];
    if (light_through(c, &s->lights[l], po, n, 1, e, dir))
      for (int k = 0; k < 3; k++)
        E[k] += e[k];
  }
  /* What crosses the portal (sky, or the base's stored radiance beyond the door): two
   * samples, one toward a uniform point of the portal box and one cosine about n, combined
   * by the balance heuristic (Veach 1997, §9.2). Each is f / (p_box + p_cos) with
   * f = L·cos, so neither exceeds π·L. The box sample alone is f / p_box, whose 1/d² blows
   * up at hits a few centimetres from the doorway (the jamb, the floor under it): door_combo
   * seed 5 had one such hit give 0.72 of a 1.16 LLG probe value that converges to ~0.73. A
   * cosine ray that misses the portal box cannot cross the leaf and is not traced. */
  float u[3] = {rnd(c, rid, smp, 20), rnd(c, rid, smp, 21), rnd(c, rid, smp, 22)};
  float q[3], w[2][3];
  ub_obb_point(&c->portal, u, q);
  for (int k = 0; k < 3; k++)
    w[0][k] = q[k] - po[k];
  float len = sqrtf(dot3(w[0], w[0]));
  int first = 1; /* the box sample only when it gave a direction */
  if (len > 0.0f) {
    for (int k = 0; k < 3; k++)
      w[0][k] /= len;
    first = 0;
  }
  ub_sample_cosine(n, rnd(c, rid, smp, 23), rnd(c, rid, smp, 24), w[1]);
  for (int i = first; i < 2; i++) {
    float cs = dot3(n, w[i]), t0, t1;
    if (!(cs > 0.0f) || (i == 1 && !ub_obb_ray(&c->portal, po, w[i], &t0, &t1)))
      continue;
    double pdf = ub_obb_pdf(&c->portal, po, w[i]) + cs * M_1_PI;
    ub_hit h;
    float L[3];
    trace(c->rt_open, po, w[i], INFINITY, &h);
    if (isfinite(pdf) && crossing_delta(c, po, w[i], &h, L))
      for (int k = 0; k < 3; k++)
        E[k] += L[k] * cs / pdf;
  }
  for (int k = 0; k < 3; k++)
    out[k] = isfinite(E[k]) ? (float)E[k] : 0.0f;
}

/* One receiver: N guided gather rays (terms a, b) + static lights through the door (c).
 * origins: norg ray origins (already offset); n: unit normal or NULL (point receiver).
 * sh: nsh × 3 radiance SH (W/(m²·sr)), iz: irradiance along n (W/m²). */
static void receiver_estimate(const door_ctx *c, const float *origins, uint32_t norg,
                              const float *n, uint32_t rid, uint32_t N, uint32_t nshadow,
                              uint32_t nsh, double *sh, double iz[3], double out_b[3])
{
  const ub_scene *s = c->s;
  for (uint32_t smp = 0; smp < N; smp++) {
    const float *x = origins + 3 * (smp % norg);
    float u[4] = {rnd(c, rid, smp, 0), rnd(c, rid, smp, 1), rnd(c, rid, smp, 2),
                  rnd(c, rid, smp, 3)};
    float w[3];
    double pdf = ub_guide_sample(&c->guide, x, n, u, w);
    if (!(pdf > 0.0) || !isfinite(pdf))
      continue;
    ub_hit h;
    trace(c->rt_open, x, w, INFINITY, &h);
    float L[3] = {0, 0, 0}, Lb[3] = {0, 0, 0};
    int bounced = 0;
    /* (a) through the door, minus the closed leaf's bounce S_C */
    int crossing = crossing_delta(c, x, w, &h, L);
    if (h.tri != UB_RT_MISS) {
      /* (b) one bounce of the door's light at the hit: on this side, or beyond the door
       * (the open door lets the light that crossed it out again: lamp A → through the door
       * → a wall of room B → back through the door to room A), there without the direct
       * light (a) took already (beyond_counts) */
      const float *alb = s->materials[s->tri_material[h.tri]].albedo;
      if (alb[0] + alb[1] + alb[2] > 0.0f) {
        float nd[3], p[3], E[3];
        int front;
        hit_normal(&h, w, nd, &front);
        for (int k = 0; k < 3; k++)
          p[k] = x[k] + w[k] * h.t;
        door_irradiance(c, p, nd, rid, smp,
                        crossing ? c->lm->tri_atlas[h.tri] >= 0 : -1, E);
        bounced = 1;
        for (int k = 0; k < 3; k++) {
          Lb[k] = alb[k] / (float)M_PI * E[k];
          L[k] += Lb[k];
        }
      }
    }
    if (L[0] == 0.0f && L[1] == 0.0f && L[2] == 0.0f)
      continue;
    double wt = 1.0 / (pdf * (double)N), wsh = n ? ub_texel_sh_weight(wt, N) : wt;
    float y[9];
    ub_sh2_eval_basis(w, y);
    for (uint32_t k = 0; k < nsh; k++)
      for (int ch = 0; ch < 3; ch++)
        sh[k * 3 + ch] += (double)y[k] * L[ch] * wsh;
    if (n) {
      double cs = fmax(0.0, dot3(n, w));
      for (int ch = 0; ch < 3; ch++)
        iz[ch] += L[ch] * cs * wt;
      if (bounced && out_b)
        for (int ch = 0; ch < 3; ch++)
          out_b[ch] += Lb[ch] * cs * wt;
    }
  }
  /* (c) static punctual lights through the door. */
  for (uint32_t l = 0; l < s->light_count; l++) {
    if (!c->portal_lights[l] || s->lights[l].cls != UB_LIGHT_STATIC)
      continue;
    for (uint32_t k = 0; k < nshadow; k++) {
      float e[3], dir[3];
      if (!light_through(c, &s->lights[l], origins + 3 * (k % norg), n, 1, e, dir))
        continue;
      /* e has the cosine applied; SH takes the radiance projection E⊥·Y(dir). */
      float cs = n ? dot3(n, dir) : 1.0f;
      float y[9];
      ub_sh2_eval_basis(dir, y);
      for (uint32_t j = 0; j < nsh; j++)
        for (int ch = 0; ch < 3; ch++)
          sh[j * 3 + ch] += (double)y[j] * (e[ch] / cs) / nshadow;
      for (int ch = 0; ch < 3; ch++)
        iz[ch] += (double)e[ch] / nshadow;
    }
  }
}

/* Shadow photons: uniform points on the portal box, a shadow ray toward a random base light
 * (or the sky); when it gets through, the photon continues away from the light and lands
 * on the first open-geometry hit. Clustered by weighted k-means into boxes with light
 * lists. Fills c->nbox, c->box, c->box_lights, c->portal_lights; returns photons landed. */
static uint32_t photons_build(door_ctx *c, uint32_t attempts, double *out_box_flux,
                              int *oom)
{
  const ub_scene *s = c->s;
  uint32_t nl = 0;
  uint32_t *cand = malloc(((size_t)s->light_count + 1) * sizeof *cand);
  float *pos = malloc((size_t)attempts * 3 * sizeof *pos);
  float *flux = malloc((size_t)attempts * sizeof *flux);
  uint32_t *from = malloc((size_t)attempts * sizeof *from);
  uint32_t *asg = malloc((size_t)attempts * sizeof *asg);
  float *pts = malloc((size_t)attempts * 3 * sizeof *pts);
  if (!cand || !pos || !flux || !from || !asg || !pts) {
    *oom = 1;
    free(cand), free(pos), free(flux), free(from), free(asg), free(pts);
    return 0;
  }
  for (uint32_t l = 0; l < s->light_count; l++)
    if (c->enabled[l])
      cand[nl++] = l;
  if (c->sky)
    cand[nl++] = UINT32_MAX;
  uint32_t np = 0;
  for (uint32_t i = 0; i < attempts && nl; i++) {
    float u[3] = {rnd(c, 0xFFFFFFu, i, 40), rnd(c, 0xFFFFFFu, i, 41), rnd(c, 0xFFFFFFu, i, 42)};
    float p[3], dir[3], e[3], dist = INFINITY;
    ub_obb_point(&c->portal, u, p);
    uint32_t pick = (uint32_t)(rnd(c, 0xFFFFFFu, i, 43) * (float)nl);
    uint32_t l = cand[pick < nl ? pick : nl - 1];
    if (l == UINT32_MAX) {
      const float up[3] = {0, 1, 0};
      ub_sample_cosine(up, rnd(c, 0xFFFFFFu, i, 44), rnd(c, 0xFFFFFFu, i, 45), dir);
      memcpy(e, c->sky_rgb, sizeof e);
      for (int k = 0; k < 3; k++)
        e[k] *= (float)M_PI;
    } else if (!ub_light_incident(&s->lights[l], p, dir, &dist, e)) {
      continue;
    }
    float tfar = isfinite(dist) ? dist * (1.0f - 1e-4f) : INFINITY;
    if (occluded(c->rt_open, p, dir, tfar))
      continue;
    if (l != UINT32_MAX)
      c->portal_lights[l] = 1;
    float back[3] = {-dir[0], -dir[1], -dir[2]};
    ub_hit h;
    trace(c->rt_open, p, back, INFINITY, &h);
    if (h.tri == UB_RT_MISS)
      continue;
    float nd[3];
    int front;
    hit_normal(&h, back, nd, &front);
    double ev[3] = {e[0], e[1], e[2]};
    const float *alb = s->materials[s->tri_material[h.tri]].albedo;
    float f = (float)(lum(ev) * fabs(dot3(nd, dir)) * (alb[0] + alb[1] + alb[2]) / 3.0);
    if (!(f > 0.0f) || !isfinite(f))
      continue;
    for (int k = 0; k < 3; k++)
      pos[3 * np + k] = p[k] + back[k] * h.t;
    flux[np] = f;
    from[np] = l;
    np++;
  }
  c->nbox = 0;
  uint32_t K = np / 16 < UB_DOOR_MAX_BOXES ? np / 16 : UB_DOOR_MAX_BOXES;
  if (K > 0) {
    double ctr[UB_DOOR_MAX_BOXES][3];
    for (uint32_t j = 0; j < K; j++)
      for (int k = 0; k < 3; k++)
        ctr[j][k] = pos[3 * (size_t)((uint64_t)j * np / K) + k];
    for (int it = 0; it < KMEANS_ITERS; it++) {
      double acc[UB_DOOR_MAX_BOXES][4];
      memset(acc, 0, sizeof acc);
      for (uint32_t i = 0; i < np; i++) {
        double best = INFINITY;
        uint32_t bj = 0;
        for (uint32_t j = 0; j < K; j++) {
          double d2 = 0.0;
          for (int k = 0; k < 3; k++)
            d2 += (pos[3 * i + k] - ctr[j][k]) * (pos[3 * i + k] - ctr[j][k]);
          if (d2 < best) {
            best = d2;
            bj = j;
          }
        }
        asg[i] = bj;
        for (int k = 0; k < 3; k++)
          acc[bj][k] += flux[i] * pos[3 * i + k];
        acc[bj][3] += flux[i];
      }
      for (uint32_t j = 0; j < K; j++)
        if (acc[j][3] > 0.0)
          for (int k = 0; k < 3; k++)
            ctr[j][k] = acc[j][k] / acc[j][3];
    }
    c->box_lights = calloc((size_t)K * (s->light_count ? s->light_count : 1), 1);
    if (!c->box_lights)
      *oom = 1;
    for (uint32_t j = 0; j < K && c->box_lights; j++) {
      uint32_t m = 0;
      double fsum = 0.0;
      for (uint32_t i = 0; i < np; i++)
        if (asg[i] == j) {
          memcpy(pts + 3 * (size_t)m++, pos + 3 * (size_t)i, 3 * sizeof(float));
          fsum += flux[i];
        }
      ub_obb b;
      if (m < 2 || !ub_obb_fit(pts, m, UB_DOOR_BOX_MARGIN, &b))
        continue;
      uint32_t bj = c->nbox++;
      c->box[bj] = b;
      out_box_flux[bj] = fsum;
      for (uint32_t i = 0; i < np; i++)
        if (asg[i] == j && from[i] != UINT32_MAX)
          c->box_lights[(size_t)bj * s->light_count + from[i]] = 1;
    }
  }
  free(cand), free(pos), free(flux), free(from), free(asg), free(pts);
  return np;
}

/* I_z-exact SH L1 (as bake/pass.c stores texels): add a cosine lobe about n so that the
 * SH's irradiance along n equals iz. Linear in the light, so records stay additive. */
static void sh1_fix_iz(const float n[3], const double iz[3], double sh[12], float out[12])
{
  const double K = M_PI * M_PI * (Y0 * Y0) + (2.0 * M_PI / 3.0) * (2.0 * M_PI / 3.0) * (Y1 * Y1);
  const double h0 = Y0 * M_PI / K, h1 = Y1 * (2.0 * M_PI / 3.0) / K;
  for (int ch = 0; ch < 3; ch++) {
    double e_sh = M_PI * Y0 * sh[ch] + (2.0 * M_PI / 3.0) * Y1 *
                                           (sh[3 + ch] * n[1] + sh[6 + ch] * n[2] +
                                            sh[9 + ch] * n[0]);
    double v = isfinite(iz[ch]) ? iz[ch] : 0.0; /* signed: S_O − S_C */
    double delta = v - e_sh;
    sh[ch] += delta * h0;
    sh[3 + ch] += delta * h1 * n[1];
    sh[6 + ch] += delta * h1 * n[2];
    sh[9 + ch] += delta * h1 * n[0];
  }
  for (int i = 0; i < 12; i++)
    out[i] = isfinite(sh[i]) ? (float)sh[i] : 0.0f;
}

/* Runs the estimator over a receiver list. Texels: out12 (T×12, written at the listed
 * texels), val (T: luminance of iz), iz3 (T×3) and ib3 (T×3: the one-bounce share (b),
 * what a further bounce reads), each optional. Probes: out27 (P×27), val. */
static void run_texels(const door_ctx *c, const uint32_t *list, uint32_t count, uint32_t rays,
                       uint32_t nshadow, float *out12, float *val, float *iz3, float *ib3)
{
  const ub_lightmap *lm = c->lm;
#pragma omp parallel for schedule(dynamic, 16)
  for (uint32_t i = 0; i < count; i++) {
    uint32_t t = list ? list[i] : i;
    double sh[27] = {0}, iz[3] = {0, 0, 0}, ib[3] = {0, 0, 0};
    const float *n = lm->texel_normal + 3 * (size_t)t;
    receiver_estimate(c, lm->sample_pos + (size_t)t * UB_TEXEL_SAMPLES * 3, UB_TEXEL_SAMPLES,
                      n, t, rays, nshadow, 4, sh, iz, ib);
    if (out12)
      sh1_fix_iz(n, iz, sh, out12 + 12 * (size_t)t);
    if (val)
      val[t] = (float)fabs(lum(iz));
    for (int k = 0; k < 3; k++) {
      if (iz3)
        iz3[3 * (size_t)t + k] = (float)iz[k];
      if (ib3)
        ib3[3 * (size_t)t + k] = (float)ib[k];
    }
  }
}

/* Probes (points): GLG probes (pos = pd->probe_pos, id PROBE_ID_BASE + q) or LLG probes
 * (LLG_ID_BASE + q); skip (may be NULL) marks probes left out (invalid LLG probes). */
static void run_probes(const door_ctx *c, const float *pos, uint32_t id_base,
                       const uint32_t *list, uint32_t count, uint32_t rays, uint32_t nshadow,
                       float *out27, float *val)
{
#pragma omp parallel for schedule(dynamic, 16)
  for (uint32_t i = 0; i < count; i++) {
    uint32_t q = list ? list[i] : i;
    double sh[27] = {0}, iz[3] = {0, 0, 0};
    receiver_estimate(c, pos + 3 * (size_t)q, 1, NULL, id_base + q, rays, nshadow, 9, sh, iz,
                      NULL);
    if (out27)
      for (int k = 0; k < 27; k++)
        out27[27 * (size_t)q + k] = isfinite(sh[k]) ? (float)sh[k] : 0.0f;
    if (val) {
      double dc[3] = {sh[0], sh[1], sh[2]};
      val[q] = (float)fabs(lum(dc));
    }
  }
}

/* Further bounces on the receiver side (series expansion, bounce k ≥ 2): gather rays from
 * a receiver read albedo/π × bounce k−1 of the door's light at their hit (bilinear from
 * prev, the images of the kept texels' previous bounce; other texels count as 0), rays
 * through the doorway too: with the door open they reach the far room's surfaces, which
 * hold door light of their own (before, they added 0 and a lit room read low with its
 * door open). Adds to sh (nsh × 3) and iz. */
static void bounce_estimate(const door_ctx *c, float *const *prev, const float *origins,
                            uint32_t norg, const float *n, uint32_t rid, uint32_t N,
                            uint32_t nsh, double *sh, double iz[3])
{
  const ub_scene *s = c->s;
  for (uint32_t smp = 0; smp < N; smp++) {
    const float *x = origins + 3 * (smp % norg);
    float u[4] = {rnd(c, rid, smp, 0), rnd(c, rid, smp, 1), rnd(c, rid, smp, 2),
                  rnd(c, rid, smp, 3)};
    float w[3];
    double pdf = ub_guide_sample(&c->cosine, x, n, u, w);
    if (!(pdf > 0.0) || !isfinite(pdf))
      continue;
    ub_hit h;
    trace(c->rt_open, x, w, INFINITY, &h);
    if (h.tri == UB_RT_MISS || c->lm->tri_atlas[h.tri] < 0)
      continue;
    float nd[3], E[3], L[3];
    int front;
    hit_normal(&h, w, nd, &front);
    if (!front)
      continue;
    image_lookup(c->lm, prev, h.tri, h.u, h.v, E);
    const float *alb = s->materials[s->tri_material[h.tri]].albedo;
    for (int k = 0; k < 3; k++)
      L[k] = alb[k] / (float)M_PI * E[k];
    if (L[0] == 0.0f && L[1] == 0.0f && L[2] == 0.0f)
      continue;
    double wt = 1.0 / (pdf * (double)N), wsh = n ? ub_texel_sh_weight(wt, N) : wt;
    float y[9];
    ub_sh2_eval_basis(w, y);
    for (uint32_t k = 0; k < nsh; k++)
      for (int ch = 0; ch < 3; ch++)
        sh[k * 3 + ch] += (double)y[k] * L[ch] * wsh;
    if (n) {
      double cs = fmax(0.0, dot3(n, w));
      for (int ch = 0; ch < 3; ch++)
        iz[ch] += L[ch] * cs * wt;
    }
  }
}

/* Per-atlas images (w×h×4) of per-texel irradiance iz (T×3), dilated 2 rings; *out_img
 * NULL: allocated here, else refilled. */
static ub_result build_images(const ub_lightmap *lm, const float *iz, float ***out_img)
{
  float **img = *out_img ? *out_img : calloc(lm->atlas_count ? lm->atlas_count : 1, sizeof *img);
  if (!img)
    return UB_ERR_OUT_OF_MEMORY;
  for (uint32_t a = 0; a < lm->atlas_count; a++) {
    const ub_atlas *at = &lm->atlases[a];
    size_t npx = (size_t)at->width * at->height;
    if (!img[a])
      img[a] = malloc(npx * 4 * sizeof(float));
    if (!img[a] || !ub_lightmap_image_fill(lm, a, iz, NULL, img[a])) {
      *out_img = img; /* the caller frees what was allocated */
      return UB_ERR_OUT_OF_MEMORY;
    }
  }
  *out_img = img;
  return UB_OK;
}

/* Texel t lies on door d's closed leaf: it keeps its base (closed) lighting whatever the
 * door does (the leaf has moved away when the door is open). */
static int own_leaf(const ub_scene *s, const ub_lightmap *lm, uint32_t t, uint32_t d)
{
  return s->nodes[s->tri_node[lm->texel_tri[t]]].door == (int32_t)d;
}

/* Scratch shared by every door pass of one bake (sized for the whole receiver sets). */
typedef struct door_work {
  float *tval, *pval, *lval;  /* influence values: texels, GLG probes, LLG probes */
  float *t12, *p27, *l27;     /* full-quality results */
  uint32_t *kt, *kp, *kl;     /* kept receivers */
  float *ib, *ib2;            /* texel_count × 3: one-bounce share, next bounce */
  float **bimg;               /* per atlas: images of ib */
  uint8_t *open, *plights;
} door_work;

static void work_free(door_work *w, const ub_lightmap *lm)
{
  for (uint32_t a = 0; w->bimg && a < lm->atlas_count; a++)
    free(w->bimg[a]);
  free(w->bimg);
  free(w->tval), free(w->pval), free(w->lval), free(w->t12), free(w->p27), free(w->l27);
  free(w->kt), free(w->kp), free(w->kl), free(w->ib), free(w->ib2);
  free(w->open), free(w->plights);
  memset(w, 0, sizeof *w);
}

static int work_alloc(door_work *w, const ub_scene *s, uint32_t T, uint32_t P, uint32_t L)
{
  memset(w, 0, sizeof *w);
  w->tval = malloc(((size_t)T + 1) * sizeof(float));
  w->pval = malloc(((size_t)P + 1) * sizeof(float));
  w->lval = malloc(((size_t)L + 1) * sizeof(float));
  w->t12 = malloc(((size_t)T * 12 + 1) * sizeof(float));
  w->p27 = malloc(((size_t)P * 27 + 1) * sizeof(float));
  w->l27 = malloc(((size_t)L * 27 + 1) * sizeof(float));
  w->kt = malloc(((size_t)T + 1) * sizeof(uint32_t));
  w->kp = malloc(((size_t)P + 1) * sizeof(uint32_t));
  w->kl = malloc(((size_t)L + 1) * sizeof(uint32_t));
  w->ib = calloc((size_t)T * 3 + 1, sizeof(float));
  w->ib2 = calloc((size_t)T * 3 + 1, sizeof(float));
  w->open = calloc(s->door_count + 1, 1);
  w->plights = calloc(s->light_count + 1, 1);
  return w->tval && w->pval && w->lval && w->t12 && w->p27 && w->l27 && w->kt && w->kp &&
         w->kl && w->ib && w->ib2 && w->open && w->plights;
}

/* One door pass: door `door` opens, emitters `lights` (+ sky, emission) whose stored
 * lighting (closed door) is `img`. The door's own record uses the base's emitters and
 * stored lighting; a door × set combination the set's lights and the set's record. */
typedef struct door_job {
  uint32_t door;
  const uint8_t *lights; /* light_count */
  int sky, emissive;
  float **img;           /* per atlas: stored irradiance of these emitters, door closed */
  uint32_t pass_base;    /* added to every pass id (0: the door's own record) */
  /* door × door: another door open in every geometry of the pass (UINT32_MAX: none) and
   * the base geometry with it open (NULL: pd->rt) */
  uint32_t other_open;
  const ub_rt *rt_base;
  /* fixed = 1: no influence pass, the receivers are w->kt/kp/kl[0, nkt/nkp/nkl) as
   * given; no_record = 1: results left in w->t12/p27/l27. Out: the kept counts. */
  int fixed, no_record;
  uint32_t nkt, nkp, nkl;
  const char *label;     /* log label ("door", "combination") */
} door_job;

/* Sorted kept lists → the record's sparse arrays (probes and LLG probes). */
static ub_result probe_record(const uint32_t *kept, uint32_t n, const float *sh27,
                              uint32_t *out_count, uint32_t **out_index, float **out_sh)
{
  if (!n)
    return UB_OK;
  *out_index = malloc((size_t)n * sizeof **out_index);
  *out_sh = malloc((size_t)n * 27 * sizeof **out_sh);
  if (!*out_index || !*out_sh)
    return UB_ERR_OUT_OF_MEMORY;
  *out_count = n;
  for (uint32_t i = 0; i < n; i++) {
    (*out_index)[i] = kept[i];
    memcpy(*out_sh + 27 * (size_t)i, sh27 + 27 * (size_t)kept[i], 27 * sizeof(float));
  }
  return UB_OK;
}

/* Keeps receivers whose value exceeds UB_DOOR_INFLUENCE_FRACTION × the mean over those
 * reached (all of them when influence culling is off: val NULL). Returns the threshold. */
static double keep_influenced(const float *val, uint32_t n, const uint8_t *skip, uint32_t *kept,
                              uint32_t *out_n)
{
  uint32_t m = 0;
  double thr = 0.0;
  if (val) {
    double sum = 0.0;
    uint32_t reached = 0;
    for (uint32_t i = 0; i < n; i++)
      if (val[i] > 0.0f)
        sum += val[i], reached++;
    thr = reached ? UB_DOOR_INFLUENCE_FRACTION * sum / reached : INFINITY;
  }
  for (uint32_t i = 0; i < n; i++)
    if ((!val || val[i] > thr) && !(skip && skip[i]))
      kept[m++] = i;
  *out_n = m;
  return thr;
}

static ub_result door_one(const ub_door_desc *dd, door_job *jb, door_work *w,
                          const ub_log *log, ub_bakefile_record *rec, ub_door_stats *st)
{
  const ub_pass_desc *pd = dd->base;
  const ub_scene *s = pd->scene;
  const ub_lightmap *lm = pd->lightmap;
  const ub_llg_set *llg = pd->llg && pd->llg->probe_count ? pd->llg : NULL;
  uint32_t T = lm->texel_count, P = pd->probe_count, L = llg ? llg->probe_count : 0;
  uint32_t d = jb->door;
  /* Portal = the OBB of the closed leaf's vertices. */
  uint32_t nleaf = ub_geom_door_triangles(s, d, 0);
  float *pts = malloc(((size_t)nleaf * 9 + 1) * sizeof *pts);
  uint8_t *leaf_mask = calloc(s->triangle_count ? s->triangle_count : 1, 1);
  if (!pts || !leaf_mask) {
    free(pts);
    free(leaf_mask);
    return UB_ERR_OUT_OF_MEMORY;
  }
  uint32_t np = 0;
  for (uint32_t t = 0; t < s->triangle_count; t++)
    if (s->nodes[s->tri_node[t]].door == (int32_t)d && !(s->tri_flags[t] & UB_TRI_DEGENERATE)) {
      leaf_mask[t] = 1;
      for (int v = 0; v < 3; v++)
        memcpy(pts + 3 * (size_t)np++, s->positions + 3 * (size_t)s->indices[3 * t + v],
               3 * sizeof(float));
    }
  door_ctx c;
  memset(&c, 0, sizeof c);
  c.s = s;
  c.lm = lm;
  c.img = jb->img;
  c.enabled = jb->lights;
  c.portal_lights = w->plights;
  memset(w->plights, 0, s->light_count + 1);
  c.sky = jb->sky && s->has_sky;
  c.sky_rgb = s->sky;
  c.emissive = jb->emissive;
  c.seed = pd->seed;
  int fitted = ub_obb_fit(pts, np, 0.01f, &c.portal);
  free(pts);
  memset(w->open, 0, s->door_count + 1);
  w->open[d] = 1;
  if (jb->other_open < s->door_count)
    w->open[jb->other_open] = 1;
  ub_geom_state gs = {w->open, NULL};
  uint8_t *open_mask = ub_geom_mask(s, &gs);
  ub_rt *rt_open = NULL, *rt_leaf = NULL, *rt_env = NULL;
  ub_result r = UB_OK;
  if (!fitted || !open_mask) {
    r = fitted ? UB_ERR_OUT_OF_MEMORY : UB_ERR_INVALID_DATA;
  } else {
    r = ub_rt_create(s, open_mask, log, &rt_open);
    if (r == UB_OK)
      r = ub_rt_create(s, leaf_mask, log, &rt_leaf);
    if (r == UB_OK && llg) {
      /* LLG probes see the level without the LLG models (probes/llg.h), door open */
      for (uint32_t n = 0; n < s->node_count; n++)
        if (llg->node_model[n] >= 0)
          memset(open_mask + s->nodes[n].first_triangle, 0, s->nodes[n].triangle_count);
      r = ub_rt_create(s, open_mask, log, &rt_env);
    }
  }
  free(open_mask);
  free(leaf_mask);
  if (r != UB_OK) {
    ub_rt_free(rt_open);
    ub_rt_free(rt_leaf);
    ub_rt_free(rt_env);
    return r;
  }
  c.rt_open = rt_open;
  c.rt_leaf = rt_leaf;
  c.rt_base = jb->rt_base ? jb->rt_base : pd->rt;
  door_ctx ce = c; /* LLG probes: the same, rays against the level without LLG models */
  ce.rt_open = rt_env;
  /* Shadow photons → boxes, light lists. */
  double t0 = now_s();
  c.pass_id = jb->pass_base + 0x1000u + 2u * d;
  double box_flux[UB_DOOR_MAX_BOXES] = {0};
  int oom = 0;
  uint32_t landed = photons_build(&c, dd->photons, box_flux, &oom);
  if (oom) {
    free(c.box_lights);
    ub_rt_free(rt_open);
    ub_rt_free(rt_leaf);
    ub_rt_free(rt_env);
    return UB_ERR_OUT_OF_MEMORY;
  }
  ub_obb boxes[1 + UB_DOOR_MAX_BOXES];
  double bw[1 + UB_DOOR_MAX_BOXES];
  boxes[0] = c.portal;
  double fsum = 0.0;
  for (uint32_t j = 0; j < c.nbox; j++)
    fsum += box_flux[j];
  bw[0] = c.nbox ? 0.5 : 1.0;
  for (uint32_t j = 0; j < c.nbox; j++) {
    boxes[1 + j] = c.box[j];
    bw[1 + j] = fsum > 0.0 ? 0.5 * box_flux[j] / fsum : 0.0;
  }
  ub_guide_init(&c.cosine, NULL, 0, NULL, 1.0);
  if (dd->guiding)
    ub_guide_init(&c.guide, boxes, 1 + c.nbox, bw, 0.3);
  else
    ub_guide_init(&c.guide, NULL, 0, NULL, 1.0);
  ce = c;
  ce.rt_open = rt_env;
#define RAYS_NOW() (ub_rt_rays_traced(rt_open) + ub_rt_rays_traced(rt_leaf) + \
                    (rt_env ? ub_rt_rays_traced(rt_env) : 0))
  uint64_t rays0 = RAYS_NOW();
  st->rays_photons += rays0;
  st->photons_deposited += landed;
  st->boxes += c.nbox;
  /* 1. Influence: a cheap pass over every receiver (texels on this door's own closed leaf
   * never: they keep their closed lighting). */
  uint8_t *skip_t = calloc((size_t)T + 1, 1), *skip_l = calloc((size_t)L + 1, 1);
  if (!skip_t || !skip_l) {
    free(skip_t), free(skip_l), free(c.box_lights);
    ub_rt_free(rt_open), ub_rt_free(rt_leaf), ub_rt_free(rt_env);
    return UB_ERR_OUT_OF_MEMORY;
  }
  for (uint32_t t = 0; t < T; t++)
    skip_t[t] = (uint8_t)own_leaf(s, lm, t, d);
  for (uint32_t q = 0; q < L; q++)
    skip_l[q] = llg->probe_valid && !llg->probe_valid[q];
  uint32_t nkt = 0, nkp = 0, nkl = 0;
  c.pass_id = ce.pass_id = jb->pass_base + 0x1000u + 2u * d;
  int cull = dd->influence_rays > 0 && !jb->fixed;
  if (cull) {
    run_texels(&c, NULL, T, dd->influence_rays, 1, NULL, w->tval, NULL, NULL);
    run_probes(&c, pd->probe_pos, PROBE_ID_BASE, NULL, P, 2 * dd->influence_rays, 1, NULL,
               w->pval);
    if (L)
      run_probes(&ce, llg->probe_pos, LLG_ID_BASE, NULL, L, 2 * dd->influence_rays, 1, NULL,
                 w->lval);
  }
  double thr_t = 0.0;
  if (jb->fixed) {
    nkt = jb->nkt, nkp = jb->nkp, nkl = jb->nkl;
  } else {
    thr_t = keep_influenced(cull ? w->tval : NULL, T, skip_t, w->kt, &nkt);
    keep_influenced(cull ? w->pval : NULL, P, NULL, w->kp, &nkp);
    keep_influenced(cull ? w->lval : NULL, L, skip_l, w->kl, &nkl);
  }
  jb->nkt = nkt, jb->nkp = nkp, jb->nkl = nkl;
  free(skip_t);
  free(skip_l);
  uint64_t rays1 = RAYS_NOW();
  st->rays_influence += rays1 - rays0;
  double t1 = now_s();
  st->seconds_influence += t1 - t0;
  /* 2. Full quality over the kept receivers. */
  c.pass_id = ce.pass_id = jb->pass_base + 0x1001u + 2u * d;
  memset(w->t12, 0, (size_t)T * 12 * sizeof *w->t12);
  float *dbg = dd->debug_texel_iz && dd->debug_door == d && !jb->pass_base ? dd->debug_texel_iz
                                                                           : NULL;
  if (dbg)
    memset(dbg, 0, (size_t)T * 3 * sizeof *dbg);
  uint32_t nsh = pd->shadow_samples ? pd->shadow_samples : 1;
  memset(w->ib, 0, (size_t)T * 3 * sizeof *w->ib);
  memset(w->ib2, 0, (size_t)T * 3 * sizeof *w->ib2);
  run_texels(&c, w->kt, nkt, dd->rays, nsh, w->t12, w->tval, dbg, w->ib);
  run_probes(&c, pd->probe_pos, PROBE_ID_BASE, w->kp, nkp, 2 * dd->rays, nsh, w->p27, NULL);
  if (nkl)
    run_probes(&ce, llg->probe_pos, LLG_ID_BASE, w->kl, nkl, 2 * dd->rays, nsh, w->l27, NULL);
  /* Further bounces on the receiver side, until one adds < stop_fraction. */
  double e_total = 0.0;
  for (uint32_t i = 0; i < nkt; i++)
    e_total += w->tval[w->kt[i]];
  uint32_t nb = 1, max_b = pd->bounces >= 0 ? (uint32_t)pd->bounces : UB_DOOR_MAX_BOUNCES;
  uint32_t rays_b = dd->rays / 2 > 16 ? dd->rays / 2 : 16;
  while (nb < max_b && r == UB_OK) {
    r = build_images(lm, w->ib, &w->bimg);
    if (r != UB_OK)
      break;
    nb++;
    c.pass_id = ce.pass_id = jb->pass_base + 0x2000u + 32u * d + nb;
    double e_k = 0.0;
    float *ib2 = w->ib2, *t12 = w->t12, *p27 = w->p27, *l27 = w->l27, **bimg = w->bimg;
    const uint32_t *kt = w->kt, *kp = w->kp, *kl = w->kl;
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : e_k)
    for (uint32_t i = 0; i < nkt; i++) {
      uint32_t t = kt[i];
      double sh[27] = {0}, iz[3] = {0, 0, 0};
      const float *n = lm->texel_normal + 3 * (size_t)t;
      bounce_estimate(&c, bimg, lm->sample_pos + (size_t)t * UB_TEXEL_SAMPLES * 3,
                      UB_TEXEL_SAMPLES, n, t, rays_b, 4, sh, iz);
      float add[12];
      sh1_fix_iz(n, iz, sh, add);
      for (int k = 0; k < 12; k++)
        t12[12 * (size_t)t + k] += add[k];
      for (int k = 0; k < 3; k++) {
        ib2[3 * (size_t)t + k] = (float)iz[k];
        if (dbg)
          dbg[3 * (size_t)t + k] += (float)iz[k];
      }
      e_k += fabs(lum(iz));
    }
#pragma omp parallel for schedule(dynamic, 16)
    for (uint32_t i = 0; i < nkp + nkl; i++) {
      int is_llg = i >= nkp;
      uint32_t q = is_llg ? kl[i - nkp] : kp[i];
      double sh[27] = {0}, iz[3] = {0, 0, 0};
      bounce_estimate(is_llg ? &ce : &c, bimg,
                      (is_llg ? llg->probe_pos : pd->probe_pos) + 3 * (size_t)q, 1, NULL,
                      (is_llg ? LLG_ID_BASE : PROBE_ID_BASE) + q, 2 * rays_b, 9, sh, iz);
      float *dst = (is_llg ? l27 : p27) + 27 * (size_t)q;
      for (int k = 0; k < 27; k++)
        dst[k] += isfinite(sh[k]) ? (float)sh[k] : 0.0f;
    }
    float *tmp = w->ib;
    w->ib = w->ib2;
    w->ib2 = tmp;
    int stop = !(e_k > pd->stop_fraction * e_total);
    e_total += e_k;
    if (stop)
      break;
  }
  if (r == UB_OK) {
    st->rays_full += RAYS_NOW() - rays1;
    st->seconds_full += now_s() - t1;
    if (!jb->no_record)
      r = ub_dls_texel_record(lm, w->kt, nkt, w->t12, rec);
  }
#undef RAYS_NOW
  if (r == UB_OK && !jb->no_record)
    r = probe_record(w->kp, nkp, w->p27, &rec->probe_count, &rec->probe_index, &rec->probe_sh);
  if (r == UB_OK && !jb->no_record)
    r = probe_record(w->kl, nkl, w->l27, &rec->llg_probe_count, &rec->llg_probe_index,
                     &rec->llg_probe_sh);
  if (r == UB_OK) {
    uint32_t nlist = 0;
    for (uint32_t l = 0; l < s->light_count; l++)
      nlist += w->plights[l];
    st->texels_kept += nkt;
    st->probes_kept += nkp;
    st->llg_probes_kept += nkl;
    ub_log_printf(log, UB_LOG_INFO,
                  "  %s %-16s: %u leaf triangles, %u of %u photons landed in %u box(es), "
                  "%u light(s) reach the portal; %u of %u texels, %u of %u probes and %u of "
                  "%u LLG probes in its influence (threshold %.3g W/m²), %u bounce(s) inside, "
                  "record %u pixels",
                  jb->label ? jb->label : "door", rec->name, nleaf, landed, dd->photons,
                  c.nbox, nlist, nkt, T, nkp, P, nkl, L, thr_t, nb, rec->texel_count);
  }
  free(c.box_lights);
  ub_rt_free(rt_open);
  ub_rt_free(rt_leaf);
  ub_rt_free(rt_env);
  return r;
}

ub_result ub_door_bake(const ub_door_desc *dd, const ub_log *log,
                       ub_bakefile_record **out_records, ub_door_stats *out_stats)
{
  const ub_pass_desc *pd = dd->base;
  const ub_scene *s = pd->scene;
  const ub_lightmap *lm = pd->lightmap;
  memset(out_stats, 0, sizeof *out_stats);
  *out_records = NULL;
  if (s->door_count == 0)
    return UB_OK;
  uint32_t T = lm->texel_count, P = pd->probe_count;
  uint32_t L = pd->llg ? pd->llg->probe_count : 0;
  ub_bakefile_record *recs = calloc(s->door_count, sizeof *recs);
  door_work w;
  float **img = NULL;
  ub_result r = UB_OK;
  if (!work_alloc(&w, s, T, P, L) || !recs)
    r = UB_ERR_OUT_OF_MEMORY;
  if (r == UB_OK)
    r = build_images(lm, dd->base_result->iz, &img);
  for (uint32_t d = 0; d < s->door_count && r == UB_OK; d++) {
    ub_bakefile_record *rec = &recs[d];
    snprintf(rec->name, sizeof rec->name, "%s", s->door_names[d]);
    rec->kind = UB_ELEMENT_DOOR;
    rec->parent[0] = rec->parent[1] = -1;
    if (ub_geom_door_triangles(s, d, 0) == 0) {
      out_stats->doors_empty++;
      ub_log_printf(log, UB_LOG_INFO, "  door %-16s: no closed leaf: skipped", rec->name);
      continue;
    }
    door_job jb = {d, pd->light_enabled, pd->sky, pd->emissive, img, 0, UINT32_MAX, NULL,
                   0, 0, 0, 0, 0, "door"};
    r = door_one(dd, &jb, &w, log, rec, out_stats);
    if (r == UB_OK)
      out_stats->doors_baked++;
  }
  for (uint32_t a = 0; img && a < lm->atlas_count; a++)
    free(img[a]);
  free(img);
  work_free(&w, lm);
  if (r != UB_OK) {
    ub_dls_records_free(recs, s->door_count);
    return r;
  }
  *out_records = recs;
  return UB_OK;
}

/* Entries common to two ascending index lists. */
static uint32_t common_count(const uint32_t *a, uint32_t na, const uint32_t *b, uint32_t nb)
{
  uint32_t i = 0, j = 0, n = 0;
  while (i < na && j < nb) {
    if (a[i] < b[j])
      i++;
    else if (a[i] > b[j])
      j++;
    else
      n++, i++, j++;
  }
  return n;
}

/* A combination's outcome: baked or skipped (empty correction), why, counted and logged. */
static void combo_note(ub_plan_combo *pc, ub_door_stats *st, const ub_log *log,
                       const char *door_name, int empty, uint32_t ct, uint32_t cp, uint32_t cl,
                       const ub_bakefile_record *rec)
{
  pc->baked = !empty;
  snprintf(pc->why, sizeof pc->why, "%s: tagged, influence regions overlap in %u texel "
           "pixels, %u probes, %u LLG probes%s", empty ? "skipped" : "baked", ct, cp, cl,
           empty ? ", but the correction is empty" : "");
  if (empty)
    st->combos_skipped++;
  else
    st->combos_baked++;
  ub_log_printf(log, UB_LOG_INFO, "  combination %s x %s: %s (record %u pixels, %u "
                "probes, %u LLG probes)", door_name, pc->name, pc->why,
                empty ? 0 : rec->texel_count, empty ? 0 : rec->probe_count,
                empty ? 0 : rec->llg_probe_count);
}

/* Door × door (a = pc->door, b = pc->other): C = L(both) − L(a) − L(b) + L(none) =
 * S_a|b open − S_a. Door a's pass runs twice with the same random numbers as its own
 * record (correlated, so the difference is low-noise): in the state "b open" (b's closed
 * leaf gone, its open pose in, the stored lighting base + b's record) with its own
 * influence, then in the base state over the same receivers. */
static ub_result door_pair(const ub_door_desc *dd, ub_plan_combo *pc, const ub_log *log,
                           door_work *w, ub_bakefile_record **io_elems, uint32_t *io_count,
                           ub_door_stats *st)
{
  const ub_pass_desc *pd = dd->base;
  const ub_scene *s = pd->scene;
  const ub_lightmap *lm = pd->lightmap;
  uint32_t a = pc->door, b = (uint32_t)pc->other;
  uint32_t T = lm->texel_count, P = pd->probe_count;
  uint32_t L = pd->llg ? pd->llg->probe_count : 0;
  if (a >= *io_count || b >= *io_count || (*io_elems)[a].kind != UB_ELEMENT_DOOR ||
      (*io_elems)[b].kind != UB_ELEMENT_DOOR)
    return UB_ERR_INVALID_ARGUMENT;
  const ub_bakefile_record *ra = &(*io_elems)[a], *rb = &(*io_elems)[b];
  uint32_t ct = common_count(ra->texel_index, ra->texel_count, rb->texel_index, rb->texel_count);
  uint32_t cp = common_count(ra->probe_index, ra->probe_count, rb->probe_index, rb->probe_count);
  uint32_t cl = common_count(ra->llg_probe_index, ra->llg_probe_count, rb->llg_probe_index,
                             rb->llg_probe_count);
  if (ct + cp + cl == 0) {
    pc->baked = 0;
    snprintf(pc->why, sizeof pc->why, "skipped: tagged, but the influence regions do not "
             "overlap (door %u / door %u pixels)", ra->texel_count, rb->texel_count);
    st->combos_skipped++;
    ub_log_printf(log, UB_LOG_INFO, "  combination %s x %s: %s", s->door_names[a], pc->name,
                  pc->why);
    return UB_OK;
  }
  float *iz = malloc(((size_t)T * 3 + 1) * sizeof *iz);
  float *sh = malloc(((size_t)T * 12 + 1) * sizeof *sh);
  float *c12 = malloc(((size_t)T * 12 + 1) * sizeof *c12);
  float *c27 = malloc(((size_t)P * 27 + 1) * sizeof *c27);
  float *cl27 = malloc(((size_t)L * 27 + 1) * sizeof *cl27);
  uint8_t *mask = NULL;
  float **img_b = NULL, **img_0 = NULL;
  ub_rt *rt_b = NULL;
  ub_bakefile_record rec;
  memset(&rec, 0, sizeof rec);
  ub_result r = iz && sh && c12 && c27 && cl27 ? UB_OK : UB_ERR_OUT_OF_MEMORY;
  if (r == UB_OK) {
    ub_record_texel_iz(lm, rb, iz, sh);
    for (size_t i = 0; i < (size_t)T * 3; i++)
      iz[i] += dd->base_result->iz[i];
    r = build_images(lm, iz, &img_b);
  }
  if (r == UB_OK)
    r = build_images(lm, dd->base_result->iz, &img_0);
  if (r == UB_OK) {
    memset(w->open, 0, s->door_count + 1);
    w->open[b] = 1;
    ub_geom_state gs = {w->open, NULL};
    mask = ub_geom_mask(s, &gs);
    r = mask ? ub_rt_create(s, mask, log, &rt_b) : UB_ERR_OUT_OF_MEMORY;
  }
  snprintf(rec.name, sizeof rec.name, "%.30s*%.30s", s->door_names[a], s->door_names[b]);
  rec.kind = UB_ELEMENT_COMBO;
  rec.parent[0] = (int32_t)(s->dls_count + a);
  rec.parent[1] = (int32_t)(s->dls_count + b);
  door_job jb = {a, pd->light_enabled, pd->sky, pd->emissive, img_b, 0, b, rt_b,
                 0, 1, 0, 0, 0, "combination"};
  if (r == UB_OK)
    r = door_one(dd, &jb, w, log, &rec, st);
  if (r == UB_OK) {
    for (uint32_t i = 0; i < jb.nkt; i++)
      memcpy(c12 + 12 * (size_t)w->kt[i], w->t12 + 12 * (size_t)w->kt[i], 12 * sizeof(float));
    for (uint32_t i = 0; i < jb.nkp; i++)
      memcpy(c27 + 27 * (size_t)w->kp[i], w->p27 + 27 * (size_t)w->kp[i], 27 * sizeof(float));
    for (uint32_t i = 0; i < jb.nkl; i++)
      memcpy(cl27 + 27 * (size_t)w->kl[i], w->l27 + 27 * (size_t)w->kl[i], 27 * sizeof(float));
    door_job j0 = {a, pd->light_enabled, pd->sky, pd->emissive, img_0, 0, UINT32_MAX, NULL,
                   1, 1, jb.nkt, jb.nkp, jb.nkl, "combination base"};
    r = door_one(dd, &j0, w, log, &rec, st);
  }
  if (r == UB_OK) {
    for (uint32_t i = 0; i < jb.nkt; i++)
      for (int k = 0; k < 12; k++)
        c12[12 * (size_t)w->kt[i] + k] -= w->t12[12 * (size_t)w->kt[i] + k];
    for (uint32_t i = 0; i < jb.nkp; i++)
      for (int k = 0; k < 27; k++)
        c27[27 * (size_t)w->kp[i] + k] -= w->p27[27 * (size_t)w->kp[i] + k];
    for (uint32_t i = 0; i < jb.nkl; i++)
      for (int k = 0; k < 27; k++)
        cl27[27 * (size_t)w->kl[i] + k] -= w->l27[27 * (size_t)w->kl[i] + k];
    r = ub_dls_texel_record(lm, w->kt, jb.nkt, c12, &rec);
  }
  if (r == UB_OK)
    r = probe_record(w->kp, jb.nkp, c27, &rec.probe_count, &rec.probe_index, &rec.probe_sh);
  if (r == UB_OK)
    r = probe_record(w->kl, jb.nkl, cl27, &rec.llg_probe_count, &rec.llg_probe_index,
                     &rec.llg_probe_sh);
  int empty = !rec.texel_count && !rec.probe_count && !rec.llg_probe_count;
  if (r == UB_OK && !empty)
    r = ub_records_append(io_elems, io_count, &rec, 1);
  if (r != UB_OK || empty) {
    free(rec.texel_index), free(rec.texel_sh), free(rec.probe_index), free(rec.probe_sh);
    free(rec.llg_probe_index), free(rec.llg_probe_sh);
  }
  if (r == UB_OK)
    combo_note(pc, st, log, s->door_names[a], empty, ct, cp, cl, &rec);
  for (uint32_t k = 0; k < lm->atlas_count; k++) {
    if (img_b)
      free(img_b[k]);
    if (img_0)
      free(img_0[k]);
  }
  free(img_b), free(img_0), free(mask);
  ub_rt_free(rt_b);
  free(iz), free(sh), free(c12), free(c27), free(cl27);
  return r;
}

ub_result ub_door_combine(const ub_door_desc *dd, ub_plan *plan,
                          const ub_bakefile_record *dls, const ub_log *log,
                          ub_bakefile_record **io_elems, uint32_t *io_count,
                          ub_door_stats *io_stats)
{
  const ub_pass_desc *pd = dd->base;
  const ub_scene *s = pd->scene;
  const ub_lightmap *lm = pd->lightmap;
  if (plan->combo_count == 0)
    return UB_OK;
  uint32_t T = lm->texel_count, P = pd->probe_count;
  uint32_t L = pd->llg ? pd->llg->probe_count : 0;
  door_work w;
  float *iz = malloc(((size_t)T * 3 + 1) * sizeof *iz);
  float *sh = malloc(((size_t)T * 12 + 1) * sizeof *sh);
  uint8_t *lights = calloc(s->light_count + 1, 1);
  ub_result r = UB_OK;
  if (!work_alloc(&w, s, T, P, L) || !iz || !sh || !lights)
    r = UB_ERR_OUT_OF_MEMORY;
  for (uint32_t k = 0; k < plan->combo_count && r == UB_OK; k++) {
    ub_plan_combo *pc = &plan->combos[k];
    const char *dn = s->door_names[pc->door];
    if (pc->other >= 0 && (uint32_t)pc->other < s->door_count) {
      r = door_pair(dd, pc, log, &w, io_elems, io_count, io_stats);
      continue;
    }
    if (pc->set < 0 || !dls || (uint32_t)pc->set >= s->dls_count) {
      io_stats->combos_skipped++;
      ub_log_printf(log, UB_LOG_INFO, "  combination %s x %s: %s", dn, pc->name, pc->why);
      continue;
    }
    /* The door's own record: elements [0, door_count) are the doors, in order. */
    const ub_bakefile_record *drec = pc->door < *io_count ? &(*io_elems)[pc->door] : NULL;
    const ub_bakefile_record *srec = &dls[pc->set];
    if (!drec || drec->kind != UB_ELEMENT_DOOR || strcmp(drec->name, dn)) {
      r = UB_ERR_INVALID_ARGUMENT;
      break;
    }
    uint32_t ct = common_count(drec->texel_index, drec->texel_count, srec->texel_index,
                               srec->texel_count);
    uint32_t cp = common_count(drec->probe_index, drec->probe_count, srec->probe_index,
                               srec->probe_count);
    uint32_t cl = common_count(drec->llg_probe_index, drec->llg_probe_count,
                               srec->llg_probe_index, srec->llg_probe_count);
    if (ct + cp + cl == 0) {
      pc->baked = 0;
      snprintf(pc->why, sizeof pc->why, "skipped: tagged, but the influence regions do not "
               "overlap (door %u / set %u pixels, %u / %u probes)", drec->texel_count,
               srec->texel_count, drec->probe_count, srec->probe_count);
      io_stats->combos_skipped++;
      ub_log_printf(log, UB_LOG_INFO, "  combination %s x %s: %s", dn, pc->name, pc->why);
      continue;
    }
    /* L_set(open) − L_set(closed): the door pass with the set's lights, reading the set's
     * stored lighting (its record) where the base pass reads the base. */
    ub_record_texel_iz(lm, srec, iz, sh);
    float **img = NULL;
    r = build_images(lm, iz, &img);
    for (uint32_t l = 0; l < s->light_count; l++)
      lights[l] = s->lights[l].dls == pc->set && plan->dls_light_reaches[l];
    ub_bakefile_record rec;
    memset(&rec, 0, sizeof rec);
    snprintf(rec.name, sizeof rec.name, "%.30s*%.30s", s->dls_names[pc->set], dn);
    rec.kind = UB_ELEMENT_COMBO;
    rec.parent[0] = pc->set;
    rec.parent[1] = (int32_t)(s->dls_count + pc->door);
    if (r == UB_OK) {
      door_job jb = {pc->door, lights, 0, 0, img,
                     0x10000u * (1u + ((uint32_t)pc->set & 0x1FFu)), UINT32_MAX, NULL, 0, 0,
                     0, 0, 0, "combination"};
      r = door_one(dd, &jb, &w, log, &rec, io_stats);
    }
    for (uint32_t a = 0; img && a < lm->atlas_count; a++)
      free(img[a]);
    free(img);
    int empty = !rec.texel_count && !rec.probe_count && !rec.llg_probe_count;
    if (r == UB_OK && !empty)
      r = ub_records_append(io_elems, io_count, &rec, 1);
    if (r != UB_OK || empty) {
      free(rec.texel_index), free(rec.texel_sh), free(rec.probe_index), free(rec.probe_sh);
      free(rec.llg_probe_index), free(rec.llg_probe_sh);
      if (r != UB_OK)
        break;
    }
    combo_note(pc, io_stats, log, dn, empty, ct, cp, cl, &rec);
  }
  work_free(&w, lm);
  free(iz);
  free(sh);
  free(lights);
  return r;
}
