/* Brute-force reference path tracer (see bake/reference.h for the quantity).
 *
 * Wavefront layout: a block of UB_REF_BLOCK paths advances one vertex depth at a time.
 * At each depth every live path adds its next-event shadow rays to a buffer traced with
 * one ub_rt_occluded call (flushed when full), then all live paths' bounce rays are
 * traced together with one ub_rt_intersect call. Blocks are fixed (independent of the
 * thread count) and merged in block order, so the result is bit-identical for any
 * number of threads.
 *
 * Estimator, with β_k the path throughput at vertex k (β_0 = 1 at the receiver,
 * β_{k+1} = β_k·ρ_{k+1} under cosine sampling, where π·(ρ/π) cancels):
 *   E ≈ Σ_k β_k·E_direct(x_k) + Σ_k β_k·π·L_sky·[bounce ray from x_k escapes],
 * with k ≤ max_bounces in both sums and primary lights excluded from E_direct(x_0).
 */
#include "bake/reference.h"

#include "ubake/sh.h"

#include <assert.h>
#include <math.h>
#include <omp.h>
#include <stdlib.h>
#include <string.h>

/* Paths per block: the unit of work and of determinism. Never derive it from the thread
 * count. */
#define UB_REF_BLOCK 1024u
/* Blocks traced per round: their statistics are merged in block order before the next
 * round, so memory stays bounded for any spp (a left fold in block order either way: the
 * same bits as merging them all at the end). */
#define UB_REF_ROUND_BLOCKS 4096u
/* Shadow rays buffered before a flush (per thread). */
#define UB_REF_SHADOW_CAP 4096u
/* Russian roulette starts at vertices after this many bounces (unlimited mode only). */
#define UB_REF_RR_DEPTH 3u
#define UB_REF_RR_MAX_SURVIVAL 0.95f
/* Squared distances below this (m²) are skipped in emitter NEE: the geometry term is
 * meaningless there and the contribution of such a sliver of area is negligible. */
#define UB_REF_MIN_DIST2 1e-12f

/* Random-number dimensions within one vertex depth. */
enum {
  DIM_EMITTER_PICK = 0,
  DIM_EMITTER_U1,
  DIM_EMITTER_U2,
  DIM_BOUNCE_U1,
  DIM_BOUNCE_U2,
  DIM_ROULETTE,
  DIM_SPHERE_ROTATE /* sphere mode: the random offset of the normals' lattice */
};

/* Sphere mode (ub_reference_radiance_sh): per path 27 SH coefficients + the L2
 * irradiance at the caller's normal. */
#define UB_REF_SH_DIMS 30

/* Read-only state shared by all threads. */
typedef struct ref_ctx {
  const ub_scene *scene;
  const ub_rt *rt;
  const ub_emitters *em;      /* NULL or count 0: no emissive NEE */
  uint32_t spp, seed, max_bounces;
  int unlimited;
  int sphere;                 /* 1: a normal per path over the sphere, SH projection */
  float sh_dir[9];            /* sphere mode: Y_lm(caller's normal) */
  const float *light_weight;  /* light_count × 3: DLS weight per light */
  const uint8_t *light_on;    /* light_count: non-zero weight and intensity */
  float p0[3], n0[3], org0[3];
} ref_ctx;

/* One block's statistics: running mean and sum of squared deviations (Welford), merged
 * across blocks with Chan's formula in block order. */
typedef struct ref_stats {
  double n;
  double mean[UB_REF_SH_DIMS];
  double m2[UB_REF_SH_DIMS];
} ref_stats;

/* Per-thread scratch, reused across the blocks a thread runs. */
typedef struct ref_scratch {
  float p[UB_REF_BLOCK][3];     /* vertex position (on the surface) */
  float n[UB_REF_BLOCK][3];     /* unit normal facing the side the path arrived from */
  float org[UB_REF_BLOCK][3];   /* offset ray origin */
  float beta[UB_REF_BLOCK][3];  /* throughput */
  float rho_max[UB_REF_BLOCK];  /* max albedo of the current vertex (roulette) */
  float n0[UB_REF_BLOCK][3];    /* sphere mode: the path's receiver normal */
  double value[UB_REF_BLOCK][3];
  uint8_t bad[UB_REF_BLOCK];    /* a non-finite quantity appeared on this path */
  uint32_t live[UB_REF_BLOCK];
  uint32_t ray_slot[UB_REF_BLOCK];
  ub_ray rays[UB_REF_BLOCK];
  ub_hit hits[UB_REF_BLOCK];
  uint8_t occ[UB_REF_BLOCK];

  uint32_t shadow_n;
  ub_ray shadow[UB_REF_SHADOW_CAP];
  float shadow_contrib[UB_REF_SHADOW_CAP][3];
  uint32_t shadow_slot[UB_REF_SHADOW_CAP];
  uint8_t shadow_occ[UB_REF_SHADOW_CAP];

  uint64_t rays_traced;
  uint64_t nonfinite;
} ref_scratch;

void ub_reference_params_init(ub_reference_params *out_params)
{
  memset(out_params, 0, sizeof *out_params);
  out_params->normal[1] = 1.0f;
  out_params->spp = UB_REFERENCE_DEFAULT_SPP;
  out_params->max_bounces = UB_REFERENCE_UNLIMITED;
}

static float dot3(const float a[3], const float b[3])
{
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static int finite3(const float v[3])
{
  return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

static float rnd(const ref_ctx *c, uint32_t path, uint32_t depth, uint32_t dim)
{
  return ub_u01(ub_hash4(c->seed, path, depth, dim));
}

static void shadow_flush(const ref_ctx *c, ref_scratch *s)
{
  if (!s->shadow_n)
    return;
  ub_rt_occluded(c->rt, s->shadow, s->shadow_n, s->shadow_occ);
  s->rays_traced += s->shadow_n;
  for (uint32_t j = 0; j < s->shadow_n; j++) {
    if (s->shadow_occ[j])
      continue;
    double *v = s->value[s->shadow_slot[j]];
    v[0] += s->shadow_contrib[j][0];
    v[1] += s->shadow_contrib[j][1];
    v[2] += s->shadow_contrib[j][2];
  }
  s->shadow_n = 0;
}

/* Queues a shadow ray from org toward target (segment, t in (0, 1)) or along a unit
 * direction to infinity (target NULL). */
static void shadow_push(const ref_ctx *c, ref_scratch *s, uint32_t slot, const float org[3],
                        const float target[3], const float dir[3], const float contrib[3])
{
  if (s->shadow_n == UB_REF_SHADOW_CAP)
    shadow_flush(c, s);
  uint32_t j = s->shadow_n++;
  ub_ray *r = s->shadow + j;
  memcpy(r->org, org, sizeof r->org);
  r->tnear = 0.0f;
  if (target) {
    r->dir[0] = target[0] - org[0];
    r->dir[1] = target[1] - org[1];
    r->dir[2] = target[2] - org[2];
    r->tfar = 1.0f;
  } else {
    memcpy(r->dir, dir, sizeof r->dir);
    r->tfar = INFINITY;
  }
  memcpy(s->shadow_contrib[j], contrib, 3 * sizeof(float));
  s->shadow_slot[j] = slot;
}

/* Next-event estimation at the current vertex of path `path` (block slot `slot`),
 * `depth` bounces after the receiver: punctual lights (one shadow ray each, primary
 * lights only once bounced) and one area sample on the emissive triangles. */
static void nee(const ref_ctx *c, ref_scratch *s, uint32_t slot, uint32_t path,
                uint32_t depth)
{
  const ub_scene *sc = c->scene;
  const float *p = s->p[slot], *n = s->n[slot], *org = s->org[slot], *beta = s->beta[slot];

  for (uint32_t l = 0; l < sc->light_count; l++) {
    const ub_light *light = sc->lights + l;
    if (!c->light_on[l] || (depth == 0 && light->cls == UB_LIGHT_PRIMARY))
      continue;
    float dir[3], dist, e[3];
    if (!ub_light_incident(light, p, dir, &dist, e))
      continue;
    float cosx = dot3(n, dir);
    if (!(cosx > 0.0f))
      continue;
    const float *w = c->light_weight + 3 * l;
    float contrib[3];
    for (int i = 0; i < 3; i++)
      contrib[i] = beta[i] * e[i] * w[i] * cosx;
    if (contrib[0] == 0.0f && contrib[1] == 0.0f && contrib[2] == 0.0f)
      continue;
    if (isinf(dist))
      shadow_push(c, s, slot, org, NULL, dir, contrib);
    else
      shadow_push(c, s, slot, org, light->position, NULL, contrib);
  }

  const ub_emitters *em = c->em;
  if (!em || !em->count)
    return;
  float y[3], ny[3], le[3], pdf;
  ub_emitters_sample(em, sc, rnd(c, path, depth, DIM_EMITTER_PICK),
                     rnd(c, path, depth, DIM_EMITTER_U1), rnd(c, path, depth, DIM_EMITTER_U2),
                     y, ny, le, &pdf);
  if (!(pdf > 0.0f))
    return;
  float v[3] = {y[0] - p[0], y[1] - p[1], y[2] - p[2]};
  float d2 = dot3(v, v);
  if (!(d2 > UB_REF_MIN_DIST2))
    return;
  /* Heights of each end above the other's tangent plane (metres). Below the ray epsilon
   * the cosines are rounding noise (e.g. a sample on the vertex's own emissive
   * triangle); the true contribution there vanishes. */
  float hx = dot3(n, v), hy = -dot3(ny, v);
  float eps = ub_rt_epsilon(c->rt, p);
  if (!(hx > eps) || !(hy > eps))
    return;
  float g = hx * hy / (d2 * d2 * pdf);
  float contrib[3];
  for (int i = 0; i < 3; i++)
    contrib[i] = beta[i] * le[i] * g;
  if (!finite3(contrib)) {
    s->bad[slot] = 1;
    return;
  }
  float target[3];
  ub_rt_offset_point(c->rt, y, ny, target);
  shadow_push(c, s, slot, org, target, NULL, contrib);
}

/* Traces paths [first, first + count) and returns their statistics. */
static void run_block(const ref_ctx *c, ref_scratch *s, uint32_t first, uint32_t count,
                      ref_stats *out)
{
  const ub_scene *sc = c->scene;
  const float pi = (float)M_PI;
  uint32_t n_live = count;
  /* Sphere mode: path k's receiver normal is point k of a spherical Fibonacci lattice
   * of spp points (rotated by the seed), so the normals are stratified over the sphere
   * and depend only on the path index. */
  float rot = c->sphere ? ub_u01(ub_hash4(c->seed, 0, 0, DIM_SPHERE_ROTATE)) : 0.0f;
  for (uint32_t i = 0; i < count; i++) {
    memcpy(s->p[i], c->p0, sizeof s->p[i]);
    if (c->sphere) {
      double k = (double)(first + i), z = 1.0 - (2.0 * k + 1.0) / (double)c->spp;
      double r = sqrt(fmax(0.0, 1.0 - z * z)), f = k * 0.6180339887498949 + rot;
      double phi = 2.0 * M_PI * (f - floor(f));
      s->n[i][0] = (float)(r * cos(phi));
      s->n[i][1] = (float)(r * sin(phi));
      s->n[i][2] = (float)z;
      memcpy(s->n0[i], s->n[i], sizeof s->n0[i]);
      ub_rt_offset_point(c->rt, c->p0, s->n[i], s->org[i]);
    } else {
      memcpy(s->n[i], c->n0, sizeof s->n[i]);
      memcpy(s->org[i], c->org0, sizeof s->org[i]);
    }
    s->beta[i][0] = s->beta[i][1] = s->beta[i][2] = 1.0f;
    s->rho_max[i] = 1.0f;
    s->value[i][0] = s->value[i][1] = s->value[i][2] = 0.0;
    s->bad[i] = 0;
    s->live[i] = i;
  }
  s->shadow_n = 0;

  for (uint32_t depth = 0; n_live > 0; depth++) {
    /* Direct light at this vertex: `depth` bounces. */
    for (uint32_t j = 0; j < n_live; j++)
      nee(c, s, s->live[j], first + s->live[j], depth);
    shadow_flush(c, s);

    /* Bounce. At the last counted depth only the sky is left to gather. */
    int last = !c->unlimited && depth >= c->max_bounces;
    if (last && !sc->has_sky)
      break;
    uint32_t n_rays = 0;
    for (uint32_t j = 0; j < n_live; j++) {
      uint32_t slot = s->live[j], path = first + slot;
      float *beta = s->beta[slot];
      if (c->unlimited && depth >= UB_REF_RR_DEPTH) {
        float q = fminf(UB_REF_RR_MAX_SURVIVAL, s->rho_max[slot]);
        if (!(rnd(c, path, depth, DIM_ROULETTE) < q))
          continue;
        beta[0] /= q;
        beta[1] /= q;
        beta[2] /= q;
      }
      ub_ray *r = s->rays + n_rays;
      memcpy(r->org, s->org[slot], sizeof r->org);
      ub_sample_cosine(s->n[slot], rnd(c, path, depth, DIM_BOUNCE_U1),
                       rnd(c, path, depth, DIM_BOUNCE_U2), r->dir);
      r->tnear = 0.0f;
      r->tfar = INFINITY;
      s->ray_slot[n_rays++] = slot;
    }
    if (last) {
      ub_rt_occluded(c->rt, s->rays, n_rays, s->occ);
      s->rays_traced += n_rays;
      for (uint32_t j = 0; j < n_rays; j++) {
        if (s->occ[j])
          continue;
        uint32_t slot = s->ray_slot[j];
        for (int i = 0; i < 3; i++)
          s->value[slot][i] += (double)(s->beta[slot][i] * pi * sc->sky[i]);
      }
      break;
    }
    ub_rt_intersect(c->rt, s->rays, n_rays, s->hits);
    s->rays_traced += n_rays;
    n_live = 0;
    for (uint32_t j = 0; j < n_rays; j++) {
      uint32_t slot = s->ray_slot[j];
      const ub_hit *h = s->hits + j;
      const ub_ray *r = s->rays + j;
      float *beta = s->beta[slot];
      if (h->tri == UB_RT_MISS) {
        if (sc->has_sky)
          for (int i = 0; i < 3; i++)
            s->value[slot][i] += (double)(beta[i] * pi * sc->sky[i]);
        continue;
      }
      /* New vertex: position from barycentrics (on the surface, not along the ray),
       * normal facing the incoming ray, throughput times albedo. */
      const uint32_t *idx = sc->indices + 3 * h->tri;
      const float *a = sc->positions + 3 * idx[0];
      const float *b = sc->positions + 3 * idx[1];
      const float *cc = sc->positions + 3 * idx[2];
      float w0 = 1.0f - h->u - h->v;
      float *p = s->p[slot], *n = s->n[slot];
      for (int i = 0; i < 3; i++)
        p[i] = w0 * a[i] + h->u * b[i] + h->v * cc[i];
      float len = sqrtf(dot3(h->ng, h->ng));
      if (!(len > 0.0f) || !isfinite(len)) {
        s->bad[slot] = 1;
        continue;
      }
      float sign = dot3(h->ng, r->dir) > 0.0f ? -1.0f : 1.0f;
      for (int i = 0; i < 3; i++)
        n[i] = sign * h->ng[i] / len;
      const float *rho = sc->materials[sc->tri_material[h->tri]].albedo;
      for (int i = 0; i < 3; i++)
        beta[i] *= rho[i];
      if (!finite3(beta) || !finite3(p)) {
        s->bad[slot] = 1;
        continue;
      }
      if (beta[0] == 0.0f && beta[1] == 0.0f && beta[2] == 0.0f)
        continue;
      s->rho_max[slot] = fmaxf(rho[0], fmaxf(rho[1], rho[2]));
      ub_rt_offset_point(c->rt, p, n, s->org[slot]);
      s->live[n_live++] = slot;
    }
  }

  /* Per-path estimates → block statistics (Welford, in path order). */
  ref_stats st = {0};
  int dims = c->sphere ? UB_REF_SH_DIMS : 3;
  for (uint32_t i = 0; i < count; i++) {
    double x[UB_REF_SH_DIMS] = {s->value[i][0], s->value[i][1], s->value[i][2]};
    if (s->bad[i] || !isfinite(x[0]) || !isfinite(x[1]) || !isfinite(x[2])) {
      s->nonfinite++;
      x[0] = x[1] = x[2] = 0.0;
    }
    if (c->sphere) {
      /* ∫E(n)·Y_lm(n) dn = A_l·L_lm: L_lm ≈ 4π·E(n_k)·Y_lm(n_k)/A_l; and the L2
       * irradiance at the caller's normal, Σ A_l·L_lm·Y_lm(n), for its standard error. */
      static const double inv_a[9] = {1.0 / UB_SH_A0, 1.0 / UB_SH_A1, 1.0 / UB_SH_A1,
                                      1.0 / UB_SH_A1, 1.0 / UB_SH_A2, 1.0 / UB_SH_A2,
                                      1.0 / UB_SH_A2, 1.0 / UB_SH_A2, 1.0 / UB_SH_A2};
      float y[9];
      ub_sh2_eval_basis(s->n0[i], y);
      double e[3] = {x[0], x[1], x[2]}, dir = 0.0;
      for (int m = 0; m < 9; m++) {
        dir += (double)c->sh_dir[m] * y[m];
        for (int ch = 0; ch < 3; ch++)
          x[3 * m + ch] = 4.0 * M_PI * e[ch] * y[m] * inv_a[m];
      }
      for (int ch = 0; ch < 3; ch++)
        x[27 + ch] = 4.0 * M_PI * e[ch] * dir;
    }
    st.n += 1.0;
    for (int k = 0; k < dims; k++) {
      double d = x[k] - st.mean[k];
      st.mean[k] += d / st.n;
      st.m2[k] += d * (x[k] - st.mean[k]);
    }
  }
  *out = st;
}

static void stats_merge(ref_stats *acc, const ref_stats *b, int dims)
{
  if (b->n == 0.0)
    return;
  double n = acc->n + b->n;
  for (int k = 0; k < dims; k++) {
    double d = b->mean[k] - acc->mean[k];
    acc->mean[k] += d * (b->n / n);
    acc->m2[k] += b->m2[k] + d * d * (acc->n * b->n / n);
  }
  acc->n = n;
}

/* Both estimators: irradiance at params->normal (sphere 0: out_mean/out_se 3 values) or
 * sphere mode (out_mean 27 SH coefficients + 3 = the L2 irradiance at the normal,
 * out_se the same 30). */
static ub_result reference_run(const ub_scene *scene, const ub_rt *rt, const ub_emitters *em,
                               const ub_reference_params *params, int sphere,
                               float *out_mean, float *out_se, const ub_log *log)
{
  assert(scene && rt && params && out_mean && out_se);
  assert(ub_rt_scene(rt) == scene);

  if (!finite3(params->position)) {
    ub_log_printf(log, UB_LOG_ERROR, "reference: receiver position is not finite");
    return UB_ERR_INVALID_ARGUMENT;
  }
  for (int i = 0; i < 3; i++)
    if (fabs((double)params->position[i]) > UB_REFERENCE_MAX_COORDINATE) {
      ub_log_printf(log, UB_LOG_ERROR,
                    "reference: receiver position (%g, %g, %g) is beyond the coordinate "
                    "limit of %g m", params->position[0], params->position[1],
                    params->position[2], UB_REFERENCE_MAX_COORDINATE);
      return UB_ERR_INVALID_ARGUMENT;
    }
  float nlen = sqrtf(dot3(params->normal, params->normal));
  if (!finite3(params->normal) || !isfinite(nlen) || !(nlen > 1e-12f)) {
    ub_log_printf(log, UB_LOG_ERROR, "reference: receiver normal (%g, %g, %g) is zero or not finite",
                  params->normal[0], params->normal[1], params->normal[2]);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (params->spp > UB_REFERENCE_MAX_SPP) {
    ub_log_printf(log, UB_LOG_ERROR, "reference: %u paths asked for, the limit is %u (2^30)",
                  params->spp, UB_REFERENCE_MAX_SPP);
    return UB_ERR_INVALID_ARGUMENT;
  }

  ref_ctx c;
  memset(&c, 0, sizeof c);
  c.scene = scene;
  c.rt = rt;
  c.spp = params->spp ? params->spp : UB_REFERENCE_DEFAULT_SPP;
  c.seed = params->seed;
  c.max_bounces = params->max_bounces;
  c.unlimited = params->max_bounces == UB_REFERENCE_UNLIMITED;
  memcpy(c.p0, params->position, sizeof c.p0);
  for (int i = 0; i < 3; i++)
    c.n0[i] = params->normal[i] / nlen;
  ub_rt_offset_point(rt, c.p0, c.n0, c.org0);
  c.sphere = sphere;
  if (sphere)
    ub_sh2_eval_basis(c.n0, c.sh_dir);
  int dims = sphere ? UB_REF_SH_DIMS : 3;

  /* Per-light weights (DLS) and a skip flag for lights that contribute nothing. */
  uint32_t nl = scene->light_count;
  float *light_weight = malloc((size_t)(nl ? nl : 1) * 3 * sizeof *light_weight);
  uint8_t *light_on = malloc(nl ? nl : 1);
  if (!light_weight || !light_on) {
    free(light_weight);
    free(light_on);
    return UB_ERR_OUT_OF_MEMORY;
  }
  for (uint32_t l = 0; l < nl; l++) {
    const ub_light *light = scene->lights + l;
    float *w = light_weight + 3 * l;
    w[0] = w[1] = w[2] = 1.0f;
    if (light->dls >= 0) {
      if ((uint32_t)light->dls >= scene->dls_count) {
        ub_log_printf(log, UB_LOG_ERROR, "reference: light %u has dynamic light set %d of %u",
                      l, (int)light->dls, scene->dls_count);
        free(light_weight);
        free(light_on);
        return UB_ERR_INVALID_DATA;
      }
      if (params->dls_weight) {
        memcpy(w, params->dls_weight + 3 * (size_t)light->dls, 3 * sizeof(float));
        if (!finite3(w)) {
          ub_log_printf(log, UB_LOG_ERROR, "reference: weight of dynamic light set '%s' is not finite",
                        scene->dls_names ? scene->dls_names[light->dls] : "?");
          free(light_weight);
          free(light_on);
          return UB_ERR_INVALID_ARGUMENT;
        }
      }
    }
    int on = 0;
    for (int i = 0; i < 3; i++)
      on |= w[i] != 0.0f && light->intensity[i] != 0.0f;
    light_on[l] = (uint8_t)on;
  }
  c.light_weight = light_weight;
  c.light_on = light_on;

  ub_emitters *own_em = NULL;
  if (!em) {
    ub_result r = ub_emitters_build(scene, &own_em);
    if (r != UB_OK) {
      free(light_weight);
      free(light_on);
      return r;
    }
    em = own_em;
  }
  c.em = em;

  uint32_t n_blocks = c.spp / UB_REF_BLOCK + (c.spp % UB_REF_BLOCK != 0);
  uint32_t round_cap = n_blocks < UB_REF_ROUND_BLOCKS ? n_blocks : UB_REF_ROUND_BLOCKS;
  ref_stats *block_stats = calloc(round_cap, sizeof *block_stats);
  if (!block_stats) {
    ub_emitters_free(own_em);
    free(light_weight);
    free(light_on);
    return UB_ERR_OUT_OF_MEMORY;
  }

  int oom = 0;
  uint64_t rays = 0, nonfinite = 0;
  ref_stats total = {0};
  int nt = params->threads > 0 ? params->threads : omp_get_max_threads();
  if ((uint32_t)nt > n_blocks)
    nt = (int)n_blocks;
  double t0 = omp_get_wtime();
#pragma omp parallel num_threads(nt) reduction(+ : rays, nonfinite) reduction(| : oom)
  {
    ref_scratch *s = malloc(sizeof *s);
    if (!s)
      oom = 1;
    /* Every thread must reach each round's barriers (the loop's and the merge's); a
     * thread without scratch takes no blocks and the whole call fails below. */
    for (uint32_t b0 = 0; b0 < n_blocks; b0 += UB_REF_ROUND_BLOCKS) {
      uint32_t nb = n_blocks - b0 < UB_REF_ROUND_BLOCKS ? n_blocks - b0 : UB_REF_ROUND_BLOCKS;
#pragma omp for schedule(dynamic, 1)
      for (uint32_t j = 0; j < nb; j++) {
        if (!s)
          continue;
        uint32_t first = (b0 + j) * UB_REF_BLOCK;
        uint32_t count = c.spp - first < UB_REF_BLOCK ? c.spp - first : UB_REF_BLOCK;
        s->rays_traced = 0;
        s->nonfinite = 0;
        run_block(&c, s, first, count, block_stats + j);
        rays += s->rays_traced;
        nonfinite += s->nonfinite;
      }
#pragma omp single
      for (uint32_t j = 0; j < nb; j++)
        stats_merge(&total, block_stats + j, dims);
    }
    free(s);
  }
  double seconds = omp_get_wtime() - t0;

  ub_result result = UB_OK;
  if (oom) {
    result = UB_ERR_OUT_OF_MEMORY;
  } else {
    int overflow = 0;
    for (int k = 0; k < dims; k++) {
      double var = total.n > 1.0 ? total.m2[k] / (total.n - 1.0) : 0.0;
      double se = sqrt(var > 0.0 ? var : 0.0) / sqrt(total.n);
      float mean = (float)total.mean[k], fse = (float)se;
      overflow |= !isfinite(mean) || !isfinite(fse);
      out_mean[k] = isfinite(mean) ? mean : 0.0f;
      out_se[k] = isfinite(fse) ? fse : 0.0f;
    }
    if (overflow)
      ub_log_printf(log, UB_LOG_WARNING,
                    "reference: the estimate overflows float; non-finite channels set to 0");
    if (nonfinite)
      ub_log_printf(log, UB_LOG_WARNING,
                    "reference: dropped %llu of %u paths with a non-finite contribution",
                    (unsigned long long)nonfinite, c.spp);
    ub_log_printf(log, UB_LOG_INFO,
                  "reference: %u paths, %llu rays in %.3f s (%.2f M rays/s, %d threads)",
                  c.spp, (unsigned long long)rays, seconds,
                  seconds > 0.0 ? (double)rays / seconds * 1e-6 : 0.0, nt);
  }
  free(block_stats);
  ub_emitters_free(own_em);
  free(light_weight);
  free(light_on);
  return result;
}

ub_result ub_reference_irradiance(const ub_scene *scene, const ub_rt *rt,
                                  const ub_emitters *em, const ub_reference_params *params,
                                  float out_rgb[3], float out_stderr[3], const ub_log *log)
{
  assert(out_rgb && out_stderr);
  return reference_run(scene, rt, em, params, 0, out_rgb, out_stderr, log);
}

ub_result ub_reference_radiance_sh(const ub_scene *scene, const ub_rt *rt,
                                   const ub_emitters *em, const ub_reference_params *params,
                                   float out_sh[27], float out_l2_rgb[3],
                                   float out_l2_stderr[3], const ub_log *log)
{
  assert(out_sh && out_l2_rgb && out_l2_stderr);
  float mean[UB_REF_SH_DIMS], se[UB_REF_SH_DIMS];
  ub_result r = reference_run(scene, rt, em, params, 1, mean, se, log);
  if (r != UB_OK)
    return r;
  memcpy(out_sh, mean, 27 * sizeof(float));
  memcpy(out_l2_rgb, mean + 27, 3 * sizeof(float));
  memcpy(out_l2_stderr, se + 27, 3 * sizeof(float));
  return UB_OK;
}
