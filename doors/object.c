/* Show/hide objects: influence-bounded, guided difference passes (see object.h). */
#include "doors/object.h"

#include <math.h>
#include <omp.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bake/dls.h"
#include "bake/geomstate.h"
#include "probes/llg.h"
#include "doors/guide.h"
#include "ubake/sh.h"

static const double Y0 = 0.282094792, Y1 = 0.488602512;

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

static inline double lum(const double *c) { return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]; }

static inline void sh_add(double *sh, uint32_t nsh, const float w[3], const double L[3], double wt)
{
  float y[9];
  ub_sh2_eval_basis(w, y);
  for (uint32_t k = 0; k < nsh; k++)
    for (int c = 0; c < 3; c++)
      sh[k * 3 + c] += (double)y[k] * L[c] * wt;
}

/* ---- lightmap fields: per-texel irradiance, read bilinearly at gather hits ---------- */

typedef struct field {
  uint32_t atlas_count;
  float **img; /* per atlas: w×h×4 (irradiance rgb, weight), dilated */
} field;

static void field_free(field *f)
{
  if (f->img)
    for (uint32_t a = 0; a < f->atlas_count; a++)
      free(f->img[a]);
  free(f->img);
  f->img = NULL;
}

/* iz: texel_count × 3 (NULL entries allowed through `only`: texels not listed are 0 but
 * still covered, so lookups there read 0 instead of a neighbour's value). */
static int field_build(const ub_lightmap *lm, const float *iz, field *out)
{
  out->atlas_count = lm->atlas_count;
  out->img = calloc(lm->atlas_count ? lm->atlas_count : 1, sizeof *out->img);
  if (!out->img)
    return 0;
  for (uint32_t a = 0; a < lm->atlas_count; a++) {
    const ub_atlas *at = &lm->atlases[a];
    size_t npx = (size_t)at->width * at->height;
    float *img = malloc(npx * 4 * sizeof(float) + 1);
    out->img[a] = img;
    if (!img || !ub_lightmap_image_fill(lm, a, iz, NULL, img)) {
      field_free(out);
      return 0;
    }
  }
  return 1;
}


/* ---- one difference pass ---------------------------------------------------------- */

typedef struct job {
  const ub_pass_desc *d;
  const ub_rt *rt_s, *rt_h;   /* shown / hidden geometry */
  /* LLG probes (the object's own record only; NULL: none): the same two geometries
   * without the LLG models, as LLG probes see the level (probes/llg.h) */
  const ub_rt *rt_s_env, *rt_h_env;
  const uint8_t *lights;      /* light_count: lights of this pass */
  int sky, emissive;          /* non-punctual emitters of this pass */
  const uint8_t *tri_obj;     /* triangle_count: 1 = the toggled object */
  ub_obb box;
  ub_guide guide;
  const field *ls;            /* L_s: the stored lighting of this pass, shown geometry */
  /* L_s per texel (texel_count × 12 SH, × 3 I_z), or NULL: texels under the object (their
   * base sample points were moved off its back faces) get D = L_s − L_h with L_h traced
   * from points on the texel itself in the hidden geometry. */
  const float *ref_sh, *ref_iz;
  uint32_t pass_id;
  /* receivers (candidates) */
  const uint32_t *kt, *kp, *kl;
  uint32_t nkt, nkp, nkl;
  /* results over the candidates */
  double *t_sh, *t_iz, *p_sh, *l_sh; /* nkt × 12, nkt × 3, nkp × 27, nkl × 27 */
  _Atomic uint64_t rays;
} job;

/* Does the segment from p along unit dir, length dist, meet the object's box? */
static int seg_box(const job *j, const float p[3], const float dir[3], float dist)
{
  float t0, t1;
  return ub_obb_ray(&j->box, p, dir, &t0, &t1) && t0 < dist;
}

/* Primary lights' direct radiance leaving a hit (albedo/π · E), by one light chosen in
 * proportion to its unoccluded irradiance; vis_s/vis_h: visibility in either geometry.
 * which: 1 = shown only, 2 = hidden only, 3 = the difference shown − hidden (rays traced
 * only when the segment meets the box; else 0). */
static void primary_at(job *j, const float hp[3], const float hn[3], uint32_t tri, uint32_t id,
                       uint32_t k, int which, double out[3])
{
  const ub_scene *s = j->d->scene;
  out[0] = out[1] = out[2] = 0.0;
  double total = 0.0, wl[64];
  uint32_t nl = s->light_count < 64 ? s->light_count : 64;
  const ub_rt *rt0 = which == 2 ? j->rt_h : j->rt_s;
  float po[3];
  ub_rt_offset_point(rt0, hp, hn, po);
  for (uint32_t l = 0; l < nl; l++) {
    wl[l] = 0.0;
    const ub_light *L = &s->lights[l];
    if (!j->lights[l] || L->cls != UB_LIGHT_PRIMARY)
      continue;
    float dir[3], dist, e[3];
    if (!ub_light_incident(L, po, dir, &dist, e))
      continue;
    float cs = dot3(hn, dir);
    if (cs <= 0.0f)
      continue;
    wl[l] = (0.2126 * e[0] + 0.7152 * e[1] + 0.0722 * e[2]) * cs;
    total += wl[l];
  }
  if (!(total > 0.0))
    return;
  double u = ub_u01(ub_hash4(j->d->seed, j->pass_id * 0x10000u + 0x3000u, id, k)) * total;
  uint32_t pick = 0;
  double acc = 0.0;
  for (uint32_t l = 0; l < nl; l++) {
    if (wl[l] <= 0.0)
      continue;
    pick = l;
    acc += wl[l];
    if (u < acc)
      break;
  }
  float dir[3], dist, e[3];
  ub_light_incident(&s->lights[pick], po, dir, &dist, e);
  if (which == 3 && !seg_box(j, po, dir, dist))
    return;
  ub_ray r;
  memcpy(r.org, po, sizeof po);
  memcpy(r.dir, dir, sizeof dir);
  r.tnear = 0.0f;
  r.tfar = isfinite(dist) ? dist * (1.0f - 1e-4f) : INFINITY;
  uint8_t occ_s = 0, occ_h = 0;
  double vis;
  if (which == 1) {
    ub_rt_occluded(j->rt_s, &r, 1, &occ_s);
    vis = !occ_s;
  } else if (which == 2) {
    ub_rt_occluded(j->rt_h, &r, 1, &occ_h);
    vis = !occ_h;
  } else {
    ub_rt_occluded(j->rt_s, &r, 1, &occ_s);
    ub_rt_occluded(j->rt_h, &r, 1, &occ_h);
    vis = (double)!occ_s - (double)!occ_h;
  }
  atomic_fetch_add(&j->rays, which == 3 ? 2 : 1);
  if (vis == 0.0)
    return;
  double scale = dot3(hn, dir) * total / wl[pick];
  const float *alb = s->materials[s->tri_material[tri]].albedo;
  for (int c = 0; c < 3; c++)
    out[c] = vis * alb[c] * M_1_PI * e[c] * scale;
}

/* Radiance the ray sees at its hit in one geometry: emission + albedo/π · (field there
 * [+ primary NEE]); sky on a miss. which: 1 shown, 2 hidden (for primary_at). */
static void hit_radiance(job *j, const field *f, int with_sky, int which, const ub_ray *ray,
                         const ub_hit *h, uint32_t id, uint32_t k, double L[3])
{
  const ub_scene *s = j->d->scene;
  const ub_lightmap *lm = j->d->lightmap;
  L[0] = L[1] = L[2] = 0.0;
  if (h->tri == UB_RT_MISS) {
    if (with_sky && j->sky)
      for (int c = 0; c < 3; c++)
        L[c] = s->sky[c];
    return;
  }
  if (dot3(h->ng, ray->dir) >= 0.0f)
    return; /* back face */
  const ub_material *m = &s->materials[s->tri_material[h->tri]];
  if (with_sky && j->emissive)
    for (int c = 0; c < 3; c++)
      L[c] += m->emission[c];
  int32_t a = lm->tri_atlas[h->tri];
  if (a >= 0 && f) {
    const float *uv = lm->tri_uv + 6 * (size_t)h->tri;
    float b0 = 1.0f - h->u - h->v;
    float u = b0 * uv[0] + h->u * uv[2] + h->v * uv[4];
    float v = b0 * uv[1] + h->u * uv[3] + h->v * uv[5];
    float e[3];
    ub_lightmap_image_sample(lm, f->img[a], (uint32_t)a, u, v, e);
    for (int c = 0; c < 3; c++)
      L[c] += m->albedo[c] * M_1_PI * e[c];
  }
  if (with_sky) {
    float gl = sqrtf(dot3(h->ng, h->ng));
    if (!(gl > 0.0f))
      return;
    float hn[3] = {h->ng[0] / gl, h->ng[1] / gl, h->ng[2] / gl};
    float hp[3] = {ray->org[0] + h->t * ray->dir[0], ray->org[1] + h->t * ray->dir[1],
                   ray->org[2] + h->t * ray->dir[2]};
    double p[3];
    primary_at(j, hp, hn, h->tri, id, k, which, p);
    for (int c = 0; c < 3; c++)
      L[c] += p[c];
  }
}


/* Is texel t under the object (its centre, just off the surface, inside the box)? */
static int texel_covered(const job *j, uint32_t t)
{
  const ub_lightmap *lm = j->d->lightmap;
  float q[3];
  ub_rt_offset_point(j->rt_h, lm->texel_pos + 3 * (size_t)t, lm->texel_normal + 3 * (size_t)t, q);
  return ub_obb_contains(&j->box, q);
}

/* L_h at a covered texel, first order: static direct + cosine gather of (L_s + P_h) [+ sky,
 * emission] in the hidden geometry, from 2×2 stratified points on the texel itself. */
static void hidden_first_order(job *j, uint32_t t, uint32_t nrays, ub_ray *rays, ub_hit *hits,
                               double *sh, double *iz)
{
  const ub_pass_desc *d = j->d;
  const ub_scene *s = d->scene;
  const ub_lightmap *lm = d->lightmap;
  const float *nrm = lm->texel_normal + 3 * (size_t)t;
  float pts[4][3];
  for (int k = 0; k < 4; k++) {
    float q[3];
    /* past the owning triangle (a chart's edge: maybe past any surface, in a wall),
     * the texel's own sample point of that quadrant, which lies on one */
    if (ub_lightmap_texel_point(s, lm, t, 0.25f + 0.5f * (float)(k & 1),
                                0.25f + 0.5f * (float)(k >> 1), q) != 1)
      memcpy(q, lm->sample_pos + ((size_t)t * UB_TEXEL_SAMPLES + (size_t)k) * 3, sizeof q);
    ub_rt_offset_point(j->rt_h, q, nrm, pts[k]);
  }
  for (uint32_t l = 0; l < s->light_count; l++) {
    const ub_light *L = &s->lights[l];
    if (!j->lights[l] || L->cls == UB_LIGHT_PRIMARY)
      continue;
    for (int k = 0; k < 4; k++) {
      float dir[3], dist, e[3];
      if (!ub_light_incident(L, pts[k], dir, &dist, e))
        continue;
      float cs = dot3(nrm, dir);
      if (cs <= 0.0f)
        continue;
      ub_ray r;
      memcpy(r.org, pts[k], sizeof r.org);
      memcpy(r.dir, dir, sizeof dir);
      r.tnear = 0.0f;
      r.tfar = isfinite(dist) ? dist * (1.0f - 1e-4f) : INFINITY;
      uint8_t oh;
      ub_rt_occluded(j->rt_h, &r, 1, &oh);
      atomic_fetch_add(&j->rays, 1);
      if (oh)
        continue;
      double ev[3] = {e[0] / 4.0, e[1] / 4.0, e[2] / 4.0};
      sh_add(sh, 4, dir, ev, 1.0);
      for (int c = 0; c < 3; c++)
        iz[c] += ev[c] * cs;
    }
  }
  uint32_t kx = (uint32_t)sqrtf((float)nrays);
  kx = kx < 1 ? 1 : kx;
  uint32_t ky = nrays / kx;
  for (uint32_t k = 0; k < nrays; k++) {
    uint32_t h = ub_hash4(d->seed, j->pass_id * 0x10000u + 0x180u, t, k);
    float u1 = ub_u01(h), u2 = ub_u01(ub_hash4(h, 7, 0, 0));
    if (k < kx * ky) {
      u1 = ((float)(k % kx) + u1) / (float)kx;
      u2 = ((float)(k / kx) + u2) / (float)ky;
    }
    memcpy(rays[k].org, pts[k & 3], sizeof rays[k].org);
    ub_sample_cosine(nrm, u1, u2, rays[k].dir);
    rays[k].tnear = 0.0f;
    rays[k].tfar = INFINITY;
  }
  ub_rt_intersect(j->rt_h, rays, nrays, hits);
  atomic_fetch_add(&j->rays, nrays);
  for (uint32_t k = 0; k < nrays; k++) {
    float cs = dot3(nrm, rays[k].dir);
    if (cs <= 1e-4f)
      continue;
    double L[3];
    hit_radiance(j, j->ls, 1, 2, &rays[k], &hits[k], t, k, L);
    double wt = M_PI / (nrays * cs);
    sh_add(sh, 4, rays[k].dir, L, ub_texel_sh_weight(wt, nrays));
    for (int c = 0; c < 3; c++)
      iz[c] += L[c] * cs * wt;
  }
}

/* First order T at one receiver (point samples + optional normal). */
static void first_order(job *j, const float *samples, uint32_t spr, const float *nrm, uint32_t id,
                        uint32_t nsh, uint32_t nrays, ub_ray *rays, ub_hit *hits, double *sh,
                        double *iz)
{
  const ub_pass_desc *d = j->d;
  const ub_scene *s = d->scene;
  uint32_t ns = d->shadow_samples ? d->shadow_samples : 1;
  if (ns > spr)
    ns = spr;
  /* 1. static direct light the object blocks (E_s − E_h) */
  for (uint32_t l = 0; l < s->light_count; l++) {
    const ub_light *L = &s->lights[l];
    if (!j->lights[l] || L->cls == UB_LIGHT_PRIMARY)
      continue;
    for (uint32_t k = 0; k < ns; k++) {
      const float *p = samples + 3 * (size_t)(k % spr);
      float dir[3], dist, e[3];
      if (!ub_light_incident(L, p, dir, &dist, e))
        continue;
      float cs = nrm ? dot3(nrm, dir) : 1.0f;
      if (cs <= 0.0f || !seg_box(j, p, dir, dist))
        continue;
      ub_ray r;
      memcpy(r.org, p, sizeof r.org);
      memcpy(r.dir, dir, sizeof dir);
      r.tnear = 0.0f;
      r.tfar = isfinite(dist) ? dist * (1.0f - 1e-4f) : INFINITY;
      uint8_t os, oh;
      ub_rt_occluded(j->rt_s, &r, 1, &os);
      ub_rt_occluded(j->rt_h, &r, 1, &oh);
      atomic_fetch_add(&j->rays, 2);
      double v = (double)!os - (double)!oh;
      if (v == 0.0)
        continue;
      double ev[3] = {v * e[0] / ns, v * e[1] / ns, v * e[2] / ns};
      sh_add(sh, nsh, dir, ev, 1.0);
      if (iz)
        for (int c = 0; c < 3; c++)
          iz[c] += ev[c] * cs;
    }
  }
  /* 2. guided gather: K_s(L_s + P_s) − K_h(L_s + P_h) */
  double *pdf = malloc(nrays * sizeof *pdf);
  if (!pdf)
    return;
  for (uint32_t k = 0; k < nrays; k++) {
    uint32_t h = ub_hash4(d->seed, j->pass_id * 0x10000u + 0x100u, id, k);
    float u[4] = {ub_u01(h), ub_u01(ub_hash4(h, 1, 0, 0)), ub_u01(ub_hash4(h, 2, 0, 0)),
                  ub_u01(ub_hash4(h, 3, 0, 0))};
    const float *p = samples + 3 * (size_t)(k % spr);
    memcpy(rays[k].org, p, sizeof rays[k].org);
    pdf[k] = ub_guide_sample(&j->guide, p, nrm, u, rays[k].dir);
    rays[k].tnear = 0.0f;
    rays[k].tfar = pdf[k] > 0.0 ? INFINITY : -1.0f;
  }
  ub_rt_intersect(j->rt_s, rays, nrays, hits);
  atomic_fetch_add(&j->rays, nrays);
  for (uint32_t k = 0; k < nrays; k++) {
    if (!(pdf[k] > 0.0) || hits[k].tri == UB_RT_MISS)
      continue;
    const ub_ray *ray = &rays[k];
    float cs = nrm ? dot3(nrm, ray->dir) : 1.0f;
    if (cs <= 1e-4f)
      continue;
    double wt = 1.0 / (nrays * pdf[k]);
    double L[3] = {0, 0, 0};
    const ub_hit *hs = &hits[k];
    if (j->tri_obj[hs->tri]) {
      double Ls[3], Lh[3];
      hit_radiance(j, j->ls, 1, 1, ray, hs, id, k, Ls);
      ub_hit hh;
      ub_rt_intersect(j->rt_h, ray, 1, &hh);
      atomic_fetch_add(&j->rays, 1);
      hit_radiance(j, j->ls, 1, 2, ray, &hh, id, k, Lh);
      for (int c = 0; c < 3; c++)
        L[c] = Ls[c] - Lh[c];
    } else {
      if (dot3(hs->ng, ray->dir) >= 0.0f)
        continue;
      float gl = sqrtf(dot3(hs->ng, hs->ng));
      if (!(gl > 0.0f))
        continue;
      float hn[3] = {hs->ng[0] / gl, hs->ng[1] / gl, hs->ng[2] / gl};
      float hp[3] = {ray->org[0] + hs->t * ray->dir[0], ray->org[1] + hs->t * ray->dir[1],
                     ray->org[2] + hs->t * ray->dir[2]};
      primary_at(j, hp, hn, hs->tri, id, k, 3, L);
    }
    if (!(isfinite(L[0]) && isfinite(L[1]) && isfinite(L[2])))
      continue;
    if (L[0] == 0.0 && L[1] == 0.0 && L[2] == 0.0)
      continue;
    sh_add(sh, nsh, ray->dir, L, nrm ? ub_texel_sh_weight(wt, nrays) : wt);
    if (iz)
      for (int c = 0; c < 3; c++)
        iz[c] += L[c] * cs * wt;
  }
  free(pdf);
}

/* One iterate of K_h D: cosine (sphere) gather in the hidden geometry reading prev. */
static void gather_prev(job *j, const field *prev, const float *samples, uint32_t spr,
                        const float *nrm, uint32_t id, uint32_t bounce, uint32_t nsh,
                        uint32_t nrays, ub_ray *rays, ub_hit *hits, double *sh, double *iz)
{
  const ub_pass_desc *d = j->d;
  uint32_t kx = (uint32_t)sqrtf((float)nrays);
  kx = kx < 1 ? 1 : kx;
  uint32_t ky = nrays / kx;
  for (uint32_t k = 0; k < nrays; k++) {
    uint32_t h = ub_hash4(d->seed, j->pass_id * 0x10000u + 0x200u + bounce, id, k);
    float u1 = ub_u01(h), u2 = ub_u01(ub_hash4(h, 7, 0, 0));
    if (k < kx * ky) {
      u1 = ((float)(k % kx) + u1) / (float)kx;
      u2 = ((float)(k / kx) + u2) / (float)ky;
    }
    const float *p = samples + 3 * (size_t)(k % spr);
    memcpy(rays[k].org, p, sizeof rays[k].org);
    if (nrm) {
      ub_sample_cosine(nrm, u1, u2, rays[k].dir);
    } else {
      float z = 1.0f - 2.0f * u1, rr = sqrtf(fmaxf(0.0f, 1.0f - z * z)), phi = 2.0f * (float)M_PI * u2;
      rays[k].dir[0] = rr * cosf(phi);
      rays[k].dir[1] = z;
      rays[k].dir[2] = rr * sinf(phi);
    }
    rays[k].tnear = 0.0f;
    rays[k].tfar = INFINITY;
  }
  ub_rt_intersect(j->rt_h, rays, nrays, hits);
  atomic_fetch_add(&j->rays, nrays);
  for (uint32_t k = 0; k < nrays; k++) {
    float cs = nrm ? dot3(nrm, rays[k].dir) : 1.0f;
    if (cs <= 1e-4f || hits[k].tri == UB_RT_MISS)
      continue;
    double pdf = nrm ? cs / M_PI : 1.0 / (4.0 * M_PI);
    double L[3];
    hit_radiance(j, prev, 0, 2, &rays[k], &hits[k], id, k, L);
    if (L[0] == 0.0 && L[1] == 0.0 && L[2] == 0.0)
      continue;
    double wt = 1.0 / (nrays * pdf);
    sh_add(sh, nsh, rays[k].dir, L, nrm ? ub_texel_sh_weight(wt, nrays) : wt);
    if (iz)
      for (int c = 0; c < 3; c++)
        iz[c] += L[c] * cs * wt;
  }
}

/* Runs T then K_h iterations over the job's candidates; fills t_sh/t_iz/p_sh. */
static ub_result job_run(job *j)
{
  const ub_pass_desc *d = j->d;
  const ub_lightmap *lm = d->lightmap;
  uint32_t T = lm->texel_count;
  uint32_t N = d->gather_rays ? d->gather_rays : 64;
  uint32_t NP = d->probe_rays ? d->probe_rays : 2 * N;
  uint32_t NMAX = N > NP ? N : NP;
  /* K_h D iterates read a smooth, small field: half the rays (at least 16) */
  uint32_t NI = N / 2 < 16 ? 16 : N / 2, NPI = NP / 2 < 16 ? 16 : NP / 2;
  j->t_sh = calloc((size_t)j->nkt * 12 + 1, sizeof(double));
  j->t_iz = calloc((size_t)j->nkt * 3 + 1, sizeof(double));
  j->p_sh = calloc((size_t)j->nkp * 27 + 1, sizeof(double));
  j->l_sh = calloc((size_t)j->nkl * 27 + 1, sizeof(double));
  double *b_l = calloc((size_t)j->nkl * 27 + 1, sizeof(double));
  /* LLG probes: the same job, rays against the level without LLG models */
  job jl = *j;
  jl.rt_s = j->rt_s_env ? j->rt_s_env : j->rt_s;
  jl.rt_h = j->rt_h_env ? j->rt_h_env : j->rt_h;
  atomic_init(&jl.rays, 0);
  double *b_sh = calloc((size_t)j->nkt * 12 + 1, sizeof(double));
  double *b_iz = calloc((size_t)j->nkt * 3 + 1, sizeof(double));
  double *b_p = calloc((size_t)j->nkp * 27 + 1, sizeof(double));
  float *prev_iz = calloc((size_t)T * 3 + 1, sizeof(float));
  if (!j->t_sh || !j->t_iz || !j->p_sh || !j->l_sh || !b_l || !b_sh || !b_iz || !b_p ||
      !prev_iz) {
    free(b_l);
    free(b_sh);
    free(b_iz);
    free(b_p);
    free(prev_iz);
    return UB_ERR_OUT_OF_MEMORY;
  }
  int oom = 0;
  int max_it = d->bounces < 0 ? UB_OBJ_MAX_ITER : (d->bounces > 1 ? d->bounces - 1 : 0);
  if (max_it > UB_OBJ_MAX_ITER)
    max_it = UB_OBJ_MAX_ITER;
  double total = 0.0;
  field prev = {0, NULL};
  for (int it = 0; it <= max_it && !oom; it++) {
    memset(b_sh, 0, (size_t)j->nkt * 12 * sizeof(double));
    memset(b_iz, 0, (size_t)j->nkt * 3 * sizeof(double));
    memset(b_p, 0, (size_t)j->nkp * 27 * sizeof(double));
    memset(b_l, 0, (size_t)j->nkl * 27 * sizeof(double));
    uint32_t nall = j->nkt + j->nkp + j->nkl;
#pragma omp parallel
    {
      ub_ray *rays = malloc((size_t)NMAX * sizeof *rays);
      ub_hit *hits = malloc((size_t)NMAX * sizeof *hits);
      if (!rays || !hits) {
#pragma omp atomic write
        oom = 1;
      }
#pragma omp for schedule(dynamic, 16)
      for (uint32_t i = 0; i < nall; i++) {
        if (!rays || !hits)
          continue;
        if (i < j->nkt) {
          uint32_t t = j->kt[i];
          const float *smp = lm->sample_pos + (size_t)t * UB_TEXEL_SAMPLES * 3;
          const float *nrm = lm->texel_normal + 3 * (size_t)t;
          if (it == 0 && j->ref_sh && texel_covered(j, t)) {
            /* D = L_s − L_h: the stored value minus a hidden-geometry estimate */
            double *sh = b_sh + 12 * (size_t)i, *iz = b_iz + 3 * (size_t)i;
            hidden_first_order(j, t, N, rays, hits, sh, iz);
            for (int k = 0; k < 12; k++)
              sh[k] = j->ref_sh[12 * (size_t)t + k] - sh[k];
            for (int c = 0; c < 3; c++)
              iz[c] = j->ref_iz[3 * (size_t)t + c] - iz[c];
          } else if (it == 0)
            first_order(j, smp, UB_TEXEL_SAMPLES, nrm, t, 4, N, rays, hits, b_sh + 12 * (size_t)i,
                        b_iz + 3 * (size_t)i);
          else
            gather_prev(j, &prev, smp, UB_TEXEL_SAMPLES, nrm, t, (uint32_t)it, 4, NI, rays, hits,
                        b_sh + 12 * (size_t)i, b_iz + 3 * (size_t)i);
        } else if (i >= j->nkt + j->nkp) {
          uint32_t q = j->kl[i - j->nkt - j->nkp];
          const float *pp = d->llg->probe_pos + 3 * (size_t)q;
          uint32_t id = 0x80000000u + q;
          double *dst = b_l + 27 * (size_t)(i - j->nkt - j->nkp);
          if (it == 0)
            first_order(&jl, pp, 1, NULL, id, 9, NP, rays, hits, dst, NULL);
          else
            gather_prev(&jl, &prev, pp, 1, NULL, id, (uint32_t)it, 9, NPI, rays, hits, dst, NULL);
        } else {
          uint32_t q = j->kp[i - j->nkt];
          const float *pp = d->probe_pos + 3 * (size_t)q;
          uint32_t id = 0x40000000u + q;
          if (it == 0)
            first_order(j, pp, 1, NULL, id, 9, NP, rays, hits, b_p + 27 * (size_t)(i - j->nkt),
                        NULL);
          else
            gather_prev(j, &prev, pp, 1, NULL, id, (uint32_t)it, 9, NPI, rays, hits,
                        b_p + 27 * (size_t)(i - j->nkt), NULL);
        }
      }
      free(rays);
      free(hits);
    }
    double e = 0.0;
    for (size_t i = 0; i < (size_t)j->nkt * 12; i++)
      j->t_sh[i] += b_sh[i];
    for (size_t i = 0; i < (size_t)j->nkt * 3; i++)
      j->t_iz[i] += b_iz[i];
    for (size_t i = 0; i < (size_t)j->nkp * 27; i++)
      j->p_sh[i] += b_p[i];
    for (size_t i = 0; i < (size_t)j->nkl * 27; i++)
      j->l_sh[i] += b_l[i];
    for (uint32_t i = 0; i < j->nkt; i++)
      e += fabs(lum(b_iz + 3 * (size_t)i));
    total += e;
    if (it > 0 && e <= d->stop_fraction * total)
      break;
    if (it == max_it)
      break;
    /* the next iterate reads this bounce's D on the candidates (0 elsewhere) */
    memset(prev_iz, 0, (size_t)T * 3 * sizeof(float));
    for (uint32_t i = 0; i < j->nkt; i++)
      for (int c = 0; c < 3; c++)
        prev_iz[3 * (size_t)j->kt[i] + c] = (float)b_iz[3 * (size_t)i + c];
    field_free(&prev);
    if (!field_build(lm, prev_iz, &prev))
      oom = 1;
  }
  field_free(&prev);
  atomic_fetch_add(&j->rays, atomic_load(&jl.rays));
  free(b_l);
  free(b_sh);
  free(b_iz);
  free(b_p);
  free(prev_iz);
  if (oom)
    return UB_ERR_OUT_OF_MEMORY;
  /* I_z-exact SH, as the base pass stores it (bake/pass.c): a cosine lobe about n adds
   * the difference between the exact irradiance along n and the SH's. Linear in D. */
  const double K = M_PI * M_PI * (Y0 * Y0) + (2.0 * M_PI / 3.0) * (2.0 * M_PI / 3.0) * (Y1 * Y1);
  const double h0 = Y0 * M_PI / K, h1 = Y1 * (2.0 * M_PI / 3.0) / K;
  for (uint32_t i = 0; i < j->nkt; i++) {
    const float *n = lm->texel_normal + 3 * (size_t)j->kt[i];
    double *sh = j->t_sh + 12 * (size_t)i;
    for (int ch = 0; ch < 3; ch++) {
      double e_sh = M_PI * Y0 * sh[ch] +
                    (2.0 * M_PI / 3.0) * Y1 * (sh[3 + ch] * n[1] + sh[6 + ch] * n[2] + sh[9 + ch] * n[0]);
      double delta = j->t_iz[3 * (size_t)i + ch] - e_sh;
      sh[ch] += delta * h0;
      sh[3 + ch] += delta * h1 * n[1];
      sh[6 + ch] += delta * h1 * n[2];
      sh[9 + ch] += delta * h1 * n[0];
    }
  }
  return UB_OK;
}

static void job_free(job *j)
{
  free(j->t_sh);
  free(j->t_iz);
  free(j->p_sh);
  free(j->l_sh);
  j->t_sh = j->t_iz = j->p_sh = j->l_sh = NULL;
}

/* ---- influence region ------------------------------------------------------------- */

static int candidate(const job *j, const float p[3], const float *nrm, float reach2)
{
  const ub_scene *s = j->d->scene;
  for (uint32_t l = 0; l < s->light_count; l++) {
    if (!j->lights[l])
      continue;
    float dir[3], dist, e[3];
    if (!ub_light_incident(&s->lights[l], p, dir, &dist, e))
      continue;
    if ((!nrm || dot3(nrm, dir) > 0.0f) && seg_box(j, p, dir, dist))
      return 1;
  }
  const ub_obb *b = &j->box;
  float dc[3] = {b->c[0] - p[0], b->c[1] - p[1], b->c[2] - p[2]};
  if (dot3(dc, dc) > reach2)
    return 0;
  if (!nrm)
    return 1;
  for (int k = 0; k < 8; k++) {
    float q[3];
    for (int c = 0; c < 3; c++)
      q[c] = b->c[c] + ((k & 1) ? 1.0f : -1.0f) * b->h[0] * b->axis[0][c] +
             ((k & 2) ? 1.0f : -1.0f) * b->h[1] * b->axis[1][c] +
             ((k & 4) ? 1.0f : -1.0f) * b->h[2] * b->axis[2][c];
    float dq[3] = {q[0] - p[0], q[1] - p[1], q[2] - p[2]};
    if (dot3(nrm, dq) > 0.0f)
      return 1;
  }
  return 0;
}

/* Fills j->kt/kp (caller frees) with the candidates of the job's lights and box; kl
 * (may be NULL: none) with the LLG probes' when the job has LLG geometries. */
static ub_result region(job *j, uint32_t **kt, uint32_t **kp, uint32_t **kl)
{
  const ub_pass_desc *d = j->d;
  const ub_lightmap *lm = d->lightmap;
  const ub_scene *s = d->scene;
  float hd = sqrtf(j->box.h[0] * j->box.h[0] + j->box.h[1] * j->box.h[1] + j->box.h[2] * j->box.h[2]);
  float reach = fmaxf(UB_OBJ_REACH_MIN, UB_OBJ_REACH_SIZE * hd) + hd;
  float reach2 = reach * reach;
  *kt = malloc(((size_t)lm->texel_count + 1) * sizeof **kt);
  *kp = malloc(((size_t)d->probe_count + 1) * sizeof **kp);
  if (!*kt || !*kp) {
    free(*kt);
    free(*kp);
    *kt = *kp = NULL;
    return UB_ERR_OUT_OF_MEMORY;
  }
  uint32_t nt = 0, np = 0;
  for (uint32_t t = 0; t < lm->texel_count; t++) {
    if (j->tri_obj[lm->texel_tri[t]])
      continue;
    if (candidate(j, lm->texel_pos + 3 * (size_t)t, lm->texel_normal + 3 * (size_t)t, reach2))
      (*kt)[nt++] = t;
  }
  for (uint32_t q = 0; q < d->probe_count; q++)
    if (candidate(j, d->probe_pos + 3 * (size_t)q, NULL, reach2))
      (*kp)[np++] = q;
  (void)s;
  uint32_t nl = 0;
  const struct ub_llg_set *llg = d->llg;
  if (kl && j->rt_h_env && llg && llg->probe_count) {
    *kl = malloc((size_t)llg->probe_count * sizeof **kl);
    if (!*kl)
      return UB_ERR_OUT_OF_MEMORY;
    for (uint32_t q = 0; q < llg->probe_count; q++)
      if ((!llg->probe_valid || llg->probe_valid[q]) &&
          candidate(j, llg->probe_pos + 3 * (size_t)q, NULL, reach2))
        (*kl)[nl++] = q;
    j->kl = *kl;
  }
  j->nkl = nl;
  j->kt = *kt;
  j->kp = *kp;
  j->nkt = nt;
  j->nkp = np;
  return UB_OK;
}

/* ---- records ---------------------------------------------------------------------- */

/* Builds a record from a job's result over its candidates, keeping receivers whose |D|
 * exceeds keep × ref (ref: per-texel iz / per-probe SH of the lighting it modifies, or
 * NULL: keep every non-zero). Returns the kept count in *out_kept. */
static ub_result make_record(const job *j, const double *t_sh, const double *t_iz,
                             const double *p_sh, const float *ref_iz, const float *ref_probe,
                             const float *ref_llg, double keep, ub_bakefile_record *rec,
                             uint32_t *out_kt, uint32_t *out_kp)
{
  const ub_lightmap *lm = j->d->lightmap;
  uint32_t T = lm->texel_count;
  float *full = calloc((size_t)T * 12 + 1, sizeof(float));
  uint32_t *kept = malloc(((size_t)j->nkt + 1) * sizeof *kept);
  if (!full || !kept) {
    free(full);
    free(kept);
    return UB_ERR_OUT_OF_MEMORY;
  }
  uint32_t nk = 0;
  for (uint32_t i = 0; i < j->nkt; i++) {
    uint32_t t = j->kt[i];
    double a = fabs(lum(t_iz + 3 * (size_t)i));
    double r = 0.0;
    if (ref_iz) {
      double rc[3] = {ref_iz[3 * (size_t)t], ref_iz[3 * (size_t)t + 1], ref_iz[3 * (size_t)t + 2]};
      r = fabs(lum(rc));
    }
    if (!(a > keep * r) || !(a > 0.0))
      continue;
    kept[nk++] = t;
    for (int k = 0; k < 12; k++)
      full[12 * (size_t)t + k] = (float)t_sh[12 * (size_t)i + k];
  }
  ub_result res = ub_dls_texel_record(lm, kept, nk, full, rec);
  free(full);
  free(kept);
  if (res != UB_OK)
    return res;
  rec->probe_index = malloc(((size_t)j->nkp + 1) * sizeof *rec->probe_index);
  rec->probe_sh = malloc(((size_t)j->nkp * 27 + 1) * sizeof *rec->probe_sh);
  if (!rec->probe_index || !rec->probe_sh)
    return UB_ERR_OUT_OF_MEMORY;
  uint32_t np = 0;
  for (uint32_t i = 0; i < j->nkp; i++) {
    uint32_t q = j->kp[i];
    const double *v = p_sh + 27 * (size_t)i;
    double a = fabs(lum(v));
    double r = ref_probe ? fabs(0.2126 * ref_probe[27 * (size_t)q] + 0.7152 * ref_probe[27 * (size_t)q + 1] +
                                0.0722 * ref_probe[27 * (size_t)q + 2])
                         : 0.0;
    if (!(a > keep * r) || !(a > 0.0))
      continue;
    rec->probe_index[np] = q;
    for (int k = 0; k < 27; k++)
      rec->probe_sh[27 * (size_t)np + k] = (float)v[k];
    np++;
  }
  rec->probe_count = np;
  /* LLG probes (the object's own record): kept like GLG probes, against the base grid */
  if (j->nkl) {
    rec->llg_probe_index = malloc((size_t)j->nkl * sizeof *rec->llg_probe_index);
    rec->llg_probe_sh = malloc((size_t)j->nkl * 27 * sizeof *rec->llg_probe_sh);
    if (!rec->llg_probe_index || !rec->llg_probe_sh)
      return UB_ERR_OUT_OF_MEMORY;
    uint32_t nl = 0;
    for (uint32_t i = 0; i < j->nkl; i++) {
      uint32_t q = j->kl[i];
      const double *v = j->l_sh + 27 * (size_t)i;
      double a = fabs(lum(v));
      double r = ref_llg ? fabs(0.2126 * ref_llg[27 * (size_t)q] + 0.7152 * ref_llg[27 * (size_t)q + 1] +
                                0.0722 * ref_llg[27 * (size_t)q + 2])
                         : 0.0;
      if (!(a > keep * r) || !(a > 0.0))
        continue;
      rec->llg_probe_index[nl] = q;
      for (int k = 0; k < 27; k++)
        rec->llg_probe_sh[27 * (size_t)nl + k] = (float)v[k];
      nl++;
    }
    rec->llg_probe_count = nl;
  }
  *out_kt = nk;
  *out_kp = np;
  return UB_OK;
}

ub_result ub_records_append(ub_bakefile_record **io_elems, uint32_t *io_count,
                            const ub_bakefile_record *add, uint32_t n)
{
  if (n == 0)
    return UB_OK;
  ub_bakefile_record *e = realloc(*io_elems, ((size_t)*io_count + n) * sizeof *e);
  if (!e)
    return UB_ERR_OUT_OF_MEMORY;
  memcpy(e + *io_count, add, (size_t)n * sizeof *e);
  *io_elems = e;
  *io_count += n;
  return UB_OK;
}

void ub_record_texel_iz(const ub_lightmap *lm, const ub_bakefile_record *rec, float *out,
                            float *out_sh)
{
  memset(out, 0, (size_t)lm->texel_count * 3 * sizeof(float));
  memset(out_sh, 0, (size_t)lm->texel_count * 12 * sizeof(float));
  for (uint32_t t = 0; t < lm->texel_count && rec->texel_count; t++) {
    uint32_t px = ub_dls_texel_pixel(lm, t);
    uint32_t lo = 0, hi = rec->texel_count;
    while (lo < hi) {
      uint32_t mid = (lo + hi) / 2;
      if (rec->texel_index[mid] < px)
        lo = mid + 1;
      else
        hi = mid;
    }
    if (lo >= rec->texel_count || rec->texel_index[lo] != px)
      continue;
    const float *sh = rec->texel_sh + 12 * (size_t)lo;
    memcpy(out_sh + 12 * (size_t)t, sh, 12 * sizeof(float));
    const float *n = lm->texel_normal + 3 * (size_t)t;
    for (int c = 0; c < 3; c++)
      out[3 * (size_t)t + c] = (float)(M_PI * Y0 * sh[c] +
                                       (2.0 * M_PI / 3.0) * Y1 *
                                           (sh[3 + c] * n[1] + sh[6 + c] * n[2] + sh[9 + c] * n[0]));
  }
}

/* Per-object data kept between the stages. */
typedef struct obj_data {
  int baked;
  uint8_t *tri;        /* triangle_count: this object's triangles */
  ub_obb box;
  ub_rt *rt_h;         /* base minus the object */
  job j;               /* its base-lights job: candidates and D over them */
  uint32_t *kt, *kp, *kl;
  ub_rt *rt_h_env;     /* base minus the object minus the LLG models (NULL: no LLG) */
  int32_t elem;        /* index in the element array */
  double sum;          /* Σ|D| (luminance) over texels */
} obj_data;

static void job_init(job *j, const ub_pass_desc *d, const ub_rt *rt_s, const ub_rt *rt_h,
                     const uint8_t *lights, int sky, int emissive, const obj_data *o,
                     const field *ls, uint32_t pass_id)
{
  memset(j, 0, sizeof *j);
  j->d = d;
  j->rt_s = rt_s;
  j->rt_h = rt_h;
  j->lights = lights;
  j->sky = sky;
  j->emissive = emissive;
  j->tri_obj = o->tri;
  j->box = o->box;
  ub_guide_init(&j->guide, &o->box, 1, NULL, UB_OBJ_GUIDE_COSINE);
  j->ls = ls;
  j->pass_id = pass_id;
  atomic_init(&j->rays, 0);
}

ub_result ub_object_bake(const ub_pass_desc *base, const ub_plan *plan,
                         const ub_pass_result *base_res, const ub_bakefile_record *dls,
                         const ub_log *log, ub_bakefile_record **io_elems, uint32_t *io_count,
                         ub_object_stats *out_stats)
{
  const ub_scene *s = base->scene;
  const ub_lightmap *lm = base->lightmap;
  memset(out_stats, 0, sizeof *out_stats);
  out_stats->objects = s->object_count;
  if (s->object_count == 0)
    return UB_OK;
  double t0 = now_s();
  uint32_t O = s->object_count, T = lm->texel_count;
  obj_data *od = calloc(O, sizeof *od);
  field ls_base = {0, NULL};
  ub_result r = UB_OK;
  if (!od || !field_build(lm, base_res->iz, &ls_base)) {
    free(od);
    field_free(&ls_base);
    return UB_ERR_OUT_OF_MEMORY;
  }
  uint8_t *shown = malloc(O);
  uint32_t first_obj = *io_count;
  if (!shown)
    r = UB_ERR_OUT_OF_MEMORY;
  /* 1. one record per object, base lights */
  for (uint32_t o = 0; o < O && r == UB_OK; o++) {
    obj_data *d = &od[o];
    d->elem = -1;
    d->tri = calloc((size_t)s->triangle_count + 1, 1);
    if (!d->tri) {
      r = UB_ERR_OUT_OF_MEMORY;
      break;
    }
    uint32_t ntri = 0;
    for (uint32_t n = 0; n < s->node_count; n++) {
      const ub_node *nd = &s->nodes[n];
      if (nd->semidynamic == (int32_t)o) {
        memset(d->tri + nd->first_triangle, 1, nd->triangle_count);
        ntri += nd->triangle_count;
      }
    }
    float *pts = malloc(((size_t)ntri * 3 + 1) * 3 * sizeof(float));
    if (!pts) {
      r = UB_ERR_OUT_OF_MEMORY;
      break;
    }
    uint32_t np = 0;
    for (uint32_t t = 0; t < s->triangle_count; t++)
      if (d->tri[t])
        for (int k = 0; k < 3; k++)
          memcpy(pts + 3 * (size_t)np++, s->positions + 3 * (size_t)s->indices[3 * (size_t)t + k],
                 3 * sizeof(float));
    int ok = ub_obb_fit(pts, np, 0.01f, &d->box);
    free(pts);
    if (!ok) {
      ub_log_printf(log, UB_LOG_WARNING, "  object %-14s: no geometry: skipped", s->object_names[o]);
      continue;
    }
    memset(shown, 1, O);
    shown[o] = 0;
    ub_geom_state gs = {NULL, shown};
    uint8_t *mask = ub_geom_mask(s, &gs);
    if (!mask) {
      r = UB_ERR_OUT_OF_MEMORY;
      break;
    }
    r = ub_rt_create(s, mask, log, &d->rt_h);
    const ub_llg_set *llg = base->llg && base->llg->probe_count ? base->llg : NULL;
    int obj_is_llg = 0;
    for (uint32_t n = 0; llg && n < s->node_count; n++)
      if (llg->node_model[n] >= 0) {
        obj_is_llg |= s->nodes[n].semidynamic == (int32_t)o;
        memset(mask + s->nodes[n].first_triangle, 0, s->nodes[n].triangle_count);
      }
    if (r == UB_OK && llg && !obj_is_llg)
      r = ub_rt_create(s, mask, log, &d->rt_h_env);
    free(mask);
    if (r != UB_OK)
      break;
    job_init(&d->j, base, base->rt, d->rt_h, base->light_enabled, base->sky, base->emissive, d,
             &ls_base, 0x100u + 2 * o);
    d->j.ref_sh = base_res->sh;
    d->j.ref_iz = base_res->iz;
    if (d->rt_h_env) {
      d->j.rt_s_env = llg->rt_env;
      d->j.rt_h_env = d->rt_h_env;
    }
    r = region(&d->j, &d->kt, &d->kp, &d->kl);
    if (r == UB_OK)
      r = job_run(&d->j);
    if (r != UB_OK)
      break;
    out_stats->rays += atomic_load(&d->j.rays);
    ub_bakefile_record rec;
    memset(&rec, 0, sizeof rec);
    snprintf(rec.name, sizeof rec.name, "%s", s->object_names[o]);
    rec.kind = UB_ELEMENT_OBJECT;
    rec.parent[0] = rec.parent[1] = -1;
    uint32_t nkt = 0, nkp = 0;
    r = make_record(&d->j, d->j.t_sh, d->j.t_iz, d->j.p_sh, base_res->iz, base_res->probe_sh,
                    base_res->llg_sh,
                    UB_OBJ_KEEP, &rec, &nkt, &nkp);
    if (r == UB_OK)
      r = ub_records_append(io_elems, io_count, &rec, 1);
    if (r != UB_OK) {
      free(rec.texel_index);
      free(rec.texel_sh);
      free(rec.probe_index);
      free(rec.probe_sh);
      free(rec.llg_probe_index);
      free(rec.llg_probe_sh);
      break;
    }
    d->elem = (int32_t)(*io_count - 1);
    d->baked = 1;
    for (uint32_t i = 0; i < d->j.nkt; i++)
      d->sum += fabs(lum(d->j.t_iz + 3 * (size_t)i));
    out_stats->objects_baked++;
    out_stats->texels_kept += nkt;
    out_stats->probes_kept += nkp;
    ub_log_printf(log, UB_LOG_INFO,
                  "  object %-14s: %u tris, %u/%u texels and %u/%u probes in its region, kept "
                  "%u texels %u probes %u of %u LLG probes, record %u pixels, %.2f M rays",
                  rec.name, ntri, d->j.nkt, T, d->j.nkp, base->probe_count, nkt, nkp,
                  rec.llg_probe_count, d->j.nkl, rec.texel_count,
                  atomic_load(&d->j.rays) * 1e-6);
  }
  (void)first_obj;
  /* 2. pairwise corrections C_ab = D_a − D_a|b hidden, for overlapping records */
  float *scratch = calloc((size_t)T * 3 + 1, sizeof(float));
  float *scratch2 = calloc((size_t)T * 3 + 1, sizeof(float));
  float *scratch_sh = calloc((size_t)T * 12 + 1, sizeof(float));
  if (r == UB_OK && (!scratch || !scratch2 || !scratch_sh))
    r = UB_ERR_OUT_OF_MEMORY;
  for (uint32_t a = 0; a < O && r == UB_OK; a++)
    for (uint32_t b = a + 1; b < O && r == UB_OK; b++) {
      if (!od[a].baked || !od[b].baked)
        continue;
      /* overlap of the records' shadow parts: receivers of a's region from which a base
       * light's segment crosses both boxes (there the naive sum subtracts twice) */
      uint32_t both = 0;
      for (uint32_t i = 0; i < od[a].j.nkt; i++) {
        uint32_t t = od[a].j.kt[i];
        const float *p = lm->texel_pos + 3 * (size_t)t;
        for (uint32_t l = 0; l < s->light_count; l++) {
          float dir[3], dist, e[3], u0, u1;
          if (!base->light_enabled[l] || !ub_light_incident(&s->lights[l], p, dir, &dist, e))
            continue;
          if (ub_obb_ray(&od[a].box, p, dir, &u0, &u1) && u0 < dist &&
              ub_obb_ray(&od[b].box, p, dir, &u0, &u1) && u0 < dist) {
            both++;
            break;
          }
        }
      }
      double share = od[a].j.nkt ? (double)both / od[a].j.nkt : 0.0;
      if (both < UB_OBJ_PAIR_MIN_TEXELS) {
        ub_log_printf(log, UB_LOG_INFO, "  pair %s × %s: %u texels in both shadows < %u: no correction",
                      s->object_names[a], s->object_names[b], both, UB_OBJ_PAIR_MIN_TEXELS);
        continue;
      }
      /* D_a with b hidden: shown = base − b, hidden = base − a − b, L_s = base − D_b */
      memset(shown, 1, O);
      shown[b] = 0;
      ub_geom_state gs = {NULL, shown};
      uint8_t *mb = ub_geom_mask(s, &gs);
      shown[a] = 0;
      uint8_t *mab = ub_geom_mask(s, &gs);
      ub_rt *rt_b = NULL, *rt_ab = NULL, *rt_b_env = NULL, *rt_ab_env = NULL;
      if (!mb || !mab)
        r = UB_ERR_OUT_OF_MEMORY;
      if (r == UB_OK)
        r = ub_rt_create(s, mb, log, &rt_b);
      if (r == UB_OK)
        r = ub_rt_create(s, mab, log, &rt_ab);
      /* a's LLG probes (a has them when it is not itself an LLG model): the same two
       * geometries without the LLG models, as for a's own record */
      if (r == UB_OK && od[a].j.nkl) {
        for (uint32_t n = 0; n < s->node_count; n++)
          if (base->llg->node_model[n] >= 0) {
            memset(mb + s->nodes[n].first_triangle, 0, s->nodes[n].triangle_count);
            memset(mab + s->nodes[n].first_triangle, 0, s->nodes[n].triangle_count);
          }
        r = ub_rt_create(s, mb, log, &rt_b_env);
        if (r == UB_OK)
          r = ub_rt_create(s, mab, log, &rt_ab_env);
      }
      free(mb);
      free(mab);
      for (size_t i = 0; i < (size_t)T * 3; i++)
        scratch2[i] = base_res->iz[i];
      for (size_t i = 0; i < (size_t)T * 12; i++)
        scratch_sh[i] = base_res->sh[i];
      for (uint32_t i = 0; i < od[b].j.nkt; i++) {
        for (int c = 0; c < 3; c++)
          scratch2[3 * (size_t)od[b].j.kt[i] + c] -= (float)od[b].j.t_iz[3 * (size_t)i + c];
        for (int k = 0; k < 12; k++)
          scratch_sh[12 * (size_t)od[b].j.kt[i] + k] -= (float)od[b].j.t_sh[12 * (size_t)i + k];
      }
      field ls_b = {0, NULL};
      if (r == UB_OK && !field_build(lm, scratch2, &ls_b))
        r = UB_ERR_OUT_OF_MEMORY;
      job jb;
      if (r == UB_OK) {
        /* same pass id as D_a: the same random numbers, so D_a − D_a|b is low-noise */
        job_init(&jb, base, rt_b, rt_ab, base->light_enabled, base->sky, base->emissive, &od[a],
                 &ls_b, od[a].j.pass_id);
        jb.ref_sh = scratch_sh;
        jb.ref_iz = scratch2;
        jb.kt = od[a].j.kt;
        jb.kp = od[a].j.kp;
        jb.nkt = od[a].j.nkt;
        jb.nkp = od[a].j.nkp;
        if (rt_b_env && rt_ab_env) {
          jb.rt_s_env = rt_b_env;
          jb.rt_h_env = rt_ab_env;
          jb.kl = od[a].j.kl;
          jb.nkl = od[a].j.nkl;
        }
        r = job_run(&jb);
        out_stats->rays += atomic_load(&jb.rays);
      }
      if (r == UB_OK) {
        for (size_t i = 0; i < (size_t)jb.nkt * 12; i++)
          jb.t_sh[i] = od[a].j.t_sh[i] - jb.t_sh[i];
        for (size_t i = 0; i < (size_t)jb.nkt * 3; i++)
          jb.t_iz[i] = od[a].j.t_iz[i] - jb.t_iz[i];
        for (size_t i = 0; i < (size_t)jb.nkp * 27; i++)
          jb.p_sh[i] = od[a].j.p_sh[i] - jb.p_sh[i];
        for (size_t i = 0; i < (size_t)jb.nkl * 27; i++)
          jb.l_sh[i] = od[a].j.l_sh[i] - jb.l_sh[i];
        ub_bakefile_record rec;
        memset(&rec, 0, sizeof rec);
        snprintf(rec.name, sizeof rec.name, "%.30s*%.30s", s->object_names[a], s->object_names[b]);
        rec.kind = UB_ELEMENT_COMBO;
        rec.parent[0] = (int32_t)s->dls_count + od[a].elem;
        rec.parent[1] = (int32_t)s->dls_count + od[b].elem;
        uint32_t nkt = 0, nkp = 0;
        r = make_record(&jb, jb.t_sh, jb.t_iz, jb.p_sh, base_res->iz, base_res->probe_sh,
                        base_res->llg_sh, UB_OBJ_KEEP_COMBO, &rec, &nkt, &nkp);
        if (r == UB_OK)
          r = ub_records_append(io_elems, io_count, &rec, 1);
        if (r == UB_OK) {
          out_stats->pairs++;
          ub_log_printf(log, UB_LOG_INFO,
                        "  pair %s × %s: %u texels (%.1f%% of the region) in both shadows: correction "
                        "over %u texels %u probes %u of %u LLG probes (record %u pixels)",
                        s->object_names[a], s->object_names[b], both, 100.0 * share, nkt,
                        nkp, rec.llg_probe_count, jb.nkl, rec.texel_count);
        } else {
          free(rec.texel_index);
          free(rec.texel_sh);
          free(rec.probe_index);
          free(rec.probe_sh);
          free(rec.llg_probe_index);
          free(rec.llg_probe_sh);
        }
        job_free(&jb);
      }
      field_free(&ls_b);
      ub_rt_free(rt_b);
      ub_rt_free(rt_ab);
      ub_rt_free(rt_b_env);
      ub_rt_free(rt_ab_env);
    }
  /* 3. set × object: S_set(shown) − S_set(hidden) where the set casts into the region */
  uint8_t *set_lights = calloc(s->light_count + 1, 1);
  if (r == UB_OK && !set_lights)
    r = UB_ERR_OUT_OF_MEMORY;
  for (uint32_t ds = 0; dls && ds < s->dls_count && r == UB_OK; ds++) {
    const ub_bakefile_record *sr = &dls[ds];
    if (!sr->texel_count && !sr->probe_count)
      continue;
    uint32_t nl = 0;
    for (uint32_t l = 0; l < s->light_count; l++) {
      set_lights[l] = s->lights[l].dls == (int32_t)ds && plan->dls_light_reaches[l];
      nl += set_lights[l];
    }
    if (!nl)
      continue;
    ub_record_texel_iz(lm, sr, scratch, scratch_sh);
    field ls_set = {0, NULL};
    if (!field_build(lm, scratch, &ls_set)) {
      r = UB_ERR_OUT_OF_MEMORY;
      break;
    }
    float *set_probe = calloc((size_t)base->probe_count * 27 + 1, sizeof(float));
    if (!set_probe) {
      field_free(&ls_set);
      r = UB_ERR_OUT_OF_MEMORY;
      break;
    }
    for (uint32_t i = 0; i < sr->probe_count; i++)
      memcpy(set_probe + 27 * (size_t)sr->probe_index[i], sr->probe_sh + 27 * (size_t)i,
             27 * sizeof(float));
    /* LLG probes likewise: base + the set's LLG part, what the combination's threshold is
     * relative to */
    const ub_llg_set *llg = base->llg && base->llg->probe_count ? base->llg : NULL;
    float *set_llg = NULL;
    if (llg && base_res->llg_sh) {
      size_t nl27 = (size_t)llg->probe_count * 27;
      set_llg = malloc(nl27 * sizeof(float) + 1);
      if (!set_llg) {
        free(set_probe);
        field_free(&ls_set);
        r = UB_ERR_OUT_OF_MEMORY;
        break;
      }
      memcpy(set_llg, base_res->llg_sh, nl27 * sizeof(float));
      for (uint32_t i = 0; i < sr->llg_probe_count; i++)
        for (int k = 0; k < 27; k++)
          set_llg[27 * (size_t)sr->llg_probe_index[i] + k] += sr->llg_probe_sh[27 * (size_t)i + k];
    }
    /* what a viewer sees there: base + the set (the combination's threshold is relative
     * to it, not to the set alone: 0.1% of a dim set is invisible) */
    for (size_t i = 0; i < (size_t)T * 3; i++)
      scratch2[i] = base_res->iz[i] + scratch[i];
    for (size_t i = 0; i < (size_t)base->probe_count * 27; i++)
      set_probe[i] += base_res->probe_sh[i];
    for (uint32_t o = 0; o < O && r == UB_OK; o++) {
      if (!od[o].baked)
        continue;
      job js;
      job_init(&js, base, base->rt, od[o].rt_h, set_lights, 0, 0, &od[o], &ls_set,
               0x1000u + 64u * ds + o);
      js.ref_sh = scratch_sh;
      js.ref_iz = scratch;
      if (od[o].rt_h_env && set_llg) {
        js.rt_s_env = llg->rt_env;
        js.rt_h_env = od[o].rt_h_env;
      }
      uint32_t *kt = NULL, *kp = NULL, *kl = NULL;
      r = region(&js, &kt, &kp, &kl);
      /* only receivers the set lights: its record covers them (or its lights cast
         through the box onto them) */
      double set_sum = 0.0;
      for (uint32_t i = 0; r == UB_OK && i < js.nkt; i++)
        set_sum += fabs(0.2126 * scratch[3 * (size_t)kt[i]] + 0.7152 * scratch[3 * (size_t)kt[i] + 1] +
                        0.0722 * scratch[3 * (size_t)kt[i] + 2]);
      if (r == UB_OK && set_sum > 0.0)
        r = job_run(&js);
      if (r == UB_OK && set_sum > 0.0) {
        out_stats->rays += atomic_load(&js.rays);
        double dsum = 0.0;
        for (uint32_t i = 0; i < js.nkt; i++)
          dsum += fabs(lum(js.t_iz + 3 * (size_t)i));
        if (dsum > 0.0) {
          ub_bakefile_record rec;
          memset(&rec, 0, sizeof rec);
          snprintf(rec.name, sizeof rec.name, "%.30s*%.30s", sr->name, s->object_names[o]);
          rec.kind = UB_ELEMENT_COMBO;
          rec.parent[0] = (int32_t)ds;
          rec.parent[1] = (int32_t)s->dls_count + od[o].elem;
          uint32_t nkt = 0, nkp = 0;
          r = make_record(&js, js.t_sh, js.t_iz, js.p_sh, scratch2, set_probe, set_llg,
                          UB_OBJ_KEEP_COMBO, &rec, &nkt, &nkp);
          int empty = r == UB_OK && nkt == 0 && nkp == 0 && rec.llg_probe_count == 0;
          if (r == UB_OK && !empty)
            r = ub_records_append(io_elems, io_count, &rec, 1);
          if (empty) {
            free(rec.texel_index);
            free(rec.texel_sh);
            free(rec.probe_index);
            free(rec.probe_sh);
            free(rec.llg_probe_index);
            free(rec.llg_probe_sh);
            ub_log_printf(log, UB_LOG_INFO, "  set × object %s: nowhere > %.0f%% of the lighting: none",
                          rec.name, 100 * UB_OBJ_KEEP_COMBO);
          } else if (r == UB_OK) {
            out_stats->set_objects++;
            ub_log_printf(log, UB_LOG_INFO,
                          "  set × object %s: changes %.1f%% of the set's light in the region: "
                          "%u texels %u probes %u of %u LLG probes (record %u pixels)",
                          rec.name, 100.0 * dsum / set_sum, nkt, nkp, rec.llg_probe_count,
                          js.nkl, rec.texel_count);
          } else {
            free(rec.texel_index);
            free(rec.texel_sh);
            free(rec.probe_index);
            free(rec.probe_sh);
            free(rec.llg_probe_index);
            free(rec.llg_probe_sh);
          }
        } else {
          ub_log_printf(log, UB_LOG_INFO, "  set × object %s*%s: changes nothing: none",
                        sr->name, s->object_names[o]);
        }
      }
      job_free(&js);
      free(kt);
      free(kp);
      free(kl);
    }
    free(set_probe);
    free(set_llg);
    field_free(&ls_set);
  }
  free(set_lights);
  free(scratch);
  free(scratch2);
  free(scratch_sh);
  for (uint32_t o = 0; o < O; o++) {
    job_free(&od[o].j);
    free(od[o].kt);
    free(od[o].kp);
    free(od[o].kl);
    ub_rt_free(od[o].rt_h_env);
    free(od[o].tri);
    ub_rt_free(od[o].rt_h);
  }
  free(od);
  free(shown);
  field_free(&ls_base);
  out_stats->seconds = now_s() - t0;
  return r;
}
