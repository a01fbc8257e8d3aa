/* The Embree wrapper's closest hits. Sorted gathers (ub_rt_intersect_sorted): Embree
 * traces streams of UB_RT_COHERENT_MIN or more rays as packets there, a different
 * traversal than ub_rt_intersect's, so the two must agree on what each ray hits. On
 * estate_small (UB_BUILD/levels), whose rooms each have their own face on the walls they
 * share: blocks of gather-like rays (64 origins just off neighbouring triangles, 64
 * hemisphere directions each, sorted by direction as the pass sorts them) traced both
 * ways: the same triangle for every ray but a few grazing ones, t within float rounding,
 * and never the back of a shared wall where its front (the twin face at the same t) is
 * there (without prefer_front, bake/rt.c: 4,990 such hits one ray at a time and 8,592 as
 * packets, of 98,304, and 3,672 rays on another triangle); below the threshold the two
 * are the same call, bit for bit. Shadow rays grouped by light (ub_rt_occluded_sorted)
 * answer as ub_rt_occluded does. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bake/rt.h"
#include "test_util.h"
#include "ubake/scene.h"

#define ORIGINS 64
#define DIRS 64
#define BLOCKS 24

static uint32_t lcg(uint32_t *s)
{
  *s = *s * 1664525u + 1013904223u;
  return *s >> 8;
}

static float u01(uint32_t *s)
{
  return (float)lcg(s) / 16777216.0f;
}

/* A coarse direction key (octant, then 4 × 4 cells of |x|, |y|), as the gathers' buckets. */
static uint32_t dir_key(const float d[3])
{
  uint32_t oct = (d[0] < 0.0f) | (d[1] < 0.0f) << 1 | (d[2] < 0.0f) << 2;
  uint32_t cx = (uint32_t)(fabsf(d[0]) * 3.999f), cy = (uint32_t)(fabsf(d[1]) * 3.999f);
  return oct * 16 + cx * 4 + cy;
}

typedef struct keyed {
  uint32_t key, i;
} keyed;

static int cmp_keyed(const void *a, const void *b)
{
  const keyed *x = a, *y = b;
  return x->key != y->key ? (x->key < y->key ? -1 : 1) : (x->i < y->i ? -1 : x->i > y->i);
}

/* Block b's rays, sorted by direction (stable): n = ORIGINS × DIRS. */
static uint32_t make_block(const ub_scene *s, uint32_t b, ub_ray *out)
{
  uint32_t seed = 0x9e3779b9u * (b + 1), n = 0;
  uint32_t t0 = lcg(&seed) % (s->triangle_count > ORIGINS ? s->triangle_count - ORIGINS : 1);
  ub_ray *tmp = malloc((size_t)ORIGINS * DIRS * sizeof *tmp);
  keyed *k = malloc((size_t)ORIGINS * DIRS * sizeof *k);
  ASSERT_TRUE(tmp && k);
  if (!tmp || !k) {
    free(tmp);
    free(k);
    return 0;
  }
  for (uint32_t o = 0; o < ORIGINS && t0 + o < s->triangle_count; o++) {
    const uint32_t *ix = s->indices + 3 * (size_t)(t0 + o);
    const float *p0 = s->positions + 3 * (size_t)ix[0], *p1 = s->positions + 3 * (size_t)ix[1],
                *p2 = s->positions + 3 * (size_t)ix[2];
    float e1[3], e2[3], nrm[3], c[3];
    for (int j = 0; j < 3; j++) {
      e1[j] = p1[j] - p0[j];
      e2[j] = p2[j] - p0[j];
      c[j] = (p0[j] + p1[j] + p2[j]) / 3.0f;
    }
    nrm[0] = e1[1] * e2[2] - e1[2] * e2[1];
    nrm[1] = e1[2] * e2[0] - e1[0] * e2[2];
    nrm[2] = e1[0] * e2[1] - e1[1] * e2[0];
    float l = sqrtf(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
    if (!(l > 1e-12f))
      continue;
    for (int j = 0; j < 3; j++)
      nrm[j] /= l;
    for (uint32_t r = 0; r < DIRS; r++) {
      float d[3];
      do { /* uniform in the ball, then onto the normal's side */
        for (int j = 0; j < 3; j++)
          d[j] = 2.0f * u01(&seed) - 1.0f;
      } while (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > 1.0f ||
               d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < 1e-4f);
      float dn = d[0] * nrm[0] + d[1] * nrm[1] + d[2] * nrm[2];
      if (dn < 0.0f)
        for (int j = 0; j < 3; j++)
          d[j] -= 2.0f * dn * nrm[j];
      ub_ray *ray = &tmp[n];
      for (int j = 0; j < 3; j++) {
        ray->org[j] = c[j] + 1e-3f * nrm[j];
        ray->dir[j] = d[j];
      }
      ray->tnear = 0.0f;
      ray->tfar = INFINITY;
      k[n].key = dir_key(d);
      k[n].i = n;
      n++;
    }
  }
  qsort(k, n, sizeof *k, cmp_keyed);
  for (uint32_t i = 0; i < n; i++)
    out[i] = tmp[k[i].i];
  free(tmp);
  free(k);
  return n;
}

/* A triangle's corners as a sorted key (positions), to find its twin: the same three
 * corners wound the other way (a wall two rooms share, each with its own face). */
typedef struct tri_key {
  float p[9];
  uint32_t t;
} tri_key;

static int cmp_pos(const void *a, const void *b)
{
  const float *x = a, *y = b;
  for (int j = 0; j < 3; j++)
    if (x[j] != y[j])
      return x[j] < y[j] ? -1 : 1;
  return 0;
}

static int cmp_tri_key(const void *a, const void *b)
{
  const tri_key *x = a, *y = b;
  for (int j = 0; j < 9; j++)
    if (x->p[j] != y->p[j])
      return x->p[j] < y->p[j] ? -1 : 1;
  return 0;
}

/* twin[t] = 1 when another triangle has t's three corners (then facing the other way, or
 * it would be a duplicate). */
static uint8_t *find_twins(const ub_scene *s, uint32_t *out_count)
{
  tri_key *k = malloc((size_t)s->triangle_count * sizeof *k);
  uint8_t *twin = calloc(s->triangle_count + 1, 1);
  ASSERT_TRUE(k && twin);
  *out_count = 0;
  if (!k || !twin) {
    free(k);
    return twin;
  }
  for (uint32_t t = 0; t < s->triangle_count; t++) {
    for (int c = 0; c < 3; c++)
      memcpy(k[t].p + 3 * c, s->positions + 3 * (size_t)s->indices[3 * (size_t)t + c],
             3 * sizeof(float));
    qsort(k[t].p, 3, 3 * sizeof(float), cmp_pos);
    k[t].t = t;
  }
  qsort(k, s->triangle_count, sizeof *k, cmp_tri_key);
  for (uint32_t i = 0; i + 1 < s->triangle_count; i++)
    if (!cmp_tri_key(&k[i], &k[i + 1])) {
      *out_count += !twin[k[i].t] + !twin[k[i + 1].t];
      twin[k[i].t] = twin[k[i + 1].t] = 1;
    }
  free(k);
  return twin;
}

/* 1 when h is a back-face hit on a triangle with a twin: the twin, at the same t, faces
 * the ray. */
static int back_on_twin(const uint8_t *twin, const ub_ray *r, const ub_hit *h)
{
  return h->tri != UB_RT_MISS && twin && twin[h->tri] &&
         h->ng[0] * r->dir[0] + h->ng[1] * r->dir[1] + h->ng[2] * r->dir[2] > 0.0f;
}

static void test_sorted(const ub_scene *s, const ub_rt *rt)
{
  uint32_t twins = 0;
  uint8_t *twin = find_twins(s, &twins);
  ub_ray *rays = malloc((size_t)ORIGINS * DIRS * sizeof *rays);
  ub_hit *ha = malloc((size_t)ORIGINS * DIRS * sizeof *ha);
  ub_hit *hb = malloc((size_t)ORIGINS * DIRS * sizeof *hb);
  ASSERT_TRUE(rays && ha && hb);
  uint64_t total = 0, hits = 0, other_tri = 0, coherent_blocks = 0, twin_back_a = 0,
           twin_back_b = 0;
  double worst_t = 0.0, worst_uv = 0.0;
  for (uint32_t b = 0; rays && ha && hb && b < BLOCKS; b++) {
    uint32_t n = make_block(s, b, rays);
    coherent_blocks += n >= UB_RT_COHERENT_MIN;
    ub_rt_intersect(rt, rays, n, ha);
    ub_rt_intersect_sorted(rt, rays, n, hb);
    for (uint32_t i = 0; i < n; i++) {
      twin_back_a += back_on_twin(twin, &rays[i], &ha[i]);
      twin_back_b += back_on_twin(twin, &rays[i], &hb[i]);
      total++;
      hits += ha[i].tri != UB_RT_MISS;
      if (ha[i].tri != hb[i].tri) {
        other_tri++;
        continue;
      }
      if (ha[i].tri == UB_RT_MISS)
        continue;
      double dt = fabs((double)ha[i].t - hb[i].t) / fmax(ha[i].t, 1e-3);
      double du = fmax(fabs((double)ha[i].u - hb[i].u), fabs((double)ha[i].v - hb[i].v));
      worst_t = fmax(worst_t, dt);
      worst_uv = fmax(worst_uv, du);
    }
    /* below the threshold: one and the same traversal */
    uint32_t m = UB_RT_COHERENT_MIN - 1 < n ? UB_RT_COHERENT_MIN - 1 : n;
    ub_rt_intersect(rt, rays, m, ha);
    ub_rt_intersect_sorted(rt, rays, m, hb);
    ASSERT_TRUE(memcmp(ha, hb, (size_t)m * sizeof *ha) == 0);
  }
  printf("test_rt: %llu rays in %llu coherent blocks, %.1f%% hit; another triangle for %llu; "
         "t within %.2e relative, barycentrics within %.2e; %u of %u triangles have a twin, "
         "back-face hits on one %llu / %llu (one by one / sorted)\n",
         (unsigned long long)total, (unsigned long long)coherent_blocks,
         total ? 100.0 * hits / total : 0.0, (unsigned long long)other_tri, worst_t, worst_uv,
         twins, s->triangle_count, (unsigned long long)twin_back_a,
         (unsigned long long)twin_back_b);
  ASSERT_TRUE(twins > 0);       /* the level has such walls (else the next check is empty) */
  ASSERT_TRUE(twin_back_a == 0 && twin_back_b == 0); /* the side the ray arrived on */
  ASSERT_TRUE(coherent_blocks >= BLOCKS / 2); /* the packet path was taken */
  ASSERT_TRUE(hits * 2 > total);              /* inside a closed level: most rays hit */
  ASSERT_TRUE(other_tri * 10000 <= total);    /* a grazing ray at an edge may differ */
  ASSERT_TRUE(worst_t <= 1e-5);
  ASSERT_TRUE(worst_uv <= 1e-5);
  free(twin);
  free(rays);
  free(ha);
  free(hb);
}

/* Shadow rays grouped by light (ub_rt_occluded_sorted, as the direct light's): from the
 * blocks' origins toward 8 points inside the level, each light's rays together; the same
 * answers as ub_rt_occluded but for rays grazing an edge. */
static void test_occluded_sorted(const ub_scene *s, const ub_rt *rt)
{
  enum { LIGHTS = 8 };
  ub_ray *rays = malloc((size_t)ORIGINS * DIRS * sizeof *rays);
  ub_ray *sh = malloc((size_t)ORIGINS * DIRS * LIGHTS * sizeof *sh);
  uint8_t *oa = malloc((size_t)ORIGINS * DIRS * LIGHTS);
  uint8_t *ob = malloc((size_t)ORIGINS * DIRS * LIGHTS);
  ASSERT_TRUE(rays && sh && oa && ob);
  uint64_t total = 0, blocked = 0, differ = 0;
  uint32_t seed = 12345;
  for (uint32_t b = 0; rays && sh && oa && ob && b < BLOCKS; b++) {
    uint32_t n = make_block(s, b, rays), m = 0;
    /* the lights: points a few metres along some of the block's own rays */
    float lp[LIGHTS][3];
    for (int l = 0; l < LIGHTS; l++) {
      const ub_ray *r = &rays[lcg(&seed) % (n ? n : 1)];
      for (int j = 0; j < 3; j++)
        lp[l][j] = r->org[j] + (1.0f + 4.0f * u01(&seed)) * r->dir[j];
    }
    for (int l = 0; l < LIGHTS; l++)
      for (uint32_t i = 0; i < n; i += DIRS) { /* one ray per origin and light */
        ub_ray *q = &sh[m++];
        float d2 = 0.0f;
        for (int j = 0; j < 3; j++) {
          q->org[j] = rays[i].org[j];
          q->dir[j] = lp[l][j] - q->org[j];
          d2 += q->dir[j] * q->dir[j];
        }
        q->tnear = 0.0f;
        q->tfar = d2 > 0.0f ? 1.0f - 1e-4f : 0.0f; /* t in units of the (unnormalised) dir */
      }
    ub_rt_occluded(rt, sh, m, oa);
    ub_rt_occluded_sorted(rt, sh, m, ob);
    for (uint32_t i = 0; i < m; i++) {
      total++;
      blocked += oa[i];
      differ += oa[i] != ob[i];
    }
  }
  printf("test_rt: %llu shadow rays grouped by light, %.1f%% blocked, %llu answered otherwise "
         "as packets\n",
         (unsigned long long)total, total ? 100.0 * blocked / total : 0.0,
         (unsigned long long)differ);
  ASSERT_TRUE(blocked > total / 20 && blocked < total - total / 20); /* both answers occur */
  ASSERT_TRUE(differ * 10000 <= total);
  free(rays);
  free(sh);
  free(oa);
  free(ob);
}

int main(void)
{
  const char *b = getenv("UB_BUILD");
  char path[1024];
  snprintf(path, sizeof path, "%s/levels/estate_small.gltf", b ? b : "build");
  ub_scene *s = NULL;
  ub_rt *rt = NULL;
  ASSERT_OK(ub_scene_load(path, NULL, &s));
  if (s)
    ASSERT_OK(ub_rt_create(s, NULL, NULL, &rt));
  if (rt) {
    test_sorted(s, rt);
    test_occluded_sorted(s, rt);
  }
  ub_rt_free(rt);
  ub_scene_free(s);
  TEST_MAIN_END();
}
