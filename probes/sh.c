/* probes/sh.c — SH L2 basis, projection, cosine convolution and deringing window.
 * Compiled into the run-time library (no baker dependency). See ubake/sh.h. */
#include "ubake/sh.h"

#include <math.h>
#include <string.h>

#define SH_C0 0.282094791773878f  /* Y00 */
#define SH_C1 0.488602511902920f  /* Y1m / (y, z, x) */
#define SH_C2 1.092548430592079f  /* Y2-2, Y2-1, Y21 */
#define SH_C20 0.315391565252520f /* Y20 / (3z² − 1) */
#define SH_C22 0.546274215296040f /* Y22 / (x² − y²) */

void ub_sh2_eval_basis(const float d[3], float out[9])
{
  const float x = d[0], y = d[1], z = d[2];
  out[0] = SH_C0;
  out[1] = SH_C1 * y;
  out[2] = SH_C1 * z;
  out[3] = SH_C1 * x;
  out[4] = SH_C2 * x * y;
  out[5] = SH_C2 * y * z;
  out[6] = SH_C20 * (3.0f * z * z - 1.0f);
  out[7] = SH_C2 * x * z;
  out[8] = SH_C22 * (x * x - y * y);
}

void ub_sh2_zero(float sh[27])
{
  memset(sh, 0, 27 * sizeof(float));
}

void ub_sh2_add(float sh[27], const float dir[3], const float L[3], float wt)
{
  float y[9];
  ub_sh2_eval_basis(dir, y);
  const float r = wt * L[0], g = wt * L[1], b = wt * L[2];
  for (int k = 0; k < 9; k++) {
    sh[k * 3 + 0] += r * y[k];
    sh[k * 3 + 1] += g * y[k];
    sh[k * 3 + 2] += b * y[k];
  }
}

void ub_sh2_madd(float acc[27], const float sh[27], float w)
{
  for (int i = 0; i < 27; i++)
    acc[i] += w * sh[i];
}

void ub_sh2_scale(float sh[27], float s)
{
  for (int i = 0; i < 27; i++)
    sh[i] *= s;
}

void ub_sh2_lerp(const float a[27], const float b[27], float t, float out[27])
{
  for (int i = 0; i < 27; i++)
    out[i] = a[i] + t * (b[i] - a[i]);
}

void ub_sh2_from_sh1(const float sh1[12], float out[27])
{
  memcpy(out, sh1, 12 * sizeof(float));
  memset(out + 12, 0, 15 * sizeof(float));
}

void ub_sh2_irradiance_basis(const float n[3], float out_w[9])
{
  float y[9];
  ub_sh2_eval_basis(n, y);
  static const float band[9] = {UB_SH_A0, UB_SH_A1, UB_SH_A1, UB_SH_A1, UB_SH_A2,
                                UB_SH_A2, UB_SH_A2, UB_SH_A2, UB_SH_A2};
  for (int k = 0; k < 9; k++)
    out_w[k] = band[k] * y[k];
}

void ub_sh2_irradiance(const float sh[27], const float n[3], float out_rgb[3])
{
  float w[9];
  ub_sh2_irradiance_basis(n, w);
  for (int c = 0; c < 3; c++) {
    float e = 0.0f;
    for (int k = 0; k < 9; k++)
      e += w[k] * sh[k * 3 + c];
    out_rgb[c] = e;
  }
}

/* ---- exact minimum of the irradiance over the sphere -------------------------------
 * On the unit sphere the L2 irradiance of one channel is E(n) = e0 + b·n + nᵀMn with
 * M symmetric (traceless): the constant in Y20 = c(3z² − 1) is folded in as
 * c(2z² − x² − y²). min over |n| = 1 of nᵀMn + b·n is the trust-region subproblem; with
 * M = Q diag(μ) Qᵀ and β = Qᵀb its Lagrange dual is
 *   g(λ) = λ − ¼ Σ β_i² / (μ_i − λ),  λ < μ_min,
 * concave, and g(λ) ≤ min for every such λ (strong duality: max g = min). We maximise g
 * by a safeguarded Newton iteration on the secular equation, so the value returned is a
 * certified lower bound (up to rounding) and tight to ~1e-12 relative. */

typedef struct sh_quad {
  double e0;      /* DC irradiance */
  double mu[3];   /* eigenvalues of M, ascending */
  double beta[3]; /* b in the eigenbasis */
} sh_quad;

static void jacobi3(double a[3][3], double v[3][3])
{
  for (int i = 0; i < 3; i++)
    for (int j = 0; j < 3; j++)
      v[i][j] = i == j ? 1.0 : 0.0;
  for (int sweep = 0; sweep < 32; sweep++) {
    double off = fabs(a[0][1]) + fabs(a[0][2]) + fabs(a[1][2]);
    double diag = fabs(a[0][0]) + fabs(a[1][1]) + fabs(a[2][2]);
    if (off <= 1e-300 || off <= 1e-18 * diag)
      break;
    for (int p = 0; p < 2; p++) {
      for (int q = p + 1; q < 3; q++) {
        if (a[p][q] == 0.0)
          continue;
        double theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
        double t = (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
        double c = 1.0 / sqrt(t * t + 1.0), s = t * c;
        for (int k = 0; k < 3; k++) { /* A ← A·J */
          double akp = a[k][p], akq = a[k][q];
          a[k][p] = c * akp - s * akq;
          a[k][q] = s * akp + c * akq;
        }
        for (int k = 0; k < 3; k++) { /* A ← Jᵀ·A */
          double apk = a[p][k], aqk = a[q][k];
          a[p][k] = c * apk - s * aqk;
          a[q][k] = s * apk + c * aqk;
        }
        for (int k = 0; k < 3; k++) {
          double vkp = v[k][p], vkq = v[k][q];
          v[k][p] = c * vkp - s * vkq;
          v[k][q] = s * vkp + c * vkq;
        }
      }
    }
  }
}

static void sh_quad_build(const float sh[27], int c, sh_quad *out)
{
  const double A0 = 3.14159265358979323846, A1 = A0 * 2.0 / 3.0, A2 = A0 / 4.0;
  double L[9];
  for (int k = 0; k < 9; k++)
    L[k] = sh[k * 3 + c];
  out->e0 = A0 * (double)SH_C0 * L[0];
  double b[3] = {A1 * (double)SH_C1 * L[3], A1 * (double)SH_C1 * L[1],
                 A1 * (double)SH_C1 * L[2]};
  double c20 = A2 * (double)SH_C20 * L[6], c22 = A2 * (double)SH_C22 * L[8];
  double c2 = A2 * (double)SH_C2 * 0.5;
  double m[3][3] = {{-c20 + c22, c2 * L[4], c2 * L[7]},
                    {c2 * L[4], -c20 - c22, c2 * L[5]},
                    {c2 * L[7], c2 * L[5], 2.0 * c20}};
  double v[3][3];
  jacobi3(m, v);
  int order[3] = {0, 1, 2};
  for (int i = 0; i < 3; i++) /* sort ascending */
    for (int j = i + 1; j < 3; j++)
      if (m[order[j]][order[j]] < m[order[i]][order[i]]) {
        int t = order[i];
        order[i] = order[j];
        order[j] = t;
      }
  for (int i = 0; i < 3; i++) {
    int k = order[i];
    out->mu[i] = m[k][k];
    out->beta[i] = v[0][k] * b[0] + v[1][k] * b[1] + v[2][k] * b[2];
  }
}

/* min over |n| = 1 of e0 + w1·b·n + w2·nᵀMn (a lower bound, tight). If out_n is not
 * NULL it receives the minimiser (approximately; unit length) in M's eigenbasis, which
 * gives the derivative of the minimum along a window path (envelope theorem). */
static double sh_quad_min_n(const sh_quad *q, double w1, double w2, double *out_n,
                            double *inout_delta);
static double sh_quad_min(const sh_quad *q, double w1, double w2)
{
  return sh_quad_min_n(q, w1, w2, NULL, NULL);
}

/* The minimiser from the secular-equation shift δ (gap_i + δ > 0 where β_i ≠ 0): n_i =
 * −w1·β_i / (2(gap_i + δ)); the hard case (δ = 0) fills the μ_min axis up to unit length. */
static void quad_argmin(const double be[3], const double gap[3], double delta, double out_n[3])
{
  double s = 0.0;
  for (int i = 0; i < 3; i++) {
    double d = gap[i] + delta;
    out_n[i] = be[i] != 0.0 && d > 0.0 ? -0.5 * be[i] / d : 0.0;
    s += out_n[i] * out_n[i];
  }
  if (s < 1.0 && be[0] == 0.0)
    out_n[0] = sqrt(1.0 - s), s = 1.0;
  if (s > 0.0) {
    double inv = 1.0 / sqrt(s);
    for (int i = 0; i < 3; i++)
      out_n[i] *= inv;
  } else {
    out_n[0] = 1.0;
  }
}

/* inout_delta: if not NULL and > 0, where the Newton iteration starts (the shift of a
 * nearby problem: a search along a window path converges in 1–3 steps instead of ~10);
 * receives the final shift. Any start gives the same certified bound. */
static double sh_quad_min_n(const sh_quad *q, double w1, double w2, double *out_n,
                            double *inout_delta)
{
  double mu[3], bb[3], bnorm2 = 0.0;
  for (int i = 0; i < 3; i++) {
    mu[i] = w2 * q->mu[i];
    double be = w1 * q->beta[i];
    bb[i] = 0.25 * be * be; /* ¼β² */
    bnorm2 += be * be;
  }
  if (!(bnorm2 > 0.0)) {
    if (out_n)
      out_n[0] = 1.0, out_n[1] = 0.0, out_n[2] = 0.0;
    return q->e0 + mu[0];
  }
  /* δ = μ_min − λ > 0; φ(δ) = Σ ¼β_i²/(μ_i − μ_min + δ)², decreasing; root of φ = 1
   * lies in [|β_0|/2, |β|/2]. gap_i = μ_i − μ_min ≥ 0. */
  double gap[3] = {0.0, mu[1] - mu[0], mu[2] - mu[0]};
  if (gap[1] < 0.0)
    gap[1] = 0.0;
  if (gap[2] < 0.0)
    gap[2] = 0.0;
  double lo = sqrt(bb[0]), hi = 0.5 * sqrt(bnorm2);
  double delta;
  /* Hard case: φ(0⁺) ≤ 1 with β_0 = 0: the optimum is at δ = 0. */
  if (bb[0] == 0.0) {
    double phi0 = 0.0;
    int infinite = 0;
    for (int i = 1; i < 3; i++) {
      if (bb[i] == 0.0)
        continue;
      if (gap[i] <= 0.0) {
        infinite = 1;
        break;
      }
      phi0 += bb[i] / (gap[i] * gap[i]);
    }
    if (!infinite && phi0 <= 1.0) {
      double g = mu[0];
      for (int i = 1; i < 3; i++)
        if (bb[i] != 0.0)
          g -= bb[i] / gap[i];
      if (out_n) {
        double be[3] = {w1 * q->beta[0], w1 * q->beta[1], w1 * q->beta[2]};
        quad_argmin(be, gap, 0.0, out_n);
      }
      return q->e0 + g;
    }
  }
  if (lo > hi)
    lo = hi;
  delta = hi;
  if (inout_delta && *inout_delta > lo && *inout_delta < hi)
    delta = *inout_delta;
  for (int it = 0; it < 100; it++) {
    /* h(δ) = φ^(-1/2) − 1, increasing and nearly linear: Newton, bracketed. */
    double phi = 0.0, dphi = 0.0;
    for (int i = 0; i < 3; i++) {
      if (bb[i] == 0.0)
        continue;
      double d = gap[i] + delta;
      double t = bb[i] / (d * d);
      phi += t;
      dphi += -2.0 * t / d;
    }
    if (phi > 1.0)
      lo = delta;
    else
      hi = delta;
    if (hi - lo <= 1e-15 * hi)
      break;
    double s = 1.0 / sqrt(phi);
    double h = s - 1.0, dh = -0.5 * s * s * s * dphi;
    if (fabs(h) < 1e-14)
      break;
    double next = dh > 0.0 ? delta - h / dh : 0.5 * (lo + hi);
    if (!(next > lo && next < hi))
      next = 0.5 * (lo + hi);
    if (next == delta)
      break;
    delta = next;
  }
  /* g at the bracket end with φ ≥ 1 side would also be a bound; any δ > 0 gives one. */
  double best = -HUGE_VAL;
  double cand[2] = {delta, hi};
  for (int j = 0; j < 2; j++) {
    double d0 = cand[j];
    if (!(d0 > 0.0))
      continue;
    double g = mu[0] - d0;
    for (int i = 0; i < 3; i++)
      if (bb[i] != 0.0)
        g -= bb[i] / (gap[i] + d0);
    if (g > best)
      best = g;
  }
  if (best == -HUGE_VAL) /* δ = 0 with β = 0 on μ_min only */
    best = mu[0];
  if (out_n) {
    double be[3] = {w1 * q->beta[0], w1 * q->beta[1], w1 * q->beta[2]};
    quad_argmin(be, gap, delta, out_n);
  }
  if (inout_delta)
    *inout_delta = delta;
  return q->e0 + best;
}

void ub_sh2_irradiance_min(const float sh[27], float out_min_rgb[3])
{
  for (int c = 0; c < 3; c++) {
    sh_quad q;
    sh_quad_build(sh, c, &q);
    out_min_rgb[c] = (float)sh_quad_min(&q, 1.0, 1.0);
  }
}

/* ---- windowing ---------------------------------------------------------------------- */

/* Phase 1, t ∈ [0, 1]: w1 = 1 − t/2, w2 = 1 − t. Phase 2, s ∈ [0, 1]: w1 = ½(1 − s),
 * w2 = 0. Each phase is linear in its parameter, so the minimum over the sphere is a
 * concave function of it (a minimum of affine functions). */
static double window_min(const sh_quad *q, int phase, double t)
{
  if (phase == 1)
    return sh_quad_min(q, 1.0 - 0.5 * t, 1.0 - t);
  return sh_quad_min(q, 0.5 * (1.0 - t), 0.0);
}

/* Smallest t in [0, t_hi] with window_min ≥ target, given min(0) < target ≤ min(t_hi)
 * (Illinois regula falsi: the function is concave, so this converges in a few steps).
 * Returns a feasible t within 1e-7 of the smallest one, or one whose minimum is at most
 * 1.5 × target. */
static double window_root(const sh_quad *q, int phase, double t_hi, double f_hi, double target)
{
  double a = 0.0, b = t_hi;
  double fa = window_min(q, phase, 0.0) - target, fb = f_hi - target;
  int side = 0;
  for (int it = 0; it < 60 && b - a > 1e-7 && fb > 0.5 * target; it++) {
    double t = (a * fb - b * fa) / (fb - fa);
    if (!(t > a && t < b))
      t = 0.5 * (a + b);
    double ft = window_min(q, phase, t) - target;
    if (ft >= 0.0) {
      b = t;
      fb = ft;
      if (side == 1)
        fa *= 0.5;
      side = 1;
    } else {
      a = t;
      fa = ft;
      if (side == -1)
        fb *= 0.5;
      side = -1;
    }
  }
  return b;
}

/* Cheap sufficient test: E(n) ≥ e0 − |b| + λ_min(M) for every unit n. M is traceless, so
 * λ_min ≥ −√(2/3)·‖M‖_F (with λ1 + λ2 + λ3 = 0, λ2² + λ3² ≥ λ1²/2, so ‖M‖_F² ≥ 1.5·λ1²;
 * equality for eigenvalues (−2a, a, a), e.g. a pure Y20 lobe). `tight` = 0 is the older,
 * looser −‖M‖_F (kept for ub_sh2_window_reference). */
static int surely_nonnegative(const float sh[27], int c, double target, int tight)
{
  const double A0 = 3.14159265358979323846, A1 = A0 * 2.0 / 3.0, A2 = A0 / 4.0;
  double e0 = A0 * (double)SH_C0 * sh[c];
  double b2 = 0.0;
  for (int k = 1; k < 4; k++)
    b2 += (double)sh[k * 3 + c] * sh[k * 3 + c];
  double bn = A1 * (double)SH_C1 * sqrt(b2);
  /* ‖M‖_F² = 2·(c2·L4)²+2·(c2·L5)²+2·(c2·L7)² + 6·c20² + 2·c22², c2 = A2·SH_C2/2 */
  double c2 = A2 * (double)SH_C2 * 0.5, c20 = A2 * (double)SH_C20 * sh[6 * 3 + c],
         c22 = A2 * (double)SH_C22 * sh[8 * 3 + c];
  double l4 = sh[4 * 3 + c], l5 = sh[5 * 3 + c], l7 = sh[7 * 3 + c];
  double mf2 = 2.0 * c2 * c2 * (l4 * l4 + l5 * l5 + l7 * l7) + 6.0 * c20 * c20 + 2.0 * c22 * c22;
  /* (1 − 1e-12): rounding of the bound itself, so it stays a bound */
  double lam = sqrt((tight ? 2.0 / 3.0 : 1.0) * mf2) * (1.0 + 1e-12);
  return e0 - bn - lam >= target;
}

/* Second, still closed-form sufficient test, for what the first cannot pass (most smooth
 * probes with a strong l=2 band): the trust-region dual without an eigendecomposition.
 * For any λ < μ_min(M), min_n E ≥ e0 + g(λ), g(λ) = λ − ¼·bᵀ(M − λI)⁻¹b (concave). λ_lo
 * = the smallest eigenvalue from the trigonometric formula, lowered by a safety margin
 * for acos's rounding, is below μ_min; start at λ_lo − |b|/2 (where the optimum lies
 * for β along the μ_min axis) and take ≤ 3 safeguarded Newton steps on g, each a 3×3
 * adjugate solve. Returns 1 when the bound reaches target (no exact minimum needed). */
static int dual_bound_ok(const float sh[27], int c, double target)
{
  const double A0 = 3.14159265358979323846, A1 = A0 * 2.0 / 3.0, A2 = A0 / 4.0;
  double L[9];
  for (int k = 0; k < 9; k++)
    L[k] = sh[k * 3 + c];
  double e0 = A0 * (double)SH_C0 * L[0];
  double b[3] = {A1 * (double)SH_C1 * L[3], A1 * (double)SH_C1 * L[1],
                 A1 * (double)SH_C1 * L[2]};
  double c20 = A2 * (double)SH_C20 * L[6], c22 = A2 * (double)SH_C22 * L[8];
  double c2 = A2 * (double)SH_C2 * 0.5;
  double m00 = -c20 + c22, m11 = -c20 - c22, m22 = 2.0 * c20, m01 = c2 * L[4],
         m02 = c2 * L[7], m12 = c2 * L[5];
  double f2 = m00 * m00 + m11 * m11 + m22 * m22 + 2.0 * (m01 * m01 + m02 * m02 + m12 * m12);
  double bn = sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
  double size = e0 + bn + sqrt(f2);
  if (!(f2 > 0.0)) /* no l=2: min = e0 − |b| exactly */
    return e0 - bn - 1e-12 * size >= target;
  /* smallest eigenvalue of the traceless M: 2p·cos(φ + 2π/3), p = ‖M‖_F/√6 */
  double pp = sqrt(f2 / 6.0);
  double B00 = m00 / pp, B11 = m11 / pp, B22 = m22 / pp, B01 = m01 / pp, B02 = m02 / pp,
         B12 = m12 / pp;
  double detB = B00 * (B11 * B22 - B12 * B12) - B01 * (B01 * B22 - B12 * B02) +
                B02 * (B01 * B12 - B11 * B02);
  double r = 0.5 * detB;
  r = r < -1.0 ? -1.0 : r > 1.0 ? 1.0 : r;
  double phi = acos(r) / 3.0;
  double lam_lo = 2.0 * pp * cos(phi + 2.0943951023931957) - 1e-6 * pp;
  if (!(bn > 0.0))
    return e0 + lam_lo - 1e-12 * size >= target;
  double lam = lam_lo - 0.5 * bn;
  double best = -HUGE_VAL;
  for (int it = 0; it < 4; it++) {
    /* A = M − λI (positive definite for λ < μ_min); x = A⁻¹b by the adjugate */
    double a00 = m00 - lam, a11 = m11 - lam, a22 = m22 - lam;
    double j00 = a11 * a22 - m12 * m12, j01 = m02 * m12 - m01 * a22, j02 = m01 * m12 - a11 * m02;
    double j11 = a00 * a22 - m02 * m02, j12 = m01 * m02 - a00 * m12, j22 = a00 * a11 - m01 * m01;
    double det = a00 * j00 + m01 * j01 + m02 * j02;
    if (!(det > 0.0) || !(a00 > 0.0) || !(j22 > 0.0))
      break; /* not positive definite (rounding near μ_min): keep the best so far */
    double inv = 1.0 / det;
    double x0 = (j00 * b[0] + j01 * b[1] + j02 * b[2]) * inv,
           x1 = (j01 * b[0] + j11 * b[1] + j12 * b[2]) * inv,
           x2 = (j02 * b[0] + j12 * b[1] + j22 * b[2]) * inv;
    double g = lam - 0.25 * (b[0] * x0 + b[1] * x1 + b[2] * x2);
    if (g > best)
      best = g;
    if (e0 + best - 1e-12 * size >= target)
      return 1;
    /* g' = 1 − ¼|x|², g'' = −½·xᵀA⁻¹x */
    double y0 = (j00 * x0 + j01 * x1 + j02 * x2) * inv, y1 = (j01 * x0 + j11 * x1 + j12 * x2) * inv,
           y2 = (j02 * x0 + j12 * x1 + j22 * x2) * inv;
    double g1 = 1.0 - 0.25 * (x0 * x0 + x1 * x1 + x2 * x2);
    double g2 = -0.5 * (x0 * y0 + x1 * y1 + x2 * y2);
    if (!(g2 < 0.0))
      break;
    double next = lam - g1 / g2;
    if (!(next < lam_lo))
      next = 0.5 * (lam + lam_lo);
    lam = next;
  }
  return 0;
}

/* The window of one channel by the original search: regula falsi on phase 1 when t = 1 is
 * feasible, else a golden-section hunt for a feasible t, else phase 2. ~10–40 exact
 * minima per channel. */
static void window_search_reference(const sh_quad *q, double target, double *w1, double *w2)
{
  double f1 = window_min(q, 1, 1.0);
  if (f1 >= target) {
    double t = window_root(q, 1, 1.0, f1, target);
    *w1 = 1.0 - 0.5 * t;
    *w2 = 1.0 - t;
    return;
  }
  /* min(t) is concave, so its feasible set is an interval: golden-section search
   * towards the peak, stopping at the first feasible t; the answer lies before it. */
  const double gr = 0.6180339887498949;
  double a = 0.0, b = 1.0;
  double x1 = b - gr * (b - a), x2 = a + gr * (b - a);
  double fx1 = window_min(q, 1, x1), fx2 = window_min(q, 1, x2);
  double feas = -1.0, ffeas = 0.0;
  for (int it = 0; it < 40; it++) {
    if (fx1 >= target || fx2 >= target) {
      feas = fx1 >= target ? x1 : x2;
      ffeas = fx1 >= target ? fx1 : fx2;
      break;
    }
    if (fx1 < fx2) {
      a = x1;
      x1 = x2;
      fx1 = fx2;
      x2 = a + gr * (b - a);
      fx2 = window_min(q, 1, x2);
    } else {
      b = x2;
      x2 = x1;
      fx2 = fx1;
      x1 = b - gr * (b - a);
      fx1 = window_min(q, 1, x1);
    }
  }
  if (feas >= 0.0) {
    double t = window_root(q, 1, feas, ffeas, target);
    *w1 = 1.0 - 0.5 * t;
    *w2 = 1.0 - t;
  } else {
    /* Not a non-negative function (or only the margin is missing): drop l=2 and
     * shrink l=1. At s = 1 only the DC remains, which is ≥ target. */
    double s = window_root(q, 2, 1.0, window_min(q, 2, 1.0), target);
    *w1 = 0.5 * (1.0 - s);
    *w2 = 0.0;
  }
}

#define WINDOW_T_TOL 1e-7 /* the window parameter is found to this (as the reference) */

/* The same window by Newton's method on the concave f(t) = min_n E_t(n) (phase 1,
 * w1 = 1 − t/2, w2 = 1 − t), started at t = 0 where f < target. f' is the derivative of
 * E_t at the current minimiser n* (envelope theorem): −½β·n* − Σμ_i n*_i². The tangent of
 * a concave function lies above it, so every Newton iterate stays at or left of the
 * smallest feasible t (never past it, never into a later feasible interval) and the
 * iteration converges to it quadratically; each iterate is nudged by the tolerance, so
 * the first feasible one is within it of the answer (~3 exact minima per channel, each
 * warm-started from the previous shift). f' ≤ 0 at an infeasible t, or a tangent root past
 * t = 1, proves phase 1 has no feasible t: phase 2 (w2 = 0) has the closed form
 * min = e0 − w1·|b|. Anything unusual (slow convergence, rounding) falls back to the
 * reference search. f0: f(0), already computed, with its minimiser n0. */
static void window_search_fast(const sh_quad *q, double target, double f0, const double n0[3],
                               double delta0, double *w1, double *w2)
{
  double t = 0.0, f = f0, n[3] = {n0[0], n0[1], n0[2]}, delta = delta0;
  for (int it = 0; it < 12; it++) {
    double bn = q->beta[0] * n[0] + q->beta[1] * n[1] + q->beta[2] * n[2];
    double mn = q->mu[0] * n[0] * n[0] + q->mu[1] * n[1] * n[1] + q->mu[2] * n[2] * n[2];
    double d = -0.5 * bn - mn;
    if (!(d > 0.0))
      goto phase2;
    double tn = t + (target - f) / d;
    if (!(tn <= 1.0)) {
      if (window_min(q, 1, 1.0) >= target)
        break; /* the tangent argument failed by rounding: search */
      goto phase2;
    }
    /* The smallest feasible t is ≥ tn: evaluating at tn + tol, a feasible answer is
     * within tol of it; an infeasible one is a valid next Newton point. */
    t = tn + WINDOW_T_TOL < 1.0 ? tn + WINDOW_T_TOL : 1.0;
    f = sh_quad_min_n(q, 1.0 - 0.5 * t, 1.0 - t, n, &delta);
    if (f >= target) {
      *w1 = 1.0 - 0.5 * t;
      *w2 = 1.0 - t;
      return;
    }
  }
  window_search_reference(q, target, w1, w2);
  return;
phase2:;
  double bnorm = sqrt(q->beta[0] * q->beta[0] + q->beta[1] * q->beta[1] +
                      q->beta[2] * q->beta[2]);
  double w = bnorm > 0.0 ? (q->e0 - target) / bnorm * (1.0 - 1e-9) : 0.5;
  *w1 = w < 0.0 ? 0.0 : (w > 0.5 ? 0.5 : w);
  *w2 = 0.0;
}

/* The window of every channel: w1, w2 per channel (1, 1 unchanged; 0, 0 zeroed). */
static unsigned window_weights(const float sh[27], int fast, double w1o[3], double w2o[3])
{
  unsigned flags = 0;
  for (int c = 0; c < 3; c++) {
    w1o[c] = w2o[c] = 1.0;
    int finite = 1, nonzero = 0;
    for (int k = 0; k < 9; k++) {
      if (!isfinite(sh[k * 3 + c]))
        finite = 0;
      if (k > 0 && sh[k * 3 + c] != 0.0f)
        nonzero = 1;
    }
    if (finite && !nonzero && sh[c] >= 0.0f)
      continue; /* constant, non-negative */
    if (!finite || !(sh[c] > 0.0f)) {
      w1o[c] = w2o[c] = 0.0;
      flags |= UB_SH2_ZEROED(c);
      continue;
    }
    const double target =
        (double)UB_SH2_WINDOW_MARGIN * 3.14159265358979323846 * (double)SH_C0 * sh[c];
    if (surely_nonnegative(sh, c, target, fast))
      continue;
    if (fast && dual_bound_ok(sh, c, target))
      continue;
    sh_quad q;
    sh_quad_build(sh, c, &q);
    double n0[3], delta0 = 0.0;
    double f0 = sh_quad_min_n(&q, 1.0, 1.0, n0, &delta0);
    if (f0 >= target)
      continue;
    if (fast)
      window_search_fast(&q, target, f0, n0, delta0, &w1o[c], &w2o[c]);
    else
      window_search_reference(&q, target, &w1o[c], &w2o[c]);
    flags |= UB_SH2_WINDOWED(c);
  }
  return flags;
}

static unsigned window_impl(float sh[27], int fast)
{
  double w1[3], w2[3];
  unsigned flags = window_weights(sh, fast, w1, w2);
  for (int c = 0; c < 3; c++) {
    if (flags & UB_SH2_ZEROED(c)) {
      for (int k = 0; k < 9; k++)
        sh[k * 3 + c] = 0.0f;
    } else if (flags & UB_SH2_WINDOWED(c)) {
      for (int k = 1; k < 4; k++)
        sh[k * 3 + c] = (float)(sh[k * 3 + c] * w1[c]);
      for (int k = 4; k < 9; k++)
        sh[k * 3 + c] = (float)(sh[k * 3 + c] * w2[c]);
    }
  }
  return flags;
}

unsigned ub_sh2_window(float sh[27])
{
  return window_impl(sh, 1);
}

unsigned ub_sh2_window_weights(const float sh[27], float out_w1[3], float out_w2[3])
{
  double w1[3], w2[3];
  unsigned flags = window_weights(sh, 1, w1, w2);
  for (int c = 0; c < 3; c++) {
    out_w1[c] = (float)w1[c];
    out_w2[c] = (float)w2[c];
  }
  return flags;
}

unsigned ub_sh2_window_reference(float sh[27])
{
  return window_impl(sh, 0);
}
