/* runtime/render.c — preview renderer: own BVH, primary rays, baked lighting + run-time
 * direct light of primary lights, tone map (include/ubake/render.h). */
#include "ubake/render.h"

#include <assert.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "ubake/glg.h"
#include "ubake/llg.h"

/* BVH build: SAH bins per axis, the largest leaf SAH may choose, and the depth at which a
 * node becomes a leaf whatever its size (bounds the traversal stack). */
#define UB_BVH_BINS 16
#define UB_BVH_MAX_LEAF 8
#define UB_BVH_MAX_DEPTH 60
#define UB_BVH_STACK 64
/* SAH costs: one node visit vs one triangle test. */
#define UB_BVH_COST_NODE 1.0f
#define UB_BVH_COST_TRI 1.0f
/* Slab-test far distances grow by this factor so rounding never drops a box the ray
 * grazes (Ize 2013: 1 + 2γ_3). */
#define UB_BVH_TFAR_SCALE 1.00000024f
/* A ray direction component smaller than this in magnitude is replaced by ±this: 1/d
 * stays finite, so slab distances never become 0·∞ = NaN. */
#define UB_BVH_TINY_DIR 1e-30f

/* Shading. GLG queries for props are made this far (metres) above the hit, so the point is
 * in the air the probes describe, not on or under the surface. */
#define UB_RENDER_GLG_OFFSET 0.02f
/* Distances below this (metres) are treated as this for the inverse square law, as the
 * baker does: a light touching a surface stays finite. */
#define UB_RENDER_LIGHT_MIN_DIST 1e-4f
#define UB_RENDER_MAX_SIZE 16384u
#define UB_RENDER_MAX_SAMPLES 16u
/* Tone map: the auto exposure puts the 95th percentile of lit luminance here (before the
 * filmic curve; the curve maps 0.8 to about 0.7, sRGB ≈ 0.86). */
#define UB_TONEMAP_PERCENTILE 0.95
#define UB_TONEMAP_KEY 0.8

typedef struct bvh_node {
  float bmin[3];
  uint32_t offset; /* leaf: first triangle (in leaf order); interior: left child (right = +1) */
  float bmax[3];
  uint32_t count;  /* leaf: triangles (≥ 1); interior: 0 */
} bvh_node;

struct ub_bvh {
  uint32_t node_count, depth, tri_count;
  bvh_node *nodes;
  float *tri;       /* tri_count × 9 in leaf order: the corners v0, v1, v2 */
  uint32_t *tri_id; /* leaf order → original triangle index */
};

/* ---- small vector helpers ------------------------------------------------------------ */

static inline float dot3(const float a[3], const float b[3])
{
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static inline void cross3(const float a[3], const float b[3], float out[3])
{
  out[0] = a[1] * b[2] - a[2] * b[1];
  out[1] = a[2] * b[0] - a[0] * b[2];
  out[2] = a[0] * b[1] - a[1] * b[0];
}

/* Unit vector in double precision; zero (and 0 returned) for a zero or non-finite input. */
static int normalise3(const float v[3], float out[3])
{
  double l = sqrt((double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2]);
  if (!(l > 0.0) || !isfinite(l)) {
    out[0] = out[1] = out[2] = 0.0f;
    return 0;
  }
  for (int i = 0; i < 3; i++)
    out[i] = (float)(v[i] / l);
  return 1;
}

static inline float maxabs3(const float p[3])
{
  return fmaxf(fabsf(p[0]), fmaxf(fabsf(p[1]), fabsf(p[2])));
}

/* ---- BVH build ----------------------------------------------------------------------- */

typedef struct aabb {
  float lo[3], hi[3];
} aabb;

static void aabb_empty(aabb *b)
{
  for (int i = 0; i < 3; i++) {
    b->lo[i] = FLT_MAX;
    b->hi[i] = -FLT_MAX;
  }
}

static void aabb_grow_point(aabb *b, const float p[3])
{
  for (int i = 0; i < 3; i++) {
    b->lo[i] = fminf(b->lo[i], p[i]);
    b->hi[i] = fmaxf(b->hi[i], p[i]);
  }
}

static void aabb_grow(aabb *b, const aabb *o)
{
  for (int i = 0; i < 3; i++) {
    b->lo[i] = fminf(b->lo[i], o->lo[i]);
    b->hi[i] = fmaxf(b->hi[i], o->hi[i]);
  }
}

static float aabb_half_area(const aabb *b)
{
  float d[3];
  for (int i = 0; i < 3; i++) {
    d[i] = b->hi[i] - b->lo[i];
    if (!(d[i] > 0.0f))
      d[i] = 0.0f;
  }
  return d[0] * d[1] + d[1] * d[2] + d[2] * d[0];
}

typedef struct build_task {
  uint32_t node, begin, end, depth;
} build_task;

typedef struct build_ctx {
  const aabb *box;      /* per triangle */
  const float *cen;     /* per triangle centroid × 3 */
  uint32_t *prim;       /* permutation being partitioned */
} build_ctx;

/* qsort has no user pointer: sort (centroid, index) pairs instead. */
typedef struct key_index {
  float key;
  uint32_t index;
} key_index;

static int cmp_key(const void *a, const void *b)
{
  const key_index *x = a, *y = b;
  if (x->key < y->key)
    return -1;
  if (x->key > y->key)
    return 1;
  return (x->index > y->index) - (x->index < y->index);
}

/* Object median split along axis (fallback when binning cannot separate the centroids). */
static int median_split(build_ctx *c, uint32_t begin, uint32_t end, int axis, uint32_t *out_mid)
{
  uint32_t n = end - begin;
  key_index *k = malloc((size_t)n * sizeof *k);
  if (!k)
    return 0;
  for (uint32_t i = 0; i < n; i++) {
    k[i].index = c->prim[begin + i];
    k[i].key = c->cen[(size_t)k[i].index * 3 + axis];
  }
  qsort(k, n, sizeof *k, cmp_key);
  for (uint32_t i = 0; i < n; i++)
    c->prim[begin + i] = k[i].index;
  free(k);
  *out_mid = begin + n / 2;
  return 1;
}

/* Chooses how to treat prim[begin, end): returns 0 for a leaf, 1 with *out_mid for a split
 * (prim partitioned), -1 on out of memory. */
static int choose_split(build_ctx *c, uint32_t begin, uint32_t end, uint32_t depth,
                        const aabb *bounds, uint32_t *out_mid)
{
  uint32_t n = end - begin;
  if (n <= 2 || depth >= UB_BVH_MAX_DEPTH)
    return 0;
  aabb cb;
  aabb_empty(&cb);
  for (uint32_t i = begin; i < end; i++)
    aabb_grow_point(&cb, &c->cen[(size_t)c->prim[i] * 3]);
  float best_cost = FLT_MAX;
  int best_axis = -1, best_bin = -1;
  int widest = 0;
  for (int a = 1; a < 3; a++)
    if (cb.hi[a] - cb.lo[a] > cb.hi[widest] - cb.lo[widest])
      widest = a;
  for (int a = 0; a < 3; a++) {
    float ext = cb.hi[a] - cb.lo[a];
    if (!(ext > 0.0f))
      continue;
    float scale = (float)UB_BVH_BINS / ext;
    aabb bin_box[UB_BVH_BINS];
    uint32_t bin_n[UB_BVH_BINS] = {0};
    for (int b = 0; b < UB_BVH_BINS; b++)
      aabb_empty(&bin_box[b]);
    for (uint32_t i = begin; i < end; i++) {
      uint32_t p = c->prim[i];
      int b = (int)((c->cen[(size_t)p * 3 + a] - cb.lo[a]) * scale);
      b = b < 0 ? 0 : b >= UB_BVH_BINS ? UB_BVH_BINS - 1 : b;
      bin_n[b]++;
      aabb_grow(&bin_box[b], &c->box[p]);
    }
    /* Sweep from the right, then from the left: cost of each of the BINS-1 planes. */
    float right_area[UB_BVH_BINS];
    uint32_t right_n[UB_BVH_BINS];
    aabb acc;
    aabb_empty(&acc);
    uint32_t cnt = 0;
    for (int b = UB_BVH_BINS - 1; b > 0; b--) {
      aabb_grow(&acc, &bin_box[b]);
      cnt += bin_n[b];
      right_area[b] = aabb_half_area(&acc);
      right_n[b] = cnt;
    }
    aabb_empty(&acc);
    cnt = 0;
    for (int b = 0; b < UB_BVH_BINS - 1; b++) {
      aabb_grow(&acc, &bin_box[b]);
      cnt += bin_n[b];
      if (cnt == 0 || right_n[b + 1] == 0)
        continue;
      float cost = aabb_half_area(&acc) * (float)cnt + right_area[b + 1] * (float)right_n[b + 1];
      if (cost < best_cost) {
        best_cost = cost;
        best_axis = a;
        best_bin = b;
      }
    }
  }
  float parent_area = aabb_half_area(bounds);
  float leaf_cost = UB_BVH_COST_TRI * (float)n;
  if (best_axis >= 0 && parent_area > 0.0f) {
    float split_cost = UB_BVH_COST_NODE + UB_BVH_COST_TRI * best_cost / parent_area;
    if (split_cost >= leaf_cost && n <= UB_BVH_MAX_LEAF)
      return 0;
    /* Partition by bin. */
    float ext = cb.hi[best_axis] - cb.lo[best_axis];
    float scale = (float)UB_BVH_BINS / ext;
    uint32_t i = begin, j = end;
    while (i < j) {
      uint32_t p = c->prim[i];
      int b = (int)((c->cen[(size_t)p * 3 + best_axis] - cb.lo[best_axis]) * scale);
      b = b < 0 ? 0 : b >= UB_BVH_BINS ? UB_BVH_BINS - 1 : b;
      if (b <= best_bin) {
        i++;
      } else {
        j--;
        c->prim[i] = c->prim[j];
        c->prim[j] = p;
      }
    }
    if (i > begin && i < end) {
      *out_mid = i;
      return 1;
    }
  }
  if (n <= UB_BVH_MAX_LEAF)
    return 0;
  if (!(cb.hi[widest] - cb.lo[widest] > 0.0f)) {
    /* Every centroid coincides: any split is as good; halve the range. */
    *out_mid = begin + n / 2;
    return 1;
  }
  return median_split(c, begin, end, widest, out_mid) ? 1 : -1;
}

ub_result ub_bvh_build(const float *positions, uint32_t vertex_count, const uint32_t *indices,
                       uint32_t triangle_count, ub_bvh **out_bvh)
{
  assert(out_bvh && (triangle_count == 0 || (positions && indices)));
  if (triangle_count > (UINT32_MAX - 1) / 2)
    return UB_ERR_INVALID_ARGUMENT;
  for (size_t i = 0; i < (size_t)triangle_count * 3; i++)
    if (indices[i] >= vertex_count)
      return UB_ERR_INVALID_ARGUMENT;
  for (size_t i = 0; i < (size_t)vertex_count * 3; i++)
    if (!isfinite(positions[i]))
      return UB_ERR_INVALID_ARGUMENT;

  ub_bvh *bvh = calloc(1, sizeof *bvh);
  if (!bvh)
    return UB_ERR_OUT_OF_MEMORY;
  if (triangle_count == 0) {
    *out_bvh = bvh;
    return UB_OK;
  }
  size_t n = triangle_count;
  aabb *box = malloc(n * sizeof *box);
  float *cen = malloc(n * 3 * sizeof *cen);
  uint32_t *prim = malloc(n * sizeof *prim);
  build_task *stack = malloc(2 * n * sizeof *stack);
  bvh->nodes = malloc((2 * n - 1) * sizeof *bvh->nodes);
  bvh->tri = malloc(n * 9 * sizeof *bvh->tri);
  bvh->tri_id = malloc(n * sizeof *bvh->tri_id);
  ub_result r = UB_ERR_OUT_OF_MEMORY;
  if (!box || !cen || !prim || !stack || !bvh->nodes || !bvh->tri || !bvh->tri_id)
    goto done;
  for (size_t t = 0; t < n; t++) {
    aabb_empty(&box[t]);
    for (int k = 0; k < 3; k++)
      aabb_grow_point(&box[t], &positions[(size_t)indices[t * 3 + k] * 3]);
    for (int a = 0; a < 3; a++)
      cen[t * 3 + a] = 0.5f * (box[t].lo[a] + box[t].hi[a]);
    prim[t] = (uint32_t)t;
  }

  build_ctx c = {box, cen, prim};
  uint32_t used = 1, sp = 0, leaf_tris = 0;
  stack[sp++] = (build_task){0, 0, (uint32_t)n, 0};
  while (sp) {
    build_task task = stack[--sp];
    aabb b;
    aabb_empty(&b);
    for (uint32_t i = task.begin; i < task.end; i++)
      aabb_grow(&b, &box[prim[i]]);
    bvh_node *node = &bvh->nodes[task.node];
    memcpy(node->bmin, b.lo, sizeof b.lo);
    memcpy(node->bmax, b.hi, sizeof b.hi);
    if (task.depth > bvh->depth)
      bvh->depth = task.depth;
    uint32_t mid = 0;
    int s = choose_split(&c, task.begin, task.end, task.depth, &b, &mid);
    if (s < 0)
      goto done;
    if (s == 0) {
      node->offset = leaf_tris;
      node->count = task.end - task.begin;
      for (uint32_t i = task.begin; i < task.end; i++) {
        uint32_t t = prim[i];
        const float *v0 = &positions[(size_t)indices[(size_t)t * 3 + 0] * 3];
        const float *v1 = &positions[(size_t)indices[(size_t)t * 3 + 1] * 3];
        const float *v2 = &positions[(size_t)indices[(size_t)t * 3 + 2] * 3];
        float *o = &bvh->tri[(size_t)leaf_tris * 9];
        memcpy(o, v0, 3 * sizeof *o);
        memcpy(o + 3, v1, 3 * sizeof *o);
        memcpy(o + 6, v2, 3 * sizeof *o);
        bvh->tri_id[leaf_tris++] = t;
      }
      continue;
    }
    node->offset = used;
    node->count = 0;
    stack[sp++] = (build_task){used + 1, mid, task.end, task.depth + 1};
    stack[sp++] = (build_task){used, task.begin, mid, task.depth + 1};
    used += 2;
  }
  bvh->node_count = used;
  bvh->tri_count = leaf_tris;
  r = UB_OK;
done:
  free(box);
  free(cen);
  free(prim);
  free(stack);
  if (r != UB_OK) {
    ub_bvh_free(bvh);
    return r;
  }
  *out_bvh = bvh;
  return UB_OK;
}

void ub_bvh_free(ub_bvh *bvh)
{
  if (!bvh)
    return;
  free(bvh->nodes);
  free(bvh->tri);
  free(bvh->tri_id);
  free(bvh);
}

void ub_bvh_stats(const ub_bvh *bvh, uint32_t *out_nodes, uint32_t *out_depth)
{
  assert(bvh);
  if (out_nodes)
    *out_nodes = bvh->node_count;
  if (out_depth)
    *out_depth = bvh->depth;
}

/* ---- BVH traversal ------------------------------------------------------------------- */

/* A ray with its slab-test reciprocals and the watertight triangle test's frame (Woop,
 * Benthin and Wald 2013): kz the axis where |d| is largest, kx and ky the others (swapped
 * when d[kz] < 0 so the winding is kept), and the shear that maps d onto +kz. */
typedef struct ray_pre {
  float o[3], inv[3];
  int kx, ky, kz;
  float sx, sy, sz;
} ray_pre;

/* 0 for a zero direction (no frame: nothing is hit). */
static int ray_prepare(const float org[3], const float dir[3], ray_pre *out)
{
  for (int a = 0; a < 3; a++) {
    out->o[a] = org[a];
    float d = dir[a];
    if (!(fabsf(d) >= UB_BVH_TINY_DIR))
      d = d < 0.0f ? -UB_BVH_TINY_DIR : UB_BVH_TINY_DIR;
    out->inv[a] = 1.0f / d;
  }
  int kz = fabsf(dir[0]) >= fabsf(dir[1]) ? 0 : 1;
  if (fabsf(dir[2]) > fabsf(dir[kz]))
    kz = 2;
  if (dir[kz] == 0.0f)
    return 0;
  int kx = kz == 2 ? 0 : kz + 1, ky = kx == 2 ? 0 : kx + 1;
  if (dir[kz] < 0.0f) {
    int k = kx;
    kx = ky;
    ky = k;
  }
  out->kx = kx;
  out->ky = ky;
  out->kz = kz;
  out->sx = dir[kx] / dir[kz];
  out->sy = dir[ky] / dir[kz];
  out->sz = 1.0f / dir[kz];
  return 1;
}

/* γ_n = n·u / (1 − n·u), u = 2^-24: the bound on n float roundings (PBR 3rd ed., 3.9.1). */
#define UB_GAMMA(n) ((n) * 0.5f * FLT_EPSILON / (1.0f - (n) * 0.5f * FLT_EPSILON))

static inline float minf(float a, float b)
{
  return a < b ? a : b;
}

static inline float maxf(float a, float b)
{
  return a > b ? a : b;
}

/* Entry distance of the ray into the node's box within (0, tmax), or INFINITY. No NaN can
 * arise: bounds, origin and 1/d are finite (ray_prepare). */
static inline float box_enter(const bvh_node *nd, const ray_pre *r, float tmax)
{
  float t0 = 0.0f, t1 = tmax;
  for (int a = 0; a < 3; a++) {
    float ta = (nd->bmin[a] - r->o[a]) * r->inv[a];
    float tb = (nd->bmax[a] - r->o[a]) * r->inv[a];
    t0 = maxf(t0, minf(ta, tb));
    t1 = minf(t1, maxf(ta, tb) * UB_BVH_TFAR_SCALE);
  }
  return t0 <= t1 ? t0 : INFINITY;
}

/* Watertight ray-triangle test (Woop, Benthin and Wald 2013) on one stored triangle: 1 with
 * t, b1, b2 for a hit in (0, tmax). The corners are moved to the ray's origin and sheared
 * so the ray runs along +kz; the 2D edge functions of an edge then depend only on its two
 * corners and the ray, so the two triangles sharing it compute them from the same numbers
 * (exactly negated, as long as no fused multiply-add contracts one product: the build
 * targets baseline x86-64) and a ray through the edge hits one of them: no ray slips through
 * (Moller-Trumbore's edges from v1 - v0 and v2 - v0 round differently in each triangle,
 * which let camera rays through shared edges: black speckles). An edge function that
 * comes out 0 in float is recomputed exactly in double, as the paper does. */
static inline int tri_hit(const float *tri, const ray_pre *r, float tmax, float *out_t,
                          float *out_b1, float *out_b2)
{
  const int kx = r->kx, ky = r->ky, kz = r->kz;
  const float *pa = tri, *pb = tri + 3, *pc = tri + 6;
  const float az = pa[kz] - r->o[kz], bz = pb[kz] - r->o[kz], cz = pc[kz] - r->o[kz];
  const float ax = (pa[kx] - r->o[kx]) - r->sx * az, ay = (pa[ky] - r->o[ky]) - r->sy * az;
  const float bx = (pb[kx] - r->o[kx]) - r->sx * bz, by = (pb[ky] - r->o[ky]) - r->sy * bz;
  const float cx = (pc[kx] - r->o[kx]) - r->sx * cz, cy = (pc[ky] - r->o[ky]) - r->sy * cz;
  float u = cx * by - cy * bx; /* weight of corner 0 (a) */
  float v = ax * cy - ay * cx; /* corner 1 (b) */
  float w = bx * ay - by * ax; /* corner 2 (c) */
  if (u == 0.0f || v == 0.0f || w == 0.0f) {
    u = (float)((double)cx * by - (double)cy * bx);
    v = (float)((double)ax * cy - (double)ay * cx);
    w = (float)((double)bx * ay - (double)by * ax);
  }
  if ((u < 0.0f || v < 0.0f || w < 0.0f) && (u > 0.0f || v > 0.0f || w > 0.0f))
    return 0;
  float det = u + v + w;
  if (det == 0.0f || !isfinite(det))
    return 0;
  const float sa = r->sz * az, sb = r->sz * bz, sc = r->sz * cz;
  float inv = 1.0f / det;
  float t = (u * sa + v * sb + w * sc) * inv;
  if (!(t > 0.0f && t < tmax))
    return 0;
  /* A t within its rounding bound of 0 (Pharr, Jakob and Humphreys, PBR 3rd ed., 3.9.6)
   * is a ray starting in the triangle's plane (a camera placed on a wall), not a hit. */
  const float zt = maxf(fabsf(sa), maxf(fabsf(sb), fabsf(sc)));
  const float xt = maxf(fabsf(ax), maxf(fabsf(bx), fabsf(cx)));
  const float yt = maxf(fabsf(ay), maxf(fabsf(by), fabsf(cy)));
  const float et = maxf(fabsf(u), maxf(fabsf(v), fabsf(w)));
  const float dx = UB_GAMMA(5) * (xt + zt), dy = UB_GAMMA(5) * (yt + zt);
  const float de = 2.0f * (UB_GAMMA(2) * xt * yt + dy * xt + dx * yt);
  if (!(t > 3.0f * (UB_GAMMA(3) * et * zt + de * zt + UB_GAMMA(3) * zt * et) * fabsf(inv)))
    return 0;
  *out_t = t;
  *out_b1 = v * inv;
  *out_b2 = w * inv;
  return 1;
}

/* any: stop at the first hit. Returns 1 on a hit (best filled). */
static int traverse(const ub_bvh *bvh, const float org[3], const float dir[3], float tmax,
                    int any, ub_bvh_hit *best)
{
  if (bvh->node_count == 0 || !(tmax > 0.0f))
    return 0;
  for (int a = 0; a < 3; a++)
    if (!isfinite(org[a]) || !isfinite(dir[a]))
      return 0;
  ray_pre r;
  if (!ray_prepare(org, dir, &r))
    return 0;
  float tbest = tmax;
  int found = 0;
  uint32_t stack[UB_BVH_STACK];
  float stack_t[UB_BVH_STACK];
  uint32_t sp = 0;
  if (box_enter(&bvh->nodes[0], &r, tbest) == INFINITY)
    return 0;
  uint32_t ni = 0;
  for (;;) {
    const bvh_node *nd = &bvh->nodes[ni];
    if (nd->count) {
      for (uint32_t k = 0; k < nd->count; k++) {
        uint32_t ti = nd->offset + k;
        float t, b1, b2;
        if (tri_hit(&bvh->tri[(size_t)ti * 9], &r, tbest, &t, &b1, &b2)) {
          tbest = t;
          found = 1;
          best->t = t;
          best->b1 = b1;
          best->b2 = b2;
          best->tri = bvh->tri_id[ti];
          if (any)
            return 1;
        }
      }
    } else {
      uint32_t l = nd->offset, rr = l + 1;
      float tl = box_enter(&bvh->nodes[l], &r, tbest);
      float tr = box_enter(&bvh->nodes[rr], &r, tbest);
      if (tl != INFINITY && tr != INFINITY) {
        uint32_t near = tl <= tr ? l : rr, far = tl <= tr ? rr : l;
        assert(sp < UB_BVH_STACK);
        stack[sp] = far;
        stack_t[sp++] = tl <= tr ? tr : tl;
        ni = near;
        continue;
      }
      if (tl != INFINITY) {
        ni = l;
        continue;
      }
      if (tr != INFINITY) {
        ni = rr;
        continue;
      }
    }
    /* Pop the next node still in front of the closest hit. */
    for (;;) {
      if (sp == 0)
        return found;
      sp--;
      if (stack_t[sp] < tbest)
        break;
    }
    ni = stack[sp];
  }
}

int ub_bvh_intersect(const ub_bvh *bvh, const float org[3], const float dir[3], float tmax,
                     ub_bvh_hit *out_hit)
{
  assert(bvh && org && dir && out_hit);
  ub_bvh_hit h;
  if (!traverse(bvh, org, dir, tmax, 0, &h))
    return 0;
  *out_hit = h;
  return 1;
}

int ub_bvh_occluded(const ub_bvh *bvh, const float org[3], const float dir[3], float tmax)
{
  assert(bvh && org && dir);
  ub_bvh_hit h;
  return traverse(bvh, org, dir, tmax, 1, &h);
}

/* ---- renderer ------------------------------------------------------------------------ */

struct ub_renderer {
  const ub_runtime *rt;
  const ub_bakefile *bf;
  ub_bvh *bvh;
  float *tri_normal;      /* triangle × 3: unit geometric normal (CCW front), 0 if degenerate */
  float scene_eps;        /* metres: ray offset floor from the level's extent */
  uint32_t primary_count;
  uint32_t *primary;      /* indices of primary lights in bf->lights */
  int has_glg;
};

void ub_render_params_default(ub_render_params *out_params)
{
  assert(out_params);
  memset(out_params, 0, sizeof *out_params);
  out_params->target[2] = -1.0f;
  out_params->fovy_degrees = 60.0f;
  out_params->width = 960;
  out_params->height = 540;
  out_params->samples = 1;
}

ub_result ub_renderer_create(const ub_runtime *rt, const ub_log *log, ub_renderer **out)
{
  assert(rt && out);
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  ub_renderer *r = calloc(1, sizeof *r);
  if (!r)
    goto oom;
  r->rt = rt;
  r->bf = bf;
  r->has_glg = ub_runtime_glg(rt) != NULL;
  /* Triangles the state hides (door leaves, objects) become degenerate: never hit. */
  uint32_t *idx = NULL;
  if (bf->tri_role) {
    idx = malloc(((size_t)bf->triangle_count * 3 + 1) * sizeof *idx);
    if (!idx) {
      ub_renderer_free(r);
      goto oom;
    }
    for (uint32_t t = 0; t < bf->triangle_count; t++) {
      int shown = ub_runtime_triangle_shown(rt, t);
      for (int k = 0; k < 3; k++)
        idx[3 * (size_t)t + k] = bf->indices[3 * (size_t)t + (shown ? k : 0)];
    }
  }
  ub_result res = ub_bvh_build(bf->positions, bf->vertex_count, idx ? idx : bf->indices,
                               bf->triangle_count, &r->bvh);
  free(idx);
  if (res == UB_ERR_OUT_OF_MEMORY) {
    ub_renderer_free(r);
    goto oom;
  }
  if (res != UB_OK) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: geometry unusable for rendering (%s)",
                  bf->level_name, ub_result_string(res));
    ub_renderer_free(r);
    return res;
  }
  if (bf->triangle_count) {
    r->tri_normal = malloc((size_t)bf->triangle_count * 3 * sizeof *r->tri_normal);
    if (!r->tri_normal) {
      ub_renderer_free(r);
      goto oom;
    }
  }
  aabb ext;
  aabb_empty(&ext);
  for (uint32_t v = 0; v < bf->vertex_count; v++)
    aabb_grow_point(&ext, &bf->positions[(size_t)v * 3]);
  float extent = 0.0f;
  if (bf->vertex_count)
    for (int a = 0; a < 3; a++)
      extent = fmaxf(extent, ext.hi[a] - ext.lo[a]);
  r->scene_eps = fmaxf(extent * 1e-5f, 1e-6f);
  for (uint32_t t = 0; t < bf->triangle_count; t++) {
    const float *v0 = &bf->positions[(size_t)bf->indices[(size_t)t * 3 + 0] * 3];
    const float *v1 = &bf->positions[(size_t)bf->indices[(size_t)t * 3 + 1] * 3];
    const float *v2 = &bf->positions[(size_t)bf->indices[(size_t)t * 3 + 2] * 3];
    float e1[3], e2[3], c[3];
    for (int a = 0; a < 3; a++) {
      e1[a] = v1[a] - v0[a];
      e2[a] = v2[a] - v0[a];
    }
    cross3(e1, e2, c);
    normalise3(c, &r->tri_normal[(size_t)t * 3]);
  }
  for (uint32_t i = 0; i < bf->light_count; i++)
    r->primary_count += bf->lights[i].cls == 1;
  if (r->primary_count) {
    r->primary = malloc((size_t)r->primary_count * sizeof *r->primary);
    if (!r->primary) {
      ub_renderer_free(r);
      goto oom;
    }
    uint32_t k = 0;
    for (uint32_t i = 0; i < bf->light_count; i++)
      if (bf->lights[i].cls == 1)
        r->primary[k++] = i;
  }
  *out = r;
  return UB_OK;
oom:
  ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory building the render BVH",
                bf->level_name);
  return UB_ERR_OUT_OF_MEMORY;
}

void ub_renderer_free(ub_renderer *r)
{
  if (!r)
    return;
  ub_bvh_free(r->bvh);
  free(r->tri_normal);
  free(r->primary);
  free(r);
}

const ub_bvh *ub_renderer_bvh(const ub_renderer *r)
{
  assert(r);
  return r->bvh;
}

ub_result ub_render_params_check(const ub_render_params *p, uint32_t dls_count,
                                 const ub_log *log)
{
  assert(p);
  for (int a = 0; a < 3; a++)
    if (!isfinite(p->eye[a]) || !isfinite(p->target[a])) {
      ub_log_printf(log, UB_LOG_ERROR, "camera: eye and target must be finite");
      return UB_ERR_INVALID_ARGUMENT;
    }
  float d[3] = {p->target[0] - p->eye[0], p->target[1] - p->eye[1], p->target[2] - p->eye[2]};
  float scale = fmaxf(1.0f, fmaxf(maxabs3(p->eye), maxabs3(p->target)));
  if (!(maxabs3(d) > scale * 1e-6f)) {
    ub_log_printf(log, UB_LOG_ERROR,
                  "camera: eye and target are the same point (%g, %g, %g): no view direction",
                  p->eye[0], p->eye[1], p->eye[2]);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (!(p->fovy_degrees > 0.0f && p->fovy_degrees < 180.0f)) {
    ub_log_printf(log, UB_LOG_ERROR, "camera: vertical field of view %g is not in (0, 180) degrees",
                  p->fovy_degrees);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (p->width < 1 || p->height < 1 || p->width > UB_RENDER_MAX_SIZE ||
      p->height > UB_RENDER_MAX_SIZE) {
    ub_log_printf(log, UB_LOG_ERROR, "image size %ux%u is not within 1..%u per side",
                  p->width, p->height, UB_RENDER_MAX_SIZE);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (p->samples > UB_RENDER_MAX_SAMPLES) {
    ub_log_printf(log, UB_LOG_ERROR, "samples %u per axis is more than %u", p->samples,
                  UB_RENDER_MAX_SAMPLES);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (p->dls_weights)
    for (uint32_t i = 0; i < dls_count * 3; i++)
      if (!isfinite(p->dls_weights[i]) || p->dls_weights[i] < 0.0f) {
        ub_log_printf(log, UB_LOG_ERROR,
                      "dynamic light set %u: weight %g is not a finite value >= 0", i / 3,
                      p->dls_weights[i]);
        return UB_ERR_INVALID_ARGUMENT;
      }
  return UB_OK;
}

/* Camera frame: unit forward, right, up and the image plane half-extents. */
typedef struct cam_frame {
  float f[3], right[3], up[3];
  float half_h, half_w;
} cam_frame;

static void camera_frame(const ub_render_params *p, cam_frame *out)
{
  float d[3] = {p->target[0] - p->eye[0], p->target[1] - p->eye[1], p->target[2] - p->eye[2]};
  normalise3(d, out->f);
  float world_up[3] = {0.0f, 1.0f, 0.0f}, c[3];
  cross3(out->f, world_up, c);
  if (!(sqrtf(dot3(c, c)) > 1e-4f)) {
    /* Looking straight up or down: the top of the image points to −Z (down) / +Z (up). */
    float alt[3] = {0.0f, 0.0f, out->f[1] < 0.0f ? -1.0f : 1.0f};
    cross3(out->f, alt, c);
  }
  normalise3(c, out->right);
  cross3(out->right, out->f, out->up);
  out->half_h = tanf(0.5f * p->fovy_degrees * (float)(M_PI / 180.0));
  out->half_w = out->half_h * (float)p->width / (float)p->height;
}

/* The (unnormalised) direction through image point (px, py), both in [0, 1] from the
 * top-left corner. */
static void camera_dir(const cam_frame *cf, float px, float py, float out[3])
{
  float u = (2.0f * px - 1.0f) * cf->half_w, v = (1.0f - 2.0f * py) * cf->half_h;
  for (int a = 0; a < 3; a++)
    out[a] = cf->f[a] + u * cf->right[a] + v * cf->up[a];
}

/* Run-time direct light (irradiance, W/m²) of light l at p with unit normal n; 0 when the
 * light is behind, outside its cone or range. Same model as the baker (bake/lights.c). */
static int light_incident(const ub_bakefile_light *l, const float p[3], float out_dir[3],
                          float *out_dist, float out_e[3])
{
  if (l->type == 2) {
    for (int a = 0; a < 3; a++) {
      out_dir[a] = -l->direction[a];
      out_e[a] = l->intensity[a];
    }
    *out_dist = INFINITY;
    return 1;
  }
  float d[3] = {l->position[0] - p[0], l->position[1] - p[1], l->position[2] - p[2]};
  float dist = sqrtf(dot3(d, d));
  if (!(dist > 0.0f))
    return 0;
  for (int a = 0; a < 3; a++)
    out_dir[a] = d[a] / dist;
  *out_dist = dist;
  float de = fmaxf(dist, UB_RENDER_LIGHT_MIN_DIST);
  float atten = 1.0f / (de * de);
  if (l->range > 0.0f) {
    if (dist >= l->range)
      return 0;
    float x = dist / l->range;
    float w = 1.0f - x * x * x * x;
    atten *= w * w;
  }
  if (l->type == 1) {
    float cd = -dot3(out_dir, l->direction);
    if (cd <= l->cos_outer)
      return 0;
    float scale = 1.0f / fmaxf(1e-3f, l->cos_inner - l->cos_outer);
    float a = (cd - l->cos_outer) * scale;
    a = a < 0.0f ? 0.0f : (a > 1.0f ? 1.0f : a);
    atten *= a * a;
  }
  for (int a = 0; a < 3; a++)
    out_e[a] = l->intensity[a] * atten;
  return 1;
}

/* Radiance (W/(m²·sr)) seen along the ray; 0 for a miss or a back face. */
static void shade(const ub_renderer *r, const ub_render_params *p, const float org[3],
                  const float dir[3], uint32_t *tet_cache, float out[3])
{
  out[0] = out[1] = out[2] = 0.0f;
  ub_bvh_hit h;
  if (!ub_bvh_intersect(r->bvh, org, dir, INFINITY, &h))
    return;
  const ub_bakefile *bf = r->bf;
  const float *n = &r->tri_normal[(size_t)h.tri * 3];
  if (!(dot3(n, dir) < 0.0f))
    return; /* back face (or degenerate): reflects nothing, as in the baker */
  const float *v0 = &bf->positions[(size_t)bf->indices[(size_t)h.tri * 3 + 0] * 3];
  const float *v1 = &bf->positions[(size_t)bf->indices[(size_t)h.tri * 3 + 1] * 3];
  const float *v2 = &bf->positions[(size_t)bf->indices[(size_t)h.tri * 3 + 2] * 3];
  float b0 = 1.0f - h.b1 - h.b2, x[3];
  for (int a = 0; a < 3; a++)
    x[a] = b0 * v0[a] + h.b1 * v1[a] + h.b2 * v2[a];
  float eps = fmaxf(r->scene_eps, maxabs3(x) * 7.62939453125e-06f);

  float e[3] = {0.0f, 0.0f, 0.0f};
  if (bf->tri_atlas[h.tri] >= 0) {
    if (ub_runtime_lightmap_at(r->rt, h.tri, h.b1, h.b2, n, e) != UB_OK)
      e[0] = e[1] = e[2] = 0.0f;
  } else {
    /* An LLG model's own surface (inside its box): its LLG, as the game shades it;
     * anything else unlit by a lightmap: the GLG. */
    uint32_t mi = UINT32_MAX;
    int llg = bf->llg_count && ub_runtime_query_llg_ex(r->rt, x, n, 0, e, &mi) == UB_OK &&
              mi < bf->llg_count &&
              ub_llg_box_distance(bf->llgs[mi].center, bf->llgs[mi].axes, bf->llgs[mi].half,
                                  x) <= 0.0f;
    if (!llg) {
      e[0] = e[1] = e[2] = 0.0f;
      float q[3];
      for (int a = 0; a < 3; a++)
        q[a] = x[a] + n[a] * (UB_RENDER_GLG_OFFSET + eps);
      if (r->has_glg && ub_runtime_query_glg(r->rt, q, n, tet_cache, e) != UB_OK)
        e[0] = e[1] = e[2] = 0.0f;
    }
  }

  if (r->primary_count) {
    float o[3];
    for (int a = 0; a < 3; a++)
      o[a] = x[a] + n[a] * eps;
    for (uint32_t k = 0; k < r->primary_count; k++) {
      const ub_bakefile_light *l = &bf->lights[r->primary[k]];
      float w[3] = {1.0f, 1.0f, 1.0f};
      if (l->dls >= 0 && (uint32_t)l->dls < bf->dls_count && p->dls_weights)
        memcpy(w, &p->dls_weights[(size_t)l->dls * 3], sizeof w);
      if (w[0] == 0.0f && w[1] == 0.0f && w[2] == 0.0f)
        continue;
      float ldir[3], dist, le[3];
      if (!light_incident(l, x, ldir, &dist, le))
        continue;
      float cs = dot3(n, ldir);
      if (!(cs > 0.0f))
        continue;
      float tmax = isfinite(dist) ? dist - 2.0f * eps : FLT_MAX;
      if (tmax > 0.0f && ub_bvh_occluded(r->bvh, o, ldir, tmax))
        continue;
      for (int a = 0; a < 3; a++)
        e[a] += le[a] * cs * w[a];
    }
  }
  const float *alb = &bf->tri_albedo[(size_t)h.tri * 3];
  for (int a = 0; a < 3; a++) {
    float v = alb[a] * (float)M_1_PI * e[a];
    out[a] = isfinite(v) && v > 0.0f ? v : 0.0f;
  }
}

ub_result ub_renderer_render(const ub_renderer *r, const ub_render_params *p,
                             uint32_t row_begin, uint32_t row_end, float *out_rgb,
                             const ub_log *log)
{
  assert(r && p && out_rgb);
  ub_result res = ub_render_params_check(p, r->bf->dls_count, log);
  if (res != UB_OK)
    return res;
  if (row_begin > row_end || row_end > p->height) {
    ub_log_printf(log, UB_LOG_ERROR, "rows %u..%u are not within the image's %u rows",
                  row_begin, row_end, p->height);
    return UB_ERR_INVALID_ARGUMENT;
  }
  cam_frame cf;
  camera_frame(p, &cf);
  uint32_t ns = p->samples ? p->samples : 1;
  float inv_ns = 1.0f / (float)ns, norm = inv_ns * inv_ns;
  uint32_t tet_cache = UB_GLG_NO_CACHE;
  for (uint32_t y = row_begin; y < row_end; y++) {
    for (uint32_t xpix = 0; xpix < p->width; xpix++) {
      double acc[3] = {0.0, 0.0, 0.0};
      for (uint32_t sy = 0; sy < ns; sy++)
        for (uint32_t sx = 0; sx < ns; sx++) {
          float px = ((float)xpix + ((float)sx + 0.5f) * inv_ns) / (float)p->width;
          float py = ((float)y + ((float)sy + 0.5f) * inv_ns) / (float)p->height;
          float d[3];
          camera_dir(&cf, px, py, d);
          float dn[3], c[3];
          if (!normalise3(d, dn))
            continue;
          shade(r, p, p->eye, dn, &tet_cache, c);
          for (int a = 0; a < 3; a++)
            acc[a] += c[a];
        }
      float *o = &out_rgb[((size_t)y * p->width + xpix) * 3];
      for (int a = 0; a < 3; a++) {
        float v = (float)(acc[a] * norm);
        o[a] = isfinite(v) && v > 0.0f ? v : 0.0f;
      }
    }
  }
  return UB_OK;
}

ub_result ub_renderer_view(const ub_renderer *r, const ub_render_params *p, uint32_t grid,
                           ub_render_view *out, const ub_log *log)
{
  assert(r && p && out);
  ub_result res = ub_render_params_check(p, r->bf->dls_count, log);
  if (res != UB_OK)
    return res;
  if (grid < 2 || grid > 1024) {
    ub_log_printf(log, UB_LOG_ERROR, "view grid %u is not within 2..1024", grid);
    return UB_ERR_INVALID_ARGUMENT;
  }
  cam_frame cf;
  camera_frame(p, &cf);
  uint64_t front = 0, back = 0, miss = 0;
  for (uint32_t y = 0; y < grid; y++)
    for (uint32_t x = 0; x < grid; x++) {
      float d[3], dn[3];
      camera_dir(&cf, ((float)x + 0.5f) / (float)grid, ((float)y + 0.5f) / (float)grid, d);
      ub_bvh_hit h;
      if (!normalise3(d, dn) || !ub_bvh_intersect(r->bvh, p->eye, dn, INFINITY, &h)) {
        miss++;
        continue;
      }
      /* the shading's test (shade): a front face is one the ray meets against its normal */
      if (dot3(&r->tri_normal[(size_t)h.tri * 3], dn) < 0.0f)
        front++;
      else
        back++;
    }
  double n = (double)grid * grid;
  out->front = (float)(front / n);
  out->back = (float)(back / n);
  out->miss = (float)(miss / n);
  return UB_OK;
}

/* ---- tone map ------------------------------------------------------------------------ */

static int cmp_float(const void *a, const void *b)
{
  float x = *(const float *)a, y = *(const float *)b;
  return (x > y) - (x < y);
}

static inline float aces_fit(float x)
{
  float v = (x * (2.51f * x + 0.03f)) / (x * (2.43f * x + 0.59f) + 0.14f);
  return v > 0.0f ? (v < 1.0f ? v : 1.0f) : 0.0f;
}

static inline uint8_t srgb8(float c)
{
  c = c > 0.0f ? (c < 1.0f ? c : 1.0f) : 0.0f;
  float s = c <= 0.0031308f ? 12.92f * c : 1.055f * powf(c, 1.0f / 2.4f) - 0.055f;
  return (uint8_t)(s * 255.0f + 0.5f);
}

ub_result ub_render_tonemap(const float *rgb, uint32_t width, uint32_t height,
                            int auto_exposure, float exposure_ev, uint8_t *out_srgb,
                            float *out_ev)
{
  assert(rgb && out_srgb);
  size_t n = (size_t)width * height;
  float ev = exposure_ev;
  if (auto_exposure) {
    float *lum = malloc((n ? n : 1) * sizeof *lum);
    if (!lum)
      return UB_ERR_OUT_OF_MEMORY;
    size_t m = 0;
    for (size_t i = 0; i < n; i++) {
      const float *c = &rgb[i * 3];
      float l = 0.2126f * c[0] + 0.7152f * c[1] + 0.0722f * c[2];
      if (isfinite(l) && l > 0.0f)
        lum[m++] = l;
    }
    ev = 0.0f;
    if (m) {
      qsort(lum, m, sizeof *lum, cmp_float);
      size_t k = (size_t)(UB_TONEMAP_PERCENTILE * (double)(m - 1));
      double key = lum[k];
      if (key > 0.0)
        ev = (float)log2(UB_TONEMAP_KEY / key);
    }
    free(lum);
  } else if (!isfinite(ev)) {
    return UB_ERR_INVALID_ARGUMENT;
  }
  float scale = exp2f(ev);
  for (size_t i = 0; i < n; i++)
    for (int a = 0; a < 3; a++) {
      float v = rgb[i * 3 + a];
      /* The curve is 1 to 8 bits well before 1e4; clamping keeps its products finite. */
      v = isfinite(v) && v > 0.0f ? fminf(v * scale, 1e4f) : 0.0f;
      out_srgb[i * 3 + a] = srgb8(aces_fit(v));
    }
  if (out_ev)
    *out_ev = ev;
  return UB_OK;
}
