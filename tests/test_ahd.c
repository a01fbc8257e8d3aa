/* tests/test_ahd.c — SH L1 projection/irradiance and AHD encode/decode (ubake/ahd.h). */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "test_util.h"
#include "runtime/cpu.h"
#include "ubake/ahd.h"

#define PI 3.14159265358979323846

static uint64_t rng_state = 0x9E3779B97F4A7C15ull;

static double rnd(void) /* [0, 1) */
{
  uint64_t z = (rng_state += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  z ^= z >> 31;
  return (double)(z >> 11) * (1.0 / 9007199254740992.0);
}

static void rnd_dir(float d[3])
{
  double z = 2.0 * rnd() - 1.0, phi = 2.0 * PI * rnd(), r = sqrt(fmax(0.0, 1.0 - z * z));
  d[0] = (float)(r * cos(phi));
  d[1] = (float)(r * sin(phi));
  d[2] = (float)z;
}

static float dot3(const float a[3], const float b[3])
{
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void frame(const float n[3], float t[3], float b[3])
{
  float a[3] = {fabsf(n[0]) < 0.9f ? 1.0f : 0.0f, fabsf(n[0]) < 0.9f ? 0.0f : 1.0f, 0.0f};
  float k = dot3(a, n);
  for (int i = 0; i < 3; i++)
    t[i] = a[i] - k * n[i];
  float l = sqrtf(dot3(t, t));
  for (int i = 0; i < 3; i++)
    t[i] /= l;
  b[0] = n[1] * t[2] - n[2] * t[1];
  b[1] = n[2] * t[0] - n[0] * t[2];
  b[2] = n[0] * t[1] - n[1] * t[0];
}

/* A positive radiance function: constant ambient + a few delta lobes, projected to L1
 * (deltas are the extreme case of positive lobes: largest linear band per unit power). */
static void random_sh(float sh[12], double *mean_irr_lum)
{
  memset(sh, 0, 12 * sizeof(float));
  float amb[3];
  double scale = 0.1 + 10.0 * rnd();
  int ambient_on = rnd() < 0.8;
  for (int c = 0; c < 3; c++)
    amb[c] = ambient_on ? (float)(scale * rnd() * 0.5) : 0.0f;
  for (int c = 0; c < 3; c++)
    sh[c] += amb[c] * (float)(4.0 * PI * 0.282094791773878);
  int lobes = 1 + (int)(rnd() * 4);
  for (int k = 0; k < lobes; k++) {
    float w[3], L[3];
    rnd_dir(w);
    for (int c = 0; c < 3; c++)
      L[c] = (float)(scale * rnd());
    ub_sh1_add(sh, w, L, 1.0f);
  }
  /* mean irradiance over the sphere = π·Y00·L00, luminance */
  double lum[3] = {0.2126, 0.7152, 0.0722}, m = 0.0;
  for (int c = 0; c < 3; c++)
    m += lum[c] * PI * 0.282094791773878 * sh[c];
  *mean_irr_lum = m;
}

static int finite_ahd(const ub_ahd *a)
{
  for (int c = 0; c < 3; c++)
    if (!isfinite(a->ambient[c]) || !isfinite(a->directional[c]) || !isfinite(a->direction[c]))
      return 0;
  return 1;
}

static void test_encode_exact_and_bounded(void)
{
  const int cases = 50000, normals_per_case = 64;
  double worst_exact = 0.0, worst_hemi = 0.0, worst_front = 0.0, sum2 = 0.0;
  long count = 0;
  int negative = 0, nonfinite = 0;
  for (int i = 0; i < cases; i++) {
    float sh[12], n[3];
    double mean_irr;
    random_sh(sh, &mean_irr);
    rnd_dir(n);
    ub_ahd ahd;
    ub_ahd_encode(sh, n, &ahd);
    if (!finite_ahd(&ahd))
      nonfinite++;
    for (int c = 0; c < 3; c++)
      if (ahd.ambient[c] < 0.0f || ahd.directional[c] < 0.0f)
        negative++;
    float e_sh[3], e_ahd[3];
    ub_sh1_irradiance(sh, n, e_sh);
    ub_ahd_irradiance(&ahd, n, e_ahd);
    for (int c = 0; c < 3; c++) {
      double err = fabs(e_ahd[c] - e_sh[c]) / fmax(fabs(e_sh[c]), 1e-6 * mean_irr + 1e-30);
      if (e_sh[c] > 0.0f && err > worst_exact)
        worst_exact = err;
    }
    /* Other normals n' in the hemisphere of n; luminance error relative to
     * E_sh(n') + mean irradiance (E_sh alone goes to 0 on the dark side). */
    float dz = dot3(ahd.direction, n);
    int front_lit = dz >= 0.5f && dz < 0.9999f; /* d well above the horizon, not fallback */
    float t[3], b[3];
    frame(n, t, b);
    for (int k = 0; k < normals_per_case; k++) {
      double z = rnd(), phi = 2.0 * PI * rnd(), r = sqrt(fmax(0.0, 1.0 - z * z));
      float m[3];
      for (int a = 0; a < 3; a++)
        m[a] = (float)(r * cos(phi) * t[a] + r * sin(phi) * b[a] + z * n[a]);
      ub_sh1_irradiance(sh, m, e_sh);
      ub_ahd_irradiance(&ahd, m, e_ahd);
      double ls = 0.2126 * e_sh[0] + 0.7152 * e_sh[1] + 0.0722 * e_sh[2];
      double la = 0.2126 * e_ahd[0] + 0.7152 * e_ahd[1] + 0.0722 * e_ahd[2];
      double rel = fabs(la - ls) / (ls + mean_irr);
      sum2 += rel * rel;
      count++;
      if (rel > worst_hemi)
        worst_hemi = rel;
      if (front_lit && z >= 0.5 && rel > worst_front) /* n' within 60° of n */
        worst_front = rel;
    }
  }
  double rms = sqrt(sum2 / (double)count);
  printf("AHD: worst relative error along n: %.3g\n", worst_exact);
  printf("AHD: |E_ahd - E_sh| / (E_sh + mean E) over the hemisphere of n: worst %.3f, "
         "rms %.3f\n", worst_hemi, rms);
  printf("AHD: same, light direction >= 30 deg above the surface, n' within 60 deg of n: "
         "worst %.3f\n", worst_front);
  ASSERT_TRUE(nonfinite == 0);
  ASSERT_TRUE(negative == 0);
  ASSERT_TRUE(worst_exact <= 1e-4);
  /* Bounds, from the values printed above (measured 1.02 / 0.16 / 0.40) plus margin.
   * AHD is one clamped lobe on a constant; the L1 irradiance is linear in n'. The worst
   * case is light at or below the horizon of n: the encoding then puts everything in
   * ambient (C_d = 0, exact along n), while the SH irradiance of normals tilted away from
   * the light falls to 0: an error of about the mean irradiance, never more (positive
   * radiance has |b| ≤ 2·mean). When the light is well above the surface the error for
   * normal-mapped normals stays below half of (E_sh + mean). */
  ASSERT_TRUE(worst_hemi <= 1.1);
  ASSERT_TRUE(rms <= 0.2);
  ASSERT_TRUE(worst_front <= 0.45);
}

static void test_edge_cases(void)
{
  float n[3] = {0.0f, 1.0f, 0.0f};
  ub_ahd a;
  float e[3];
  /* zero SH */
  float zero[12] = {0};
  ub_ahd_encode(zero, n, &a);
  ASSERT_TRUE(finite_ahd(&a));
  ub_ahd_irradiance(&a, n, e);
  for (int c = 0; c < 3; c++)
    ASSERT_TRUE(e[c] == 0.0f && a.ambient[c] == 0.0f && a.directional[c] == 0.0f);
  ASSERT_NEAR(dot3(a.direction, a.direction), 1.0, 1e-6, 0);

  /* negative lobes (ringing from a previous subtraction, or a negative delta record) */
  for (int i = 0; i < 2000; i++) {
    float sh[12] = {0}, w[3], L[3], m[3];
    rnd_dir(w);
    rnd_dir(m);
    for (int c = 0; c < 3; c++)
      L[c] = (float)(4.0 * rnd() - 2.0);
    ub_sh1_add(sh, w, L, 1.0f);
    rnd_dir(w);
    ub_sh1_add(sh, w, L, -0.5f);
    ub_ahd_encode(sh, m, &a);
    ASSERT_TRUE(finite_ahd(&a));
    float es[3];
    ub_sh1_irradiance(sh, m, es);
    ub_ahd_irradiance(&a, m, e);
    for (int c = 0; c < 3; c++) {
      ASSERT_TRUE(a.ambient[c] >= 0.0f && a.directional[c] >= 0.0f);
      ASSERT_TRUE(es[c] >= 0.0f);
      ASSERT_NEAR(e[c], es[c], 1e-5, 1e-4);
    }
  }

  /* d·n = 0 exactly: linear band along +x, normal +y */
  float sh[12] = {0};
  float w[3] = {1.0f, 0.0f, 0.0f}, L[3] = {1.0f, 2.0f, 3.0f};
  ub_sh1_add(sh, w, L, 1.0f);
  ub_ahd_encode(sh, n, &a);
  ASSERT_TRUE(finite_ahd(&a));
  float es[3];
  ub_sh1_irradiance(sh, n, es);
  ub_ahd_irradiance(&a, n, e);
  for (int c = 0; c < 3; c++) {
    ASSERT_NEAR(e[c], es[c], 1e-6, 1e-5);
    ASSERT_TRUE(a.directional[c] == 0.0f); /* everything in ambient */
  }
  /* light from straight behind the surface */
  float back[3] = {0.0f, -1.0f, 0.0f};
  memset(sh, 0, sizeof sh);
  ub_sh1_add(sh, back, L, 1.0f);
  ub_ahd_encode(sh, n, &a);
  ASSERT_TRUE(finite_ahd(&a));
  ub_ahd_irradiance(&a, n, e);
  ub_sh1_irradiance(sh, n, es);
  for (int c = 0; c < 3; c++)
    ASSERT_NEAR(e[c], es[c], 1e-6, 1e-5);

  /* non-finite input and a zero normal do not leak NaN */
  float bad[12] = {NAN, 1.0f, INFINITY, 0, 0, 0, 0, 0, 0, -INFINITY, 0, 0};
  float zn[3] = {0, 0, 0};
  ub_ahd_encode(bad, zn, &a);
  ASSERT_TRUE(finite_ahd(&a));
  ub_ahd_irradiance(&a, zn, e);
  ASSERT_TRUE(isfinite(e[0]) && isfinite(e[1]) && isfinite(e[2]));
  ub_sh1_irradiance(bad, n, e);
  ASSERT_TRUE(isfinite(e[0]) && isfinite(e[1]) && isfinite(e[2]));
}

/* Projects L(ω) with a lat-long midpoint quadrature through ub_sh1_add. */
typedef void (*radiance_fn)(const float w[3], float L[3]);

static void project(radiance_fn f, float sh[12])
{
  const int nt = 400, np = 800;
  double acc[12] = {0};
  for (int i = 0; i < nt; i++) {
    float row[12] = {0};
    double th = (i + 0.5) * PI / nt;
    for (int j = 0; j < np; j++) {
      double ph = (j + 0.5) * 2.0 * PI / np;
      float w[3] = {(float)(sin(th) * cos(ph)), (float)(sin(th) * sin(ph)), (float)cos(th)};
      float L[3];
      f(w, L);
      ub_sh1_add(row, w, L, (float)(sin(th) * (PI / nt) * (2.0 * PI / np)));
    }
    for (int k = 0; k < 12; k++)
      acc[k] += row[k];
  }
  for (int k = 0; k < 12; k++)
    sh[k] = (float)acc[k];
}

/* ∫_{H(n)} L(ω) (n·ω) dω by midpoint quadrature in n's frame. */
static void hemisphere_irradiance(radiance_fn f, const float n[3], double E[3])
{
  const int nt = 200, np = 400;
  float t[3], b[3];
  frame(n, t, b);
  E[0] = E[1] = E[2] = 0.0;
  for (int i = 0; i < nt; i++) {
    double th = (i + 0.5) * (PI / 2) / nt;
    for (int j = 0; j < np; j++) {
      double ph = (j + 0.5) * 2.0 * PI / np;
      float w[3];
      for (int a = 0; a < 3; a++)
        w[a] = (float)(sin(th) * cos(ph) * t[a] + sin(th) * sin(ph) * b[a] + cos(th) * n[a]);
      float L[3];
      f(w, L);
      double dw = sin(th) * ((PI / 2) / nt) * (2.0 * PI / np);
      for (int c = 0; c < 3; c++)
        E[c] += L[c] * cos(th) * dw;
    }
  }
}

static void rad_const(const float w[3], float L[3])
{
  (void)w;
  L[0] = 1.0f;
  L[1] = 2.0f;
  L[2] = 0.5f;
}

static void rad_linear(const float w[3], float L[3])
{
  /* L1-exact and positive: c0 + c1 (ω·v), c0 ≥ |c1| */
  const float v[3] = {0.48f, 0.6f, 0.64f};
  float t = dot3(w, v);
  L[0] = 1.0f + 0.9f * t;
  L[1] = 2.0f - 1.5f * t;
  L[2] = 0.3f + 0.1f * t;
}

static void test_irradiance_quadrature(void)
{
  float sh[12];
  project(rad_const, sh);
  for (int i = 0; i < 20; i++) {
    float n[3], e[3];
    rnd_dir(n);
    ub_sh1_irradiance(sh, n, e);
    ASSERT_NEAR(e[0], PI * 1.0, 0, 1e-3);
    ASSERT_NEAR(e[1], PI * 2.0, 0, 1e-3);
    ASSERT_NEAR(e[2], PI * 0.5, 0, 1e-3);
  }
  project(rad_linear, sh);
  for (int i = 0; i < 20; i++) {
    float n[3], e[3];
    double ref[3];
    rnd_dir(n);
    ub_sh1_irradiance(sh, n, e);
    hemisphere_irradiance(rad_linear, n, ref);
    for (int c = 0; c < 3; c++)
      ASSERT_NEAR(e[c], ref[c], 1e-4, 1e-3);
  }
}

/* ub_ahd_encode_iz8 (AVX lanes) gives the bits of eight ub_ahd_encode_iz calls, on random
 * texels and on the edge cases: negative and zero I_z, light from behind or grazing the
 * surface (d·n at and around the guard), no linear band, NaN, ±Inf, −0, denormals. */
static void test_encode_iz8_bits(void)
{
  static const float special[] = {0.0f, -0.0f, 1e-40f, -1e-40f, 1e-30f, 1e30f, -1.0f,
                                  INFINITY, -INFINITY, NAN};
  const int ns = (int)(sizeof special / sizeof special[0]);
  int mismatches = 0, total = 0, pmismatch = 0, saturated = 0, nmismatch = 0, ntotal = 0;
  int paired = 0;
  for (int round = 0; round < 4000; round++) {
    /* 8..24 texels: the first 8 for the eight-texel calls, all for
     * ub_ahd_encode_iz_packed_n (two groups side by side, then eight, then one by one) */
    const int count = 8 + round % 17;
    float sh[12 * 24], n[3 * 24];
    ub_ahd got[8], want[8];
    ub_ahd_packed gotp[8], wantp, gotn[24];
    const float inv_scale = (round & 1) ? 0.125f : 1.0f;
    for (int j = 0; j < count; j++) {
      rnd_dir(n + 3 * j);
      double m;
      random_sh(sh + 12 * j, &m);
      int kind = (int)(rnd() * 7);
      if (round % 3 == 0 && (kind == 1 || kind == 6))
        kind = 0; /* a third of the rounds all finite: whole lane groups take the SIMD math */
      if (kind == 1) /* one coefficient replaced by a special value */
        sh[12 * j + (int)(rnd() * 12)] = special[(int)(rnd() * ns)];
      else if (kind == 2) /* light exactly along a direction at the guard from n */
        for (int c = 0; c < 3; c++) {
          float t[3], bb[3];
          frame(n + 3 * j, t, bb);
          float g = (float)(1e-2 * (0.5 + rnd())), h = sqrtf(1.0f - g * g);
          sh[12 * j + 3 + c] = h * t[1] + g * n[3 * j + 1];
          sh[12 * j + 6 + c] = h * t[2] + g * n[3 * j + 2];
          sh[12 * j + 9 + c] = h * t[0] + g * n[3 * j + 0];
        }
      else if (kind == 3) /* no linear band */
        for (int k = 3; k < 12; k++)
          sh[12 * j + k] = 0.0f;
      else if (kind == 4) /* a negative (delta) texel */
        for (int k = 0; k < 12; k++)
          sh[12 * j + k] = -sh[12 * j + k];
      else if (kind == 5) /* beyond the half range at this scale: saturated when packed */
        for (int k = 0; k < 12; k++)
          sh[12 * j + k] *= 3e5f;
      else if (kind == 6) /* finite, but the AVX finite check's lane sum overflows */
        for (int c = 0; c < 3; c++)
          sh[12 * j + c] = 3e38f;
    }
    ub_ahd_encode_iz8(sh, n, got);
    ub_ahd_encode_iz8_packed(sh, n, inv_scale, gotp);
    ub_ahd_encode_iz_packed_n(sh, n, inv_scale, gotn, (size_t)count);
    paired += count >= 16;
    for (int j = 0; j < count; j++) {
      ub_ahd a;
      ub_ahd_encode_iz(sh + 12 * j, n + 3 * j, &a);
      ub_ahd_pack(&a, inv_scale, &wantp);
      ntotal++;
      nmismatch += memcmp(&gotn[j], &wantp, sizeof wantp) != 0;
    }
    for (int j = 0; j < 8; j++) {
      ub_ahd_encode_iz(sh + 12 * j, n + 3 * j, &want[j]);
      total++;
      ub_ahd_pack(&want[j], inv_scale, &wantp);
      pmismatch += memcmp(&gotp[j], &wantp, sizeof wantp) != 0;
      saturated += wantp.ambient[0] == 0x7bffu || wantp.directional[1] == 0x7bffu;
      if (memcmp(&got[j], &want[j], sizeof want[j]) != 0) {
        if (mismatches++ < 3)
          printf("encode_iz8 lane %d differs: ambient %.9g/%.9g dir %.9g/%.9g\n", j,
                 got[j].ambient[0], want[j].ambient[0], got[j].direction[0],
                 want[j].direction[0]);
      }
    }
  }
  printf("ub_ahd_encode_iz8: %d of %d texels differ from ub_ahd_encode_iz in any bit\n",
         mismatches, total);
  printf("ub_ahd_encode_iz8_packed (%s): %d of %d texels differ from ub_ahd_encode_iz + "
         "ub_ahd_pack (%d saturated)\n",
         (ub_cpu_features_cached() & (UB_CPU_AVX | UB_CPU_F16C)) == (UB_CPU_AVX | UB_CPU_F16C)
             ? "AVX + F16C path"
             : "scalar path: this CPU has no AVX + F16C",
         pmismatch, total, saturated);
  printf("ub_ahd_encode_iz_packed_n (%s; 8..24 texels, %d calls of 16 or more): %d of %d "
         "texels differ from ub_ahd_encode_iz + ub_ahd_pack\n",
         (ub_cpu_features_cached() & UB_CPU_AVX512) ? "AVX-512 path" : "no AVX-512 path",
         paired, nmismatch, ntotal);
  ASSERT_TRUE(mismatches == 0);
  ASSERT_TRUE(pmismatch == 0);
  ASSERT_TRUE(nmismatch == 0);
  ASSERT_TRUE(paired > 0);
  ASSERT_TRUE(saturated > 0);
}

/* ub_ahd_pack / ub_ahd_unpack: colours within half rounding (2^-11 relative, 2^-25 ×
 * scale absolute below the normal range), saturated at 65504 × scale, never Inf; the
 * octahedral direction within 1e-4 rad everywhere on the sphere (both hemispheres, the
 * axes, the folds); the decoded irradiance within 2^-10 of the float AHD's. */
static void test_pack_bounds(void)
{
  double worst_col = 0.0, worst_ang = 0.0, worst_e = 0.0;
  static const float axes[][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1},
                                  {0, 0, -1}, {0.70710678f, 0, -0.70710678f},
                                  {0, -0.70710678f, -0.70710678f}};
  for (int round = 0; round < 200000; round++) {
    const float scale = (round & 3) == 3 ? 4.0f : 1.0f;
    ub_ahd a, b;
    if (round < 8)
      memcpy(a.direction, axes[round], sizeof a.direction);
    else
      rnd_dir(a.direction);
    for (int c = 0; c < 3; c++) {
      a.ambient[c] = (float)(pow(10.0, -6.0 + 10.0 * rnd()));
      a.directional[c] = (float)(pow(10.0, -6.0 + 10.0 * rnd()));
    }
    ub_ahd_packed p;
    ub_ahd_pack(&a, 1.0f / scale, &p);
    ub_ahd_unpack(&p, scale, &b);
    for (int c = 0; c < 3; c++) {
      const float *x[2] = {a.ambient, a.directional}, *y[2] = {b.ambient, b.directional};
      for (int k = 0; k < 2; k++) {
        double want = x[k][c] < 65504.0f * scale ? x[k][c] : 65504.0 * scale;
        double err = fabs(y[k][c] - want), tol = ldexp(fabs(want), -11) + ldexp(scale, -25);
        ASSERT_TRUE(isfinite(y[k][c]));
        if (err / tol > worst_col)
          worst_col = err / tol;
      }
    }
    /* the angle as atan2(|a × b|, a · b): acos near 1 would see float roundoff as 6e-4 */
    const float *u = a.direction, *v = b.direction;
    double cx = (double)u[1] * v[2] - (double)u[2] * v[1];
    double cy = (double)u[2] * v[0] - (double)u[0] * v[2];
    double cz = (double)u[0] * v[1] - (double)u[1] * v[0];
    double ang = atan2(sqrt(cx * cx + cy * cy + cz * cz),
                       (double)u[0] * v[0] + (double)u[1] * v[1] + (double)u[2] * v[2]);
    if (ang > worst_ang)
      worst_ang = ang;
    if (a.ambient[0] < 1e3f && a.directional[0] < 1e3f && a.ambient[0] > 1e-3f &&
        a.directional[0] > 1e-3f) {
      float n[3], ea[3], eb[3];
      rnd_dir(n);
      ub_ahd_irradiance(&a, n, ea);
      ub_ahd_irradiance(&b, n, eb);
      double rel = fabs(eb[0] - ea[0]) / (a.ambient[0] + a.directional[0]);
      if (rel > worst_e)
        worst_e = rel;
    }
  }
  printf("ub_ahd_pack: worst colour error %.3f of half rounding, direction %.2e rad, "
         "irradiance %.2e of C_a + C_d\n", worst_col, worst_ang, worst_e);
  ASSERT_TRUE(worst_col <= 1.0);
  ASSERT_TRUE(worst_ang < 1e-4);
  ASSERT_TRUE(worst_e < ldexp(1.0, -10));
  /* a zero direction packs to (0, 0) and unpacks to +z; the largest colour to 65504 */
  ub_ahd z = {{1e9f, 0, 0}, {0, 0, 0}, {0, 0, 0}}, zb;
  ub_ahd_packed zp;
  ub_ahd_pack(&z, 1.0f, &zp);
  ub_ahd_unpack(&zp, 1.0f, &zb);
  ASSERT_TRUE(zp.oct[0] == 0 && zp.oct[1] == 0 && zb.direction[2] == 1.0f);
  ASSERT_TRUE(zb.ambient[0] == 65504.0f);
}

int main(void)
{
  test_encode_iz8_bits();
  test_pack_bounds();
  test_irradiance_quadrature();
  test_edge_cases();
  test_encode_exact_and_bounded();
  TEST_MAIN_END();
}
