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
 * answer as ub_rt_occluded does. The twin search on a large plane with both sides (a
 * floor of 28,800 triangles, the other side over part of it) flags exactly the triangles
 * whose bounds meet the other side's, and prints its time (all pairs of the plane before
 * the sweep: O(k²)). */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

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

/* A floor at y = 3.7 of n×n unit quads facing up, and below it the same quads facing
 * down over the m×m corner [0, m]² (the other side of the same surface), written as a
 * glTF at path (its buffer beside it). 1 when written. */
static int write_plane(const char *path, uint32_t n, uint32_t m)
{
  const uint32_t nv = (n + 1) * (n + 1), nt = 2 * (n * n + m * m);
  float *pos = malloc((size_t)nv * 3 * sizeof *pos);
  uint32_t *idx = malloc((size_t)nt * 3 * sizeof *idx);
  if (!pos || !idx) {
    free(pos);
    free(idx);
    return 0;
  }
  for (uint32_t z = 0; z <= n; z++)
    for (uint32_t x = 0; x <= n; x++) {
      float *p = pos + 3 * ((size_t)z * (n + 1) + x);
      p[0] = (float)x, p[1] = 3.7f, p[2] = (float)z;
    }
  size_t k = 0;
  for (int side = 0; side < 2; side++) {
    uint32_t e = side ? m : n;
    for (uint32_t z = 0; z < e; z++)
      for (uint32_t x = 0; x < e; x++) {
        uint32_t a = z * (n + 1) + x, b = a + 1, c = a + n + 1, d = c + 1;
        uint32_t q[6] = {a, c, b, b, c, d}; /* up: (c − a) × (b − a) = +y */
        for (int j = 0; j < 6; j++)
          idx[k++] = side ? q[j - j % 3 + (3 - j % 3) % 3] : q[j]; /* down: reversed */
      }
  }
  char bin[1200];
  snprintf(bin, sizeof bin, "%s.bin", path);
  FILE *fb = fopen(bin, "wb"), *f = fopen(path, "w");
  int ok = fb && f && fwrite(pos, sizeof *pos, (size_t)nv * 3, fb) == (size_t)nv * 3 &&
           fwrite(idx, sizeof *idx, (size_t)nt * 3, fb) == (size_t)nt * 3;
  if (f) {
    const char *name = strrchr(bin, '/');
    fprintf(f,
            "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
            "\"nodes\":[{\"name\":\"plane\",\"mesh\":0}],\"meshes\":[{\"primitives\":"
            "[{\"attributes\":{\"POSITION\":0},\"indices\":1}]}],"
            "\"buffers\":[{\"uri\":\"%s\",\"byteLength\":%zu}],\"bufferViews\":["
            "{\"buffer\":0,\"byteOffset\":0,\"byteLength\":%zu},"
            "{\"buffer\":0,\"byteOffset\":%zu,\"byteLength\":%zu}],\"accessors\":["
            "{\"bufferView\":0,\"componentType\":5126,\"count\":%u,\"type\":\"VEC3\","
            "\"min\":[0,3.7,0],\"max\":[%u,3.7,%u]},"
            "{\"bufferView\":1,\"componentType\":5125,\"count\":%u,\"type\":\"SCALAR\"}]}\n",
            name ? name + 1 : bin, ((size_t)nv * 3 + (size_t)nt * 3) * 4, (size_t)nv * 12,
            (size_t)nv * 12, (size_t)nt * 12, nv, n, n, nt * 3);
    ok = ok && fclose(f) == 0;
  }
  if (fb)
    ok = fclose(fb) == 0 && ok;
  free(pos);
  free(idx);
  return ok;
}

/* Twins on a large two-sided plane: the down faces (m² quads) all, the up faces of the
 * (m + 1)² quads whose bounds meet the corner (inside it or touching its edge; the next
 * ones are a unit apart, far beyond the search's tolerance), none elsewhere. */
static void test_twins_plane(const char *build)
{
  const uint32_t n = 120, m = 80;
  char dir[1024], path[1100];
  snprintf(dir, sizeof dir, "%s/test_out", build);
  mkdir(dir, 0777);
  snprintf(path, sizeof path, "%s/rt_plane.gltf", dir);
  ASSERT_TRUE(write_plane(path, n, m));
  ub_scene *s = NULL;
  ub_rt *rt = NULL;
  ASSERT_OK(ub_scene_load(path, NULL, &s));
  if (!s)
    return;
  struct timespec t0, t1;
  clock_gettime(CLOCK_MONOTONIC, &t0);
  ASSERT_OK(ub_rt_create(s, NULL, NULL, &rt));
  clock_gettime(CLOCK_MONOTONIC, &t1);
  uint64_t want = 2 * (uint64_t)m * m + 2 * (uint64_t)(m + 1) * (m + 1);
  uint64_t got = rt ? ub_rt_twin_count(rt) : 0;
  printf("two-sided plane: %u triangles, %llu with a twin (expected %llu), ub_rt_create "
         "%.3f s\n",
         s->triangle_count, (unsigned long long)got, (unsigned long long)want,
         (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec));
  ASSERT_TRUE(s->triangle_count == 2 * (n * n + m * m));
  ASSERT_TRUE(got == want);
  ub_rt_free(rt);
  ub_scene_free(s);
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
  test_twins_plane(b ? b : "build");
  TEST_MAIN_END();
}
