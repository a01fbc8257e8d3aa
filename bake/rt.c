/* Embree 3 wrapper: one robust scene over the level's triangles, batched stream queries. */
#include "bake/rt.h"

#include <embree3/rtcore.h>
#include <math.h>
#include <pmmintrin.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <xmmintrin.h>

/* Rays per Embree stream call: large enough for Embree to form packets, small enough to
 * live on the stack. */
#define UB_RT_STREAM 256

struct ub_rt {
  const ub_scene *scene;
  RTCDevice device;
  RTCScene rscene;
  uint32_t *prim_to_tri; /* Embree primitive id → scene triangle */
  uint32_t prim_count;
  float scene_eps;       /* absolute epsilon floor from the level's extent */
  uint8_t *twin;         /* per primitive: another faces the other way in its plane */
  uint64_t twin_count;
  _Atomic uint64_t rays;
  const ub_log *log;
};

static void rt_error(void *user, enum RTCError code, const char *str)
{
  const ub_rt *rt = user;
  ub_log_printf(rt->log, UB_LOG_ERROR, "embree error %d: %s", (int)code, str ? str : "");
}

/* A primitive's plane, for find_twins: the normal turned so that its largest component
 * (axis ax) is positive, side = whether it was turned, d = n·centroid. */
typedef struct plane_key {
  double n[3], d;
  float lo[3], hi[3]; /* bounds */
  float sweep;        /* lo along an in-plane axis: find_twins' order within a run */
  uint32_t prim;
  uint8_t ax, side;
} plane_key;

static int cmp_plane(const void *a, const void *b)
{
  const plane_key *x = a, *y = b;
  if (x->ax != y->ax)
    return x->ax < y->ax ? -1 : 1;
  return x->d < y->d ? -1 : x->d > y->d;
}

static int cmp_sweep(const void *a, const void *b)
{
  const plane_key *x = a, *y = b;
  return x->sweep < y->sweep ? -1 : x->sweep > y->sweep;
}

/* rt->twin: the primitives with another in the same plane (d within tol, normals within
 * 1e-4) facing the other way, their bounds (grown by tol) overlapping: a superset of the
 * faces a ray can find at the same t as an opposite one (prefer_front traces only their
 * back-face hits again). NULL (no primitive has one) or an array of prim_count flags. */
static int find_twins(ub_rt *rt, const ub_scene *s, double tol)
{
  const uint32_t n = rt->prim_count;
  plane_key *k = malloc((size_t)(n ? n : 1) * sizeof *k);
  if (!k)
    return 0;
  for (uint32_t i = 0; i < n; i++) {
    const uint32_t *ix = s->indices + 3 * (size_t)rt->prim_to_tri[i];
    const float *p0 = s->positions + 3 * (size_t)ix[0], *p1 = s->positions + 3 * (size_t)ix[1],
                *p2 = s->positions + 3 * (size_t)ix[2];
    double e1[3], e2[3], c[3];
    plane_key *q = &k[i];
    for (int j = 0; j < 3; j++) {
      e1[j] = (double)p1[j] - p0[j];
      e2[j] = (double)p2[j] - p0[j];
      c[j] = ((double)p0[j] + p1[j] + p2[j]) / 3.0;
      q->lo[j] = fminf(p0[j], fminf(p1[j], p2[j])) - (float)tol;
      q->hi[j] = fmaxf(p0[j], fmaxf(p1[j], p2[j])) + (float)tol;
    }
    double m[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                   e1[0] * e2[1] - e1[1] * e2[0]};
    double l = sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
    q->prim = i;
    q->ax = fabs(m[0]) >= fabs(m[1]) ? (fabs(m[0]) >= fabs(m[2]) ? 0 : 2)
                                     : (fabs(m[1]) >= fabs(m[2]) ? 1 : 2);
    q->side = m[q->ax] < 0.0;
    double f = l > 0.0 ? (q->side ? -1.0 : 1.0) / l : 0.0;
    for (int j = 0; j < 3; j++)
      q->n[j] = m[j] * f;
    q->d = q->n[0] * c[0] + q->n[1] * c[1] + q->n[2] * c[2];
  }
  qsort(k, n, sizeof *k, cmp_plane);
  uint64_t flagged = 0;
  for (uint32_t a = 0, b; a < n; a = b) {
    /* a run of primitives whose planes chain within tol, both sides present */
    int sides = 1 << k[a].side;
    for (b = a + 1; b < n && k[b].ax == k[a].ax && k[b].d - k[b - 1].d <= tol; b++)
      sides |= 1 << k[b].side;
    if (sides != 3)
      continue;
    /* The pairs overlapping along an in-plane axis, by a sweep in the order of their low
     * bounds on it: a large plane with both sides present (a floor of 10k triangles a
     * side) costs a sort and its neighbours' pairs, not every pair of the run (the d-order
     * window was O(k²) there). The same pairs as every pair of the run within tol: the
     * overlap on that axis is one of the conditions below. */
    const int u = (k[a].ax + 1) % 3;
    for (uint32_t i = a; i < b; i++)
      k[i].sweep = k[i].lo[u];
    qsort(k + a, b - a, sizeof *k, cmp_sweep);
    for (uint32_t i = a; i < b; i++)
      for (uint32_t j = i + 1; j < b && k[j].lo[u] <= k[i].hi[u]; j++) {
        if (fabs(k[j].d - k[i].d) > tol)
          continue;
        int apart = k[i].side == k[j].side;
        for (int c = 0; c < 3 && !apart; c++)
          apart = fabs(k[i].n[c] - k[j].n[c]) > 1e-4 || k[i].hi[c] < k[j].lo[c] ||
                  k[j].hi[c] < k[i].lo[c];
        if (apart)
          continue;
        if (!rt->twin && !(rt->twin = calloc(n, 1))) {
          free(k);
          return 0;
        }
        flagged += !rt->twin[k[i].prim] + !rt->twin[k[j].prim];
        rt->twin[k[i].prim] = rt->twin[k[j].prim] = 1;
      }
  }
  free(k);
  rt->twin_count = flagged;
  return 1;
}

static void set_ftz_daz(void)
{
  _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
  _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
}

ub_result ub_rt_create(const ub_scene *scene, const uint8_t *mask, const ub_log *log,
                       ub_rt **out_rt)
{
  ub_rt *rt = calloc(1, sizeof *rt);
  if (!rt)
    return UB_ERR_OUT_OF_MEMORY;
  rt->scene = scene;
  rt->log = log;
  rt->device = rtcNewDevice(NULL);
  if (!rt->device) {
    ub_log_printf(log, UB_LOG_ERROR, "embree: cannot create device (error %d)",
                  (int)rtcGetDeviceError(NULL));
    free(rt);
    return UB_ERR_EXTERNAL;
  }
  rtcSetDeviceErrorFunction(rt->device, rt_error, rt);

  uint32_t n = 0;
  for (uint32_t t = 0; t < scene->triangle_count; t++)
    if (!(scene->tri_flags[t] & UB_TRI_DEGENERATE) && (!mask || mask[t]))
      n++;
  rt->prim_to_tri = malloc((size_t)(n ? n : 1) * sizeof *rt->prim_to_tri);
  if (!rt->prim_to_tri) {
    ub_rt_free(rt);
    return UB_ERR_OUT_OF_MEMORY;
  }
  rt->prim_count = n;

  rt->rscene = rtcNewScene(rt->device);
  rtcSetSceneFlags(rt->rscene, RTC_SCENE_FLAG_ROBUST | RTC_SCENE_FLAG_CONTEXT_FILTER_FUNCTION);
  rtcSetSceneBuildQuality(rt->rscene, RTC_BUILD_QUALITY_HIGH);
  if (n > 0) {
    RTCGeometry geom = rtcNewGeometry(rt->device, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *vb = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                        3 * sizeof(float), scene->vertex_count);
    uint32_t *ib = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                           3 * sizeof(uint32_t), n);
    if (!vb || !ib) {
      rtcReleaseGeometry(geom);
      ub_rt_free(rt);
      return UB_ERR_OUT_OF_MEMORY;
    }
    memcpy(vb, scene->positions, (size_t)scene->vertex_count * 3 * sizeof(float));
    uint32_t k = 0;
    for (uint32_t t = 0; t < scene->triangle_count; t++) {
      if ((scene->tri_flags[t] & UB_TRI_DEGENERATE) || (mask && !mask[t]))
        continue;
      memcpy(ib + 3 * k, scene->indices + 3 * t, 3 * sizeof(uint32_t));
      rt->prim_to_tri[k++] = t;
    }
    rtcCommitGeometry(geom);
    rtcAttachGeometry(rt->rscene, geom);
    rtcReleaseGeometry(geom);
  }
  rtcCommitScene(rt->rscene);
  if (rtcGetDeviceError(rt->device) != RTC_ERROR_NONE) {
    ub_rt_free(rt);
    return UB_ERR_EXTERNAL;
  }
  /* Epsilon floor: 1e-7 of the extent, at least a micrometre. */
  float extent = ub_scene_extent(scene);
  rt->scene_eps = fmaxf(extent * 1e-7f, 1e-6f);
  if (!find_twins(rt, scene, 4.0 * rt->scene_eps)) {
    ub_rt_free(rt);
    return UB_ERR_OUT_OF_MEMORY;
  }
  atomic_init(&rt->rays, 0);
  *out_rt = rt;
  return UB_OK;
}

void ub_rt_free(ub_rt *rt)
{
  if (!rt)
    return;
  if (rt->rscene)
    rtcReleaseScene(rt->rscene);
  if (rt->device)
    rtcReleaseDevice(rt->device);
  free(rt->prim_to_tri);
  free(rt->twin);
  free(rt);
}

/* A context filter: only hits on a triangle's front side (its geometric normal against
 * the ray). */
static void front_only(const struct RTCFilterFunctionNArguments *a)
{
  /* the SOA layouts of RTCRayN and RTCHitN (rtcore_ray.h: dir at 4N..6N, Ng at 0..2N) */
  const float *ray = (const float *)a->ray, *hit = (const float *)a->hit;
  const unsigned N = a->N;
  for (unsigned i = 0; i < N; i++)
    if (a->valid[i] && hit[i] * ray[4 * N + i] + hit[N + i] * ray[5 * N + i] +
                               hit[2 * N + i] * ray[6 * N + i] >
                           0.0f)
      a->valid[i] = 0;
}

/* Two triangles in one plane facing opposite ways (a wall between two rooms modelled as
 * each room's own face) are hit at the same t, and which one Embree returns depends on
 * its traversal: of test_rt's 98,304 gather-like rays on estate_small, 4,990 got the far
 * room's face (a back face: no light) one ray at a time and 8,592 as packets. A back-face
 * hit on a primitive with a twin (find_twins) is traced again within t's rounding, front
 * faces only: a front face there is the side the ray arrived on. */
static void prefer_front(const ub_rt *rt, struct RTCRayHit *h)
{
  if (h->hit.geomID == RTC_INVALID_GEOMETRY_ID || !rt->twin || !rt->twin[h->hit.primID] ||
      h->hit.Ng_x * h->ray.dir_x + h->hit.Ng_y * h->ray.dir_y + h->hit.Ng_z * h->ray.dir_z <= 0.0f)
    return;
  struct RTCRayHit f = *h;
  const float t = h->ray.tfar, d = t * 1e-6f;
  f.ray.tnear = t - d > h->ray.tnear ? t - d : h->ray.tnear;
  f.ray.tfar = t + d;
  f.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  f.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  struct RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  ctx.filter = front_only;
  rtcIntersect1(rt->rscene, &ctx, &f);
  if (f.hit.geomID != RTC_INVALID_GEOMETRY_ID)
    *h = f; /* its hit and t (tfar); the caller reads nothing else */
}

static void intersect(const ub_rt *rt, const ub_ray *rays, uint32_t n, ub_hit *out_hits,
                      int coherent)
{
  set_ftz_daz();
  struct RTCRayHit buf[UB_RT_STREAM] __attribute__((aligned(64)));
  struct RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  if (coherent)
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  for (uint32_t base = 0; base < n; base += UB_RT_STREAM) {
    uint32_t m = n - base < UB_RT_STREAM ? n - base : UB_RT_STREAM;
    for (uint32_t i = 0; i < m; i++) {
      const ub_ray *r = rays + base + i;
      struct RTCRayHit *h = buf + i;
      h->ray.org_x = r->org[0];
      h->ray.org_y = r->org[1];
      h->ray.org_z = r->org[2];
      h->ray.tnear = r->tnear;
      h->ray.dir_x = r->dir[0];
      h->ray.dir_y = r->dir[1];
      h->ray.dir_z = r->dir[2];
      h->ray.time = 0.0f;
      h->ray.tfar = r->tfar;
      h->ray.mask = 0xFFFFFFFFu;
      h->ray.id = i;
      h->ray.flags = 0;
      h->hit.geomID = RTC_INVALID_GEOMETRY_ID;
      h->hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    }
    rtcIntersect1M(rt->rscene, &ctx, buf, m, sizeof(struct RTCRayHit));
    for (uint32_t i = 0; i < m; i++) {
      struct RTCRayHit *h = buf + i;
      prefer_front(rt, h);
      ub_hit *o = out_hits + base + i;
      if (h->hit.geomID == RTC_INVALID_GEOMETRY_ID) {
        o->tri = UB_RT_MISS;
        o->t = INFINITY;
        o->u = o->v = 0.0f;
        o->ng[0] = o->ng[1] = o->ng[2] = 0.0f;
      } else {
        o->tri = rt->prim_to_tri[h->hit.primID];
        o->t = h->ray.tfar;
        o->u = h->hit.u;
        o->v = h->hit.v;
        o->ng[0] = h->hit.Ng_x;
        o->ng[1] = h->hit.Ng_y;
        o->ng[2] = h->hit.Ng_z;
      }
    }
  }
  atomic_fetch_add_explicit(&((ub_rt *)rt)->rays, n, memory_order_relaxed);
}

void ub_rt_intersect(const ub_rt *rt, const ub_ray *rays, uint32_t n, ub_hit *out_hits)
{
  intersect(rt, rays, n, out_hits, 0);
}

/* Sorted gathers, measured on the scale-0.12 ESTATE level (draft, 2 bounces, one thread
 * each, two runs at once, 2 rounds swapped): with the flag from 4096 rays the base pass
 * and the DLS full passes ran 4-11% faster (Embree's packets); from 2048 rays, or with
 * every stream coherent, the influence passes (8 rays a receiver, sparse) ran 8-10%
 * slower; from 8192 as from 4096. (Shadow rays: ub_rt_occluded_sorted.) */
void ub_rt_intersect_sorted(const ub_rt *rt, const ub_ray *rays, uint32_t n, ub_hit *out_hits)
{
  intersect(rt, rays, n, out_hits, n >= UB_RT_COHERENT_MIN);
}

static void occluded(const ub_rt *rt, const ub_ray *rays, uint32_t n, uint8_t *out_occluded,
                     int coherent)
{
  set_ftz_daz();
  struct RTCRay buf[UB_RT_STREAM] __attribute__((aligned(64)));
  struct RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  if (coherent)
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  for (uint32_t base = 0; base < n; base += UB_RT_STREAM) {
    uint32_t m = n - base < UB_RT_STREAM ? n - base : UB_RT_STREAM;
    for (uint32_t i = 0; i < m; i++) {
      const ub_ray *r = rays + base + i;
      struct RTCRay *h = buf + i;
      h->org_x = r->org[0];
      h->org_y = r->org[1];
      h->org_z = r->org[2];
      h->tnear = r->tnear;
      h->dir_x = r->dir[0];
      h->dir_y = r->dir[1];
      h->dir_z = r->dir[2];
      h->time = 0.0f;
      h->tfar = r->tfar;
      h->mask = 0xFFFFFFFFu;
      h->id = i;
      h->flags = 0;
    }
    rtcOccluded1M(rt->rscene, &ctx, buf, m, sizeof(struct RTCRay));
    for (uint32_t i = 0; i < m; i++)
      out_occluded[base + i] = buf[i].tfar == -INFINITY;
  }
  atomic_fetch_add_explicit(&((ub_rt *)rt)->rays, n, memory_order_relaxed);
}

void ub_rt_occluded(const ub_rt *rt, const ub_ray *rays, uint32_t n, uint8_t *out_occluded)
{
  occluded(rt, rays, n, out_occluded, 0);
}

/* As packets at any n: a block's rays toward one light stay coherent even when few (a
 * DLS set's 2 lights); measured in bake/pass.c trace_by_light. The texel lights' and the
 * gather hits' shadow rays go everywhere: traced as packets they made a bake 5% slower. */
void ub_rt_occluded_sorted(const ub_rt *rt, const ub_ray *rays, uint32_t n,
                           uint8_t *out_occluded)
{
  occluded(rt, rays, n, out_occluded, 1);
}

float ub_rt_epsilon(const ub_rt *rt, const float p[3])
{
  /* Float spacing grows with magnitude: 2^-22 ≈ 2.4e-7 relative is 2 ulps, enough with
   * Embree's robust (watertight) mode, and keeps a room 20 km out within 1% of the same
   * room at the origin (2^-17, 15 cm there, moved sample points off its walls: 52%). The
   * extent floor (1e-7 of the level) covers points near the origin. */
  float m = fmaxf(fabsf(p[0]), fmaxf(fabsf(p[1]), fabsf(p[2])));
  return fmaxf(rt->scene_eps, m * 2.384185791015625e-07f);
}

void ub_rt_offset_point(const ub_rt *rt, const float p[3], const float n[3], float out[3])
{
  float eps = ub_rt_epsilon(rt, p);
  out[0] = p[0] + n[0] * eps;
  out[1] = p[1] + n[1] * eps;
  out[2] = p[2] + n[2] * eps;
}

uint64_t ub_rt_rays_traced(const ub_rt *rt)
{
  return atomic_load_explicit(&((ub_rt *)rt)->rays, memory_order_relaxed);
}

uint64_t ub_rt_twin_count(const ub_rt *rt)
{
  return rt->twin_count;
}

const ub_scene *ub_rt_scene(const ub_rt *rt)
{
  return rt->scene;
}
