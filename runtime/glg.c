/* runtime/glg.c — global light grid: tetrahedral walk, hull projection, SH interpolation.
 * See ubake/glg.h. */
#include "ubake/glg.h"

#include <assert.h>
#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <threads.h>

#include "runtime/bigalloc.h"
#include "runtime/cpu.h"
#include "runtime/half.h"
#include "ubake/sh.h"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define GLG_HAVE_AVX_PATH 1
#endif

/* One cache line per walk step: λ1..3 = m·(p − o), λ0 = 1 − Σ; nb[i] ≥ 0 is the tet
 * opposite corner i, nb[i] < 0 is hull face −nb[i] − 1. Ill-conditioned and singular
 * tets have m = 0 (so λ = (1,0,0,0) "accepts" them) and are resolved by tet_flags. */
struct ub_glg_tet {
  float m[9];
  float o[3];
  int32_t nb[4];
};

/* A hull face: v are probe indices (outward counter-clockwise), adj[k] the hull face
 * across the edge opposite v[k], tet/corner the tet it bounds and its opposite corner,
 * fc[k] the tet corner holding v[k]. */
struct ub_glg_hull {
  uint32_t v[3];
  uint32_t adj[3];
  uint32_t tet;
  uint8_t corner;
  uint8_t fc[3];
  float p[9]; /* the positions of v[0..2] (the GLG keeps no other probe positions) */
};

_Static_assert(sizeof(struct ub_glg_tet) == 64, "walk record is one cache line");

#define GLG_EPS 1e-5f           /* barycentric "inside" tolerance */
#define GLG_ILL_Q 1e-3          /* |det| / lmax³ below this: evaluate in double */
#define GLG_SINGULAR_Q 1e-13    /* below this: singular, use the closest face */
#define GLG_BRUTE_ACCEPT -1e-3  /* brute force: accept the best tet above this */
#define GLG_RING_CAP 256        /* faces around one hull vertex */
#define GLG_NEAR_BARY -0.05f    /* cached tet still "near" p: min barycentric above this
                                   (inside the tet grown 20% about its centroid). At
                                   −0.25 (×2) 1.8% of random queries on kaos walked from
                                   a far, huge tet, 14 steps each (+0.2 per query); a
                                   moving object leaves a tet by far less */
#define GLG_FLAG_ILL 1
#define GLG_FLAG_SINGULAR 2
#define GLG_NONE 0xFFFFFFFFu
#define GLG_CACHE_HULL 0x80000000u /* cache value: outside, at hull face (low bits) */
#ifndef GLG_GRID_CELLS_PER_PROBE
#define GLG_GRID_CELLS_PER_PROBE 4.0 /* start-grid density: ~8 B per probe; walks of ~2.3
                                         tets from a random point on kaos (2: 2.5, 0.5: 3.3) */
#endif
#define GLG_GRID_BLOCK 4 /* start-grid cells per block and axis (one base tet each) */

static const int face_of[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};

/* ---- small double helpers ----------------------------------------------------------- */

static void d3load(const float *p, double o[3])
{
  o[0] = p[0];
  o[1] = p[1];
  o[2] = p[2];
}
static void d3sub(const double a[3], const double b[3], double o[3])
{
  o[0] = a[0] - b[0];
  o[1] = a[1] - b[1];
  o[2] = a[2] - b[2];
}
static double d3dot(const double a[3], const double b[3])
{
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
static void d3cross(const double a[3], const double b[3], double o[3])
{
  double x = a[1] * b[2] - a[2] * b[1], y = a[2] * b[0] - a[0] * b[2],
         z = a[0] * b[1] - a[1] * b[0];
  o[0] = x;
  o[1] = y;
  o[2] = z;
}

/* Minimum of four finite floats, inline (fminf is a libm call at -O2 on x86-64). */
static inline float min4f(const float l[4])
{
  float a = l[0] < l[1] ? l[0] : l[1], b = l[2] < l[3] ? l[2] : l[3];
  return a < b ? a : b;
}

/* Corner i of tet t with small_walk; else of a badly shaped tet t (ill-conditioned or
 * singular): the positions kept for them (ill_ids ascending), found by bisection. */
static const float *tet_corner(const ub_glg *g, uint32_t t, int i)
{
  if (g->pos)
    return g->pos + 3 * (size_t)g->tets[4 * (size_t)t + i];
  uint32_t lo = 0, hi = g->ill_tet_count;
  while (hi - lo > 1) {
    uint32_t mid = lo + (hi - lo) / 2;
    if (g->ill_ids[mid] <= t)
      lo = mid;
    else
      hi = mid;
  }
  assert(g->ill_tet_count && g->ill_ids[lo] == t);
  return g->ill_pos + 12 * (size_t)lo + 3 * i;
}

/* ---- barycentrics ------------------------------------------------------------------- */

static inline void rec_bary(const struct ub_glg_tet *r, const float p[3], float l[4])
{
  float dx = p[0] - r->o[0], dy = p[1] - r->o[1], dz = p[2] - r->o[2];
  l[1] = r->m[0] * dx + r->m[1] * dy + r->m[2] * dz;
  l[2] = r->m[3] * dx + r->m[4] * dy + r->m[5] * dz;
  l[3] = r->m[6] * dx + r->m[7] * dy + r->m[8] * dz;
  l[0] = 1.0f - l[1] - l[2] - l[3];
}

/* The cofactor rows of tet (a, b, c, d) in double, from the exact differences of its
 * float corners e1 = b − a, e2 = c − a, e3 = d − a: r = (e2 × e3, e3 × e1, e1 × e2);
 * returns det = e1 · (e2 × e3). λ_i = r_i · (p − a) / det. */
static inline double tet_cofactors(const float *a, const float *b, const float *c,
                                   const float *d, double r[9])
{
  double e1[3], e2[3], e3[3];
  for (int k = 0; k < 3; k++) {
    e1[k] = (double)b[k] - a[k];
    e2[k] = (double)c[k] - a[k];
    e3[k] = (double)d[k] - a[k];
  }
  d3cross(e2, e3, r);
  d3cross(e3, e1, r + 3);
  d3cross(e1, e2, r + 6);
  return d3dot(e1, r);
}

/* small_walk: well-shaped tet t's geometry for geo_bary: its cofactor rows (geo[0..8]),
 * 1 / det (geo[9]; det far from 0) and corner 0 (geo[10..12]). */
static inline void tet_geo(const ub_glg *g, uint32_t t, double geo[13])
{
  const uint32_t *v = g->tets + 4 * (size_t)t;
  const float *a = g->pos + 3 * (size_t)v[0];
  geo[9] = 1.0 / tet_cofactors(a, g->pos + 3 * (size_t)v[1], g->pos + 3 * (size_t)v[2],
                               g->pos + 3 * (size_t)v[3], geo);
  for (int k = 0; k < 3; k++)
    geo[10 + k] = a[k];
}

/* The barycentrics of p from tet_geo's geometry, rounded to float. */
static inline void geo_bary(const double geo[13], const float p[3], float l[4])
{
  const double x[3] = {(double)p[0] - geo[10], (double)p[1] - geo[11], (double)p[2] - geo[12]};
  l[1] = (float)(d3dot(geo, x) * geo[9]);
  l[2] = (float)(d3dot(geo + 3, x) * geo[9]);
  l[3] = (float)(d3dot(geo + 6, x) * geo[9]);
  l[0] = 1.0f - l[1] - l[2] - l[3];
}

/* small_walk: the barycentrics of p in tet t from its corners (tet_geo, geo_bary); a badly
 * shaped tet gives (1, 0, 0, 0) as its zeroed record does (its callers go on to
 * tet_bary_double by its flag). */
static inline void corner_bary(const ub_glg *g, uint32_t t, const float p[3], float l[4])
{
  if (g->tet_flags[t]) {
    l[0] = 1.0f;
    l[1] = l[2] = l[3] = 0.0f;
    return;
  }
  double geo[13];
  tet_geo(g, t, geo);
  geo_bary(geo, p, l);
}

/* Barycentrics of p in tet t as the walk computes them (record or corners). */
static inline void walk_bary(const ub_glg *g, uint32_t t, const float p[3], float l[4])
{
  if (g->tet_data)
    rec_bary(&g->tet_data[t], p, l);
  else
    corner_bary(g, t, p, l);
}

/* Tet t's four links: ≥ 0 the tet across the face opposite corner i, < 0 −1 − hull face. */
static inline const int32_t *tet_links(const ub_glg *g, uint32_t t)
{
  return g->tet_data ? g->tet_data[t].nb : g->tet_nb + 4 * (size_t)t;
}

/* Requests tet t's walk record, or (small walk) its links (the callers request the
 * corners, g->tets, where they need them). One prefetch of a selected address: GCC 12
 * dropped the record's prefetch when it was one branch of an if. */
static inline void prefetch_walk(const ub_glg *g, uint32_t t)
{
#if defined(__GNUC__)
  __builtin_prefetch(g->tet_data ? (const void *)&g->tet_data[t]
                                 : (const void *)(g->tet_nb + 4 * (size_t)t));
#else
  (void)g;
  (void)t;
#endif
}

/* Double-precision barycentrics from the positions; 0 if the tet is singular. */
static int tet_bary_double(const ub_glg *g, uint32_t t, const float p[3], double l[4])
{
  const float *a = tet_corner(g, t, 0);
  double r[9];
  const double det = tet_cofactors(a, tet_corner(g, t, 1), tet_corner(g, t, 2),
                                   tet_corner(g, t, 3), r);
  if (!(fabs(det) > 0.0) || !isfinite(det))
    return 0;
  const double x[3] = {(double)p[0] - a[0], (double)p[1] - a[1], (double)p[2] - a[2]};
  l[1] = d3dot(r, x) / det;
  l[2] = d3dot(r + 3, x) / det;
  l[3] = d3dot(r + 6, x) / det;
  l[0] = 1.0 - l[1] - l[2] - l[3];
  return 1;
}

/* Clamp to [0, 1] and renormalise; a zero sum gives the centroid. */
static inline void bary_finish(float l[4])
{
  /* Inside (every λ in [0, 1]): already a partition of unity to rounding (λ0 = 1 − Σ), so
   * no clamp and no division on the hot path of a moving object's queries. */
  if (l[0] >= 0.0f && l[1] >= 0.0f && l[2] >= 0.0f && l[3] >= 0.0f && l[0] <= 1.0f &&
      l[1] <= 1.0f && l[2] <= 1.0f && l[3] <= 1.0f)
    return;
  float s = 0.0f;
  for (int i = 0; i < 4; i++) {
    float x = l[i];
    if (!(x > 0.0f))
      x = 0.0f;
    if (x > 1.0f)
      x = 1.0f;
    l[i] = x;
    s += x;
  }
  if (!(s > 0.0f)) {
    l[0] = l[1] = l[2] = l[3] = 0.25f;
    return;
  }
  float inv = 1.0f / s;
  for (int i = 0; i < 4; i++)
    l[i] *= inv;
}

/* Closest point on triangle abc to p (Ericson, RTCD §5.1.5), in double. Writes the
 * barycentrics (of a, b, c) and returns the region: 0..2 vertex k, 3..5 the edge opposite
 * vertex k − 3, 6 the interior. */
static int closest_on_tri(const double p[3], const double a[3], const double b[3],
                          const double c[3], double out_w[3])
{
  double ab[3], ac[3], ap[3], bp[3], cp[3];
  d3sub(b, a, ab);
  d3sub(c, a, ac);
  d3sub(p, a, ap);
  double d1 = d3dot(ab, ap), d2 = d3dot(ac, ap);
  if (d1 <= 0.0 && d2 <= 0.0) {
    out_w[0] = 1.0, out_w[1] = 0.0, out_w[2] = 0.0;
    return 0;
  }
  d3sub(p, b, bp);
  double d3 = d3dot(ab, bp), d4 = d3dot(ac, bp);
  if (d3 >= 0.0 && d4 <= d3) {
    out_w[0] = 0.0, out_w[1] = 1.0, out_w[2] = 0.0;
    return 1;
  }
  double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
    double den = d1 - d3;
    double v = den > 0.0 ? d1 / den : 0.0;
    out_w[0] = 1.0 - v, out_w[1] = v, out_w[2] = 0.0;
    return 5;
  }
  d3sub(p, c, cp);
  double d5 = d3dot(ab, cp), d6 = d3dot(ac, cp);
  if (d6 >= 0.0 && d5 <= d6) {
    out_w[0] = 0.0, out_w[1] = 0.0, out_w[2] = 1.0;
    return 2;
  }
  double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
    double den = d2 - d6;
    double w = den > 0.0 ? d2 / den : 0.0;
    out_w[0] = 1.0 - w, out_w[1] = 0.0, out_w[2] = w;
    return 4;
  }
  double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    double den = (d4 - d3) + (d5 - d6);
    double w = den > 0.0 ? (d4 - d3) / den : 0.0;
    out_w[0] = 0.0, out_w[1] = 1.0 - w, out_w[2] = w;
    return 3;
  }
  double s = va + vb + vc;
  if (!(s > 0.0)) { /* degenerate triangle: nearest vertex */
    out_w[0] = 1.0, out_w[1] = 0.0, out_w[2] = 0.0;
    return 0;
  }
  double v = vb / s, w = vc / s;
  out_w[0] = 1.0 - v - w, out_w[1] = v, out_w[2] = w;
  return 6;
}

/* ---- outside the hull: projection onto the closest hull face --------------------------- */

typedef struct hull_hit {
  uint32_t face;
  double w[3];
  double d2;
  int region;
} hull_hit;

static void hull_eval(const ub_glg *g, const double p[3], uint32_t h, hull_hit *out)
{
  const struct ub_glg_hull *f = &g->hull[h];
  double a[3], b[3], c[3], q[3], e[3];
  d3load(f->p, a);
  d3load(f->p + 3, b);
  d3load(f->p + 6, c);
  out->face = h;
  out->region = closest_on_tri(p, a, b, c, out->w);
  for (int i = 0; i < 3; i++)
    q[i] = out->w[0] * a[i] + out->w[1] * b[i] + out->w[2] * c[i];
  d3sub(p, q, e);
  out->d2 = d3dot(e, e);
}

/* (p − q)·n_h ≥ −tol·|p − q|·|n_h|: p is on the outer side of face h's plane. */
static int hull_sees(const ub_glg *g, const double p[3], const hull_hit *hit, uint32_t h)
{
  const struct ub_glg_hull *f = &g->hull[h];
  const struct ub_glg_hull *fh = &g->hull[hit->face];
  double a[3], b[3], c[3], e1[3], e2[3], n[3], q[3], d[3];
  d3load(f->p, a);
  d3load(f->p + 3, b);
  d3load(f->p + 6, c);
  d3sub(b, a, e1);
  d3sub(c, a, e2);
  d3cross(e1, e2, n);
  double qa[3], qb[3], qc[3];
  d3load(fh->p, qa);
  d3load(fh->p + 3, qb);
  d3load(fh->p + 6, qc);
  for (int i = 0; i < 3; i++)
    q[i] = hit->w[0] * qa[i] + hit->w[1] * qb[i] + hit->w[2] * qc[i];
  d3sub(p, q, d);
  double dn = d3dot(d, n);
  return dn >= -1e-9 * sqrt(d3dot(d, d) * d3dot(n, n));
}

/* The nearest hull face by a scan of them all (ub_glg_init keeps at least 4); when no
 * distance is below HUGE_VAL (p so far that they overflow), face 0's weights, so *best
 * always names a face. */
static void hull_brute(const ub_glg *g, const double p[3], hull_hit *best)
{
  hull_eval(g, p, 0, best);
  best->d2 = HUGE_VAL;
  for (uint32_t h = 0; h < g->hull_count; h++) {
    hull_hit hit;
    hull_eval(g, p, h, &hit);
    if (hit.d2 < best->d2)
      *best = hit;
  }
}

static int local_index(const struct ub_glg_hull *f, uint32_t vid)
{
  for (int k = 0; k < 3; k++)
    if (f->v[k] == vid)
      return k;
  return -1;
}

/* Local search over hull faces from h0 for the closest point q of the (convex) hull to
 * an outside point p: move to an adjacent face (across q's edge, or around q's vertex)
 * while that is strictly closer. The stop is certified by the normal-cone condition: q is
 * the closest point of every face around it (so p − q is normal to the hull's tangent
 * cone at q) and p lies on the outer side of at least one of those faces (which rules out
 * local minima on the far side of the hull). If that fails, or after too many steps,
 * brute force over all hull faces. */
static void hull_project(const ub_glg *g, const double p[3], uint32_t h0, hull_hit *out,
                         ub_glg_locate_info *info)
{
  hull_hit cur;
  hull_eval(g, p, h0, &cur);
  uint32_t cap = 64 + 4 * (uint32_t)sqrt((double)g->hull_count);
  for (uint32_t step = 0; step < cap; step++) {
    if (info)
      info->hull_steps++;
    if (cur.d2 == 0.0) {
      *out = cur;
      return;
    }
    const double shrink = 1.0 - 1e-12;
    if (cur.region == 6) {
      if (hull_sees(g, p, &cur, cur.face)) {
        *out = cur;
        return;
      }
      break; /* behind an interior face: a trap on the far side */
    }
    const struct ub_glg_hull *f = &g->hull[cur.face];
    if (cur.region >= 3) { /* edge opposite vertex region−3 */
      uint32_t nbf = f->adj[cur.region - 3];
      hull_hit nh;
      hull_eval(g, p, nbf, &nh);
      if (nh.d2 < cur.d2 * shrink) {
        cur = nh;
        continue;
      }
      if (hull_sees(g, p, &cur, cur.face) || hull_sees(g, p, &cur, nbf)) {
        *out = cur;
        return;
      }
      break;
    }
    /* vertex: the ring of faces around it */
    uint32_t vid = f->v[cur.region];
    uint32_t prev = GLG_NONE, at = cur.face;
    hull_hit best = cur;
    int seen = 0, closed = 0;
    for (int r = 0; r < GLG_RING_CAP; r++) {
      const struct ub_glg_hull *fa = &g->hull[at];
      int j = local_index(fa, vid);
      if (j < 0)
        break;
      if (at != cur.face) {
        hull_hit hh;
        hull_eval(g, p, at, &hh);
        if (hh.d2 < best.d2 * shrink)
          best = hh;
      }
      seen |= hull_sees(g, p, &cur, at);
      uint32_t nx = fa->adj[(j + 1) % 3];
      if (nx == prev)
        nx = fa->adj[(j + 2) % 3];
      prev = at;
      at = nx;
      if (at == cur.face) {
        closed = 1;
        break;
      }
    }
    if (!closed)
      break;
    if (best.face != cur.face) {
      cur = best;
      continue;
    }
    if (seen) {
      *out = cur;
      return;
    }
    break;
  }
  if (info)
    info->fallback = 1;
  hull_brute(g, p, out);
}

static uint32_t hull_result(const ub_glg *g, const hull_hit *hit, float bary[4])
{
  const struct ub_glg_hull *f = &g->hull[hit->face];
  bary[0] = bary[1] = bary[2] = bary[3] = 0.0f;
  for (int k = 0; k < 3; k++)
    bary[f->fc[k]] = (float)hit->w[k];
  bary_finish(bary);
  return f->tet;
}

/* ---- singular tets -------------------------------------------------------------------- */

static void singular_weights(const ub_glg *g, uint32_t t, const float p[3], float bary[4])
{
  double q[3], best = HUGE_VAL;
  d3load(p, q);
  bary[0] = bary[1] = bary[2] = bary[3] = 0.0f;
  float out[4] = {0.25f, 0.25f, 0.25f, 0.25f};
  for (int i = 0; i < 4; i++) {
    double a[3], b[3], c[3], w[3], x[3], e[3];
    d3load(tet_corner(g, t, face_of[i][0]), a);
    d3load(tet_corner(g, t, face_of[i][1]), b);
    d3load(tet_corner(g, t, face_of[i][2]), c);
    closest_on_tri(q, a, b, c, w);
    for (int k = 0; k < 3; k++)
      x[k] = w[0] * a[k] + w[1] * b[k] + w[2] * c[k];
    d3sub(q, x, e);
    double d2 = d3dot(e, e);
    if (d2 < best) {
      best = d2;
      out[0] = out[1] = out[2] = out[3] = 0.0f;
      for (int k = 0; k < 3; k++)
        out[face_of[i][k]] = (float)w[k];
    }
  }
  memcpy(bary, out, sizeof out);
  bary_finish(bary);
}

/* ---- the walk ----------------------------------------------------------------------- */

/* Barycentrics of p in tet t into l: from the walk record, or in double for an
 * ill-shaped tet. 0 for a singular tet (or a failed double solve), l untouched. */
static inline int tet_bary(const ub_glg *g, uint32_t t, const float p[3], float l[4])
{
  uint8_t fl = g->tet_flags[t];
  if (fl == GLG_FLAG_SINGULAR)
    return 0;
  if (fl == GLG_FLAG_ILL) {
    double ld[4];
    if (!tet_bary_double(g, t, p, ld))
      return 0;
    for (int i = 0; i < 4; i++)
      l[i] = (float)ld[i];
  } else {
    walk_bary(g, t, p, l);
  }
  return 1;
}

/* min barycentric of p in tet t (singular tets score −1e30 so they rank last). */
static float tet_min_bary(const ub_glg *g, uint32_t t, const float p[3])
{
  float l[4];
  return tet_bary(g, t, p, l) ? min4f(l) : -1e30f;
}

static uint32_t brute_locate(const ub_glg *g, const float p[3], float bary[4],
                             ub_glg_locate_info *info, uint32_t *out_cache)
{
  float best_min = -HUGE_VALF, best_l[4] = {0.25f, 0.25f, 0.25f, 0.25f};
  uint32_t best_t = 0;
  for (uint32_t t = 0; t < g->tet_count; t++) {
    float l[4];
    if (!tet_bary(g, t, p, l))
      continue;
    float mn = min4f(l);
    if (mn > best_min) {
      best_min = mn;
      best_t = t;
      memcpy(best_l, l, sizeof best_l);
    }
  }
  if (best_min >= (float)GLG_BRUTE_ACCEPT) {
    memcpy(bary, best_l, sizeof best_l);
    bary_finish(bary);
    *out_cache = best_t;
    return best_t;
  }
  if (info)
    info->outside = 1;
  double q[3];
  d3load(p, q);
  hull_hit hit;
  hull_brute(g, q, &hit);
  *out_cache = GLG_CACHE_HULL | hit.face;
  return hull_result(g, &hit, bary);
}

/* Walks from tet t to the tet containing p (or p's projection onto the hull).
 * *out_cache receives the value for the caller's cache: the tet, or GLG_CACHE_HULL | face
 * when p was outside. */
static uint32_t walk(const ub_glg *g, const float p[3], uint32_t t, float bary[4],
                     ub_glg_locate_info *info, uint32_t *out_cache)
{
  *out_cache = GLG_NONE;
  uint32_t prev = GLG_NONE;
  for (uint32_t step = 0; step < g->walk_cap; step++) {
    if (info)
      info->steps++;
    const int32_t *lk = tet_links(g, t);
#if defined(__GNUC__)
    /* This tet may be the answer: start loading what the interpolation reads of it
     * (corners, flag, leak plane) while its walk record arrives (random queries are
     * bound by these dependent cache misses). */
    __builtin_prefetch(g->tets + 4 * (size_t)t);
    __builtin_prefetch(g->tet_flags + t);
    if (g->leak_plane_of) {
      __builtin_prefetch(g->leak_plane_of + t);
      __builtin_prefetch(g->leak_drop + t);
    }
    /* If p is not in t, the next step is one of t's neighbours: request their records as
     * soon as t's arrives rather than after the barycentric test has picked one (~6%
     * more random queries per second on kaos, 2.5 steps per query). */
    for (int i = 0; i < 4; i++)
      if (lk[i] >= 0 && (uint32_t)lk[i] != prev)
        prefetch_walk(g, (uint32_t)lk[i]);
#endif
    float l[4];
    walk_bary(g, t, p, l);
    float mn = min4f(l);
    if (mn >= -GLG_EPS) {
      uint8_t fl = g->tet_flags[t];
      if (!fl) {
        memcpy(bary, l, sizeof l);
        bary_finish(bary);
        *out_cache = t;
        return t;
      }
      double ld[4];
      if (fl == GLG_FLAG_SINGULAR || !tet_bary_double(g, t, p, ld)) {
        /* Zero volume: nothing is inside. Step to the neighbour that best contains p
         * (stacks of flat tets come from jittered retries on coplanar probes). */
        uint32_t best = GLG_NONE;
        float best_v = -HUGE_VALF;
        for (int i = 0; i < 4; i++) {
          int32_t u = lk[i];
          if (u < 0 || (uint32_t)u == prev)
            continue;
          float v = tet_min_bary(g, (uint32_t)u, p);
          if (best == GLG_NONE || v > best_v) {
            best = (uint32_t)u;
            best_v = v;
          }
        }
        if (best == GLG_NONE) {
          singular_weights(g, t, p, bary);
          *out_cache = t;
          return t;
        }
        prev = t;
        t = best;
        continue;
      }
      for (int i = 0; i < 4; i++)
        l[i] = (float)ld[i];
      mn = min4f(l);
      if (mn >= -GLG_EPS) {
        memcpy(bary, l, sizeof l);
        bary_finish(bary);
        *out_cache = t;
        return t;
      }
    }
    /* Cross the face with the most negative barycentric, never straight back; beyond
     * any hull face's plane p is outside the convex hull, so project right away. */
    int k = -1;
    float kv = -GLG_EPS;
    int hull_k = -1;
    for (int i = 0; i < 4; i++) {
      if (l[i] < kv && !(lk[i] >= 0 && (uint32_t)lk[i] == prev)) {
        kv = l[i];
        k = i;
      }
      if (lk[i] < 0 && l[i] < -GLG_EPS && (hull_k < 0 || l[i] < l[hull_k]))
        hull_k = i;
    }
    if (hull_k >= 0)
      k = hull_k;
    if (k < 0) { /* only the face we came through is violated: numerically on it */
      memcpy(bary, l, sizeof l);
      bary_finish(bary);
      *out_cache = t;
      return t;
    }
    int32_t nb = lk[k];
    if (nb < 0) { /* beyond a hull face's supporting plane: outside the convex hull */
      if (info)
        info->outside = 1;
      double q[3];
      d3load(p, q);
      hull_hit hit;
      hull_project(g, q, (uint32_t)(-nb - 1), &hit, info);
      *out_cache = GLG_CACHE_HULL | hit.face;
      return hull_result(g, &hit, bary);
    }
    prev = t;
    t = (uint32_t)nb;
  }
  if (info)
    info->fallback = 1;
  return brute_locate(g, p, bary, info, out_cache);
}

/* The start tet of p's grid cell: its block's base tet plus the cell's 16-bit offset (the
 * mesh is in Morton order, so the tets of a few neighbouring cells are close in index):
 * 2 B per cell instead of 4, twice the cells in the bytes that stay in cache. */
static uint32_t grid_start(const ub_glg *g, const float p[3])
{
  uint32_t c[3];
  for (int a = 0; a < 3; a++) {
    float x = (p[a] - g->grid_lo[a]) * g->grid_inv_cell[a];
    /* clamped before the conversion: a point far outside (or x = inf) does not fit an
     * integer, and converting it is undefined (UBSan's float-cast-overflow) */
    const float top = (float)g->grid_dim[a] - 1.0f;
    c[a] = x > 0.0f ? (uint32_t)(x < top ? x : top) : 0;
  }
  const uint32_t bx = (g->grid_dim[0] + GLG_GRID_BLOCK - 1) / GLG_GRID_BLOCK,
                 by = (g->grid_dim[1] + GLG_GRID_BLOCK - 1) / GLG_GRID_BLOCK;
  uint32_t base = g->start_grid[c[0] / GLG_GRID_BLOCK +
                                (size_t)bx * (c[1] / GLG_GRID_BLOCK +
                                              (size_t)by * (c[2] / GLG_GRID_BLOCK))];
  int16_t d = g->start_delta[c[0] + (size_t)g->grid_dim[0] * (c[1] + (size_t)g->grid_dim[1] * c[2])];
  return (uint32_t)((int64_t)base + d);
}

/* p strictly on the outer side of hull face h's plane. */
static int hull_outside(const ub_glg *g, const float p[3], uint32_t h)
{
  const struct ub_glg_hull *f = &g->hull[h];
  double a[3], b[3], c[3], q[3], e1[3], e2[3], n[3], d[3];
  d3load(f->p, a);
  d3load(f->p + 3, b);
  d3load(f->p + 6, c);
  d3load(p, q);
  d3sub(b, a, e1);
  d3sub(c, a, e2);
  d3cross(e1, e2, n);
  d3sub(q, a, d);
  return d3dot(n, d) > 0.0;
}

/* ub_glg_locate_ex once the cache (start: a tet or GLG_NONE) is known not to hold the
 * finite p; start_min is p's min barycentric in start when start is well shaped. */
static uint32_t locate_walk(const ub_glg *g, const float p[3], uint32_t start, float start_min,
                            float out_bary[4], ub_glg_locate_info *info,
                            uint32_t *inout_tet_cache)
{
  if (g->start_grid) {
    int far = 1;
    if (start != GLG_NONE) {
      /* Near the cached tet, in its own units (barycentrics: a big tet in open space
       * stays near for a long way) or within two grid cells: walk from it. */
      const float *o = g->tet_data ? g->tet_data[start].o : tet_corner(g, start, 0);
      float dx = p[0] - o[0], dy = p[1] - o[1], dz = p[2] - o[2];
      far = dx * dx + dy * dy + dz * dz > g->grid_far2;
      uint8_t fl = g->tet_flags[start];
      if (far && fl != GLG_FLAG_SINGULAR)
        far = !((fl ? tet_min_bary(g, start, p) : start_min) >= GLG_NEAR_BARY);
    }
    if (far) {
      start = grid_start(g, p);
      if (info)
        info->from_grid = 1;
    }
  }
  if (start == GLG_NONE)
    start = 0;
  uint32_t out_cache;
  uint32_t t = walk(g, p, start, out_bary, info, &out_cache);
  if (inout_tet_cache)
    *inout_tet_cache = out_cache;
  return t;
}

uint32_t ub_glg_locate_ex(const ub_glg *g, const float p[3], uint32_t *inout_tet_cache,
                          float out_bary[4], ub_glg_locate_info *info)
{
  assert(g && g->tet_flags && p && out_bary);
  if (info)
    memset(info, 0, sizeof *info);
  uint32_t cache = inout_tet_cache ? *inout_tet_cache : GLG_NONE;
  int finite = isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2]);
  if (cache != GLG_NONE && (cache & GLG_CACHE_HULL)) {
    /* Last query was outside: stay on the hull while p is beyond the cached face. */
    uint32_t h = cache & ~GLG_CACHE_HULL;
    if (h >= g->hull_count) {
      cache = GLG_NONE;
    } else if (finite && hull_outside(g, p, h)) {
      if (info)
        info->outside = 1;
      double q[3];
      d3load(p, q);
      hull_hit hit;
      hull_project(g, q, h, &hit, info);
      if (inout_tet_cache)
        *inout_tet_cache = GLG_CACHE_HULL | hit.face;
      return hull_result(g, &hit, out_bary);
    } else {
      cache = g->hull[h].tet;
    }
  }
  if (cache >= g->tet_count)
    cache = GLG_NONE;
  if (!finite) {
    out_bary[0] = out_bary[1] = out_bary[2] = out_bary[3] = 0.25f;
    return cache == GLG_NONE ? 0 : cache;
  }
  uint32_t start = cache;
  float start_min = 0.0f; /* min barycentric of p in a well-shaped cached tet */
  if (start != GLG_NONE && !g->tet_flags[start]) {
    /* Still inside the cached tet (the common case for a moving object): done. Tets can
     * be much larger than a start-grid cell, so this comes before the distance test. */
    float l[4];
    walk_bary(g, start, p, l);
    start_min = min4f(l);
    if (start_min >= -GLG_EPS) {
      if (info)
        info->steps = 1;
      memcpy(out_bary, l, sizeof l);
      bary_finish(out_bary);
      if (inout_tet_cache)
        *inout_tet_cache = start;
      return start;
    }
  }
  return locate_walk(g, p, start, start_min, out_bary, info, inout_tet_cache);
}

uint32_t ub_glg_locate(const ub_glg *g, const float p[3], uint32_t *inout_tet_cache,
                       float out_bary[4])
{
  return ub_glg_locate_ex(g, p, inout_tet_cache, out_bary, NULL);
}

/* ---- interpolation ------------------------------------------------------------------ */

/* Leak-control weights for tet t at p: w = λ·vis·side, renormalised (plain λ when all 0).
 * The side of each corner w.r.t. the tet's leak plane is precomputed at init
 * (leak_drop: bit i = corner i is dropped when p is on the + side, bit 4 + i when on the
 * − side), so only p's side is evaluated here; the same float expressions as evaluating
 * it at the query, so the same bits. */
static inline void leak_weights(const ub_glg *g, uint32_t t, const float p[3], float w[4])
{
  uint32_t pl = g->leak_plane_of ? g->leak_plane_of[t] : UB_GLG_NO_LEAK_PLANE;
  if (!g->corner_visible && pl == UB_GLG_NO_LEAK_PLANE)
    return;
  unsigned drop = 0; /* bit i: corner i does not contribute */
  if (pl != UB_GLG_NO_LEAK_PLANE && isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2])) {
    const float *n = g->leak_planes + 4 * (size_t)pl;
    float sp = n[0] * p[0] + n[1] * p[1] + n[2] * p[2] + n[3];
    drop = (g->leak_drop[t] >> (sp >= 0.0f ? 0 : 4)) & 15u;
  }
  if (!drop && !g->corner_visible) /* nothing dropped: λ is already a partition of unity */
    return;
  float vw[4] = {w[0], w[1], w[2], w[3]}, s = 0.0f;
  if (g->corner_visible) { /* visibility weights 0..255 */
    const uint8_t *vis = g->corner_visible + 4 * (size_t)t;
    for (int i = 0; i < 4; i++)
      vw[i] *= (float)vis[i];
  }
  for (int i = 0; i < 4; i++) {
    if (drop >> i & 1u)
      vw[i] = 0.0f;
    s += vw[i];
  }
  if (s > 0.0f) {
    float inv = 1.0f / s;
    for (int i = 0; i < 4; i++)
      w[i] = vw[i] * inv;
  }
}

/* out = Σ w_i·sh(v_i) over the four corners (a zero weight adds exactly 0), summed left
 * to right ((w0·s0 + w1·s1) + w2·s2) + w3·s3 in every path, so the SSE2, AVX and scalar
 * paths give the same bits for float SH; half SH is converted exactly first. */
static inline void interp4_sse(const float *s0, const float *s1, const float *s2,
                               const float *s3, const float w[4], float out[27])
{
#if defined(__SSE2__)
  const __m128 w0 = _mm_set1_ps(w[0]), w1 = _mm_set1_ps(w[1]), w2 = _mm_set1_ps(w[2]),
               w3 = _mm_set1_ps(w[3]);
  for (int k = 0; k < 24; k += 4) {
    __m128 a = _mm_mul_ps(w0, _mm_loadu_ps(s0 + k));
    a = _mm_add_ps(a, _mm_mul_ps(w1, _mm_loadu_ps(s1 + k)));
    a = _mm_add_ps(a, _mm_mul_ps(w2, _mm_loadu_ps(s2 + k)));
    a = _mm_add_ps(a, _mm_mul_ps(w3, _mm_loadu_ps(s3 + k)));
    _mm_storeu_ps(out + k, a);
  }
  for (int k = 24; k < 27; k++)
    out[k] = w[0] * s0[k] + w[1] * s1[k] + w[2] * s2[k] + w[3] * s3[k];
#else
  for (int k = 0; k < 27; k++)
    out[k] = w[0] * s0[k] + w[1] * s1[k] + w[2] * s2[k] + w[3] * s3[k];
#endif
}

#if defined(GLG_HAVE_AVX_PATH)
/* 27 = 8 + 8 + 8 + the last 8 from 19 (lanes 19..23 computed twice, identically). */
__attribute__((target("avx"))) static void interp4_avx(const float *s0, const float *s1,
                                                       const float *s2, const float *s3,
                                                       const float w[4], float out[27])
{
  const __m256 w0 = _mm256_set1_ps(w[0]), w1 = _mm256_set1_ps(w[1]),
               w2 = _mm256_set1_ps(w[2]), w3 = _mm256_set1_ps(w[3]);
  static const int at[4] = {0, 8, 16, 19};
  for (int j = 0; j < 4; j++) {
    int k = at[j];
    __m256 a = _mm256_mul_ps(w0, _mm256_loadu_ps(s0 + k));
    a = _mm256_add_ps(a, _mm256_mul_ps(w1, _mm256_loadu_ps(s1 + k)));
    a = _mm256_add_ps(a, _mm256_mul_ps(w2, _mm256_loadu_ps(s2 + k)));
    a = _mm256_add_ps(a, _mm256_mul_ps(w3, _mm256_loadu_ps(s3 + k)));
    _mm256_storeu_ps(out + k, a);
  }
}

__attribute__((target("avx,f16c"))) static void interp4_f16c(const uint16_t *s0,
                                                             const uint16_t *s1,
                                                             const uint16_t *s2,
                                                             const uint16_t *s3,
                                                             const float w[4], float out[27])
{
  const __m256 w0 = _mm256_set1_ps(w[0]), w1 = _mm256_set1_ps(w[1]),
               w2 = _mm256_set1_ps(w[2]), w3 = _mm256_set1_ps(w[3]);
  static const int at[4] = {0, 8, 16, 19};
  for (int j = 0; j < 4; j++) {
    int k = at[j];
#define GLG_H8(s) _mm256_cvtph_ps(_mm_loadu_si128((const __m128i *)(const void *)((s) + k)))
    __m256 a = _mm256_mul_ps(w0, GLG_H8(s0));
    a = _mm256_add_ps(a, _mm256_mul_ps(w1, GLG_H8(s1)));
    a = _mm256_add_ps(a, _mm256_mul_ps(w2, GLG_H8(s2)));
    a = _mm256_add_ps(a, _mm256_mul_ps(w3, GLG_H8(s3)));
#undef GLG_H8
    _mm256_storeu_ps(out + k, a);
  }
}
#endif

static void interp4_half_scalar(const uint16_t *s0, const uint16_t *s1, const uint16_t *s2,
                                const uint16_t *s3, const float w[4], float out[27])
{
  for (int k = 0; k < 27; k++)
    out[k] = w[0] * ub_half_to_float(s0[k]) + w[1] * ub_half_to_float(s1[k]) +
             w[2] * ub_half_to_float(s2[k]) + w[3] * ub_half_to_float(s3[k]);
}

/* ---- compact probe store: the word (the rest below) ------------------------------- */

/* The word: bits 0..20 a 7-bit window code per channel, 21..23 zeroed channels, 24 stale,
 * 25..31 e + 64. */
#define CP_STALE (1u << 24)
/* Two words no encode makes (a stale word's codes are 0): the rows are not in the store
 * (the row source has them, ub_glg_mark_unblended), and a query is writing them. Both
 * carry the stale bit, so the fast path of cp_word never takes them. */
#define CP_UNBLENDED (CP_STALE | 0x1FFFFFu)
#define CP_FILLING (CP_STALE | 0x1FFFFEu)
#define CP_CODE(w, c) (((w) >> (7 * (c))) & 0x7Fu)
#define CP_ZERO(w) (((w) >> 21) & 7u)
#define CP_EXP(w) ((int)((w) >> 25) - 64)
#define CP_EXP_MIN -64
#define CP_EXP_MAX 63

static inline _Atomic uint32_t *cp_words(const ub_glg *g)
{
  return (_Atomic uint32_t *)g->cp_word;
}

/* ---- lazy windowing -------------------------------------------------------------- */

enum { GLG_WINDOWED = 0, GLG_STALE = 1, GLG_WRITING = 2 };

static inline _Atomic unsigned char *stale_of(const ub_glg *g)
{
  return (_Atomic unsigned char *)g->stale;
}

/* Probe v's windowed row, windowing it first when stale: into tmp (28 floats); the thread
 * that moves the state from stale to writing also writes it back and publishes it
 * (release), so a reader that sees "windowed" (acquire) reads a complete row. Others
 * use their own copy: the same bits (ub_sh2_window is a pure function). */
static const float *glg_row_slow(const ub_glg *g, uint32_t v, float *tmp)
{
  _Atomic unsigned char *st = stale_of(g) + v;
  memcpy(tmp, g->sh_raw + 27 * (size_t)v, 27 * sizeof(float));
  tmp[27] = 0.0f;
  ub_sh2_window(tmp);
  unsigned char expect = GLG_STALE;
  if (atomic_compare_exchange_strong_explicit(st, &expect, GLG_WRITING, memory_order_acquire,
                                              memory_order_acquire)) {
    memcpy(g->sh_win + 27 * (size_t)v, tmp, 27 * sizeof(float));
    atomic_store_explicit(st, GLG_WINDOWED, memory_order_release);
  }
  return tmp;
}

static inline const float *glg_row(const ub_glg *g, uint32_t v, float *tmp)
{
  if (g->stale &&
      atomic_load_explicit(stale_of(g) + v, memory_order_acquire) != GLG_WINDOWED)
    return glg_row_slow(g, v, tmp);
  return g->sh + 27 * (size_t)v;
}

ub_result ub_glg_enable_lazy(ub_glg *g, float *win, const float *raw)
{
  if (!g || !win || !raw || !g->tet_flags || g->sh_half || !g->sh_windowed || win != g->sh)
    return UB_ERR_INVALID_ARGUMENT;
  if (g->stale)
    return UB_OK;
  _Atomic unsigned char *st = ub_big_alloc((size_t)g->probe_count + 1);
  if (!st)
    return UB_ERR_OUT_OF_MEMORY;
  for (uint32_t q = 0; q < g->probe_count; q++)
    atomic_init(st + q, GLG_WINDOWED);
  g->sh_win = win;
  g->sh_raw = raw;
  g->stale = (void *)st;
  return UB_OK;
}

void ub_glg_mark_stale(ub_glg *g, uint32_t first, uint32_t count)
{
  assert(g && g->stale && first <= g->probe_count && count <= g->probe_count - first);
  _Atomic unsigned char *st = stale_of(g);
  for (uint32_t q = first; q < first + count; q++)
    atomic_store_explicit(st + q, GLG_STALE, memory_order_relaxed);
}

static uint32_t cp_word(const ub_glg *g, uint32_t v);

uint32_t ub_glg_refresh(const ub_glg *g)
{
  if (g && g->cp_rows) {
    uint32_t n = 0;
    for (uint32_t q = 0; q < g->probe_count; q++)
      if (atomic_load_explicit(cp_words(g) + q, memory_order_relaxed) & CP_STALE) {
        cp_word(g, q);
        n++;
      }
    return n;
  }
  if (!g || !g->stale)
    return 0;
  uint32_t n = 0;
  float tmp[28];
  for (uint32_t q = 0; q < g->probe_count; q++)
    if (atomic_load_explicit(stale_of(g) + q, memory_order_acquire) != GLG_WINDOWED) {
      glg_row_slow(g, q, tmp);
      n++;
      /* another query may be writing this row back: the caller is about to read it */
      while (atomic_load_explicit(stale_of(g) + q, memory_order_acquire) != GLG_WINDOWED)
        ;
    }
  return n;
}

/* ---- compact probe store -------------------------------------------------------- */


/* Band weights of a window code (τ/2 = code/128): w1 = 1 − code/128, w2 = max(0, 1 −
 * code/64); code 127 is w1 = w2 = 0. Each has ≤ 8 significant bits, so w·h is exact in
 * float for any half h: windowed rows (2^e·w)·h are exact, and a query's terms
 * λ·((2^e·w)·h) round once, like λ·row (what a cursor's cached rows give, bit for bit). */
#define CPW(c)                                                                              \
  {(c) == 127 ? 0.0f : (float)(1.0 - (c) / 128.0), (c) >= 64 ? 0.0f : (float)(1.0 - (c) / 64.0)}
#define CPW4(b) CPW(b), CPW(b + 1), CPW(b + 2), CPW(b + 3)
#define CPW16(b) CPW4(b), CPW4(b + 4), CPW4(b + 8), CPW4(b + 12)
#define CPW64(b) CPW16(b), CPW16(b + 16), CPW16(b + 32), CPW16(b + 48)
static const float cp_wtab[128][2] = {CPW64(0), CPW64(64)};
#undef CPW
#undef CPW4
#undef CPW16
#undef CPW64

static inline float pow2f(int e) /* |e| ≤ 126 */
{
  union { uint32_t u; float f; } x = {(uint32_t)(127 + e) << 23};
  return x.f;
}

/* A probe's band factors per channel c times 2^e (exact): 2^e, 2^e·w1_c, 2^e·w2_c (all 0
 * for a zeroed channel), laid out as bw[band][c]. */
static inline void cp_weights(uint32_t w, float bw[3][4])
{
  unsigned z = CP_ZERO(w);
  float e = pow2f(CP_EXP(w));
  for (int c = 0; c < 3; c++) {
    const float *t = cp_wtab[CP_CODE(w, c)];
    int zc = (z >> c) & 1u;
    bw[0][c] = zc ? 0.0f : e;
    bw[1][c] = zc ? 0.0f : t[0] * e;
    bw[2][c] = zc ? 0.0f : t[1] * e;
  }
  bw[0][3] = bw[1][3] = bw[2][3] = 0.0f;
}

/* 1 per kept channel, 0 per zeroed one (CP_ZERO bits), as 4 lanes. */
static const float cp_ztab[8][4] = {{1, 1, 1, 0}, {0, 1, 1, 0}, {1, 0, 1, 0}, {0, 0, 1, 0},
                                    {1, 1, 0, 0}, {0, 1, 0, 0}, {1, 0, 0, 0}, {0, 0, 0, 0}};

/* Raw row v decoded: h·2^e (exact: a power of two times a half). */
static void cp_decode(const ub_glg *g, uint32_t v, uint32_t w, float out[27])
{
  const uint16_t *h = g->cp_rows + 27 * (size_t)v;
  float s = pow2f(CP_EXP(w));
  for (int k = 0; k < 27; k++)
    out[k] = s * ub_half_to_float(h[k]);
}

/* Row v with the window of word w applied: (2^e·w_band,c)·h, zeroed channels 0. */
static void cp_windowed(const ub_glg *g, uint32_t v, uint32_t w, float out[27])
{
  const uint16_t *h = g->cp_rows + 27 * (size_t)v;
  float bw[3][4];
  cp_weights(w, bw);
  for (int k = 0; k < 27; k++)
    out[k] = bw[k < 3 ? 0 : k < 12 ? 1 : 2][k % 3] * ub_half_to_float(h[k]); /* exact */
}

/* The window of probe v (word w, stale): per channel the code of ub_sh2_window's τ rounded
 * up, raised until the channel of the windowed stored values is non-negative for every
 * normal (see ubake/glg.h). */
static uint32_t cp_find_window(const ub_glg *g, uint32_t v, uint32_t w)
{
  float raw[27], w1[3], w2[3];
  cp_decode(g, v, w, raw);
  unsigned flags = ub_sh2_window_weights(raw, w1, w2);
  uint32_t nw = w & ~(CP_STALE | 0xFFFFFFu), check = 0;
  for (int c = 0; c < 3; c++) {
    if (flags & UB_SH2_ZEROED(c)) {
      nw |= 1u << (21 + c);
    } else if (flags & UB_SH2_WINDOWED(c)) {
      double x = ceil((1.0 - (double)w1[c]) * 128.0); /* τ/2 = 1 − w1 */
      uint32_t code = x >= 127.0 ? 127u : x <= 0.0 ? 0u : (uint32_t)x;
      nw |= code << (7 * c);
      check |= 1u << c;
    }
  }
  for (uint32_t step = 1; check; step *= 2) {
    float row[27], mn[3];
    cp_windowed(g, v, nw, row);
    ub_sh2_irradiance_min(row, mn);
    for (int c = 0; c < 3; c++) {
      if (!(check >> c & 1u))
        continue;
      uint32_t code = CP_CODE(nw, c);
      if (mn[c] >= 0.0f || code == 127u) {
        check &= ~(1u << c);
        continue;
      }
      uint32_t up = code + step > 127u ? 127u : code + step;
      nw = (nw & ~(0x7Fu << (7 * c))) | up << (7 * c);
    }
  }
  return nw;
}

static uint32_t cp_encode_probe(const ub_glg *g, const float *row, uint32_t v);
static void cp_new_generation(ub_glg *g);

/* Probe v's rows into the store when they are not there (word w, CP_UNBLENDED or
 * CP_FILLING): the thread that moves the word to CP_FILLING asks the row source for the
 * row, encodes it, finds its window and publishes the word (release); the others wait for
 * it (acquire), so nobody reads a row being written. Returns the published word. */
__attribute__((noinline)) static uint32_t cp_fill(const ub_glg *g, uint32_t v, uint32_t w)
{
  _Atomic uint32_t *pw = cp_words(g) + v;
  uint32_t spins = 0;
  for (;;) {
    if (w == CP_UNBLENDED &&
        atomic_compare_exchange_weak_explicit(pw, &w, CP_FILLING, memory_order_acquire,
                                              memory_order_acquire)) {
      float row[28] = {0};
      if (!g->row_fn(g->row_user, v, row))
        memset(row, 0, sizeof row); /* (it may have written part of it) */
      uint32_t nw = cp_find_window(g, v, cp_encode_probe(g, row, v));
      atomic_store_explicit(pw, nw, memory_order_release);
      return nw;
    }
    if (w != CP_UNBLENDED && w != CP_FILLING)
      return w;
    if (w == CP_FILLING) {
      /* the filling thread may be preempted (more query threads than cores): yield now
       * and then instead of spinning through its time slice */
      if ((++spins & 255u) == 0)
        thrd_yield();
#if defined(__x86_64__) || defined(__i386__)
      else
        __builtin_ia32_pause();
#endif
      w = atomic_load_explicit(pw, memory_order_acquire);
    }
  }
}

/* Probe v's word with its rows in the store (stale or not). */
static inline uint32_t cp_word_rows(const ub_glg *g, uint32_t v)
{
  uint32_t w = atomic_load_explicit(cp_words(g) + v, memory_order_acquire);
  if (__builtin_expect(w == CP_UNBLENDED || w == CP_FILLING, 0))
    w = cp_fill(g, v, w);
  return w;
}

/* Probe v's word, its window found first when stale (published with one CAS; a racing
 * query computes the same word); its rows asked for first when not in the store. */
__attribute__((noinline)) static uint32_t cp_word_slow(const ub_glg *g, uint32_t v, uint32_t w)
{
  if (w == CP_UNBLENDED || w == CP_FILLING) {
    w = cp_fill(g, v, w);
    if (!(w & CP_STALE))
      return w;
  }
  uint32_t nw = cp_find_window(g, v, w);
  if (atomic_compare_exchange_strong_explicit(cp_words(g) + v, &w, nw, memory_order_relaxed,
                                              memory_order_relaxed))
    return nw;
  return w & CP_STALE ? nw : w; /* another query published first: use its word */
}

static inline uint32_t cp_word(const ub_glg *g, uint32_t v)
{
  /* acquire: rows a query filled in (cp_fill) are read after their word (x86: a plain load) */
  uint32_t w = atomic_load_explicit(cp_words(g) + v, memory_order_acquire);
  if (__builtin_expect(!(w & CP_STALE), 1))
    return w;
  return cp_word_slow(g, v, w);
}

/* Encodes one raw row: e with the largest |value| in [2^13, 2^14) after scaling (e in
 * [−64, 63]; a channel with a value that is not finite, or too large even so, is 0). */
static uint32_t cp_encode(const float *row, uint16_t *h)
{
  float mx = 0.0f;
  unsigned bad = 0;
  for (int k = 0; k < 27; k++) {
    if (!isfinite(row[k]))
      bad |= 1u << (k % 3);
    else if (fabsf(row[k]) > mx)
      mx = fabsf(row[k]);
  }
  int e = 0;
  if (mx > 0.0f) {
    frexpf(mx, &e); /* mx < 2^e */
    e -= 14;
    e = e < CP_EXP_MIN ? CP_EXP_MIN : e > CP_EXP_MAX ? CP_EXP_MAX : e;
  }
  float s = pow2f(-e);
  for (int k = 0; k < 27; k++)
    if (!(bad >> (k % 3) & 1u) && !(fabsf(row[k] * s) <= 65504.0f))
      bad |= 1u << (k % 3);
  for (int k = 0; k < 27; k++)
    h[k] = (bad >> (k % 3) & 1u) ? 0 : ub_half_from_float(row[k] * s);
  return (uint32_t)(e + 64) << 25 | CP_STALE;
}

#if defined(GLG_HAVE_AVX_PATH)
/* cp_encode with F16C (its conversion rounds to nearest even like ub_half_from_float):
 * the largest |value| from the float bits; rows with a value that is not finite, a
 * subnormal largest value or an exponent beyond the range go to cp_encode. */
__attribute__((target("avx,f16c"))) static uint32_t cp_encode_f16c(const float *row, uint16_t *h)
{
  const __m256 absmask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7FFFFFFF));
  __m256 a = _mm256_and_ps(absmask, _mm256_loadu_ps(row));
  __m256 b = _mm256_and_ps(absmask, _mm256_loadu_ps(row + 8));
  __m256 c = _mm256_and_ps(absmask, _mm256_loadu_ps(row + 16));
  /* the last three one by one: a vector load overlapping the blend's last stores of the
   * row stalls on store forwarding (it was 40% of this function) */
  __m256 tail = _mm256_setr_ps(row[24], row[25], row[26], 0.0f, 0.0f, 0.0f, 0.0f, 0.0f);
  __m256 d = _mm256_and_ps(absmask, tail);
  /* max of the bit patterns as floats: NaN/Inf patterns are the largest (checked below) */
  __m256 m = _mm256_max_ps(_mm256_max_ps(a, b), _mm256_max_ps(c, d));
  __m128 m4 = _mm_max_ps(_mm256_castps256_ps128(m), _mm256_extractf128_ps(m, 1));
  m4 = _mm_max_ps(m4, _mm_movehl_ps(m4, m4));
  m4 = _mm_max_ss(m4, _mm_shuffle_ps(m4, m4, 1));
  float mx = _mm_cvtss_f32(m4);
  /* _mm256_max_ps returns the second operand when either is NaN: check every value */
  __m256 ninf = _mm256_set1_ps(INFINITY);
  __m256 bad = _mm256_or_ps(_mm256_or_ps(_mm256_cmp_ps(a, ninf, _CMP_NLT_UQ),
                                         _mm256_cmp_ps(b, ninf, _CMP_NLT_UQ)),
                            _mm256_or_ps(_mm256_cmp_ps(c, ninf, _CMP_NLT_UQ),
                                         _mm256_cmp_ps(d, ninf, _CMP_NLT_UQ)));
  if (_mm256_movemask_ps(bad) || !(mx >= 1.17549435e-38f))
    return cp_encode(row, h);
  uint32_t bits;
  memcpy(&bits, &mx, sizeof bits);
  int e = (int)(bits >> 23) - 127 + 1 - 14; /* frexp's exponent − 14 */
  if (e < CP_EXP_MIN || e > CP_EXP_MAX)
    return cp_encode(row, h);
  __m256 sc = _mm256_set1_ps(pow2f(-e));
  __m128i h0 = _mm256_cvtps_ph(_mm256_mul_ps(_mm256_loadu_ps(row), sc), _MM_FROUND_TO_NEAREST_INT);
  __m128i h8 = _mm256_cvtps_ph(_mm256_mul_ps(_mm256_loadu_ps(row + 8), sc), _MM_FROUND_TO_NEAREST_INT);
  __m128i h16 = _mm256_cvtps_ph(_mm256_mul_ps(_mm256_loadu_ps(row + 16), sc), _MM_FROUND_TO_NEAREST_INT);
  __m128i h24 = _mm256_cvtps_ph(_mm256_mul_ps(tail, sc), _MM_FROUND_TO_NEAREST_INT);
  _mm_storeu_si128((__m128i *)(void *)h, h0);
  _mm_storeu_si128((__m128i *)(void *)(h + 8), h8);
  _mm_storeu_si128((__m128i *)(void *)(h + 16), h16);
  uint32_t t01 = (uint32_t)_mm_cvtsi128_si32(h24);
  memcpy(h + 24, &t01, sizeof t01);
  h[26] = (uint16_t)_mm_extract_epi16(h24, 2);
  return (uint32_t)(e + 64) << 25 | CP_STALE;
}
#endif

/* Probe v's row from row (the same halves and word on every path), its word returned. */
static uint32_t cp_encode_probe(const ub_glg *g, const float *row, uint32_t v)
{
  uint16_t *h = g->cp_rows + 27 * (size_t)v;
#if defined(GLG_HAVE_AVX_PATH)
  if (g->simd)
    return cp_encode_f16c(row, h);
#endif
  return cp_encode(row, h);
}

void ub_glg_set_probes(ub_glg *g, uint32_t first, uint32_t count, const float *rows)
{
  assert(g && g->cp_rows && first <= g->probe_count && count <= g->probe_count - first);
  for (uint32_t i = 0; i < count; i++)
    atomic_store_explicit(cp_words(g) + first + i,
                          cp_encode_probe(g, rows + 27 * (size_t)i, first + i),
                          memory_order_relaxed);
  cp_new_generation(g);
}

static void cp_new_generation(ub_glg *g)
{
  /* A new generation for cursors: a relaxed load and store, not a locked add (one per
   * call was most of ub_glg_set_probes). Concurrent calls may write the same value: it is
   * still greater than any generation a cursor took before them, which is all it needs. */
  _Atomic uint32_t *gen = cp_words(g) + g->probe_count;
  atomic_store_explicit(gen, atomic_load_explicit(gen, memory_order_relaxed) + 1u,
                        memory_order_relaxed);
}

void ub_glg_set_row_source(ub_glg *g, ub_glg_row_fn fn, void *user)
{
  assert(g);
  g->row_fn = fn;
  g->row_user = user;
}

void ub_glg_mark_unblended(ub_glg *g, uint32_t first, uint32_t count)
{
  assert(g && g->cp_rows && g->row_fn && first <= g->probe_count &&
         count <= g->probe_count - first);
  for (uint32_t i = 0; i < count; i++)
    atomic_store_explicit(cp_words(g) + first + i, CP_UNBLENDED, memory_order_relaxed);
  cp_new_generation(g);
}

void ub_glg_mark_unblended_list(ub_glg *g, const uint32_t *probes, uint32_t count)
{
  assert(g && g->cp_rows && g->row_fn && (probes || !count));
  _Atomic uint32_t *w = cp_words(g);
  for (uint32_t i = 0; i < count; i++) {
    assert(probes[i] < g->probe_count);
    atomic_store_explicit(w + probes[i], CP_UNBLENDED, memory_order_relaxed);
  }
  cp_new_generation(g);
}

void ub_glg_probe_sh(const ub_glg *g, uint32_t v, int windowed, float out[27])
{
  assert(g && v < g->probe_count);
  if (g->cp_rows) {
    if (windowed)
      cp_windowed(g, v, cp_word(g, v), out);
    else
      cp_decode(g, v, cp_word_rows(g, v), out);
    return;
  }
  if (g->sh_half) {
    float s = g->sh_half_exp ? pow2f(g->sh_half_exp[v]) : 1.0f;
    for (int k = 0; k < 27; k++)
      out[k] = s * ub_half_to_float(g->sh_half[27 * (size_t)v + k]);
  } else if (windowed && g->stale) {
    float tmp[28];
    memcpy(out, glg_row(g, v, tmp), 27 * sizeof(float));
    return;
  } else {
    memcpy(out, (!windowed && g->sh_raw ? g->sh_raw : g->sh) + 27 * (size_t)v, 27 * sizeof(float));
  }
  if (windowed && !g->sh_windowed)
    ub_sh2_window(out);
}

/* Compact interpolation: out = Σ λ_i·((2^e_i·w_band,c,i)·h_i), the product in brackets
 * exact (w·h has ≤ 19 significant bits and 2^e·w·h ≥ 2^-95 stays normal), so each term
 * rounds once whatever λ is; summed left to right in every path (AVX + F16C, scalar, a
 * cursor's rows λ_i·row_i), so all give the same bits. */
static void interp4_compact_scalar(const ub_glg *g, const uint32_t v[4], const float w[4],
                                   float out[27])
{
  float bw[4][3][4];
  for (int i = 0; i < 4; i++)
    cp_weights(cp_word(g, v[i]), bw[i]);
  for (int k = 0; k < 27; k++) {
    int b = k < 3 ? 0 : k < 12 ? 1 : 2;
    float acc = 0.0f;
    for (int i = 0; i < 4; i++) {
      float t = w[i] * (bw[i][b][k % 3] * ub_half_to_float(g->cp_rows[27 * (size_t)v[i] + k]));
      acc = i ? acc + t : t;
    }
    out[k] = acc;
  }
}

#if defined(GLG_HAVE_AVX_PATH)
/* Lanes 3k + c: coefficient k, channel c. Lanes 0..2 band 0, 3..11 band 1, 12..26 band 2;
 * the blocks start at 0, 8, 16, 19 (as interp4_avx): with B = (b0, b1, b2, ·) the band-1
 * and C the band-2 factors of the channels, block 0 = (a a a b0 | b1 b2 b0 b1), block 8 =
 * (b2 b0 b1 b2 | c0 c1 c2 c0), blocks 16 and 19 = (c1 c2 c0 c1 | c2 c0 c1 c2). */
/* The three pattern vectors of a probe's word: band factors per lane (see above) times
 * 2^e, exact. */
__attribute__((target("avx,f16c,sse4.1"))) static inline void cp_patterns(uint32_t wd,
                                                                           __m256 *p0,
                                                                           __m256 *p8,
                                                                           __m256 *p16)
{
  const float *t0 = cp_wtab[CP_CODE(wd, 0)], *t1 = cp_wtab[CP_CODE(wd, 1)],
              *t2 = cp_wtab[CP_CODE(wd, 2)];
  __m128 a = _mm_set1_ps(1.0f);
  __m128 b = _mm_setr_ps(t0[0], t1[0], t2[0], 0.0f), c = _mm_setr_ps(t0[1], t1[1], t2[1], 0.0f);
  if (__builtin_expect(CP_ZERO(wd) != 0, 0)) {
    __m128 z = _mm_loadu_ps(cp_ztab[CP_ZERO(wd)]);
    a = z;
    b = _mm_mul_ps(b, z);
    c = _mm_mul_ps(c, z);
  }
  __m128 l0 = _mm_blend_ps(a, _mm_shuffle_ps(b, b, 0), 8);  /* a0 a1 a2 b0 */
  __m128 h0 = _mm_shuffle_ps(b, b, _MM_SHUFFLE(1, 0, 2, 1));  /* b1 b2 b0 b1 */
  __m128 l8 = _mm_shuffle_ps(b, b, _MM_SHUFFLE(2, 1, 0, 2));  /* b2 b0 b1 b2 */
  __m128 h8 = _mm_shuffle_ps(c, c, _MM_SHUFFLE(0, 2, 1, 0));  /* c0 c1 c2 c0 */
  __m128 l16 = _mm_shuffle_ps(c, c, _MM_SHUFFLE(1, 0, 2, 1)); /* c1 c2 c0 c1 */
  __m128 h16 = _mm_shuffle_ps(c, c, _MM_SHUFFLE(2, 1, 0, 2)); /* c2 c0 c1 c2 */
  __m256 e = _mm256_set1_ps(pow2f(CP_EXP(wd)));
  *p0 = _mm256_mul_ps(_mm256_insertf128_ps(_mm256_castps128_ps256(l0), h0, 1), e);
  *p8 = _mm256_mul_ps(_mm256_insertf128_ps(_mm256_castps128_ps256(l8), h8, 1), e);
  *p16 = _mm256_mul_ps(_mm256_insertf128_ps(_mm256_castps128_ps256(l16), h16, 1), e);
}

#define GLG_H8(s, k) _mm256_cvtph_ps(_mm_loadu_si128((const __m128i *)(const void *)((s) + (k))))

__attribute__((target("avx,f16c,sse4.1"))) static void interp4_compact_f16c(const ub_glg *g,
                                                                            const uint32_t v[4],
                                                                            const float w[4],
                                                                            float out[27])
{
  __m256 p0[4], p8[4], p16[4], s[4];
  const uint16_t *h[4];
  for (int i = 0; i < 4; i++) {
    cp_patterns(cp_word(g, v[i]), &p0[i], &p8[i], &p16[i]);
    s[i] = _mm256_set1_ps(w[i]);
    h[i] = g->cp_rows + 27 * (size_t)v[i];
  }
#define GLG_TERM(P, i, k) _mm256_mul_ps(s[i], _mm256_mul_ps(P[i], GLG_H8(h[i], k)))
#define GLG_BLOCK(P, k)                                                                      \
  do {                                                                                       \
    __m256 acc = GLG_TERM(P, 0, k);                                                          \
    acc = _mm256_add_ps(acc, GLG_TERM(P, 1, k));                                             \
    acc = _mm256_add_ps(acc, GLG_TERM(P, 2, k));                                             \
    acc = _mm256_add_ps(acc, GLG_TERM(P, 3, k));                                             \
    _mm256_storeu_ps(out + (k), acc);                                                        \
  } while (0)
  GLG_BLOCK(p0, 0);
  GLG_BLOCK(p8, 8);
  GLG_BLOCK(p16, 16);
  GLG_BLOCK(p16, 19);
#undef GLG_BLOCK
#undef GLG_TERM
}

/* Probe v's windowed row (2^e·w)·h, exact, into out (27 floats; 28 written, the last 0). */
__attribute__((target("avx,f16c,sse4.1"))) static void cp_row_f16c(const ub_glg *g, uint32_t v,
                                                                   float out[28])
{
  __m256 p0, p8, p16;
  cp_patterns(cp_word(g, v), &p0, &p8, &p16);
  const uint16_t *h = g->cp_rows + 27 * (size_t)v;
  _mm256_storeu_ps(out, _mm256_mul_ps(p0, GLG_H8(h, 0)));
  _mm256_storeu_ps(out + 8, _mm256_mul_ps(p8, GLG_H8(h, 8)));
  _mm256_storeu_ps(out + 16, _mm256_mul_ps(p16, GLG_H8(h, 16)));
  _mm256_storeu_ps(out + 19, _mm256_mul_ps(p16, GLG_H8(h, 19)));
  out[27] = 0.0f;
}
#undef GLG_H8
#endif

static void interp4_compact(const ub_glg *g, const uint32_t v[4], const float w[4], float out[27])
{
#if defined(GLG_HAVE_AVX_PATH)
  if (g->simd) {
    interp4_compact_f16c(g, v, w, out);
    return;
  }
#endif
  interp4_compact_scalar(g, v, w, out);
}

static inline void interp4(const ub_glg *g, const uint32_t v[4], const float w[4],
                           float out[27])
{
  if (g->cp_rows) {
    interp4_compact(g, v, w, out);
    return;
  }
  if (g->sh_half) {
    float ws[4] = {w[0], w[1], w[2], w[3]};
    if (g->sh_half_exp) /* w·2^e: exact unless it underflows (|e| ≤ 100, checked at init) */
      for (int i = 0; i < 4; i++) {
        union { uint32_t u; float f; } x = {(uint32_t)(127 + g->sh_half_exp[v[i]]) << 23};
        ws[i] *= x.f;
      }
    w = ws;
    const uint16_t *h0 = g->sh_half + 27 * (size_t)v[0], *h1 = g->sh_half + 27 * (size_t)v[1],
                   *h2 = g->sh_half + 27 * (size_t)v[2], *h3 = g->sh_half + 27 * (size_t)v[3];
#if defined(GLG_HAVE_AVX_PATH)
    if (g->simd) {
      interp4_f16c(h0, h1, h2, h3, w, out);
      return;
    }
#endif
    interp4_half_scalar(h0, h1, h2, h3, w, out);
    return;
  }
  float tmp[4][28];
  const float *s0 = glg_row(g, v[0], tmp[0]), *s1 = glg_row(g, v[1], tmp[1]),
              *s2 = glg_row(g, v[2], tmp[2]), *s3 = glg_row(g, v[3], tmp[3]);
#if defined(GLG_HAVE_AVX_PATH)
  if (g->simd) {
    interp4_avx(s0, s1, s2, s3, w, out);
    return;
  }
#endif
  interp4_sse(s0, s1, s2, s3, w, out);
}

/* Irradiance from interpolated SH (windowed here unless the probes were). sh holds 28
 * floats (the 28th is read by the last 4-lane load and ignored). */
static void shade(const ub_glg *g, float sh[28], const float n[3], float out_rgb[3])
{
  if (!g->sh_windowed)
    ub_sh2_window(sh);
  float l2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
  if (!(l2 > 0.0f) || !isfinite(l2)) {
    for (int c = 0; c < 3; c++)
      out_rgb[c] = fmaxf(0.0f, UB_SH_A0 * 0.282094792f * sh[c]);
    return;
  }
  /* A unit normal (to 1e-6, below float's own normalisation error) is used as it is. */
  float inv = l2 > 0.999999f && l2 < 1.000001f ? 1.0f : 1.0f / sqrtf(l2);
  float x = n[0] * inv, y = n[1] * inv, z = n[2] * inv;
  /* ub_sh2_irradiance inline: the band factor times the basis, then 9 × RGB products. */
  const float c[9] = {UB_SH_A0 * 0.282094791773878f,
                      UB_SH_A1 * 0.488602511902920f * y,
                      UB_SH_A1 * 0.488602511902920f * z,
                      UB_SH_A1 * 0.488602511902920f * x,
                      UB_SH_A2 * 1.092548430592079f * x * y,
                      UB_SH_A2 * 1.092548430592079f * y * z,
                      UB_SH_A2 * 0.315391565252520f * (3.0f * z * z - 1.0f),
                      UB_SH_A2 * 1.092548430592079f * x * z,
                      UB_SH_A2 * 0.546274215296040f * (x * x - y * y)};
#if defined(__SSE2__)
  /* RGB of coefficient k in lanes 0..2 of one load at 3k; three independent sums. */
  __m128 a0 = _mm_mul_ps(_mm_set1_ps(c[0]), _mm_loadu_ps(sh));
  __m128 a1 = _mm_mul_ps(_mm_set1_ps(c[1]), _mm_loadu_ps(sh + 3));
  __m128 a2 = _mm_mul_ps(_mm_set1_ps(c[2]), _mm_loadu_ps(sh + 6));
  a0 = _mm_add_ps(a0, _mm_mul_ps(_mm_set1_ps(c[3]), _mm_loadu_ps(sh + 9)));
  a1 = _mm_add_ps(a1, _mm_mul_ps(_mm_set1_ps(c[4]), _mm_loadu_ps(sh + 12)));
  a2 = _mm_add_ps(a2, _mm_mul_ps(_mm_set1_ps(c[5]), _mm_loadu_ps(sh + 15)));
  a0 = _mm_add_ps(a0, _mm_mul_ps(_mm_set1_ps(c[6]), _mm_loadu_ps(sh + 18)));
  a1 = _mm_add_ps(a1, _mm_mul_ps(_mm_set1_ps(c[7]), _mm_loadu_ps(sh + 21)));
  a2 = _mm_add_ps(a2, _mm_mul_ps(_mm_set1_ps(c[8]), _mm_loadu_ps(sh + 24)));
  float e[4];
  _mm_storeu_ps(e, _mm_add_ps(_mm_add_ps(a0, a1), a2));
  float e0 = e[0], e1 = e[1], e2 = e[2];
#else
  float e0 = 0.0f, e1 = 0.0f, e2 = 0.0f;
  for (int k = 0; k < 9; k++) {
    e0 += c[k] * sh[3 * k];
    e1 += c[k] * sh[3 * k + 1];
    e2 += c[k] * sh[3 * k + 2];
  }
#endif
  out_rgb[0] = e0 > 0.0f ? e0 : 0.0f;
  out_rgb[1] = e1 > 0.0f ? e1 : 0.0f;
  out_rgb[2] = e2 > 0.0f ? e2 : 0.0f;
}

/* The tet for p and its interpolation weights (barycentrics with the leak weights). */
static inline uint32_t sample_locate(const ub_glg *g, const float p[3], uint32_t *inout_tet_cache,
                                     const double *geo, float w[4])
{
  uint32_t t = inout_tet_cache ? *inout_tet_cache : GLG_NONE;
  /* Fast path, the same answer as ub_glg_locate's first test: p (finite) still inside
   * the cached, well-shaped tet (geo: its tet_geo when the caller keeps it, the bits
   * walk_bary gives without reading the corners). */
  if (t < g->tet_count && !g->tet_flags[t] && isfinite(p[0] + p[1] + p[2])) {
    if (geo)
      geo_bary(geo, p, w);
    else
      walk_bary(g, t, p, w);
    float mn = min4f(w);
    if (mn >= -GLG_EPS)
      bary_finish(w);
    else /* ub_glg_locate_ex from its cache test on */
      t = locate_walk(g, p, t, mn, w, NULL, inout_tet_cache);
  } else {
    t = ub_glg_locate_ex(g, p, inout_tet_cache, w, NULL);
  }
  leak_weights(g, t, p, w);
  return t;
}

void ub_glg_sample(const ub_glg *g, const float p[3], uint32_t *inout_tet_cache,
                   float out_sh[27])
{
  float w[4];
  uint32_t t = sample_locate(g, p, inout_tet_cache, NULL, w);
  interp4(g, g->tets + 4 * (size_t)t, w, out_sh);
}

void ub_glg_cursor_init(ub_glg_cursor *c)
{
  assert(c);
  memset(c, 0, sizeof *c);
  c->tet = c->rows_tet = c->geo_tet = UB_GLG_NO_CACHE;
}

/* ub_glg_sample through a cursor (compact store): the interpolated windowed SH into sh
 * (28 floats, the last 0). With the small walk, sample_locate tests the cached tet with the
 * cursor's geometry (the bits corner_bary gives) instead of reading its corners. */
static void cursor_sample(const ub_glg *g, const float p[3], ub_glg_cursor *c, float sh[28])
{
  float w[4];
  sh[27] = 0.0f;
  const double *geo = g->pos && c->tet == c->geo_tet && c->geo[9] != 0.0 ? c->geo : NULL;
  uint32_t t = sample_locate(g, p, &c->tet, geo, w);
  if (g->pos && c->tet == t && t != c->geo_tet && t < g->tet_count && !g->tet_flags[t]) {
    tet_geo(g, t, c->geo);
    c->geo_tet = t;
  }
  uint32_t gen = atomic_load_explicit(cp_words(g) + g->probe_count, memory_order_relaxed);
  if (t != c->rows_tet || gen != c->generation) {
    const uint32_t *v = g->tets + 4 * (size_t)t;
    for (int i = 0; i < 4; i++) {
#if defined(GLG_HAVE_AVX_PATH)
      if (g->simd) {
        cp_row_f16c(g, v[i], c->rows[i]);
        continue;
      }
#endif
      cp_windowed(g, v[i], cp_word(g, v[i]), c->rows[i]);
      c->rows[i][27] = 0.0f;
    }
    c->rows_tet = t;
    c->generation = gen;
  }
  /* λ_i·row_i: the compact kernel's terms (λ_i·2^e_i)·(w·h_i), bit for bit */
#if defined(GLG_HAVE_AVX_PATH)
  if (g->simd)
    interp4_avx(c->rows[0], c->rows[1], c->rows[2], c->rows[3], w, sh);
  else
#endif
    interp4_sse(c->rows[0], c->rows[1], c->rows[2], c->rows[3], w, sh);
}

void ub_glg_query_cursor(const ub_glg *g, const float p[3], const float n[3], ub_glg_cursor *c,
                         float out_rgb[3])
{
  if (!g->cp_rows) {
    ub_glg_query(g, p, n, &c->tet, out_rgb);
    return;
  }
  float sh[28];
  cursor_sample(g, p, c, sh);
  shade(g, sh, n, out_rgb);
}

void ub_glg_query(const ub_glg *g, const float p[3], const float n[3],
                  uint32_t *inout_tet_cache, float out_rgb[3])
{
  float sh[28];
  sh[27] = 0.0f;
  ub_glg_sample(g, p, inout_tet_cache, sh);
  shade(g, sh, n, out_rgb);
}

/* Batches of GLG_BATCH queries in stages, each stage issuing the next loads of every
 * query before any is waited for: random queries are bound by dependent cache misses
 * (start grid → tet record → corners → probe SH), and this keeps ~GLG_BATCH of them in
 * flight instead of one. The same answers as ub_glg_query, query by query. */
#define GLG_BATCH 16

void ub_glg_query_batch(const ub_glg *g, uint32_t count, const float *points,
                        const float *normals, uint32_t *inout_tet_caches, float *out_rgb)
{
  assert(g && g->tet_flags && (points || !count) && (normals || !count) && (out_rgb || !count));
  for (uint32_t b0 = 0; b0 < count; b0 += GLG_BATCH) {
    uint32_t nb = count - b0 < GLG_BATCH ? count - b0 : GLG_BATCH;
    uint32_t cache[GLG_BATCH], tet[GLG_BATCH];
    float bary[GLG_BATCH][4];
    /* 1: where each walk starts (the caller's cache, else the start grid) */
    for (uint32_t i = 0; i < nb; i++) {
      const float *p = points + 3 * (size_t)(b0 + i);
      uint32_t c = inout_tet_caches ? inout_tet_caches[b0 + i] : GLG_NONE;
      if (c >= g->tet_count && !(c != GLG_NONE && (c & GLG_CACHE_HULL)) && g->start_grid &&
          isfinite(p[0] + p[1] + p[2]))
        c = grid_start(g, p);
      cache[i] = c;
#if defined(__GNUC__)
      if (c < g->tet_count) {
        prefetch_walk(g, c);
        __builtin_prefetch(g->tets + 4 * (size_t)c);
      }
#endif
    }
    /* 2: walk all of them a step at a time, round-robin, so the next record of every
     * walk is in flight at once; anything but a plain step in a well-shaped tet (hull,
     * badly shaped tets, long walks, hull caches, non-finite points) finishes through
     * ub_glg_locate_ex from where the walk got to. */
    uint32_t at[GLG_BATCH], prev[GLG_BATCH], steps[GLG_BATCH], active[GLG_BATCH], na = 0;
    for (uint32_t i = 0; i < nb; i++) {
      const float *p = points + 3 * (size_t)(b0 + i);
      if (cache[i] < g->tet_count && isfinite(p[0] + p[1] + p[2])) {
        at[i] = cache[i];
        prev[i] = GLG_NONE;
        steps[i] = 0;
        active[na++] = i;
      } else {
        tet[i] = ub_glg_locate_ex(g, p, &cache[i], bary[i], NULL);
      }
    }
    while (na) {
      uint32_t keep = 0;
      for (uint32_t j = 0; j < na; j++) {
        uint32_t i = active[j], t = at[i];
        const float *p = points + 3 * (size_t)(b0 + i);
        const int32_t *lk = tet_links(g, t);
        int finish = g->tet_flags[t] != 0 || steps[i] >= 64;
        if (!finish) {
          float l[4];
          walk_bary(g, t, p, l);
          if (min4f(l) >= -GLG_EPS) {
            memcpy(bary[i], l, sizeof l);
            bary_finish(bary[i]);
            tet[i] = t;
            cache[i] = t;
            continue;
          }
          /* walk()'s choice: the most negative face, never straight back */
          int k = -1;
          float kv = -GLG_EPS;
          for (int f = 0; f < 4; f++)
            if (l[f] < kv && !(lk[f] >= 0 && (uint32_t)lk[f] == prev[i])) {
              kv = l[f];
              k = f;
            }
          for (int f = 0; f < 4; f++)
            if (lk[f] < 0 && l[f] < -GLG_EPS)
              k = -1; /* beyond a hull face: the hull projection */
          if (k < 0 || lk[k] < 0) {
            finish = 1;
          } else {
            prev[i] = t;
            at[i] = (uint32_t)lk[k];
            steps[i]++;
#if defined(__GNUC__)
            prefetch_walk(g, at[i]);
            __builtin_prefetch(g->tets + 4 * (size_t)at[i]);
#endif
            active[keep++] = i;
            continue;
          }
        }
        cache[i] = t;
        tet[i] = ub_glg_locate_ex(g, p, &cache[i], bary[i], NULL);
      }
      na = keep;
    }
    /* the corners' probe SH and the leak planes for stage 3 */
    for (uint32_t i = 0; i < nb; i++) {
#if defined(__GNUC__)
      const uint32_t *v = g->tets + 4 * (size_t)tet[i];
      for (int k = 0; k < 4; k++) {
        const char *row = g->cp_rows   ? (const char *)(g->cp_rows + 27 * (size_t)v[k])
                          : g->sh_half ? (const char *)(g->sh_half + 27 * (size_t)v[k])
                                       : (const char *)(g->sh + 27 * (size_t)v[k]);
        __builtin_prefetch(row);
        __builtin_prefetch(row + 64);
      }
      if (g->leak_plane_of) {
        uint32_t pl = g->leak_plane_of[tet[i]];
        if (pl != UB_GLG_NO_LEAK_PLANE)
          __builtin_prefetch(g->leak_planes + 4 * (size_t)pl);
      }
#endif
    }
    /* 3: weights, interpolation, irradiance */
    for (uint32_t i = 0; i < nb; i++) {
      const float *p = points + 3 * (size_t)(b0 + i);
      float sh[28];
      sh[27] = 0.0f;
      leak_weights(g, tet[i], p, bary[i]);
      interp4(g, g->tets + 4 * (size_t)tet[i], bary[i], sh);
      shade(g, sh, normals + 3 * (size_t)(b0 + i), out_rgb + 3 * (size_t)(b0 + i));
      if (inout_tet_caches)
        inout_tet_caches[b0 + i] = cache[i];
    }
  }
}

ub_result ub_glg_resample_llg(const ub_glg *g, const float center[3], const float axes[9],
                              const float half[3], uint32_t nx, uint32_t ny, uint32_t nz,
                              uint32_t *inout_tet_cache, float *out_sh)
{
  if (!g || !g->tet_flags || !center || !axes || !half || !out_sh || !nx || !ny || !nz)
    return UB_ERR_INVALID_ARGUMENT;
  if ((uint64_t)nx * ny * nz > ((uint64_t)1 << 32) / 27)
    return UB_ERR_INVALID_ARGUMENT;
  uint32_t local = GLG_NONE;
  uint32_t *cache = inout_tet_cache ? inout_tet_cache : &local;
  const uint32_t dims[3] = {nx, ny, nz};
  /* compact store: the current tet's windowed rows held while the points stay in it (the
   * same bits as ub_glg_sample) */
  ub_glg_cursor cur;
  ub_glg_cursor_init(&cur);
  cur.tet = *cache;
  for (uint32_t iz = 0; iz < nz; iz++) {
    for (uint32_t jy = 0; jy < ny; jy++) {
      uint32_t iy = (iz & 1) ? ny - 1 - jy : jy; /* serpentine: neighbours stay adjacent */
      for (uint32_t jx = 0; jx < nx; jx++) {
        uint32_t ix = ((iz * ny + jy) & 1) ? nx - 1 - jx : jx;
        const uint32_t idx[3] = {ix, iy, iz};
        float p[3] = {center[0], center[1], center[2]};
        for (int a = 0; a < 3; a++) {
          float s = dims[a] > 1 ? -1.0f + 2.0f * (float)idx[a] / (float)(dims[a] - 1) : 0.0f;
          for (int i = 0; i < 3; i++)
            p[i] += s * half[a] * axes[3 * a + i];
        }
        float *o = out_sh + 27 * ((size_t)ix + nx * ((size_t)iy + (size_t)ny * iz));
        if (g->cp_rows) {
          float sh[28];
          cursor_sample(g, p, &cur, sh);
          memcpy(o, sh, 27 * sizeof *o);
        } else {
          ub_glg_sample(g, p, cache, o);
        }
      }
    }
  }
  if (g->cp_rows)
    *cache = cur.tet;
  return UB_OK;
}

/* ---- init --------------------------------------------------------------------------- */

static int same_face(const uint32_t *a, int ia, const uint32_t *b, int ib)
{
  int hits = 0;
  for (int i = 0; i < 3; i++)
    for (int j = 0; j < 3; j++)
      hits += a[face_of[ia][i]] == b[face_of[ib][j]];
  return hits == 3;
}

static uint64_t mix64(uint64_t k)
{
  k ^= k >> 33;
  k *= 0xff51afd7ed558ccdull;
  k ^= k >> 33;
  k *= 0xc4ceb9fe1a85ec53ull;
  k ^= k >> 33;
  return k;
}

/* Links hull faces across their edges; every hull edge must have exactly two faces. */
static ub_result build_hull_adjacency(ub_glg *g, const ub_log *log)
{
  size_t cap = 16;
  while (cap < 6 * (size_t)g->hull_count)
    cap <<= 1;
  uint64_t *keys = ub_big_alloc(cap * sizeof *keys);
  uint32_t *val = ub_big_alloc(cap * sizeof *val); /* face << 2 | k; GLG_NONE = empty */
  if (!keys || !val) {
    free(keys);
    free(val);
    return UB_ERR_OUT_OF_MEMORY;
  }
  for (size_t i = 0; i < cap; i++)
    val[i] = GLG_NONE;
  ub_result res = UB_OK;
  for (uint32_t h = 0; h < g->hull_count && res == UB_OK; h++) {
    struct ub_glg_hull *f = &g->hull[h];
    for (int k = 0; k < 3; k++) {
      uint32_t a = f->v[(k + 1) % 3], b = f->v[(k + 2) % 3];
      uint64_t key = a < b ? ((uint64_t)a << 32 | b) : ((uint64_t)b << 32 | a);
      size_t s = mix64(key) & (cap - 1);
      while (val[s] != GLG_NONE && keys[s] != key)
        s = (s + 1) & (cap - 1);
      if (val[s] == GLG_NONE) {
        keys[s] = key;
        val[s] = h << 2 | (uint32_t)k;
        continue;
      }
      uint32_t other = val[s];
      if (other == GLG_NONE - 1) {
        ub_log_printf(log, UB_LOG_ERROR, "glg: hull edge %u-%u has more than two faces", a, b);
        res = UB_ERR_INVALID_DATA;
        break;
      }
      uint32_t oh = other >> 2, ok = other & 3;
      f->adj[k] = oh;
      g->hull[oh].adj[ok] = h;
      val[s] = GLG_NONE - 1; /* full */
    }
  }
  for (uint32_t h = 0; h < g->hull_count && res == UB_OK; h++)
    for (int k = 0; k < 3; k++)
      if (g->hull[h].adj[k] == GLG_NONE) {
        ub_log_printf(log, UB_LOG_ERROR, "glg: hull is not closed at face of tet %u",
                      g->hull[h].tet);
        res = UB_ERR_INVALID_DATA;
        break;
      }
  free(keys);
  free(val);
  return res;
}

/* Centre of start-grid cell (x, y, z). */
static void grid_centre(const ub_glg *g, uint32_t x, uint32_t y, uint32_t z, const float lo[3],
                        const double ext[3], float p[3])
{
  const uint32_t c[3] = {x, y, z};
  for (int a = 0; a < 3; a++)
    p[a] = (float)(lo[a] + (c[a] + 0.5) * ext[a] / g->grid_dim[a]);
}

/* The last tet within 2^15 of base (in index) on a walk from base towards p: a start for
 * p that a 16-bit offset from base can name. */
static uint32_t walk_within(const ub_glg *g, const float p[3], uint32_t base)
{
  uint32_t t = base, prev = GLG_NONE, best = base;
  for (uint32_t step = 0; step < g->walk_cap; step++) {
    int64_t d = (int64_t)t - base;
    if (d >= INT16_MIN && d <= INT16_MAX)
      best = t;
    const int32_t *lk = tet_links(g, t);
    float l[4];
    if (!tet_bary(g, t, p, l))
      break;
    int k = -1;
    float kv = -GLG_EPS;
    for (int i = 0; i < 4; i++)
      if (l[i] < kv && lk[i] >= 0 && (uint32_t)lk[i] != prev) {
        kv = l[i];
        k = i;
      }
    if (k < 0)
      break;
    prev = t;
    t = (uint32_t)lk[k];
  }
  return best;
}

static ub_result build_start_grid(ub_glg *g, const float *positions)
{
  float lo[3] = {HUGE_VALF, HUGE_VALF, HUGE_VALF}, hi[3] = {-HUGE_VALF, -HUGE_VALF, -HUGE_VALF};
  for (uint32_t i = 0; i < g->probe_count; i++)
    for (int a = 0; a < 3; a++) {
      lo[a] = fminf(lo[a], positions[3 * (size_t)i + a]);
      hi[a] = fmaxf(hi[a], positions[3 * (size_t)i + a]);
    }
  double ext[3], diag = 0.0;
  for (int a = 0; a < 3; a++) {
    ext[a] = (double)hi[a] - lo[a];
    diag += ext[a] * ext[a];
  }
  diag = sqrt(diag);
  for (int a = 0; a < 3; a++)
    if (ext[a] < 1e-6 * diag)
      ext[a] = 1e-6 * diag;
  if (!(diag > 0.0))
    return UB_ERR_INVALID_DATA;
  double cells = g->probe_count * GLG_GRID_CELLS_PER_PROBE + 1.0;
  if (cells > (double)(1u << 22))
    cells = (double)(1u << 22);
  double s = cbrt(ext[0] * ext[1] * ext[2] / cells);
  size_t total = 1;
  double cd2 = 0.0;
  for (int a = 0; a < 3; a++) {
    double d = ceil(ext[a] / s);
    if (d < 1.0)
      d = 1.0;
    if (d > 1024.0)
      d = 1024.0;
    g->grid_dim[a] = (uint32_t)d;
    g->grid_lo[a] = lo[a];
    g->grid_inv_cell[a] = (float)(d / ext[a]);
    total *= g->grid_dim[a];
    double c = ext[a] / d;
    cd2 += c * c;
  }
  g->grid_far2 = (float)(4.0 * cd2); /* two cell diagonals */
  uint32_t bd[3];
  size_t blocks = 1;
  for (int a = 0; a < 3; a++) {
    bd[a] = (g->grid_dim[a] + GLG_GRID_BLOCK - 1) / GLG_GRID_BLOCK;
    blocks *= bd[a];
  }
  uint32_t *centre = ub_big_alloc(total * sizeof *centre);
  g->start_grid = ub_big_alloc(blocks * sizeof(uint32_t) + total * sizeof(int16_t));
  if (!centre || !g->start_grid) {
    free(centre);
    return UB_ERR_OUT_OF_MEMORY;
  }
  g->start_delta = (int16_t *)(void *)(g->start_grid + blocks);
  /* The tet at each cell's centre, walking in serpentine order. */
  uint32_t t = 0;
  for (uint32_t z = 0; z < g->grid_dim[2]; z++)
    for (uint32_t jy = 0; jy < g->grid_dim[1]; jy++) {
      uint32_t y = (z & 1) ? g->grid_dim[1] - 1 - jy : jy;
      for (uint32_t jx = 0; jx < g->grid_dim[0]; jx++) {
        uint32_t x = ((z * g->grid_dim[1] + jy) & 1) ? g->grid_dim[0] - 1 - jx : jx;
        float p[3];
        grid_centre(g, x, y, z, lo, ext, p);
        float bary[4];
        uint32_t cache;
        t = walk(g, p, t, bary, NULL, &cache);
        centre[x + (size_t)g->grid_dim[0] * (y + (size_t)g->grid_dim[1] * z)] = t;
      }
    }
  /* Each block's base is the median of its cells' tets; a cell whose tet is more than
   * 2^15 from it (~7% on kaos) starts from the last tet within reach on the walk from
   * the base to its centre instead. */
  for (uint32_t kz = 0; kz < bd[2]; kz++)
    for (uint32_t ky = 0; ky < bd[1]; ky++)
      for (uint32_t kx = 0; kx < bd[0]; kx++) {
        uint32_t v[GLG_GRID_BLOCK * GLG_GRID_BLOCK * GLG_GRID_BLOCK] = {0}, m = 0;
        const uint32_t k0[3] = {kx * GLG_GRID_BLOCK, ky * GLG_GRID_BLOCK, kz * GLG_GRID_BLOCK};
        for (uint32_t z = k0[2]; z < k0[2] + GLG_GRID_BLOCK && z < g->grid_dim[2]; z++)
          for (uint32_t y = k0[1]; y < k0[1] + GLG_GRID_BLOCK && y < g->grid_dim[1]; y++)
            for (uint32_t x = k0[0]; x < k0[0] + GLG_GRID_BLOCK && x < g->grid_dim[0]; x++)
              v[m++] = centre[x + (size_t)g->grid_dim[0] * (y + (size_t)g->grid_dim[1] * z)];
        for (uint32_t a = 1; a < m; a++) /* insertion sort, m ≤ 64 */
          for (uint32_t b = a; b > 0 && v[b - 1] > v[b]; b--) {
            uint32_t tmp = v[b];
            v[b] = v[b - 1];
            v[b - 1] = tmp;
          }
        uint32_t base = v[m / 2];
        g->start_grid[kx + (size_t)bd[0] * (ky + (size_t)bd[1] * kz)] = base;
        for (uint32_t z = k0[2]; z < k0[2] + GLG_GRID_BLOCK && z < g->grid_dim[2]; z++)
          for (uint32_t y = k0[1]; y < k0[1] + GLG_GRID_BLOCK && y < g->grid_dim[1]; y++)
            for (uint32_t x = k0[0]; x < k0[0] + GLG_GRID_BLOCK && x < g->grid_dim[0]; x++) {
              size_t i = x + (size_t)g->grid_dim[0] * (y + (size_t)g->grid_dim[1] * z);
              int64_t d = (int64_t)centre[i] - base;
              if (d < INT16_MIN || d > INT16_MAX) {
                float p[3];
                grid_centre(g, x, y, z, lo, ext, p);
                d = (int64_t)walk_within(g, p, base) - base;
              }
              g->start_delta[i] = (int16_t)d;
            }
      }
  free(centre);
  return UB_OK;
}

ub_result ub_glg_init(ub_glg *g, const ub_glg_desc *d, const ub_log *log)
{
  if (!g)
    return UB_ERR_INVALID_ARGUMENT;
  memset(g, 0, sizeof *g);
  if (!d || !d->positions || (!d->sh && !d->sh_half) || !d->tets || !d->neigh || d->probe_count < 4 ||
      d->tet_count < 1 || (d->compact && (!d->sh || d->sh_half || d->sh_windowed))) {
    ub_log_printf(log, UB_LOG_ERROR, "glg: missing arrays or fewer than 4 probes / 1 tet");
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (d->tet_count > 0x3FFFFFFFu || d->probe_count > 0x3FFFFFFFu) {
    ub_log_printf(log, UB_LOG_ERROR, "glg: %u tets / %u probes is too many", d->tet_count,
                  d->probe_count);
    return UB_ERR_INVALID_DATA;
  }
  for (size_t i = 0; i < 3 * (size_t)d->probe_count; i++)
    if (!isfinite(d->positions[i])) {
      ub_log_printf(log, UB_LOG_ERROR, "glg: probe %zu position is not finite", i / 3);
      return UB_ERR_INVALID_DATA;
    }
  for (size_t i = 0; i < 27 * (size_t)d->probe_count; i++)
    if (d->sh_half ? !ub_half_is_finite(d->sh_half[i]) : !isfinite(d->sh[i])) {
      ub_log_printf(log, UB_LOG_ERROR, "glg: probe %zu SH is not finite", i / 27);
      return UB_ERR_INVALID_DATA;
    }
  g->probe_count = d->probe_count;
  g->sh = d->sh_half || d->compact ? NULL : d->sh;
  g->sh_half = d->sh_half;
  g->sh_half_exp = d->sh_half ? d->sh_half_exp : NULL;
  if (g->sh_half_exp)
    for (uint32_t q = 0; q < d->probe_count; q++)
      if (g->sh_half_exp[q] < -100 || g->sh_half_exp[q] > 100) {
        ub_log_printf(log, UB_LOG_ERROR, "glg: probe %u SH exponent %d out of range", q,
                      g->sh_half_exp[q]);
        memset(g, 0, sizeof *g);
        return UB_ERR_INVALID_DATA;
      }
#if defined(GLG_HAVE_AVX_PATH)
  unsigned cpu = ub_cpu_features();
  g->simd = (cpu & UB_CPU_AVX) && ((!d->sh_half && !d->compact) || (cpu & UB_CPU_F16C));
#endif
  g->tet_count = d->tet_count;
  g->tets = d->tets;
  g->corner_visible = d->corner_visible;
  g->sh_windowed = d->sh_windowed || d->compact;
  if (d->leak_plane_of) {
    if (d->leak_plane_count && !d->leak_planes) {
      ub_log_printf(log, UB_LOG_ERROR, "glg: leak planes missing");
      memset(g, 0, sizeof *g);
      return UB_ERR_INVALID_ARGUMENT;
    }
    for (size_t i = 0; i < 4 * (size_t)d->leak_plane_count; i++)
      if (!isfinite(d->leak_planes[i])) {
        ub_log_printf(log, UB_LOG_ERROR, "glg: leak plane %zu is not finite", i / 4);
        memset(g, 0, sizeof *g);
        return UB_ERR_INVALID_DATA;
      }
    for (uint32_t t = 0; t < d->tet_count; t++)
      if (d->leak_plane_of[t] != UB_GLG_NO_LEAK_PLANE && d->leak_plane_of[t] >= d->leak_plane_count) {
        ub_log_printf(log, UB_LOG_ERROR, "glg: tet %u: leak plane %u out of range", t,
                      d->leak_plane_of[t]);
        memset(g, 0, sizeof *g);
        return UB_ERR_INVALID_DATA;
      }
    g->leak_plane_count = d->leak_plane_count;
    g->leak_planes = d->leak_planes;
    g->leak_plane_of = d->leak_plane_of;
  }

  if (d->compact) { /* every probe encoded now, windowed lazily */
    g->cp_rows = ub_big_alloc((size_t)d->probe_count * 27 * sizeof *g->cp_rows);
    g->cp_word = ub_big_alloc(((size_t)d->probe_count + 1) * sizeof(uint32_t)); /* + generation */
    if (!g->cp_rows || !g->cp_word) {
      ub_log_printf(log, UB_LOG_ERROR, "glg: out of memory (%u probes)", d->probe_count);
      ub_glg_release(g);
      return UB_ERR_OUT_OF_MEMORY;
    }
    for (uint32_t q = 0; q < d->probe_count; q++)
      atomic_init(cp_words(g) + q, cp_encode_probe(g, d->sh + 27 * (size_t)q, q));
    atomic_init(cp_words(g) + d->probe_count, 0u);
  }
  ub_result res = UB_OK;
  /* Topology: indices, neighbour symmetry, shared faces; count hull faces. */
  uint32_t hull_count = 0;
  for (uint32_t t = 0; t < d->tet_count && res == UB_OK; t++) {
    const uint32_t *v = d->tets + 4 * (size_t)t;
    for (int i = 0; i < 4 && res == UB_OK; i++) {
      if (v[i] >= d->probe_count) {
        ub_log_printf(log, UB_LOG_ERROR, "glg: tet %u corner %d: probe %u out of range", t, i,
                      v[i]);
        res = UB_ERR_INVALID_DATA;
      }
      for (int j = 0; j < i && res == UB_OK; j++)
        if (v[i] == v[j]) {
          ub_log_printf(log, UB_LOG_ERROR, "glg: tet %u repeats probe %u", t, v[i]);
          res = UB_ERR_INVALID_DATA;
        }
    }
    for (int i = 0; i < 4 && res == UB_OK; i++) {
      int32_t u = d->neigh[4 * (size_t)t + i];
      if (u == -1) {
        hull_count++;
        continue;
      }
      if (u < 0 || (uint32_t)u >= d->tet_count || (uint32_t)u == t) {
        ub_log_printf(log, UB_LOG_ERROR, "glg: tet %u neighbour %d invalid", t, u);
        res = UB_ERR_INVALID_DATA;
        break;
      }
      int back = -1, backs = 0;
      for (int j = 0; j < 4; j++)
        if (d->neigh[4 * (size_t)u + j] == (int32_t)t) {
          back = j;
          backs++;
        }
      if (backs != 1 || !same_face(v, i, d->tets + 4 * (size_t)u, back)) {
        ub_log_printf(log, UB_LOG_ERROR, "glg: tets %u and %d are not neighbours sharing a face",
                      t, u);
        res = UB_ERR_INVALID_DATA;
      }
    }
  }
  if (res != UB_OK)
    goto fail;
  if (hull_count < 4 || hull_count >= (1u << 29)) {
    ub_log_printf(log, UB_LOG_ERROR, "glg: tet mesh has %u hull faces (not closed)", hull_count);
    res = UB_ERR_INVALID_DATA;
    goto fail;
  }

  res = UB_ERR_OUT_OF_MEMORY;
  if (d->small_walk) {
    g->tet_nb = ub_big_alloc((size_t)d->tet_count * 4 * sizeof *g->tet_nb);
    g->pos = ub_big_alloc((size_t)d->probe_count * 3 * sizeof *g->pos);
    if (!g->tet_nb || !g->pos)
      goto fail;
    memcpy(g->pos, d->positions, (size_t)d->probe_count * 3 * sizeof *g->pos);
  } else {
    const size_t tb = (size_t)d->tet_count * sizeof *g->tet_data; /* (big: 2 MiB-aligned) */
    g->tet_data = tb >= UB_BIG_ALLOC_MIN ? ub_big_alloc(tb) : aligned_alloc(64, tb);
    if (!g->tet_data)
      goto fail;
  }
  g->tet_flags = ub_big_calloc(d->tet_count, 1);
  g->hull = ub_big_alloc((size_t)hull_count * sizeof *g->hull);
  if (!g->tet_flags || !g->hull)
    goto fail;
  g->hull_count = hull_count;

  uint32_t h = 0;
  for (uint32_t t = 0; t < d->tet_count; t++) {
    const uint32_t *v = d->tets + 4 * (size_t)t;
    struct ub_glg_tet rec; /* the walk record (kept unless small_walk) */
    struct ub_glg_tet *r = g->tet_data ? &g->tet_data[t] : &rec;
    double inv[9], lmax2 = 0.0; /* inv: the cofactor rows (the inverse times det) */
    double q[4][3];
    for (int i = 0; i < 4; i++)
      d3load(d->positions + 3 * (size_t)v[i], q[i]);
    for (int i = 0; i < 4; i++)
      for (int j = i + 1; j < 4; j++) {
        double x[3];
        d3sub(q[i], q[j], x);
        lmax2 = fmax(lmax2, d3dot(x, x));
      }
    const double det =
        tet_cofactors(d->positions + 3 * (size_t)v[0], d->positions + 3 * (size_t)v[1],
                      d->positions + 3 * (size_t)v[2], d->positions + 3 * (size_t)v[3], inv);
    double qual = fabs(det) / (lmax2 * sqrt(lmax2));
    for (int i = 0; i < 3; i++)
      r->o[i] = (float)q[0][i];
    if (!(qual >= GLG_ILL_Q) || !isfinite(qual)) {
      memset(r->m, 0, sizeof r->m);
      g->tet_flags[t] = (qual >= GLG_SINGULAR_Q && isfinite(qual)) ? GLG_FLAG_ILL
                                                                    : GLG_FLAG_SINGULAR;
      g->ill_tet_count++;
      g->singular_tet_count += g->tet_flags[t] == GLG_FLAG_SINGULAR;
    } else {
      for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
          r->m[3 * i + j] = (float)(inv[3 * i + j] / det);
    }
    for (int i = 0; i < 4; i++) {
      int32_t u = d->neigh[4 * (size_t)t + i];
      if (u >= 0) {
        r->nb[i] = u;
        continue;
      }
      struct ub_glg_hull *f = &g->hull[h];
      f->tet = t;
      f->corner = (uint8_t)i;
      for (int k = 0; k < 3; k++) {
        f->fc[k] = (uint8_t)face_of[i][k];
        f->v[k] = v[face_of[i][k]];
        f->adj[k] = GLG_NONE;
      }
      /* outward: the normal must point away from the opposite corner */
      double e1[3], e2[3], n[3], w[3];
      d3sub(q[f->fc[1]], q[f->fc[0]], e1);
      d3sub(q[f->fc[2]], q[f->fc[0]], e2);
      d3cross(e1, e2, n);
      d3sub(q[i], q[f->fc[0]], w);
      if (d3dot(n, w) > 0.0) {
        uint8_t tc = f->fc[1];
        f->fc[1] = f->fc[2];
        f->fc[2] = tc;
        uint32_t tv = f->v[1];
        f->v[1] = f->v[2];
        f->v[2] = tv;
      }
      for (int k = 0; k < 3; k++)
        memcpy(f->p + 3 * k, d->positions + 3 * (size_t)f->v[k], 3 * sizeof(float));
      r->nb[i] = -(int32_t)h - 1;
      h++;
    }
    if (g->tet_nb)
      memcpy(g->tet_nb + 4 * (size_t)t, r->nb, sizeof r->nb);
  }
  if (g->ill_tet_count && !g->pos) { /* the badly shaped tets' corners, for tet_corner (the
                                        small walk keeps every probe's position) */
    g->ill_ids = ub_big_alloc((size_t)g->ill_tet_count * sizeof *g->ill_ids);
    g->ill_pos = ub_big_alloc((size_t)g->ill_tet_count * 12 * sizeof *g->ill_pos);
    if (!g->ill_ids || !g->ill_pos) {
      res = UB_ERR_OUT_OF_MEMORY;
      goto fail;
    }
    uint32_t k = 0;
    for (uint32_t t = 0; t < d->tet_count; t++)
      if (g->tet_flags[t]) {
        g->ill_ids[k] = t;
        for (int i = 0; i < 4; i++)
          memcpy(g->ill_pos + 12 * (size_t)k + 3 * i, d->positions + 3 * (size_t)d->tets[4 * (size_t)t + i],
                 3 * sizeof(float));
        k++;
      }
  }
  if (g->leak_plane_of) {
    /* Each corner's side of its tet's leak plane (see leak_weights). */
    g->leak_drop = ub_big_calloc(d->tet_count, 1);
    if (!g->leak_drop) {
      res = UB_ERR_OUT_OF_MEMORY;
      goto fail;
    }
    for (uint32_t t = 0; t < d->tet_count; t++) {
      uint32_t pl = g->leak_plane_of[t];
      if (pl == UB_GLG_NO_LEAK_PLANE)
        continue;
      const float *n = g->leak_planes + 4 * (size_t)pl;
      unsigned bits = 0;
      for (int i = 0; i < 4; i++) {
        const float *x = d->positions + 3 * (size_t)d->tets[4 * (size_t)t + i];
        float si = n[0] * x[0] + n[1] * x[1] + n[2] * x[2] + n[3];
        bits |= (si < 0.0f ? 1u : 0u) << i;       /* dropped when p is on the + side */
        bits |= (si > 0.0f ? 1u : 0u) << (4 + i); /* dropped when p is on the − side */
      }
      g->leak_drop[t] = (uint8_t)bits;
    }
  }
  res = build_hull_adjacency(g, log);
  if (res != UB_OK)
    goto fail;
  g->walk_cap = 4 * (uint32_t)cbrt((double)d->tet_count) + 64;
  res = build_start_grid(g, d->positions);
  if (res != UB_OK)
    goto fail;
  if (g->ill_tet_count)
    ub_log_printf(log, UB_LOG_INFO, "glg: %u badly shaped tet(s) evaluated in double, %u singular",
                  g->ill_tet_count, g->singular_tet_count);
  return UB_OK;

fail:
  if (res == UB_ERR_OUT_OF_MEMORY)
    ub_log_printf(log, UB_LOG_ERROR, "glg: out of memory (%u tets)", d->tet_count);
  ub_glg_release(g);
  return res;
}

void ub_glg_release(ub_glg *g)
{
  if (!g)
    return;
  free(g->tet_data);
  free(g->tet_nb);
  free(g->pos);
  free(g->tet_flags);
  free(g->leak_drop);
  free(g->hull);
  free(g->ill_ids);
  free(g->ill_pos);
  free(g->start_grid);
  free(g->stale);
  free(g->cp_rows);
  free(g->cp_word);
  memset(g, 0, sizeof *g);
}

/* The start grid: a base tet per block, a 16-bit offset per cell. */
static size_t grid_bytes(const ub_glg *g)
{
  size_t blocks = 1, cells = 1;
  for (int a = 0; a < 3; a++) {
    blocks *= (g->grid_dim[a] + GLG_GRID_BLOCK - 1) / GLG_GRID_BLOCK;
    cells *= g->grid_dim[a];
  }
  return blocks * sizeof(uint32_t) + cells * sizeof(int16_t);
}

/* Walk bytes a tet: its record, or (small_walk) its links. */
static size_t walk_bytes(const ub_glg *g)
{
  return g->tet_data ? sizeof(struct ub_glg_tet) : 4 * sizeof(int32_t);
}

size_t ub_glg_owned_bytes(const ub_glg *g)
{
  if (!g || !g->tet_flags)
    return 0;
  return (size_t)g->tet_count * (walk_bytes(g) + 1 + (g->leak_drop ? 1 : 0)) +
         (g->pos ? (size_t)g->probe_count * 3 * sizeof(float) : 0) +
         (size_t)g->hull_count * sizeof(struct ub_glg_hull) + grid_bytes(g) +
         (g->ill_ids ? (size_t)g->ill_tet_count * (4 + 12 * sizeof(float)) : 0) +
         (g->stale ? (size_t)g->probe_count : 0) +
         (g->cp_rows ? (size_t)g->probe_count * (27 * sizeof(uint16_t) + sizeof(uint32_t)) : 0);
}

void ub_glg_memory_usage(const ub_glg *g, ub_glg_memory *out)
{
  assert(out);
  memset(out, 0, sizeof *out);
  if (!g || !g->tet_flags)
    return;
  size_t np = g->probe_count, nt = g->tet_count;
  out->positions = (g->ill_ids ? (size_t)g->ill_tet_count * (4 + 12 * sizeof(float)) : 0) +
                   (size_t)g->hull_count * 9 * sizeof(float) +
                   (g->pos ? np * 3 * sizeof(float) : 0);
  out->sh = np * (g->cp_rows ? 27 * sizeof(uint16_t) + sizeof(uint32_t)
                  : g->sh_half ? 27 * sizeof(uint16_t) + (g->sh_half_exp ? 1 : 0)
                               : 27 * sizeof(float));
  out->walk_records = nt * walk_bytes(g);
  out->tet_corners = nt * 4 * sizeof(uint32_t);
  out->tet_flags = nt;
  if (g->leak_plane_of)
    out->leak = nt * (sizeof(uint32_t) + 1) + (size_t)g->leak_plane_count * 4 * sizeof(float);
  if (g->corner_visible)
    out->leak += nt * 4;
  out->hull = (size_t)g->hull_count * (sizeof(struct ub_glg_hull) - 9 * sizeof(float));
  out->start_grid = grid_bytes(g);
  out->total = out->positions + out->sh + out->walk_records + out->tet_corners +
               out->tet_flags + out->leak + out->hull + out->start_grid;
}
