/* runtime/llg.c — local light grid evaluation (see include/ubake/llg.h). */
#include "ubake/llg.h"

#include <math.h>
#include <string.h>

#include "ubake/runtime.h"
#include "ubake/sh.h"

/* Real-SH triple products C_ijk = ∫ Y_i Y_j Y_k dω for i ≤ j (symmetric in i, j), all
 * indices < 9, |C| > 1e-9. Computed once offline by 16-point Gauss–Legendre in cos θ ×
 * 32 uniform φ (exact for the degree-6 integrands), in the basis order of ubake/sh.h. */
typedef struct tp_entry {
  uint8_t i, j, k;
  float c;
} tp_entry;

static const tp_entry ub_llg_tp[] = {
  {0, 0, 0, 0.282094792f},
  {0, 1, 1, 0.282094792f},
  {0, 2, 2, 0.282094792f},
  {0, 3, 3, 0.282094792f},
  {0, 4, 4, 0.282094792f},
  {0, 5, 5, 0.282094792f},
  {0, 6, 6, 0.282094792f},
  {0, 7, 7, 0.282094792f},
  {0, 8, 8, 0.282094792f},
  {1, 1, 0, 0.282094792f},
  {1, 1, 6, -0.126156626f},
  {1, 1, 8, -0.218509686f},
  {1, 2, 5, 0.218509686f},
  {1, 3, 4, 0.218509686f},
  {1, 4, 3, 0.218509686f},
  {1, 5, 2, 0.218509686f},
  {1, 6, 1, -0.126156626f},
  {1, 8, 1, -0.218509686f},
  {2, 2, 0, 0.282094792f},
  {2, 2, 6, 0.252313252f},
  {2, 3, 7, 0.218509686f},
  {2, 5, 1, 0.218509686f},
  {2, 6, 2, 0.252313252f},
  {2, 7, 3, 0.218509686f},
  {3, 3, 0, 0.282094792f},
  {3, 3, 6, -0.126156626f},
  {3, 3, 8, 0.218509686f},
  {3, 4, 1, 0.218509686f},
  {3, 6, 3, -0.126156626f},
  {3, 7, 2, 0.218509686f},
  {3, 8, 3, 0.218509686f},
  {4, 4, 0, 0.282094792f},
  {4, 4, 6, -0.180223752f},
  {4, 5, 7, 0.156078347f},
  {4, 6, 4, -0.180223752f},
  {4, 7, 5, 0.156078347f},
  {5, 5, 0, 0.282094792f},
  {5, 5, 6, 0.090111876f},
  {5, 5, 8, -0.156078347f},
  {5, 6, 5, 0.090111876f},
  {5, 7, 4, 0.156078347f},
  {5, 8, 5, -0.156078347f},
  {6, 6, 0, 0.282094792f},
  {6, 6, 6, 0.180223752f},
  {6, 7, 7, 0.090111876f},
  {6, 8, 8, -0.180223752f},
  {7, 7, 0, 0.282094792f},
  {7, 7, 6, 0.090111876f},
  {7, 7, 8, 0.156078347f},
  {7, 8, 7, 0.156078347f},
  {8, 8, 0, 0.282094792f},
  {8, 8, 6, -0.180223752f},
};

void ub_llg_sh_rotation(const float R[9], float out_M[81])
{
  /* icosahedron vertices (0, ±1, ±φ) and cyclic permutations, normalised */
  const double phi = 1.6180339887498949, inv = 1.0 / sqrt(1.0 + phi * phi);
  double acc[81] = {0};
  for (int i = 0; i < 12; i++) {
    double a = (i & 1) ? -1.0 : 1.0, b = (i & 2) ? -phi : phi, e[3];
    int rot = i >> 2; /* 0, 1, 2: cyclic position */
    e[rot] = 0.0;
    e[(rot + 1) % 3] = a * inv;
    e[(rot + 2) % 3] = b * inv;
    float d[3] = {(float)e[0], (float)e[1], (float)e[2]}, rd[3], yd[9], yr[9];
    for (int k = 0; k < 3; k++) /* Rᵀ d */
      rd[k] = (float)((double)R[k] * e[0] + (double)R[3 + k] * e[1] + (double)R[6 + k] * e[2]);
    ub_sh2_eval_basis(d, yd);
    ub_sh2_eval_basis(rd, yr);
    for (int k = 0; k < 9; k++)
      for (int j = 0; j < 9; j++)
        acc[9 * k + j] += (double)yd[k] * yr[j];
  }
  for (int k = 0; k < 81; k++)
    out_M[k] = (float)(acc[k] * (4.0 * M_PI / 12.0));
}

void ub_llg_sh_rotate(const float M[81], const float in[9], float out[9])
{
  for (int k = 0; k < 9; k++) {
    float s = 0.0f;
    for (int j = 0; j < 9; j++)
      s += M[9 * k + j] * in[j];
    out[k] = s;
  }
}

void ub_llg_sh_product(const float L[27], const float V[9], float out[27])
{
  memset(out, 0, 27 * sizeof *out);
  for (size_t e = 0; e < sizeof ub_llg_tp / sizeof ub_llg_tp[0]; e++) {
    const tp_entry *t = &ub_llg_tp[e];
    const float *li = L + t->i * 3, *lj = L + t->j * 3;
    float vi = V[t->i], vj = V[t->j], w = t->i != t->j ? 1.0f : 0.0f;
    float *o = out + t->k * 3;
    for (int c = 0; c < 3; c++)
      o[c] += (li[c] * vj + w * lj[c] * vi) * t->c;
  }
}

static void local_coords(const float center[3], const float axes[9], const float p[3],
                         float out_q[3])
{
  float d[3] = {p[0] - center[0], p[1] - center[1], p[2] - center[2]};
  for (int a = 0; a < 3; a++)
    out_q[a] = d[0] * axes[3 * a] + d[1] * axes[3 * a + 1] + d[2] * axes[3 * a + 2];
}

uint32_t ub_llg_grid_corners(const float center[3], const float axes[9], const float half[3],
                             const uint32_t dims[3], const float p[3], uint32_t idx[8],
                             float wt[8])
{
  float q[3];
  local_coords(center, axes, p, q);
  uint32_t i0[3];
  float t[3];
  for (int a = 0; a < 3; a++) {
    float g = half[a] > 0.0f ? (q[a] + half[a]) / (2.0f * half[a]) * (float)(dims[a] - 1) : 0.0f;
    if (!(g > 0.0f))
      g = 0.0f; /* also NaN */
    if (g > (float)(dims[a] - 1))
      g = (float)(dims[a] - 1);
    uint32_t i = (uint32_t)g;
    if (i >= dims[a] - 1)
      i = dims[a] >= 2 ? dims[a] - 2 : 0;
    i0[a] = i;
    t[a] = dims[a] >= 2 ? g - (float)i : 0.0f;
  }
  uint32_t n = 0;
  for (int c = 0; c < 8; c++) {
    uint32_t ix = i0[0] + (c & 1), iy = i0[1] + ((c >> 1) & 1), iz = i0[2] + ((c >> 2) & 1);
    if (ix >= dims[0] || iy >= dims[1] || iz >= dims[2])
      continue;
    float w = ((c & 1) ? t[0] : 1.0f - t[0]) * (((c >> 1) & 1) ? t[1] : 1.0f - t[1]) *
              (((c >> 2) & 1) ? t[2] : 1.0f - t[2]);
    if (w == 0.0f)
      continue;
    idx[n] = ((uint32_t)iz * dims[1] + iy) * dims[0] + ix;
    wt[n++] = w;
  }
  return n;
}

void ub_llg_grid_sample(const float center[3], const float axes[9], const float half[3],
                        const uint32_t dims[3], const float *probe_sh, const float p[3],
                        float out_sh[27])
{
  uint32_t idx[8];
  float wt[8];
  const uint32_t n = ub_llg_grid_corners(center, axes, half, dims, p, idx, wt);
  double acc[27];
  memset(acc, 0, sizeof acc);
  for (uint32_t c = 0; c < n; c++) {
    const float *s = probe_sh + 27 * (size_t)idx[c];
    for (int k = 0; k < 27; k++)
      acc[k] += (double)wt[c] * s[k];
  }
  for (int k = 0; k < 27; k++)
    out_sh[k] = (float)acc[k];
}

void ub_llg_probe_position(const float center[3], const float axes[9], const float half[3],
                           const uint32_t dims[3], uint32_t ix, uint32_t iy, uint32_t iz,
                           float out_p[3])
{
  uint32_t idx[3] = {ix, iy, iz};
  for (int k = 0; k < 3; k++)
    out_p[k] = center[k];
  for (int a = 0; a < 3; a++) {
    float s = dims[a] > 1 ? -half[a] + 2.0f * half[a] * (float)idx[a] / (float)(dims[a] - 1) : 0.0f;
    for (int k = 0; k < 3; k++)
      out_p[k] += axes[3 * a + k] * s;
  }
}

float ub_llg_box_distance(const float center[3], const float axes[9], const float half[3],
                          const float p[3])
{
  float q[3];
  local_coords(center, axes, p, q);
  double d2 = 0.0;
  for (int a = 0; a < 3; a++) {
    double e = fabs((double)q[a]) - half[a];
    if (e > 0.0)
      d2 += e * e;
  }
  return (float)sqrt(d2);
}

void ub_llg_irradiance(const float L[27], const float *vis, const float *self, const float n[3],
                       float out_rgb[3])
{
  float prod[27];
  const float *s = L;
  if (vis) {
    ub_llg_sh_product(L, vis, prod);
    s = prod;
  }
  ub_sh2_irradiance(s, n, out_rgb);
  ub_llg_irradiance_finish(out_rgb, self, out_rgb);
}

void ub_llg_irradiance_finish(const float e[3], const float *self, float out_rgb[3])
{
  for (int c = 0; c < 3; c++) {
    float v = isfinite(e[c]) && e[c] > 0.0f ? e[c] : 0.0f;
    if (self && isfinite(self[c]) && self[c] > 0.0f)
      v += self[c];
    out_rgb[c] = v;
  }
}

void ub_llg_irradiance_weights(const float *vis, const float n[3], float w[9])
{
  float a9[9]; /* ub_sh2_irradiance's weights */
  ub_sh2_irradiance_basis(n, a9);
  if (!vis) {
    memcpy(w, a9, sizeof a9);
    return;
  }
  /* prod_k = Σ_t c_t (L_i V_j + [i ≠ j] L_j V_i) over the entries t = (i, j, k): L_i's
   * weight gathers c_t·V_j·a_k, L_j's c_t·V_i·a_k */
  memset(w, 0, 9 * sizeof *w);
  for (size_t e = 0; e < sizeof ub_llg_tp / sizeof ub_llg_tp[0]; e++) {
    const tp_entry *t = &ub_llg_tp[e];
    const float a = a9[t->k] * t->c;
    w[t->i] += a * vis[t->j];
    if (t->i != t->j)
      w[t->j] += a * vis[t->i];
  }
}

/* ---------------------------------------------------------------------------------- */
/* Run-time queries over a loaded bake file.                                           */


#define UB_LLG_FACING_PENALTY 0.01 /* metres */

/* Closest point of triangle abc to p (Ericson, Real-Time Collision Detection §5.1.5):
 * barycentrics of b and c, squared distance. */
static double closest_on_triangle(const float p[3], const float a[3], const float b[3],
                                  const float c[3], float *out_u, float *out_v)
{
  double ab[3], ac[3], ap[3];
  for (int k = 0; k < 3; k++) {
    ab[k] = (double)b[k] - a[k];
    ac[k] = (double)c[k] - a[k];
    ap[k] = (double)p[k] - a[k];
  }
#define DOT(x, y) ((x)[0] * (y)[0] + (x)[1] * (y)[1] + (x)[2] * (y)[2])
  double d1 = DOT(ab, ap), d2 = DOT(ac, ap), u, v;
  double bp[3] = {(double)p[0] - b[0], (double)p[1] - b[1], (double)p[2] - b[2]};
  double cp[3] = {(double)p[0] - c[0], (double)p[1] - c[1], (double)p[2] - c[2]};
  double d3 = DOT(ab, bp), d4 = DOT(ac, bp), d5 = DOT(ab, cp), d6 = DOT(ac, cp);
  double vc = d1 * d4 - d3 * d2, vb = d5 * d2 - d1 * d6, va = d3 * d6 - d5 * d4;
  if (d1 <= 0 && d2 <= 0) {
    u = 0, v = 0;
  } else if (d3 >= 0 && d4 <= d3) {
    u = 1, v = 0;
  } else if (vc <= 0 && d1 >= 0 && d3 <= 0) {
    u = d1 / (d1 - d3), v = 0;
  } else if (d6 >= 0 && d5 <= d6) {
    u = 0, v = 1;
  } else if (vb <= 0 && d2 >= 0 && d6 <= 0) {
    u = 0, v = d2 / (d2 - d6);
  } else if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    v = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    u = 1 - v;
  } else {
    double den = va + vb + vc;
    if (!(fabs(den) > 0)) {
      u = 0, v = 0;
    } else {
      u = vb / den;
      v = vc / den;
    }
  }
#undef DOT
  double q2 = 0.0;
  for (int k = 0; k < 3; k++) {
    double q = a[k] + u * ab[k] + v * ac[k] - p[k];
    q2 += q * q;
  }
  *out_u = (float)u;
  *out_v = (float)v;
  return q2;
}

ub_result ub_runtime_query_llg_ex(const ub_runtime *rt, const float p[3], const float n_in[3],
                                  unsigned flags, float out_rgb[3], uint32_t *out_model)
{
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]))
    return UB_ERR_INVALID_ARGUMENT;
  double nl = sqrt((double)n_in[0] * n_in[0] + (double)n_in[1] * n_in[1] +
                   (double)n_in[2] * n_in[2]);
  if (!(nl > 0.0) || !isfinite(nl))
    return UB_ERR_INVALID_ARGUMENT;
  if (!bf || bf->llg_count == 0)
    return UB_ERR_NOT_BAKED;
  float n[3] = {(float)(n_in[0] / nl), (float)(n_in[1] / nl), (float)(n_in[2] / nl)};
  uint32_t best = 0;
  float best_d = INFINITY;
  for (uint32_t i = 0; i < bf->llg_count; i++) {
    const ub_bakefile_llg *m = &bf->llgs[i];
    float d = ub_llg_box_distance(m->center, m->axes, m->half, p);
    if (d < best_d) {
      best_d = d;
      best = i;
      if (d == 0.0f)
        break;
    }
  }
  const ub_bakefile_llg *m = &bf->llgs[best];
  float L[27];
  ub_llg_grid_sample(m->center, m->axes, m->half, m->dims, m->probe_sh, p, L);
  float vis[9], self[3];
  int use_vis = 0;
  if (!(flags & UB_LLG_QUERY_NO_VISIBILITY)) {
    double bd = INFINITY;
    uint32_t bt = 0;
    float bu = 0.0f, bv = 0.0f;
    for (uint32_t t = 0; t < m->triangle_count; t++) {
      const uint32_t *ix = m->indices + 3 * (size_t)t;
      const float *a = m->positions + 3 * (size_t)ix[0], *b = m->positions + 3 * (size_t)ix[1],
                  *c = m->positions + 3 * (size_t)ix[2];
      float u, v;
      double d2 = closest_on_triangle(p, a, b, c, &u, &v);
      /* Facing n: along a concave edge a point just off one face is also on the plane of
       * the other; a face turned away from n costs up to UB_LLG_FACING_PENALTY² m². */
      double e1[3] = {(double)b[0] - a[0], (double)b[1] - a[1], (double)b[2] - a[2]};
      double e2[3] = {(double)c[0] - a[0], (double)c[1] - a[1], (double)c[2] - a[2]};
      double g[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                     e1[0] * e2[1] - e1[1] * e2[0]};
      double gl = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
      double facing = gl > 0.0 ? (g[0] * n[0] + g[1] * n[1] + g[2] * n[2]) / gl : 0.0;
      d2 += (1.0 - facing) * 0.5 * UB_LLG_FACING_PENALTY * UB_LLG_FACING_PENALTY;
      if (d2 < bd) {
        bd = d2;
        bt = t;
        bu = u;
        bv = v;
      }
    }
    if (bd <= (double)UB_LLG_SURFACE_DISTANCE * UB_LLG_SURFACE_DISTANCE +
                  UB_LLG_FACING_PENALTY * UB_LLG_FACING_PENALTY) {
      const uint32_t *ix = m->indices + 3 * (size_t)bt;
      float b[3] = {1.0f - bu - bv, bu, bv};
      memset(vis, 0, sizeof vis);
      memset(self, 0, sizeof self);
      for (int k = 0; k < 3; k++) {
        for (int j = 0; j < 9; j++)
          vis[j] += b[k] * m->vis[9 * (size_t)ix[k] + j];
        for (int j = 0; j < 3; j++)
          self[j] += b[k] * m->self[3 * (size_t)ix[k] + j];
      }
      use_vis = 1;
    }
  }
  ub_llg_irradiance(L, use_vis ? vis : NULL, use_vis ? self : NULL, n, out_rgb);
  if (out_model)
    *out_model = best;
  return UB_OK;
}

ub_result ub_runtime_query_llg(const ub_runtime *rt, const float p[3], const float n[3],
                               float out_rgb[3])
{
  return ub_runtime_query_llg_ex(rt, p, n, 0u, out_rgb, NULL);
}
