/* lightmaps/layout.c — lightmap atlases, UVs, conservative texel rasterisation and sample
 * placement (ub_lightmap_build / ub_lightmap_free, see lightmap.h).
 *
 * Stages, each an item-parallel loop or a cheap sequential pass (deterministic for any
 * thread count):
 *   1. classify triangles: authored (TEXCOORD_1 → atlas 0), generated, not lightmapped;
 *   2. generated charts: weld positions, grow edge-connected charts within 30° of the
 *      seed normal, project on the average-normal plane, rotate to the smallest box,
 *      split/scale oversized charts, skyline-pack with padding into ≤ 4096² atlases;
 *   3. rasterise every atlas in 32×32 tiles: a texel is covered when a triangle overlaps
 *      its square with positive area; the owner is the triangle containing the texel
 *      centre (else the one overlapping most), ties to the lowest triangle index;
 *   4. texel position/normal on the owner, 2×2 stratified sample points;
 *   5. back-face fix with short rays (see fix_samples()), then normal offsets.
 */
#include "lightmaps/lm_internal.h"
#include "runtime/texel_links.h"

#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define UB_LM_TILE 32          /* rasterisation tile side, texels */
#define UB_LM_FIX_RAYS 8       /* per texel: 4 toward the samples, 4 along ±tangents */
#define UB_LM_FIX_CHUNK 1024   /* texels per back-face-fix work item */
#define UB_LM_FIX_REACH 3      /* texels: how far case (a) of the back-face fix looks */
#define UB_LM_FIX_CANDS 8      /* neighbours case (a) tries, nearest first */

static double now_seconds(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static ub_receiver_kind tri_receiver(const ub_scene *s, uint32_t t)
{
  uint32_t nd = s->tri_node ? s->tri_node[t] : UINT32_MAX;
  if (nd < s->node_count)
    return s->nodes[nd].receiver;
  return UB_RECEIVER_LIGHTMAP;
}

/* ---------------------------------------------------------------------------------- */
/* rasterisation */

/* Per lightmapped triangle, texel-space data of its atlas. */
typedef struct lm_rtri {
  double tx[6];    /* corners in texel units of the atlas */
  double inv_det;  /* 1 / (e1 × e2) in texel space, 0 when degenerate in UV */
  float dpdx[3];   /* world displacement per texel step in x */
  float dpdy[3];
  float inset[3];  /* minimum barycentrics, see inset_setup() */
} lm_rtri;

/* Barycentrics (l0, l1, l2) of q in the triangle (needs inv_det != 0). */
static inline void bary2(const lm_rtri *r, double qx, double qy, double l[3])
{
  double ax = r->tx[0], ay = r->tx[1];
  double e1x = r->tx[2] - ax, e1y = r->tx[3] - ay, e2x = r->tx[4] - ax, e2y = r->tx[5] - ay;
  double dx = qx - ax, dy = qy - ay;
  l[1] = (dx * e2y - dy * e2x) * r->inv_det;
  l[2] = (e1x * dy - e1y * dx) * r->inv_det;
  l[0] = 1.0 - l[1] - l[2];
}

/* Barycentrics of the point of the triangle closest to q (texel space). */
static void closest_bary(const lm_rtri *r, double qx, double qy, double l[3])
{
  bary2(r, qx, qy, l);
  if (l[0] >= 0.0 && l[1] >= 0.0 && l[2] >= 0.0)
    return;
  double best = DBL_MAX;
  for (int e = 0; e < 3; e++) {
    int i = e, j = (e + 1) % 3;
    double ax = r->tx[2 * i], ay = r->tx[2 * i + 1];
    double bx = r->tx[2 * j], by = r->tx[2 * j + 1];
    double dx = bx - ax, dy = by - ay, len2 = dx * dx + dy * dy;
    double s = len2 > 0.0 ? ((qx - ax) * dx + (qy - ay) * dy) / len2 : 0.0;
    s = s < 0.0 ? 0.0 : (s > 1.0 ? 1.0 : s);
    double px = ax + s * dx - qx, py = ay + s * dy - qy, d2 = px * px + py * py;
    if (d2 < best) {
      best = d2;
      l[0] = l[1] = l[2] = 0.0;
      l[i] = 1.0 - s;
      l[j] = s;
    }
  }
}

/* Area of the triangle ∩ the unit texel square at (x, y), Sutherland–Hodgman. */
static double clip_area(const double *tx, double x0, double y0)
{
  /* a triangle cut by 4 lines has ≤ 7 corners; rounding can add a near-duplicate per cut
   * (a review built 8 from corners an ulp off the pixel's lines), so room for 16 */
  double a[32], b[32];
  int n = 3;
  memcpy(a, tx, 6 * sizeof *a);
  const double bounds[4] = {x0, x0 + 1.0, y0, y0 + 1.0};
  for (int side = 0; side < 4; side++) {
    int axis = side >> 1;
    int keep_greater = (side & 1) == 0;
    double lim = bounds[side];
    int m = 0;
    for (int i = 0; i < n; i++) {
      const double *p = a + 2 * i, *q = a + 2 * ((i + 1) % n);
      double dp = keep_greater ? p[axis] - lim : lim - p[axis];
      double dq = keep_greater ? q[axis] - lim : lim - q[axis];
      if (dp >= 0.0 && m < 16) {
        b[2 * m] = p[0];
        b[2 * m + 1] = p[1];
        m++;
      }
      if ((dp >= 0.0) != (dq >= 0.0) && m < 16) {
        double t = dp / (dp - dq);
        b[2 * m] = p[0] + t * (q[0] - p[0]);
        b[2 * m + 1] = p[1] + t * (q[1] - p[1]);
        m++;
      }
    }
    n = m;
    if (n < 3)
      return 0.0;
    memcpy(a, b, 2 * (size_t)n * sizeof *a);
  }
  double area = 0.0;
  for (int i = 0; i < n; i++) {
    const double *p = a + 2 * i, *q = a + 2 * ((i + 1) % n);
    area += p[0] * q[1] - q[0] * p[1];
  }
  return fabs(area) * 0.5;
}

typedef struct lm_atlas_work {
  uint32_t w, h;
  uint32_t ntri;
  uint32_t *tris;         /* scene triangles in this atlas, ascending */
  uint32_t ntx, nty;      /* tiles */
  uint32_t *tile_start;   /* ntx·nty + 1 */
  uint32_t *tile_tris;    /* indices into tris */
  int32_t *owner;         /* w × h: scene triangle, -1 empty */
  uint8_t *overlap;       /* w × h */
} lm_atlas_work;

/* The name of triangle t's glTF node (for messages). */
static const char *tri_node_name(const ub_scene *s, uint32_t t)
{
  if (!s->tri_node || t >= s->triangle_count || s->tri_node[t] >= s->node_count)
    return "?";
  const char *n = s->nodes[s->tri_node[t]].name;
  return n && *n ? n : "(unnamed)";
}

static void tri_texel_bbox(const lm_rtri *r, uint32_t w, uint32_t h, int64_t *x0, int64_t *x1,
                           int64_t *y0, int64_t *y1)
{
  double mnx = fmin(r->tx[0], fmin(r->tx[2], r->tx[4]));
  double mxx = fmax(r->tx[0], fmax(r->tx[2], r->tx[4]));
  double mny = fmin(r->tx[1], fmin(r->tx[3], r->tx[5]));
  double mxy = fmax(r->tx[1], fmax(r->tx[3], r->tx[5]));
  *x0 = (int64_t)floor(mnx);
  *x1 = (int64_t)ceil(mxx) - 1;
  *y0 = (int64_t)floor(mny);
  *y1 = (int64_t)ceil(mxy) - 1;
  if (*x1 < *x0)
    *x1 = *x0;
  if (*y1 < *y0)
    *y1 = *y0;
  if (*x0 < 0)
    *x0 = 0;
  if (*y0 < 0)
    *y0 = 0;
  if (*x1 > (int64_t)w - 1)
    *x1 = (int64_t)w - 1;
  if (*y1 > (int64_t)h - 1)
    *y1 = (int64_t)h - 1;
}

static ub_result bin_tiles(lm_atlas_work *aw, const lm_rtri *rt)
{
  aw->ntx = (aw->w + UB_LM_TILE - 1) / UB_LM_TILE;
  aw->nty = (aw->h + UB_LM_TILE - 1) / UB_LM_TILE;
  size_t nt = (size_t)aw->ntx * aw->nty;
  aw->tile_start = calloc(nt + 1, sizeof *aw->tile_start);
  if (!aw->tile_start)
    return UB_ERR_OUT_OF_MEMORY;
  for (int pass = 0; pass < 2; pass++) {
    uint32_t *cursor = NULL;
    if (pass == 1) {
      for (size_t k = 0; k < nt; k++)
        aw->tile_start[k + 1] += aw->tile_start[k];
      aw->tile_tris = malloc((size_t)(aw->tile_start[nt] ? aw->tile_start[nt] : 1) *
                             sizeof *aw->tile_tris);
      cursor = malloc(nt * sizeof *cursor);
      if (!aw->tile_tris || !cursor) {
        free(cursor);
        return UB_ERR_OUT_OF_MEMORY;
      }
      memcpy(cursor, aw->tile_start, nt * sizeof *cursor);
    }
    for (uint32_t i = 0; i < aw->ntri; i++) {
      const lm_rtri *r = &rt[aw->tris[i]];
      if (r->inv_det == 0.0)
        continue;
      int64_t x0, x1, y0, y1;
      tri_texel_bbox(r, aw->w, aw->h, &x0, &x1, &y0, &y1);
      for (int64_t ty = y0 / UB_LM_TILE; ty <= y1 / UB_LM_TILE; ty++)
        for (int64_t tx = x0 / UB_LM_TILE; tx <= x1 / UB_LM_TILE; tx++) {
          size_t k = (size_t)ty * aw->ntx + (size_t)tx;
          if (pass == 0)
            aw->tile_start[k + 1]++;
          else
            aw->tile_tris[cursor[k]++] = i;
        }
    }
    free(cursor);
  }
  return UB_OK;
}

/* Coplanar: same orientation and within plane_tol of each other's plane. */
static int coplanar(const lm_ctx *c, uint32_t a, uint32_t b)
{
  const float *na = c->tri_n + 3 * (size_t)a, *nb = c->tri_n + 3 * (size_t)b;
  if (f3_dot(na, nb) < 0.999f)
    return 0;
  const ub_scene *s = c->scene;
  double pa[3], pb[3], d[3], n[3];
  load3(s->positions + 3 * (size_t)s->indices[3 * (size_t)a], pa);
  load3(s->positions + 3 * (size_t)s->indices[3 * (size_t)b], pb);
  load3(na, n);
  v3_sub(pb, pa, d);
  return fabs(v3_dot(d, n)) <= c->plane_tol;
}

/* Pass 1 over one tile: owners and overlap flags. */
static void raster_tile(const lm_ctx *c, lm_atlas_work *aw, const lm_rtri *rt, uint32_t tile)
{
  uint32_t tx = tile % aw->ntx, ty = tile / aw->ntx;
  int64_t bx0 = (int64_t)tx * UB_LM_TILE, by0 = (int64_t)ty * UB_LM_TILE;
  int64_t bx1 = bx0 + UB_LM_TILE - 1, by1 = by0 + UB_LM_TILE - 1;
  if (bx1 > (int64_t)aw->w - 1)
    bx1 = (int64_t)aw->w - 1;
  if (by1 > (int64_t)aw->h - 1)
    by1 = (int64_t)aw->h - 1;
  double score[UB_LM_TILE * UB_LM_TILE];
  int32_t inside_first[UB_LM_TILE * UB_LM_TILE];
  for (int i = 0; i < UB_LM_TILE * UB_LM_TILE; i++) {
    score[i] = 0.0;
    inside_first[i] = -1;
  }
  for (uint32_t k = aw->tile_start[tile]; k < aw->tile_start[tile + 1]; k++) {
    uint32_t t = aw->tris[aw->tile_tris[k]];
    const lm_rtri *r = &rt[t];
    int64_t x0, x1, y0, y1;
    tri_texel_bbox(r, aw->w, aw->h, &x0, &x1, &y0, &y1);
    if (x0 < bx0)
      x0 = bx0;
    if (y0 < by0)
      y0 = by0;
    if (x1 > bx1)
      x1 = bx1;
    if (y1 > by1)
      y1 = by1;
    double uv_area = 0.5 / fabs(r->inv_det);
    double min_area = fmin(1e-7, 0.5 * uv_area);
    for (int64_t y = y0; y <= y1; y++)
      for (int64_t x = x0; x <= x1; x++) {
        double l[3];
        /* Fast path: all four corners inside → full overlap. */
        int corners_in = 0;
        for (int cy = 0; cy < 2; cy++)
          for (int cx = 0; cx < 2; cx++) {
            bary2(r, (double)(x + cx), (double)(y + cy), l);
            corners_in += l[0] >= 0.0 && l[1] >= 0.0 && l[2] >= 0.0;
          }
        double area = corners_in == 4 ? 1.0 : clip_area(r->tx, (double)x, (double)y);
        if (!(area > min_area))
          continue;
        bary2(r, (double)x + 0.5, (double)y + 0.5, l);
        int contains = l[0] >= -1e-9 && l[1] >= -1e-9 && l[2] >= -1e-9;
        int strictly = l[0] > 1e-6 && l[1] > 1e-6 && l[2] > 1e-6;
        size_t li = (size_t)(y - by0) * UB_LM_TILE + (size_t)(x - bx0);
        size_t gi = (size_t)y * aw->w + (size_t)x;
        double sc = (contains ? 2.0 : 0.0) + area;
        if (sc > score[li]) {
          score[li] = sc;
          aw->owner[gi] = (int32_t)t;
        }
        if (strictly) {
          if (inside_first[li] < 0)
            inside_first[li] = (int32_t)t;
          else if (!aw->overlap[gi] && !coplanar(c, (uint32_t)inside_first[li], t))
            aw->overlap[gi] = 1;
        }
      }
  }
}

/* Per-texel outputs being built. */
typedef struct lm_out {
  ub_lightmap *lm;
  float *raw_samples; /* texel_count × 4 × 3: sample points on the surface (before fixes) */
} lm_out;

static void surface_point(const ub_scene *s, uint32_t t, const double l[3], double p[3])
{
  double q[3][3];
  tri_corners(s, t, q);
  for (int a = 0; a < 3; a++)
    p[a] = l[0] * q[0][a] + l[1] * q[1][a] + l[2] * q[2][a];
}

/* Ray epsilon at p (ub_rt's, or the same formula on the local extent without a ub_rt). */
static float point_eps(const lm_ctx *c, const float p[3])
{
  if (c->rt)
    return ub_rt_epsilon(c->rt, p);
  float m = fmaxf(fabsf(p[0]), fmaxf(fabsf(p[1]), fabsf(p[2])));
  return fmaxf(c->local_eps, m * 2.384185791015625e-07f);
}

/* Per-triangle minimum barycentrics that keep a point 4 ray epsilons (world) inside
 * every edge: λ_i = distance to the opposite edge / height_i. A point clamped onto an edge
 * where a wall stands on the floor would otherwise sit in the wall's plane, where no ray
 * can tell its sides apart. Triangles thinner than that use their centroid (inset[0] = -1). */
static void inset_setup(const lm_ctx *c, uint32_t t, lm_rtri *r)
{
  double p[3][3];
  tri_corners(c->scene, t, p);
  const float pf[3] = {(float)p[0][0], (float)p[0][1], (float)p[0][2]};
  double delta = 4.0 * point_eps(c, pf);
  double area2 = 2.0 * c->tri_area[t], esum = 0.0;
  for (int i = 0; i < 3; i++) {
    double d[3];
    v3_sub(p[(i + 2) % 3], p[(i + 1) % 3], d);
    r->inset[i] = area2 > 0.0 ? (float)(delta * v3_len(d) / area2) : 1.0f;
    esum += r->inset[i];
  }
  if (!(esum < 0.75))
    r->inset[0] = -1.0f;
}

static void inset_bary(const lm_rtri *r, double l[3])
{
  if (r->inset[0] < 0.0f) {
    l[0] = l[1] = l[2] = 1.0 / 3.0;
    return;
  }
  double deficit = 0.0, excess = 0.0;
  int raised[3] = {0, 0, 0};
  for (int i = 0; i < 3; i++)
    if (l[i] < r->inset[i]) {
      deficit += r->inset[i] - l[i];
      l[i] = r->inset[i];
      raised[i] = 1;
    }
  if (deficit == 0.0)
    return;
  for (int i = 0; i < 3; i++)
    if (!raised[i])
      excess += l[i] - r->inset[i];
  /* excess ≥ deficit because Σ inset < 1: every λ stays ≥ its minimum */
  for (int i = 0; i < 3; i++)
    if (!raised[i] && excess > 0.0)
      l[i] -= deficit * (l[i] - r->inset[i]) / excess;
}

/* Pass 2 over one tile: texel position, normal, sample points. */
static void texel_tile(const lm_ctx *c, const lm_atlas_work *aw, const lm_rtri *rt,
                       uint32_t atlas_index, const ub_atlas *atlas, uint32_t tile, lm_out *o)
{
  const ub_scene *s = c->scene;
  ub_lightmap *lm = o->lm;
  uint32_t tx = tile % aw->ntx, ty = tile / aw->ntx;
  int64_t bx0 = (int64_t)tx * UB_LM_TILE, by0 = (int64_t)ty * UB_LM_TILE;
  int64_t bx1 = bx0 + UB_LM_TILE - 1, by1 = by0 + UB_LM_TILE - 1;
  if (bx1 > (int64_t)aw->w - 1)
    bx1 = (int64_t)aw->w - 1;
  if (by1 > (int64_t)aw->h - 1)
    by1 = (int64_t)aw->h - 1;

  /* 2×2 stratified points of each footprint, each mapped through a triangle containing
   * it: the owner if it does, else the lowest-index triangle of the tile that contains it
   * and faces the owner's way (same surface); left -1 → clamped onto the owner. */
  int32_t stri[UB_LM_TILE * UB_LM_TILE][UB_TEXEL_SAMPLES];
  uint32_t open = 0;
  for (int64_t y = by0; y <= by1; y++)
    for (int64_t x = bx0; x <= bx1; x++) {
      size_t li = (size_t)(y - by0) * UB_LM_TILE + (size_t)(x - bx0);
      int32_t own = aw->owner[(size_t)y * aw->w + (size_t)x];
      for (int j = 0; j < UB_TEXEL_SAMPLES; j++) {
        stri[li][j] = -1;
        if (own < 0)
          continue;
        double l[3];
        bary2(&rt[own], x + 0.25 + 0.5 * (j & 1), y + 0.25 + 0.5 * ((j >> 1) & 1), l);
        if (l[0] >= -1e-9 && l[1] >= -1e-9 && l[2] >= -1e-9)
          stri[li][j] = own;
        else
          open++;
      }
    }
  for (uint32_t k = aw->tile_start[tile]; k < aw->tile_start[tile + 1] && open; k++) {
    uint32_t u = aw->tris[aw->tile_tris[k]];
    const lm_rtri *r = &rt[u];
    int64_t x0, x1, y0, y1;
    tri_texel_bbox(r, aw->w, aw->h, &x0, &x1, &y0, &y1);
    x0 = x0 < bx0 ? bx0 : x0;
    y0 = y0 < by0 ? by0 : y0;
    x1 = x1 > bx1 ? bx1 : x1;
    y1 = y1 > by1 ? by1 : y1;
    for (int64_t y = y0; y <= y1; y++)
      for (int64_t x = x0; x <= x1; x++) {
        size_t li = (size_t)(y - by0) * UB_LM_TILE + (size_t)(x - bx0);
        int32_t own = aw->owner[(size_t)y * aw->w + (size_t)x];
        if (own < 0 || (uint32_t)own == u)
          continue;
        for (int j = 0; j < UB_TEXEL_SAMPLES; j++) {
          if (stri[li][j] >= 0)
            continue;
          double l[3];
          bary2(r, x + 0.25 + 0.5 * (j & 1), y + 0.25 + 0.5 * ((j >> 1) & 1), l);
          if (l[0] >= -1e-9 && l[1] >= -1e-9 && l[2] >= -1e-9 &&
              f3_dot(c->tri_n + 3 * (size_t)u, c->tri_n + 3 * (size_t)own) >= 0.5f) {
            stri[li][j] = (int32_t)u;
            open--;
          }
        }
      }
  }

  for (int64_t y = by0; y <= by1; y++)
    for (int64_t x = bx0; x <= bx1; x++) {
      size_t gi = (size_t)y * aw->w + (size_t)x;
      int32_t own = aw->owner[gi];
      if (own < 0)
        continue;
      size_t li = (size_t)(y - by0) * UB_LM_TILE + (size_t)(x - bx0);
      uint32_t ti = (uint32_t)atlas->texel_of[gi];
      uint32_t t = (uint32_t)own;
      const lm_rtri *r = &rt[t];
      double l[3], p[3];
      closest_bary(r, x + 0.5, y + 0.5, l);
      inset_bary(r, l);
      surface_point(s, t, l, p);
      const float *gn = c->tri_n + 3 * (size_t)t;
      double n[3] = {0, 0, 0};
      if (s->normals) {
        for (int k = 0; k < 3; k++) {
          const float *vn = s->normals + 3 * (size_t)s->indices[3 * (size_t)t + k];
          for (int a = 0; a < 3; a++)
            n[a] += l[k] * vn[a];
        }
      }
      double gnd[3];
      load3(gn, gnd);
      /* A shading normal opposite to the winding (broken asset) would offset samples
       * into the surface: use the geometric normal then. */
      if (v3_normalize(n) == 0.0 || v3_dot(n, gnd) <= 0.0)
        memcpy(n, gnd, sizeof n);
      lm->texel_atlas[ti] = atlas_index;
      lm->texel_xy[2 * (size_t)ti] = (uint32_t)x;
      lm->texel_xy[2 * (size_t)ti + 1] = (uint32_t)y;
      lm->texel_tri[ti] = t;
      for (int a = 0; a < 3; a++) {
        lm->texel_pos[3 * (size_t)ti + a] = (float)p[a];
        lm->texel_normal[3 * (size_t)ti + a] = (float)n[a];
      }
      for (int j = 0; j < UB_TEXEL_SAMPLES; j++) {
        double qx = x + 0.25 + 0.5 * (j & 1), qy = y + 0.25 + 0.5 * ((j >> 1) & 1);
        uint32_t st = stri[li][j] >= 0 ? (uint32_t)stri[li][j] : t;
        double sl[3], sp[3];
        if (stri[li][j] >= 0)
          bary2(&rt[st], qx, qy, sl);
        else
          closest_bary(r, qx, qy, sl);
        inset_bary(&rt[st], sl);
        surface_point(s, st, sl, sp);
        float *dst = o->raw_samples + ((size_t)ti * UB_TEXEL_SAMPLES + j) * 3;
        dst[0] = (float)sp[0];
        dst[1] = (float)sp[1];
        dst[2] = (float)sp[2];
      }
    }
}

/* ---------------------------------------------------------------------------------- */
/* back-face fix
 *
 * The leak: a floor texel at a wall/floor junction has a footprint that reaches under the
 * wall (or its centre lies under it, when the floor continues below the wall), so some
 * sample points sit inside the wall or in the next room and gather light from there.
 *
 * The fix, per texel, with P = texel centre and S_j = sample points, all lifted off the
 * surface by the ray epsilon along the texel normal:
 *   rays 0..3: P → S_j (length max(|S_j − P|, half texel diagonal));
 *   rays 4..7: P along ±T, ±B (the texel's x/y directions on the surface), half diagonal.
 *   (a) If the nearest hit of all 8 rays is a BACK face, P lies behind a surface: the
 *       level's back sides face solid space (closed geometry, like brush-based levels),
 *       so P is inside a wall. P must not simply move to the front of that nearest back
 *       face: for a floor slab running under a wall, a texel centred under the wall is
 *       about as near the wall's OUTER face as its inner one, and on the outer side it
 *       bakes outdoor light that the run-time's bilinear filter (and the bake's gather
 *       rays, which read the same texels) carry onto the room's floor edge: a leak
 *       (sunroom: 1.3 W/m² 5 cm inside the sealed room, test_hard_wall_junction).
 *       The side to take is the side of the texel's own chart, where its neighbours are
 *       read with it. So, once every texel is classified (pass 1), rays go from the
 *       centres of up to UB_LM_FIX_CANDS nearby texels of the same chart whose centres
 *       are not behind a surface (outside_candidates(); fixed order, thread-independent)
 *       to P. A ray that meets a FRONT face before P comes from the chart's open side.
 *       If one of them meets the nearest back face's plane, the old move (to the front
 *       of that face) is on the chart's side and is kept: a floor under a wall between
 *       two rooms still goes to the nearer room, as before. Otherwise P moves to the
 *       first hit of the nearest such candidate, pulled back by eps toward it
 *       (pull_point): the foot of the wall on the chart's side, joined to that
 *       candidate's centre by a free segment. With no such candidate (no open texel of
 *       the chart nearby, so no visible texel blends with this one) the old move stays.
 *       The sample rays are then traced from the moved P.
 *   (b) Every sample whose segment from P (the moved P in case (a)) hits anything before
 *       reaching S_j is pulled to just before the first hit: hit − dir·eps, plus the hit
 *       face's normal turned toward P, × eps.
 * Why a fixed sample is inside the room: its segment from P is free of geometry up to
 * the first hit, and it stops eps before that hit, so it is connected to P by an
 * unobstructed path; P itself is either in front of every surface around it or, in case
 * (a), was moved to the front side of the surface it was behind, or to a point joined
 * by a free segment to the centre of an open texel of its chart. Samples whose segment
 * is free are left where they are. backface_fixes counts the sample points moved.
 * Finally every sample is offset along the texel normal (ub_rt_offset_point) so gather
 * rays leave without self-hits. */

static void ray_setup(ub_ray *ray, const float o[3], const float d[3], float tfar)
{
  memcpy(ray->org, o, 3 * sizeof(float));
  memcpy(ray->dir, d, 3 * sizeof(float));
  ray->tnear = 0.0f;
  ray->tfar = tfar;
}

static float unit3f(const float a[3], float out[3])
{
  float l = sqrtf(f3_dot(a, a));
  if (!(l > 0.0f) || !isfinite(l)) {
    out[0] = out[1] = out[2] = 0.0f;
    return 0.0f;
  }
  out[0] = a[0] / l;
  out[1] = a[1] / l;
  out[2] = a[2] / l;
  return l;
}

/* Pull point: before the hit, on the side facing the ray origin. */
static void pull_point(const ub_rt *rt, const ub_ray *ray, const ub_hit *h, float out[3])
{
  float hp[3], ng[3];
  for (int a = 0; a < 3; a++)
    hp[a] = ray->org[a] + ray->dir[a] * h->t;
  unit3f(h->ng, ng);
  float eps = ub_rt_epsilon(rt, hp);
  float side = f3_dot(ng, ray->dir) > 0.0f ? -1.0f : 1.0f;
  for (int a = 0; a < 3; a++)
    out[a] = hp[a] - ray->dir[a] * eps + side * ng[a] * eps;
}

/* Case (a) candidates: up to UB_LM_FIX_CANDS covered texels of the same atlas, at most
 * UB_LM_FIX_REACH texels away, nearest first, whose own centre is not behind a surface
 * and which lie on ti's plane next to it on the surface (same chart, not a chart packed
 * alongside). "Not behind a surface" only means that no back face is within half a texel
 * diagonal, so a candidate may still lie deep inside a thick wall: the caller only uses
 * candidates that see a front face on their way to P. Fixed scan order, ties keep the
 * first found: the choice does not depend on threads. Returns the count. */
static int outside_candidates(const ub_lightmap *lm, const lm_rtri *rtri, const uint8_t *inside,
                              uint32_t ti, uint32_t out_k[UB_LM_FIX_CANDS])
{
  const ub_atlas *at = &lm->atlases[lm->texel_atlas[ti]];
  int64_t x = lm->texel_xy[2 * (size_t)ti], y = lm->texel_xy[2 * (size_t)ti + 1];
  const float *n = lm->texel_normal + 3 * (size_t)ti, *p = lm->texel_pos + 3 * (size_t)ti;
  const lm_rtri *r = &rtri[lm->texel_tri[ti]];
  float step = sqrtf(fmaxf(f3_dot(r->dpdx, r->dpdx), f3_dot(r->dpdy, r->dpdy)));
  if (!(step > 0.0f) || !isfinite(step))
    return 0;
  int cnt = 0, cd[UB_LM_FIX_CANDS];
  for (int dy = -UB_LM_FIX_REACH; dy <= UB_LM_FIX_REACH; dy++)
    for (int dx = -UB_LM_FIX_REACH; dx <= UB_LM_FIX_REACH; dx++) {
      int d2 = dx * dx + dy * dy;
      int64_t xx = x + dx, yy = y + dy;
      if (d2 == 0 || (cnt == UB_LM_FIX_CANDS && d2 >= cd[cnt - 1]) || xx < 0 || yy < 0 ||
          xx >= at->width || yy >= at->height)
        continue;
      int32_t k = at->texel_of[(size_t)yy * at->width + (size_t)xx];
      if (k < 0 || inside[k])
        continue;
      const float *nk = lm->texel_normal + 3 * (size_t)k, *pk = lm->texel_pos + 3 * (size_t)k;
      float dp[3] = {pk[0] - p[0], pk[1] - p[1], pk[2] - p[2]};
      float reach = (sqrtf((float)d2) + 1.5f) * step;
      if (f3_dot(n, nk) < 0.99f || fabsf(f3_dot(dp, n)) > 0.25f * step ||
          f3_dot(dp, dp) > reach * reach)
        continue;
      int at_i = cnt < UB_LM_FIX_CANDS ? cnt : UB_LM_FIX_CANDS - 1;
      while (at_i > 0 && cd[at_i - 1] > d2) { /* stable: equal distances keep scan order */
        if (at_i < UB_LM_FIX_CANDS) {
          cd[at_i] = cd[at_i - 1];
          out_k[at_i] = out_k[at_i - 1];
        }
        at_i--;
      }
      cd[at_i] = d2;
      out_k[at_i] = (uint32_t)k;
      if (cnt < UB_LM_FIX_CANDS)
        cnt++;
    }
  return cnt;
}

/* Work item `chunk` of the back-face fix and the texel links: texels [*t0, *t1) of
 * count. 0 when a thread ran out of memory (the rest of the items are skipped). */
static int fix_chunk(int *oom, int64_t chunk, uint32_t count, uint32_t *t0, uint32_t *t1)
{
  int stop;
#pragma omp atomic read
  stop = *oom;
  if (stop)
    return 0;
  *t0 = (uint32_t)chunk * UB_LM_FIX_CHUNK;
  *t1 = *t0 + UB_LM_FIX_CHUNK < count ? *t0 + UB_LM_FIX_CHUNK : count;
  return 1;
}

/* texel_area: the world area of the surface whose lightmap UV falls in each texel's
 * pixel, i.e. what a gather ray hitting the surface reads as that texel (hit_pixel). At a
 * chart's edge a conservatively rasterised texel covers part of its square only; the
 * texel-light strategy's density is per unit of this area, and with the square's area it
 * read an edge texel up to twice as bright as the gathers do. Each triangle is clipped to
 * every pixel of its box (clip_area); its world/UV area ratio turns that into metres. */
static void texel_areas(const lm_ctx *c, const lm_rtri *rtri, ub_lightmap *lm)
{
  memset(lm->texel_area, 0, (size_t)lm->texel_count * sizeof *lm->texel_area);
  const ub_scene *s = c->scene;
  for (uint32_t t = 0; t < s->triangle_count; t++) {
    int32_t a = lm->tri_atlas[t];
    const lm_rtri *r = &rtri[t];
    if (a < 0 || r->inv_det == 0.0 || !(c->tri_area[t] > 0.0))
      continue;
    const ub_atlas *at = &lm->atlases[a];
    double ratio = c->tri_area[t] * fabs(r->inv_det) * 2.0; /* m² per texel² */
    int64_t x0, x1, y0, y1;
    tri_texel_bbox(r, at->width, at->height, &x0, &x1, &y0, &y1);
    for (int64_t y = y0; y <= y1; y++)
      for (int64_t x = x0; x <= x1; x++) {
        int32_t ti = at->texel_of[(size_t)y * at->width + (size_t)x];
        if (ti < 0)
          continue;
        lm->texel_area[ti] += (float)(clip_area(r->tx, (double)x, (double)y) * ratio);
      }
  }
}

static uint64_t fix_samples(const lm_ctx *c, const lm_rtri *rtri, lm_out *o)
{
  ub_lightmap *lm = o->lm;
  const ub_rt *rt = c->rt;
  uint32_t nchunks = (lm->texel_count + UB_LM_FIX_CHUNK - 1) / UB_LM_FIX_CHUNK;
  uint64_t fixes = 0;
  int oom = 0;
  /* Per texel, between the two passes: is P behind a surface (case (a)), and P or, in
   * case (a), the fallback point in front of the nearest back face. */
  uint8_t *inside = calloc(lm->texel_count ? lm->texel_count : 1, 1);
  float *centre = malloc((size_t)(lm->texel_count ? lm->texel_count : 1) * 3 * sizeof *centre);
  float *face_n = malloc((size_t)(lm->texel_count ? lm->texel_count : 1) * 3 * sizeof *face_n);
  if (!inside || !centre || !face_n) {
    free(inside);
    free(centre);
    free(face_n);
    return UINT64_MAX;
  }

  /* pass 1: the 8 short rays per texel; classify P */
#pragma omp parallel
  {
    ub_ray *rays = malloc((size_t)UB_LM_FIX_CHUNK * UB_LM_FIX_RAYS * sizeof *rays);
    ub_hit *hits = malloc((size_t)UB_LM_FIX_CHUNK * UB_LM_FIX_RAYS * sizeof *hits);
    if (!rays || !hits) {
#pragma omp atomic write
      oom = 1;
    }
#pragma omp for schedule(dynamic, 1)
    for (int64_t chunk = 0; chunk < (int64_t)nchunks; chunk++) {
      uint32_t t0, t1;
      if (!fix_chunk(&oom, chunk, lm->texel_count, &t0, &t1))
        continue;
      uint32_t m = t1 - t0;
      for (uint32_t i = 0; i < m; i++) {
        uint32_t ti = t0 + i;
        const float *n = lm->texel_normal + 3 * (size_t)ti;
        const lm_rtri *r = &rtri[lm->texel_tri[ti]];
        float P[3];
        ub_rt_offset_point(rt, lm->texel_pos + 3 * (size_t)ti, n, P);
        memcpy(centre + 3 * (size_t)ti, P, sizeof P);
        float dx2 = f3_dot(r->dpdx, r->dpdx), dy2 = f3_dot(r->dpdy, r->dpdy);
        float half_diag = 0.5f * sqrtf(dx2 + dy2);
        if (!(half_diag > 0.0f) || !isfinite(half_diag))
          half_diag = 0.0f;
        /* tangents: texel axes projected on the tangent plane */
        float T[3], B[3], tmp[3];
        float dn = f3_dot(r->dpdx, n);
        for (int a = 0; a < 3; a++)
          tmp[a] = r->dpdx[a] - n[a] * dn;
        if (unit3f(tmp, T) == 0.0f) {
          float ax[3] = {fabsf(n[0]) < 0.9f ? 1.0f : 0.0f, fabsf(n[0]) < 0.9f ? 0.0f : 1.0f, 0.0f};
          float k = f3_dot(ax, n);
          for (int a = 0; a < 3; a++)
            tmp[a] = ax[a] - n[a] * k;
          unit3f(tmp, T);
        }
        B[0] = n[1] * T[2] - n[2] * T[1];
        B[1] = n[2] * T[0] - n[0] * T[2];
        B[2] = n[0] * T[1] - n[1] * T[0];
        ub_ray *rr = rays + (size_t)i * UB_LM_FIX_RAYS;
        for (int j = 0; j < 4; j++) {
          float S[3], d[3], u[3];
          ub_rt_offset_point(rt, o->raw_samples + ((size_t)ti * 4 + j) * 3, n, S);
          for (int a = 0; a < 3; a++)
            d[a] = S[a] - P[a];
          float len = unit3f(d, u);
          if (len == 0.0f) { /* sample at the centre: probe the diagonal instead */
            float sx = (j & 1) ? 1.0f : -1.0f, sy = (j & 2) ? 1.0f : -1.0f;
            for (int a = 0; a < 3; a++)
              tmp[a] = sx * T[a] + sy * B[a];
            unit3f(tmp, u);
          }
          ray_setup(&rr[j], P, u, fmaxf(len, half_diag));
        }
        const float *ax4[4] = {T, T, B, B};
        for (int j = 0; j < 4; j++) {
          float d[3], sg = (j & 1) ? -1.0f : 1.0f;
          for (int a = 0; a < 3; a++)
            d[a] = sg * ax4[j][a];
          ray_setup(&rr[4 + j], P, d, half_diag);
        }
      }
      ub_rt_intersect(rt, rays, m * UB_LM_FIX_RAYS, hits);
      for (uint32_t i = 0; i < m; i++) {
        const ub_hit *hh = hits + (size_t)i * UB_LM_FIX_RAYS;
        const ub_ray *rr = rays + (size_t)i * UB_LM_FIX_RAYS;
        int best = -1;
        for (int j = 0; j < UB_LM_FIX_RAYS; j++)
          if (hh[j].tri != UB_RT_MISS && (best < 0 || hh[j].t < hh[best].t))
            best = j;
        if (best >= 0 && f3_dot(hh[best].ng, rr[best].dir) > 0.0f) {
          float hp[3], ng[3];
          for (int a = 0; a < 3; a++)
            hp[a] = rr[best].org[a] + rr[best].dir[a] * hh[best].t;
          unit3f(hh[best].ng, ng);
          float eps = ub_rt_epsilon(rt, hp);
          for (int a = 0; a < 3; a++)
            centre[3 * (size_t)(t0 + i) + a] = hp[a] + ng[a] * eps; /* fallback */
          memcpy(face_n + 3 * (size_t)(t0 + i), ng, sizeof ng);
          inside[t0 + i] = 1;
        }
      }
    }
    free(rays);
    free(hits);
  }

  /* pass 2: move the centres of case (a) toward their chart; pull the samples (b) */
#pragma omp parallel reduction(+ : fixes)
  {
    ub_ray *rays = malloc((size_t)UB_LM_FIX_CHUNK * 4 * sizeof *rays);
    ub_hit *hits = malloc((size_t)UB_LM_FIX_CHUNK * 4 * sizeof *hits);
    ub_ray *nb_rays = malloc((size_t)UB_LM_FIX_CHUNK * UB_LM_FIX_CANDS * sizeof *nb_rays);
    ub_hit *nb_hits = malloc((size_t)UB_LM_FIX_CHUNK * UB_LM_FIX_CANDS * sizeof *nb_hits);
    uint32_t *nb_of = malloc((size_t)UB_LM_FIX_CHUNK * UB_LM_FIX_CANDS * sizeof *nb_of);
    float *pos = malloc((size_t)UB_LM_FIX_CHUNK * 3 * sizeof *pos);
    float *dist = malloc((size_t)UB_LM_FIX_CHUNK * 4 * sizeof *dist);
    float *target = malloc((size_t)UB_LM_FIX_CHUNK * 4 * 3 * sizeof *target);
    if (!rays || !hits || !nb_rays || !nb_hits || !nb_of || !pos || !dist || !target) {
#pragma omp atomic write
      oom = 1;
    }
#pragma omp for schedule(dynamic, 1)
    for (int64_t chunk = 0; chunk < (int64_t)nchunks; chunk++) {
      uint32_t t0, t1;
      if (!fix_chunk(&oom, chunk, lm->texel_count, &t0, &t1))
        continue;
      uint32_t m = t1 - t0;
      /* (a) rays from the candidates' centres to P. Those that meet a FRONT face before
       * P come from the chart's open side. If one of them meets the nearest back face's
       * plane, the fallback (the front of that face) is on the chart's side: it stays.
       * Else the nearest such candidate's hit, pulled back by eps, is the new P; no such
       * candidate: the fallback stays. */
      uint32_t nnb = 0;
      for (uint32_t i = 0; i < m; i++) {
        uint32_t ti = t0 + i;
        memcpy(pos + 3 * (size_t)i, centre + 3 * (size_t)ti, 3 * sizeof(float));
        if (!inside[ti])
          continue;
        uint32_t cand[UB_LM_FIX_CANDS];
        int nc = outside_candidates(lm, rtri, inside, ti, cand);
        float P[3];
        ub_rt_offset_point(rt, lm->texel_pos + 3 * (size_t)ti, lm->texel_normal + 3 * (size_t)ti, P);
        for (int j = 0; j < nc; j++) {
          float d[3], u[3];
          const float *pk = centre + 3 * (size_t)cand[j];
          for (int a = 0; a < 3; a++)
            d[a] = P[a] - pk[a];
          float len = unit3f(d, u);
          if (len == 0.0f)
            continue;
          ray_setup(&nb_rays[nnb], pk, u, len);
          nb_of[nnb++] = i;
        }
      }
      if (nnb)
        ub_rt_intersect(rt, nb_rays, nnb, nb_hits);
      for (uint32_t q = 0; q < nnb; q++) {
        if (q > 0 && nb_of[q] == nb_of[q - 1])
          continue; /* rays of one texel are contiguous; its first good one wins */
        uint32_t i = nb_of[q], ti = t0 + i, first = UINT32_MAX;
        const float *fn = face_n + 3 * (size_t)ti, *F = centre + 3 * (size_t)ti;
        const lm_rtri *r = &rtri[lm->texel_tri[ti]];
        float tol = 0.01f * sqrtf(fmaxf(f3_dot(r->dpdx, r->dpdx), f3_dot(r->dpdy, r->dpdy)));
        int keep = 0;
        for (uint32_t e = q; e < nnb && nb_of[e] == i; e++) {
          const ub_hit *h = &nb_hits[e];
          if (h->tri == UB_RT_MISS || !(h->t < nb_rays[e].tfar) ||
              !(f3_dot(h->ng, nb_rays[e].dir) < 0.0f))
            continue;
          if (first == UINT32_MAX)
            first = e;
          float ng[3], hp[3], dF[3];
          unit3f(h->ng, ng);
          for (int a = 0; a < 3; a++) {
            hp[a] = nb_rays[e].org[a] + nb_rays[e].dir[a] * h->t;
            dF[a] = hp[a] - F[a];
          }
          if (f3_dot(ng, fn) > 0.99f && fabsf(f3_dot(fn, dF)) <= tol)
            keep = 1; /* the nearest back face is the chart's own side: as before */
        }
        if (!keep && first != UINT32_MAX)
          pull_point(rt, &nb_rays[first], &nb_hits[first], pos + 3 * (size_t)i);
      }
      /* (b) sample segments from the (moved) centres */
      for (uint32_t i = 0; i < m; i++) {
        uint32_t ti = t0 + i;
        const float *n = lm->texel_normal + 3 * (size_t)ti;
        for (int j = 0; j < 4; j++) {
          float *S = target + 3 * (size_t)i * 4 + 3 * j, d[3], u[3];
          ub_rt_offset_point(rt, o->raw_samples + ((size_t)ti * 4 + j) * 3, n, S);
          for (int a = 0; a < 3; a++)
            d[a] = S[a] - pos[3 * i + a];
          float len = unit3f(d, u);
          dist[4 * i + j] = len;
          if (len == 0.0f)
            memcpy(u, n, sizeof u);
          ray_setup(&rays[4 * (size_t)i + j], pos + 3 * i, u, len);
        }
      }
      ub_rt_intersect(rt, rays, m * 4, hits);
      /* A back face met at the segment's start (t within a few eps) is a face the segment
       * leaves: P lies on its plane (a floor texel centred on the foot of a wall) and the
       * sample is on its open side. Pulled back before that hit, the sample went to the
       * far side, inside the wall, where its gather rays met only back faces (the floor
       * edge texels of sunpatch at half their irradiance). Those segments are traced
       * again from past the start; a front face met there is still an obstacle. */
      uint32_t nre = 0;
      for (uint32_t q = 0; q < m * 4; q++) {
        const ub_hit *h = &hits[q];
        float e = 4.0f * ub_rt_epsilon(rt, rays[q].org);
        if (h->tri != UB_RT_MISS && h->t < rays[q].tfar && h->t <= e &&
            f3_dot(h->ng, rays[q].dir) > 0.0f && e < rays[q].tfar) {
          nb_rays[nre] = rays[q];
          nb_rays[nre].tnear = e;
          nb_of[nre++] = q;
        }
      }
      if (nre) /* nb_rays holds UB_LM_FIX_CANDS ≥ 4 rays per texel */
        ub_rt_intersect(rt, nb_rays, nre, nb_hits);
      for (uint32_t q = 0; q < nre; q++)
        hits[nb_of[q]] = nb_hits[q];
      for (uint32_t i = 0; i < m; i++) {
        uint32_t ti = t0 + i;
        const float *n = lm->texel_normal + 3 * (size_t)ti;
        for (int j = 0; j < 4; j++) {
          const ub_hit *h = &hits[4 * (size_t)i + j];
          const ub_ray *ray = &rays[4 * (size_t)i + j];
          float *dst = lm->sample_pos + ((size_t)ti * UB_TEXEL_SAMPLES + j) * 3;
          if (h->tri != UB_RT_MISS && h->t < dist[4 * i + j]) {
            float q[3];
            pull_point(rt, ray, h, q);
            ub_rt_offset_point(rt, q, n, dst);
            fixes++;
          } else {
            memcpy(dst, target + 3 * (size_t)i * 4 + 3 * j, 3 * sizeof(float));
          }
        }
      }
    }
    free(rays);
    free(hits);
    free(nb_rays);
    free(nb_hits);
    free(nb_of);
    free(pos);
    free(dist);
    free(target);
  }
  free(inside);
  free(centre);
  free(face_n);
  return oom ? UINT64_MAX : fixes;
}

/* Texel links (runtime/texel_links.h): for every covered texel and its covered +x / +y
 * neighbour in the atlas, a segment between the two texels' mean sample points, each
 * lifted off its surface by 5% of their distance: blocked (a wall or a closed door leaf
 * standing on the surface between them) sets the texel's UB_LINK_X / UB_LINK_Y bit.
 * Returns the number of separated pairs, UINT64_MAX when out of memory. */
static uint64_t texel_links(const ub_rt *rt, ub_lightmap *lm)
{
  uint64_t separated = 0;
  int oom = 0;
  for (uint32_t a = 0; a < lm->atlas_count; a++) {
    ub_atlas *at = &lm->atlases[a];
    at->link = calloc((size_t)at->width * at->height + 1, 1);
    if (!at->link)
      return UINT64_MAX;
  }
  uint32_t nchunks = (lm->texel_count + UB_LM_FIX_CHUNK - 1) / UB_LM_FIX_CHUNK;
#pragma omp parallel reduction(+ : separated)
  {
    ub_ray *rays = malloc((size_t)UB_LM_FIX_CHUNK * 2 * sizeof *rays);
    ub_hit *hits = malloc((size_t)UB_LM_FIX_CHUNK * 2 * sizeof *hits);
    uint32_t *of = malloc((size_t)UB_LM_FIX_CHUNK * 2 * sizeof *of);
    if (!rays || !hits || !of) {
#pragma omp atomic write
      oom = 1;
    }
#pragma omp for schedule(dynamic, 1)
    for (int64_t chunk = 0; chunk < (int64_t)nchunks; chunk++) {
      uint32_t t0, t1;
      if (!fix_chunk(&oom, chunk, lm->texel_count, &t0, &t1))
        continue;
      uint32_t n = 0;
      for (uint32_t t = t0; t < t1; t++) {
        const ub_atlas *at = &lm->atlases[lm->texel_atlas[t]];
        uint32_t x = lm->texel_xy[2 * (size_t)t], y = lm->texel_xy[2 * (size_t)t + 1];
        for (int d = 0; d < 2; d++) {
          uint32_t xx = x + (d == 0), yy = y + (d == 1);
          if (xx >= at->width || yy >= at->height)
            continue;
          int32_t u = at->texel_of[(size_t)yy * at->width + xx];
          if (u < 0)
            continue;
          float pa[3] = {0, 0, 0}, pb[3] = {0, 0, 0};
          for (int j = 0; j < UB_TEXEL_SAMPLES; j++)
            for (int k = 0; k < 3; k++) {
              pa[k] += lm->sample_pos[((size_t)t * UB_TEXEL_SAMPLES + j) * 3 + k] / UB_TEXEL_SAMPLES;
              pb[k] += lm->sample_pos[((size_t)u * UB_TEXEL_SAMPLES + j) * 3 + k] / UB_TEXEL_SAMPLES;
            }
          float dd[3] = {pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]};
          float lift = 0.05f * sqrtf(f3_dot(dd, dd));
          const float *na = lm->texel_normal + 3 * (size_t)t, *nb = lm->texel_normal + 3 * (size_t)u;
          for (int k = 0; k < 3; k++) {
            pa[k] += na[k] * lift;
            pb[k] += nb[k] * lift;
            dd[k] = pb[k] - pa[k];
          }
          float dir[3], len = unit3f(dd, dir);
          if (len == 0.0f)
            continue;
          ray_setup(&rays[n], pa, dir, len);
          of[n++] = (t - t0) * 2 + (uint32_t)d;
        }
      }
      if (n)
        ub_rt_intersect(rt, rays, n, hits);
      for (uint32_t i = 0; i < n; i++) {
        if (hits[i].tri == UB_RT_MISS || !(hits[i].t < rays[i].tfar))
          continue;
        uint32_t t = t0 + of[i] / 2;
        ub_atlas *at = &lm->atlases[lm->texel_atlas[t]];
        size_t px = (size_t)lm->texel_xy[2 * (size_t)t + 1] * at->width + lm->texel_xy[2 * (size_t)t];
        at->link[px] |= (of[i] & 1) ? UB_LINK_Y : UB_LINK_X; /* one texel: one chunk */
        separated++;
      }
    }
    free(rays);
    free(hits);
    free(of);
  }
  return oom ? UINT64_MAX : separated;
}

/* ---------------------------------------------------------------------------------- */

void ub_lightmap_free(ub_lightmap *lm)
{
  if (!lm)
    return;
  if (lm->atlases)
    for (uint32_t a = 0; a < lm->atlas_count; a++) {
      free(lm->atlases[a].texel_of);
      free(lm->atlases[a].link);
    }
  free(lm->atlases);
  free(lm->tri_atlas);
  free(lm->tri_uv);
  free(lm->tri_chart);
  free(lm->texel_atlas);
  free(lm->texel_xy);
  free(lm->texel_tri);
  free(lm->texel_pos);
  free(lm->texel_normal);
  free(lm->sample_pos);
  free(lm->texel_area);
  free(lm);
}

static int alloc_texels(ub_lightmap *lm)
{
  size_t n = lm->texel_count ? lm->texel_count : 1;
  lm->texel_atlas = malloc(n * sizeof *lm->texel_atlas);
  lm->texel_xy = malloc(n * 2 * sizeof *lm->texel_xy);
  lm->texel_tri = malloc(n * sizeof *lm->texel_tri);
  lm->texel_pos = malloc(n * 3 * sizeof *lm->texel_pos);
  lm->texel_normal = malloc(n * 3 * sizeof *lm->texel_normal);
  lm->sample_pos = malloc(n * UB_TEXEL_SAMPLES * 3 * sizeof *lm->sample_pos);
  lm->texel_area = malloc(n * sizeof *lm->texel_area);
  return lm->texel_atlas && lm->texel_xy && lm->texel_tri && lm->texel_pos &&
         lm->texel_normal && lm->sample_pos && lm->texel_area;
}

ub_result ub_lightmap_build(const ub_scene *scene, const ub_rt *rt, float default_texel_size,
                            const ub_log *log, ub_lightmap **out_lightmap)
{
  if (!scene || !out_lightmap || (scene->triangle_count && (!scene->indices || !scene->positions)))
    return UB_ERR_INVALID_ARGUMENT;
  if (!(default_texel_size > 0.0f) || !isfinite(default_texel_size))
    default_texel_size = 0.25f;
  double t_start = now_seconds();
  const ub_scene *s = scene;
  uint32_t nt = s->triangle_count;
  for (uint64_t i = 0; i < 3ull * nt; i++)
    if (s->indices[i] >= s->vertex_count) {
      ub_log_printf(log, UB_LOG_ERROR, "lightmap: triangle %llu has vertex index %u ≥ %u",
                    (unsigned long long)(i / 3), s->indices[i], s->vertex_count);
      return UB_ERR_INVALID_DATA;
    }

  lm_ctx c;
  memset(&c, 0, sizeof c);
  c.scene = s;
  c.rt = rt;
  c.log = log;
  ub_result res = UB_OK;
  ub_lightmap *lm = calloc(1, sizeof *lm);
  lm_charts g;
  memset(&g, 0, sizeof g);
  lm_rtri *rtri = NULL;
  lm_atlas_work *aw = NULL;
  uint32_t naw = 0; /* entries of aw */
  uint32_t *gen_w = NULL, *gen_h = NULL;
  uint32_t gen_count = 0;
  float *raw_samples = NULL;
  size_t ntn = nt ? nt : 1;
  c.tri_n = malloc(ntn * 3 * sizeof *c.tri_n);
  c.tri_area = malloc(ntn * sizeof *c.tri_area);
  c.tri_kind = malloc(ntn);
  if (!lm || !c.tri_n || !c.tri_area || !c.tri_kind) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto fail;
  }
  lm->tri_atlas = malloc(ntn * sizeof *lm->tri_atlas);
  lm->tri_uv = calloc(ntn * 6, sizeof *lm->tri_uv);
  lm->tri_chart = malloc(ntn * sizeof *lm->tri_chart);
  rtri = calloc(ntn, sizeof *rtri);
  if (!lm->tri_atlas || !lm->tri_uv || !lm->tri_chart || !rtri) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto fail;
  }

  /* Scene scale. */
  {
    float mn[3] = {FLT_MAX, FLT_MAX, FLT_MAX}, mx[3] = {-FLT_MAX, -FLT_MAX, -FLT_MAX};
    for (uint32_t v = 0; v < s->vertex_count; v++)
      for (int a = 0; a < 3; a++) {
        float p = s->positions[3 * (size_t)v + a];
        if (isfinite(p)) {
          mn[a] = fminf(mn[a], p);
          mx[a] = fmaxf(mx[a], p);
        }
      }
    float e = 0.0f;
    for (int a = 0; a < 3; a++)
      if (mx[a] >= mn[a])
        e = fmaxf(e, mx[a] - mn[a]);
    c.extent = e;
    c.plane_tol = fmax(1e-5 * (double)e, 1e-6);
    c.local_eps = fmaxf(1e-7f * e, 1e-6f);
  }

  /* 1. per-triangle normals, areas, classification */
  uint32_t n_auth = 0, n_gen = 0;
#pragma omp parallel for schedule(static) reduction(+ : n_auth, n_gen)
  for (int64_t ii = 0; ii < (int64_t)nt; ii++) {
    uint32_t t = (uint32_t)ii;
    double p[3][3], e1[3], e2[3], n[3];
    tri_corners(s, t, p);
    v3_sub(p[1], p[0], e1);
    v3_sub(p[2], p[0], e2);
    v3_cross(e1, e2, n);
    double len = v3_normalize(n);
    int ok = !(s->tri_flags && (s->tri_flags[t] & UB_TRI_DEGENERATE)) && len > 0.0 &&
             isfinite(len);
    c.tri_area[t] = ok ? 0.5 * len : 0.0;
    for (int a = 0; a < 3; a++)
      c.tri_n[3 * (size_t)t + a] = ok ? (float)n[a] : 0.0f;
    int kind = -1;
    if (ok && tri_receiver(s, t) == UB_RECEIVER_LIGHTMAP)
      kind = (s->tri_flags && (s->tri_flags[t] & UB_TRI_HAS_UV1) && s->uv1) ? 0 : 1;
    c.tri_kind[t] = (int8_t)kind;
    n_auth += kind == 0;
    n_gen += kind == 1;
    lm->tri_atlas[t] = -1;
    lm->tri_chart[t] = -1;
  }

  /* The texels the surfaces ask for, before any atlas is made: past UB_LM_MAX_TEXELS the
   * texel size is a mistake (or the level needs splitting), not something to allocate. */
  {
    double want = 0.0, want_auth = 0.0, area = 0.0, ts_min = INFINITY;
    for (uint32_t t = 0; t < nt; t++) {
      if (c.tri_kind[t] < 0)
        continue;
      double ts = ub_lm_texel_size(&c, t, default_texel_size);
      *(c.tri_kind[t] == 0 ? &want_auth : &want) += c.tri_area[t] / (ts * ts);
      area += c.tri_area[t];
      ts_min = ts < ts_min ? ts : ts_min;
    }
    /* the level's own UVs get one atlas, at most UB_ATLAS_MAX_SIZE² texels (step 2) */
    const double auth_max = (double)UB_ATLAS_MAX_SIZE * UB_ATLAS_MAX_SIZE;
    want += want_auth < auth_max ? want_auth : auth_max;
    if (want > UB_LM_MAX_TEXELS) {
      ub_log_printf(log, UB_LOG_ERROR,
                    "%s: lightmap: %.4g m² of lightmapped surfaces at texel sizes down to %g m "
                    "(--texel-size, ubake_texel_size) ask for %.3g texels, more than the "
                    "limit of %.3g: use a larger texel size", s->path ? s->path : "level",
                    area, ts_min, want, UB_LM_MAX_TEXELS);
      res = UB_ERR_INVALID_ARGUMENT;
      goto fail;
    }
  }

  /* 2. authored atlas (atlas 0 when present) */
  uint32_t auth_res = 0, uv_clamped = 0;
  if (n_auth) {
    double want = 0.0, uv_area = 0.0;
    for (uint32_t t = 0; t < nt; t++) {
      if (c.tri_kind[t] != 0)
        continue;
      float ts = ub_lm_texel_size(&c, t, default_texel_size);
      want += c.tri_area[t] / ((double)ts * ts);
      double uv[6];
      for (int k = 0; k < 3; k++)
        for (int a = 0; a < 2; a++) {
          float u = s->uv1[2 * (size_t)s->indices[3 * (size_t)t + k] + a];
          float uc = isfinite(u) ? fminf(fmaxf(u, 0.0f), 1.0f) : 0.0f;
          if (uc != u)
            uv_clamped++;
          uv[2 * k + a] = uc;
          lm->tri_uv[6 * (size_t)t + 2 * k + a] = uc;
        }
      uv_area += 0.5 * fabs((uv[2] - uv[0]) * (uv[5] - uv[1]) - (uv[4] - uv[0]) * (uv[3] - uv[1]));
      lm->tri_atlas[t] = 0;
    }
    double r = uv_area > 0.0 ? sqrt(want / uv_area) : UB_LM_MIN_SIZE;
    auth_res = round_up4(r);
    if (auth_res < UB_LM_MIN_SIZE)
      auth_res = UB_LM_MIN_SIZE;
    if (auth_res > UB_ATLAS_MAX_SIZE)
      auth_res = UB_ATLAS_MAX_SIZE;
    if (uv_clamped)
      ub_log_printf(log, UB_LOG_WARNING,
                    "lightmap: %u TEXCOORD_1 values outside [0,1] clamped", uv_clamped);
  }

  /* 3. generated charts */
  res = ub_lm_charts_build(&c, default_texel_size, &g);
  if (res != UB_OK)
    goto fail;
  if (g.chart_count) {
    res = ub_lm_charts_pack(&g, &gen_count, &gen_w, &gen_h);
    if (res != UB_OK)
      goto fail;
  }
  if (g.overlap_splits)
    ub_log_printf(log, UB_LOG_INFO,
                  "lightmap: %u generated charts folded over themselves and were split",
                  g.overlap_splits);
  if (g.scaled_charts)
    ub_log_printf(log, UB_LOG_WARNING,
                  "lightmap: %u charts larger than a %u² atlas scaled down (coarser texels)",
                  g.scaled_charts, UB_ATLAS_MAX_SIZE);

  lm->atlas_count = (n_auth ? 1u : 0u) + gen_count;
  lm->chart_count = g.chart_count;
  lm->atlases = calloc(lm->atlas_count ? lm->atlas_count : 1, sizeof *lm->atlases);
  aw = calloc(lm->atlas_count ? lm->atlas_count : 1, sizeof *aw);
  naw = aw ? lm->atlas_count : 0;
  if (!lm->atlases || !aw) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto fail;
  }
  uint32_t gen_base = n_auth ? 1u : 0u;
  if (n_auth) {
    lm->atlases[0].width = lm->atlases[0].height = auth_res;
    lm->atlases[0].generated = 0;
  }
  for (uint32_t a = 0; a < gen_count; a++) {
    lm->atlases[gen_base + a].width = gen_w[a];
    lm->atlases[gen_base + a].height = gen_h[a];
    lm->atlases[gen_base + a].generated = 1;
  }
  for (uint32_t ci = 0; ci < g.chart_count; ci++) {
    const lm_chart *ch = &g.charts[ci];
    uint32_t a = gen_base + ch->atlas;
    double W = lm->atlases[a].width, H = lm->atlases[a].height;
    double eu = ch->umax - ch->umin, ev = ch->vmax - ch->vmin;
    /* centre the chart in its rectangle's interior */
    double ou = ch->x + UB_LM_PADDING + 0.5 * (ub_lm_chart_cells(eu) - eu) - ch->umin;
    double ov = ch->y + UB_LM_PADDING + 0.5 * (ub_lm_chart_cells(ev) - ev) - ch->vmin;
    for (uint32_t m = 0; m < ch->count; m++) {
      uint32_t gi = g.order[ch->first + m];
      uint32_t t = g.gtri[gi];
      lm->tri_atlas[t] = (int32_t)a;
      lm->tri_chart[t] = (int32_t)ci;
      for (int k = 0; k < 3; k++) {
        lm->tri_uv[6 * (size_t)t + 2 * k] = (float)((g.guv[6 * (size_t)gi + 2 * k] + ou) / W);
        lm->tri_uv[6 * (size_t)t + 2 * k + 1] =
            (float)((g.guv[6 * (size_t)gi + 2 * k + 1] + ov) / H);
      }
    }
  }
  double t_charts = now_seconds();

  /* 4. rasterisation setup: texel-space triangles and UV→world Jacobians */
  uint32_t uv_degenerate = 0;
#pragma omp parallel for schedule(static) reduction(+ : uv_degenerate)
  for (int64_t ii = 0; ii < (int64_t)nt; ii++) {
    uint32_t t = (uint32_t)ii;
    int32_t a = lm->tri_atlas[t];
    if (a < 0)
      continue;
    lm_rtri *r = &rtri[t];
    double W = lm->atlases[a].width, H = lm->atlases[a].height;
    for (int k = 0; k < 3; k++) {
      r->tx[2 * k] = lm->tri_uv[6 * (size_t)t + 2 * k] * W;
      r->tx[2 * k + 1] = lm->tri_uv[6 * (size_t)t + 2 * k + 1] * H;
    }
    double e1x = r->tx[2] - r->tx[0], e1y = r->tx[3] - r->tx[1];
    double e2x = r->tx[4] - r->tx[0], e2y = r->tx[5] - r->tx[1];
    double det = e1x * e2y - e1y * e2x;
    if (!(fabs(det) > 1e-12) || !isfinite(det)) {
      r->inv_det = 0.0;
      uv_degenerate++;
      continue;
    }
    r->inv_det = 1.0 / det;
    inset_setup(&c, t, r);
    double p[3][3], E1[3], E2[3];
    tri_corners(s, t, p);
    v3_sub(p[1], p[0], E1);
    v3_sub(p[2], p[0], E2);
    for (int q = 0; q < 3; q++) {
      r->dpdx[q] = (float)((E1[q] * e2y - E2[q] * e1y) * r->inv_det);
      r->dpdy[q] = (float)((E2[q] * e1x - E1[q] * e2x) * r->inv_det);
    }
  }
  if (uv_degenerate) {
    uint32_t t0 = 0;
    while (t0 + 1 < nt && !(lm->tri_atlas[t0] >= 0 && rtri[t0].inv_det == 0.0))
      t0++;
    ub_log_printf(log, UB_LOG_WARNING,
                  "lightmap: %u triangles with zero lightmap-UV area get no texels (the first: "
                  "triangle %u of node '%s')",
                  uv_degenerate, t0, tri_node_name(s, t0));
  }

  /* per-atlas triangle lists (ascending) and tile bins */
  for (uint32_t t = 0; t < nt; t++)
    if (lm->tri_atlas[t] >= 0)
      aw[lm->tri_atlas[t]].ntri++;
  for (uint32_t a = 0; a < lm->atlas_count; a++) {
    aw[a].w = lm->atlases[a].width;
    aw[a].h = lm->atlases[a].height;
    aw[a].tris = malloc((size_t)(aw[a].ntri ? aw[a].ntri : 1) * sizeof *aw[a].tris);
    size_t npx = (size_t)aw[a].w * aw[a].h;
    aw[a].owner = malloc(npx * sizeof *aw[a].owner);
    aw[a].overlap = calloc(npx, 1);
    lm->atlases[a].texel_of = malloc(npx * sizeof *lm->atlases[a].texel_of);
    if (!aw[a].tris || !aw[a].owner || !aw[a].overlap || !lm->atlases[a].texel_of) {
      res = UB_ERR_OUT_OF_MEMORY;
      goto fail;
    }
    for (size_t i = 0; i < npx; i++)
      aw[a].owner[i] = -1;
    aw[a].ntri = 0;
  }
  for (uint32_t t = 0; t < nt; t++)
    if (lm->tri_atlas[t] >= 0) {
      lm_atlas_work *w = &aw[lm->tri_atlas[t]];
      w->tris[w->ntri++] = t;
    }

  /* pass 1: owners */
  uint64_t total_texels = 0, overlaps = 0;
  for (uint32_t a = 0; a < lm->atlas_count; a++) {
    res = bin_tiles(&aw[a], rtri);
    if (res != UB_OK)
      goto fail;
    int64_t ntiles = (int64_t)aw[a].ntx * aw[a].nty;
#pragma omp parallel for schedule(dynamic, 4)
    for (int64_t tile = 0; tile < ntiles; tile++)
      raster_tile(&c, &aw[a], rtri, (uint32_t)tile);
    size_t npx = (size_t)aw[a].w * aw[a].h;
    lm->atlases[a].first_texel = (uint32_t)total_texels;
    uint32_t cnt = 0;
    for (size_t i = 0; i < npx; i++) {
      if (aw[a].owner[i] >= 0) {
        lm->atlases[a].texel_of[i] = (int32_t)(total_texels + cnt);
        cnt++;
        overlaps += aw[a].overlap[i];
      } else {
        lm->atlases[a].texel_of[i] = -1;
      }
    }
    lm->atlases[a].texel_count = cnt;
    total_texels += cnt;
    if (total_texels > INT32_MAX) {
      ub_log_printf(log, UB_LOG_ERROR, "lightmap: more than 2^31 texels; raise the texel size");
      res = UB_ERR_INVALID_DATA;
      goto fail;
    }
  }
  lm->texel_count = (uint32_t)total_texels;
  lm->overlap_texels = (uint32_t)overlaps;
  if (overlaps) {
    /* the first such texel's owner names one of the surfaces */
    uint32_t fa = 0, fx = 0, fy = 0;
    int32_t own = -1;
    for (uint32_t a = 0; a < lm->atlas_count && own < 0; a++)
      for (size_t i = 0; i < (size_t)aw[a].w * aw[a].h; i++)
        if (aw[a].owner[i] >= 0 && aw[a].overlap[i]) {
          own = aw[a].owner[i];
          fa = a, fx = (uint32_t)(i % aw[a].w), fy = (uint32_t)(i / aw[a].w);
          break;
        }
    ub_log_printf(log, UB_LOG_WARNING,
                  "lightmap: %llu texels claimed by overlapping UVs of different surfaces (the "
                  "first: atlas %u texel (%u, %u), node '%s' and another)",
                  (unsigned long long)overlaps, fa, fx, fy,
                  own >= 0 ? tri_node_name(s, (uint32_t)own) : "?");
  }
  if (!alloc_texels(lm)) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto fail;
  }
  raw_samples = malloc((size_t)(total_texels ? total_texels : 1) * UB_TEXEL_SAMPLES * 3 *
                       sizeof *raw_samples);
  if (!raw_samples) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto fail;
  }
  lm_out out = {lm, raw_samples};

  /* pass 2: texel positions, normals, sample points */
  for (uint32_t a = 0; a < lm->atlas_count; a++) {
    int64_t ntiles = (int64_t)aw[a].ntx * aw[a].nty;
#pragma omp parallel for schedule(dynamic, 4)
    for (int64_t tile = 0; tile < ntiles; tile++)
      texel_tile(&c, &aw[a], rtri, a, &lm->atlases[a], (uint32_t)tile, &out);
  }
  texel_areas(&c, rtri, lm);
  double t_raster = now_seconds();

  /* 5. back-face fix and normal offsets */
  if (rt && lm->texel_count) {
    uint64_t fixes = fix_samples(&c, rtri, &out);
    if (fixes == UINT64_MAX) {
      res = UB_ERR_OUT_OF_MEMORY;
      goto fail;
    }
    lm->backface_fixes = (uint32_t)(fixes > UINT32_MAX ? UINT32_MAX : fixes);
    uint64_t sep = texel_links(rt, lm);
    if (sep == UINT64_MAX) {
      res = UB_ERR_OUT_OF_MEMORY;
      goto fail;
    }
    lm->separated_links = (uint32_t)(sep > UINT32_MAX ? UINT32_MAX : sep);
  } else {
    /* No ray tracer: offset only, with the scene-scaled epsilon ub_rt would use. */
#pragma omp parallel for schedule(static)
    for (int64_t ii = 0; ii < (int64_t)lm->texel_count; ii++) {
      const float *n = lm->texel_normal + 3 * (size_t)ii;
      for (int j = 0; j < UB_TEXEL_SAMPLES; j++) {
        const float *p = raw_samples + ((size_t)ii * UB_TEXEL_SAMPLES + j) * 3;
        float m = fmaxf(fabsf(p[0]), fmaxf(fabsf(p[1]), fabsf(p[2])));
        float eps = fmaxf(c.local_eps, m * 2.384185791015625e-07f);
        float *d = lm->sample_pos + ((size_t)ii * UB_TEXEL_SAMPLES + j) * 3;
        for (int a = 0; a < 3; a++)
          d[a] = p[a] + n[a] * eps;
      }
    }
  }
  double t_end = now_seconds();

  {
    char sizes[256];
    size_t off = 0;
    sizes[0] = '\0';
    for (uint32_t a = 0; a < lm->atlas_count && off < sizeof sizes - 32; a++)
      off += (size_t)snprintf(sizes + off, sizeof sizes - off, "%s%ux%u%s", a ? " " : "",
                              lm->atlases[a].width, lm->atlases[a].height,
                              lm->atlases[a].generated ? "g" : "a");
    ub_log_printf(log, UB_LOG_INFO,
                  "lightmap: %u atlases [%s], %u texels, %u authored + %u generated "
                  "triangles in %u charts, %u backface fixes, %u overlap texels, %u texel "
                  "pairs separated by geometry (charts %.3f s, raster %.3f s, fix %.3f s)",
                  lm->atlas_count, sizes, lm->texel_count, n_auth, n_gen, g.chart_count,
                  lm->backface_fixes, lm->overlap_texels, lm->separated_links, t_charts - t_start,
                  t_raster - t_charts, t_end - t_raster);
  }

  *out_lightmap = lm;
  lm = NULL; /* handed over; the cleanup below frees only the scratch */
  res = UB_OK;

fail:
  for (uint32_t a = 0; a < naw; a++) {
    free(aw[a].tris);
    free(aw[a].tile_start);
    free(aw[a].tile_tris);
    free(aw[a].owner);
    free(aw[a].overlap);
  }
  free(aw);
  free(raw_samples);
  free(rtri);
  free(gen_w);
  free(gen_h);
  ub_lm_charts_free(&g);
  free(c.tri_n);
  free(c.tri_area);
  free(c.tri_kind);
  if (res == UB_OK)
    return UB_OK;
  ub_lightmap_free(lm);
  if (res == UB_ERR_OUT_OF_MEMORY)
    ub_log_printf(log, UB_LOG_ERROR, "lightmap: out of memory");
  return res;
}
