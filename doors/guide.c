/* Guided directions toward boxes, mixed with cosine/sphere sampling (see guide.h). */
#include "doors/guide.h"

#include <math.h>
#include <string.h>

#include "bake/lights.h"

static inline double dot3d(const float a[3], const float b[3])
{
  return (double)a[0] * b[0] + (double)a[1] * b[1] + (double)a[2] * b[2];
}

static void clamp_half(float h[3])
{
  for (int i = 0; i < 3; i++)
    h[i] = isfinite(h[i]) && h[i] > UB_OBB_MIN_HALF ? h[i] : UB_OBB_MIN_HALF;
}

void ub_obb_make(const float c[3], const float axis[3][3], const float h[3], ub_obb *out)
{
  memcpy(out->c, c, sizeof out->c);
  memcpy(out->axis, axis, sizeof out->axis);
  memcpy(out->h, h, sizeof out->h);
  clamp_half(out->h);
}

/* Eigenvectors of a symmetric 3×3 matrix by Jacobi rotations (rows of v). */
static void jacobi3(double a[3][3], double v[3][3])
{
  for (int i = 0; i < 3; i++)
    for (int j = 0; j < 3; j++)
      v[i][j] = i == j;
  for (int sweep = 0; sweep < 32; sweep++) {
    double off = fabs(a[0][1]) + fabs(a[0][2]) + fabs(a[1][2]);
    if (off < 1e-30)
      break;
    for (int p = 0; p < 2; p++)
      for (int q = p + 1; q < 3; q++) {
        if (fabs(a[p][q]) < 1e-300)
          continue;
        double th = 0.5 * (a[q][q] - a[p][p]) / a[p][q];
        double t = (th >= 0 ? 1.0 : -1.0) / (fabs(th) + sqrt(th * th + 1.0));
        double cs = 1.0 / sqrt(t * t + 1.0), sn = t * cs;
        for (int k = 0; k < 3; k++) { /* columns p, q of a */
          double akp = a[k][p], akq = a[k][q];
          a[k][p] = cs * akp - sn * akq;
          a[k][q] = sn * akp + cs * akq;
        }
        for (int k = 0; k < 3; k++) { /* rows p, q */
          double apk = a[p][k], aqk = a[q][k];
          a[p][k] = cs * apk - sn * aqk;
          a[q][k] = sn * apk + cs * aqk;
        }
        for (int k = 0; k < 3; k++) { /* eigenvector rows */
          double vp = v[p][k], vq = v[q][k];
          v[p][k] = cs * vp - sn * vq;
          v[q][k] = sn * vp + cs * vq;
        }
      }
  }
}

int ub_obb_fit(const float *pts, uint32_t n, float margin, ub_obb *out)
{
  if (!n)
    return 0;
  double mean[3] = {0, 0, 0};
  for (uint32_t i = 0; i < n; i++)
    for (int k = 0; k < 3; k++) {
      if (!isfinite(pts[3 * (size_t)i + k]))
        return 0;
      mean[k] += pts[3 * (size_t)i + k];
    }
  for (int k = 0; k < 3; k++)
    mean[k] /= n;
  double cov[3][3] = {{0}};
  for (uint32_t i = 0; i < n; i++) {
    double d[3];
    for (int k = 0; k < 3; k++)
      d[k] = pts[3 * (size_t)i + k] - mean[k];
    for (int a = 0; a < 3; a++)
      for (int b = 0; b < 3; b++)
        cov[a][b] += d[a] * d[b];
  }
  double v[3][3];
  jacobi3(cov, v);
  /* Orthonormalise (Gram–Schmidt) and make right-handed; fall back to the world axes. */
  double ax[3][3];
  int ok = 1;
  for (int a = 0; a < 2 && ok; a++) {
    double w[3] = {v[a][0], v[a][1], v[a][2]};
    for (int b = 0; b < a; b++) {
      double d = w[0] * ax[b][0] + w[1] * ax[b][1] + w[2] * ax[b][2];
      for (int k = 0; k < 3; k++)
        w[k] -= d * ax[b][k];
    }
    double l = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    if (!(l > 1e-9))
      ok = 0;
    else
      for (int k = 0; k < 3; k++)
        ax[a][k] = w[k] / l;
  }
  if (!ok)
    for (int a = 0; a < 3; a++)
      for (int k = 0; k < 3; k++)
        ax[a][k] = a == k;
  ax[2][0] = ax[0][1] * ax[1][2] - ax[0][2] * ax[1][1];
  ax[2][1] = ax[0][2] * ax[1][0] - ax[0][0] * ax[1][2];
  ax[2][2] = ax[0][0] * ax[1][1] - ax[0][1] * ax[1][0];
  double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (uint32_t i = 0; i < n; i++)
    for (int a = 0; a < 3; a++) {
      double s = 0.0;
      for (int k = 0; k < 3; k++)
        s += ax[a][k] * (pts[3 * (size_t)i + k] - mean[k]);
      lo[a] = s < lo[a] ? s : lo[a];
      hi[a] = s > hi[a] ? s : hi[a];
    }
  for (int k = 0; k < 3; k++) {
    double c = mean[k];
    for (int a = 0; a < 3; a++)
      c += ax[a][k] * 0.5 * (lo[a] + hi[a]);
    out->c[k] = (float)c;
  }
  for (int a = 0; a < 3; a++) {
    for (int k = 0; k < 3; k++)
      out->axis[a][k] = (float)ax[a][k];
    out->h[a] = (float)(0.5 * (hi[a] - lo[a])) + (isfinite(margin) && margin > 0 ? margin : 0.0f);
  }
  clamp_half(out->h);
  return 1;
}

double ub_obb_volume(const ub_obb *b)
{
  return 8.0 * (double)b->h[0] * b->h[1] * b->h[2];
}

int ub_obb_ray(const ub_obb *b, const float o[3], const float w[3], float *t0, float *t1)
{
  double lo = 0.0, hi = INFINITY;
  float d[3] = {o[0] - b->c[0], o[1] - b->c[1], o[2] - b->c[2]};
  for (int a = 0; a < 3; a++) {
    double p = dot3d(b->axis[a], d), q = dot3d(b->axis[a], w);
    if (fabs(q) < 1e-12) {
      if (fabs(p) > b->h[a])
        return 0;
      continue;
    }
    double ta = (-b->h[a] - p) / q, tb = (b->h[a] - p) / q;
    if (ta > tb) {
      double t = ta;
      ta = tb;
      tb = t;
    }
    lo = ta > lo ? ta : lo;
    hi = tb < hi ? tb : hi;
    if (lo > hi)
      return 0;
  }
  if (!(hi > lo))
    return 0;
  *t0 = (float)lo;
  *t1 = (float)hi;
  return 1;
}

void ub_obb_point(const ub_obb *b, const float u[3], float out[3])
{
  for (int k = 0; k < 3; k++) {
    double p = b->c[k];
    for (int a = 0; a < 3; a++)
      p += (2.0 * u[a] - 1.0) * b->h[a] * b->axis[a][k];
    out[k] = (float)p;
  }
}

double ub_obb_pdf(const ub_obb *b, const float x[3], const float w[3])
{
  float t0, t1;
  if (!ub_obb_ray(b, x, w, &t0, &t1))
    return 0.0;
  double a = t0, c = t1;
  return (c * c * c - a * a * a) / (3.0 * ub_obb_volume(b));
}

int ub_obb_contains(const ub_obb *b, const float p[3])
{
  float d[3] = {p[0] - b->c[0], p[1] - b->c[1], p[2] - b->c[2]};
  for (int a = 0; a < 3; a++)
    if (fabs(dot3d(b->axis[a], d)) > b->h[a])
      return 0;
  return 1;
}

void ub_guide_init(ub_guide *g, const ub_obb *boxes, uint32_t box_count,
                   const double *box_weight, double cosine_prob)
{
  memset(g, 0, sizeof *g);
  if (box_count > UB_GUIDE_MAX_BOXES)
    box_count = UB_GUIDE_MAX_BOXES;
  double wsum = 0.0;
  double w[UB_GUIDE_MAX_BOXES];
  for (uint32_t j = 0; j < box_count; j++) {
    double x = box_weight ? box_weight[j] : 1.0;
    w[j] = isfinite(x) && x > 0.0 ? x : 0.0;
    wsum += w[j];
  }
  double c0 = isfinite(cosine_prob) ? cosine_prob : 1.0;
  c0 = c0 < UB_GUIDE_MIN_COSINE ? UB_GUIDE_MIN_COSINE : (c0 > 1.0 ? 1.0 : c0);
  if (!(wsum > 0.0))
    c0 = 1.0;
  g->prob[0] = c0;
  uint32_t m = 0;
  for (uint32_t j = 0; j < box_count; j++) {
    if (!(w[j] > 0.0))
      continue;
    g->box[m] = boxes[j];
    clamp_half(g->box[m].h);
    g->prob[1 + m] = (1.0 - c0) * w[j] / wsum;
    m++;
  }
  g->box_count = m;
}

static double base_pdf(const float n[3], const float w[3])
{
  if (!n)
    return 0.25 * M_1_PI;
  double c = dot3d(n, w);
  return c > 0.0 ? c * M_1_PI : 0.0;
}

double ub_guide_pdf(const ub_guide *g, const float x[3], const float n[3], const float w[3])
{
  if (n && dot3d(n, w) <= 0.0)
    return 0.0;
  double p = g->prob[0] * base_pdf(n, w);
  for (uint32_t j = 0; j < g->box_count; j++)
    p += g->prob[1 + j] * ub_obb_pdf(&g->box[j], x, w);
  return p;
}

double ub_guide_weight(const ub_guide *g, uint32_t s, const float x[3], const float n[3],
                       const float w[3])
{
  double total = ub_guide_pdf(g, x, n, w);
  if (!(total > 0.0) || s > g->box_count)
    return 0.0;
  double ps = s == 0 ? base_pdf(n, w) : ub_obb_pdf(&g->box[s - 1], x, w);
  return g->prob[s] * ps / total;
}

double ub_guide_sample(const ub_guide *g, const float x[3], const float n[3], const float u[4],
                       float out_w[3])
{
  double pick = u[0];
  double acc = g->prob[0];
  if (pick < acc || !g->box_count) {
    /* The first uniform chose the strategy; rescale it for reuse. */
    float u1 = (float)(acc > 0.0 ? pick / acc : pick);
    u1 = u1 < 1.0f ? u1 : 0.99999994f;
    if (n) {
      ub_sample_cosine(n, u1, u[1], out_w);
    } else {
      double z = 1.0 - 2.0 * u1, r = sqrt(fmax(0.0, 1.0 - z * z)), ph = 2.0 * M_PI * u[1];
      out_w[0] = (float)(r * cos(ph));
      out_w[1] = (float)(r * sin(ph));
      out_w[2] = (float)z;
    }
  } else {
    uint32_t j = 0;
    for (; j + 1 < g->box_count; j++) {
      acc += g->prob[1 + j];
      if (pick < acc)
        break;
    }
    float p[3];
    float uu[3] = {u[1], u[2], u[3]};
    ub_obb_point(&g->box[j], uu, p);
    double d[3] = {p[0] - x[0], p[1] - x[1], p[2] - x[2]};
    double l = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (!(l > 1e-12))
      return 0.0;
    for (int k = 0; k < 3; k++)
      out_w[k] = (float)(d[k] / l);
  }
  return ub_guide_pdf(g, x, n, out_w);
}
