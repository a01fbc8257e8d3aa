/* lightmaps/lm_internal.h — internals shared by layout.c and charts.c (not installed,
 * not part of any public interface). */
#ifndef UBAKE_LIGHTMAPS_LM_INTERNAL_H
#define UBAKE_LIGHTMAPS_LM_INTERNAL_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>

#include "lightmaps/lightmap.h"

#define UB_LM_PADDING 2        /* empty texels on every side of a generated chart */
#define UB_LM_CHART_COS 0.8660254f /* cos 30°: max angle to the chart's seed normal */
#define UB_LM_MIN_SIZE 16      /* smallest atlas side */

/* ---------------------------------------------------------------------------------- */
/* small double-precision vector helpers (cglm is float-only and takes non-const args) */

static inline void v3_sub(const double a[3], const double b[3], double o[3])
{
  o[0] = a[0] - b[0];
  o[1] = a[1] - b[1];
  o[2] = a[2] - b[2];
}
static inline double v3_dot(const double a[3], const double b[3])
{
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
static inline void v3_cross(const double a[3], const double b[3], double o[3])
{
  double x = a[1] * b[2] - a[2] * b[1];
  double y = a[2] * b[0] - a[0] * b[2];
  double z = a[0] * b[1] - a[1] * b[0];
  o[0] = x;
  o[1] = y;
  o[2] = z;
}
static inline double v3_len(const double a[3])
{
  return sqrt(v3_dot(a, a));
}
/* Normalises in place; a zero or non-finite vector becomes zero. Returns the length. */
static inline double v3_normalize(double a[3])
{
  double l = v3_len(a);
  if (!(l > 0.0) || !isfinite(l)) {
    a[0] = a[1] = a[2] = 0.0;
    return 0.0;
  }
  a[0] /= l;
  a[1] /= l;
  a[2] /= l;
  return l;
}
static inline void load3(const float *p, double o[3])
{
  o[0] = p[0];
  o[1] = p[1];
  o[2] = p[2];
}
static inline float f3_dot(const float a[3], const float b[3])
{
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}


static inline uint32_t round_up4(double x)
{
  if (!(x > 0.0))
    return 0;
  if (x > 1e9)
    x = 1e9;
  uint32_t v = (uint32_t)ceil(x);
  return (v + 3u) & ~3u;
}

/* ---------------------------------------------------------------------------------- */
/* build context */

typedef struct lm_ctx {
  const ub_scene *scene;
  const ub_rt *rt;
  const ub_log *log;
  float extent;        /* largest side of the vertex bounds, metres */
  float local_eps;     /* normal offset when there is no ub_rt */
  double plane_tol;    /* coplanarity distance, metres */
  float *tri_n;        /* triangle_count × 3: unit geometric normal (0 when degenerate) */
  double *tri_area;    /* triangle_count: world area, m² */
  int8_t *tri_kind;    /* -1 none, 0 authored, 1 generated */
} lm_ctx;

static inline void tri_corners(const ub_scene *s, uint32_t t, double p[3][3])
{
  for (int k = 0; k < 3; k++)
    load3(s->positions + 3 * (size_t)s->indices[3 * (size_t)t + k], p[k]);
}

/* Metres per texel for triangle t: its node's, else the level's, else default_ts. */
float ub_lm_texel_size(const lm_ctx *c, uint32_t t, float default_ts);

/* ---------------------------------------------------------------------------------- */
/* generated charts (charts.c) */

typedef struct lm_chart {
  uint32_t first, count;         /* members: order[first .. first+count) (generated-list idx) */
  double umin, vmin, umax, vmax; /* texel units, chart-local */
  uint32_t rect_w, rect_h;       /* packed rectangle incl. padding */
  uint32_t atlas, x, y;          /* placement (atlas index among generated atlases) */
  uint32_t node;
  int projected;                 /* guv holds this chart's projection */
} lm_chart;

typedef struct lm_charts {
  uint32_t gcount;  /* generated triangles */
  uint32_t *gtri;   /* gcount: scene triangle */
  double *guv;      /* gcount × 6: chart-local texel coordinates per corner */
  uint32_t *order;  /* gcount: members of chart 0, then chart 1, ... */
  lm_chart *charts;
  uint32_t chart_count, chart_cap;
  uint32_t split_charts, scaled_charts;
  uint32_t overlap_splits;      /* charts that folded over themselves and were split */
} lm_charts;

/* Charts for the triangles with tri_kind == 1: edge-connected (welded positions, same
 * node) within 30° of the seed normal, projected in texel units, oversized ones split
 * or scaled down. On failure g is empty. */
ub_result ub_lm_charts_build(const lm_ctx *c, float default_ts, lm_charts *g);
/* Skyline-packs the charts with padding into atlases ≤ UB_ATLAS_MAX_SIZE; fills each
 * chart's atlas/x/y and returns the atlas sizes (caller frees). */
ub_result ub_lm_charts_pack(lm_charts *g, uint32_t *out_count, uint32_t **out_w,
                            uint32_t **out_h);
/* Texels spanned by a chart of extent ext once centred in them (see charts.c). */
uint32_t ub_lm_chart_cells(double ext);
void ub_lm_charts_free(lm_charts *g);

#endif
