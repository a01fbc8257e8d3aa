/* Hard case: SH L1 of a single very bright direction, through the lightmap path the baker
 * and the run-time use (L1 projection → cosine-lobe correction so the irradiance along the
 * texel normal n is exact, as bake/pass.c does → float storage → AHD encode → decode).
 * A delta of radiant intensity-per-area I from direction w gives E(n') = I·max(0, w·n').
 * L1 cannot hold that shape; asserted for every (w, n, n') on Fibonacci spheres and every
 * I in 1 … 1e30: finite, never negative, never above I (the largest irradiance for any
 * normal), exact along n (1e-4 relative + 1e-6·I absolute: float cancellation), and the
 * same for ub_sh1_irradiance (which clamps at 0).
 * Second pass, as the .ubk stores it (runtime/bakefile.c writes the SH as half floats,
 * clamped to ±65504): finite, never negative, never above I (+0.1%: half rounding); along n
 * within 0.2% of I up to I = 1e5. Beyond the half range (I ≳ 1.3e5) the writer clamps the
 * coefficients (and counts them): the value along n is then printed, not asserted.
 * Third pass, as the run-time stores its AHD (ub_ahd_packed: colours in half of value /
 * ub_ahd_pack_scale(the row's largest value), octahedral direction): for every I up to
 * 1e30 no colour saturates, finite, never negative, never above I (+0.2%), along n within
 * 0.2% of I.
 * The L2 probe path (windowing, negative lobes) is covered by tests/test_sh.c
 * (test_window_delta, test_window_hostile). */
#include <float.h>

#include "hard_util.h"
#include "runtime/half.h"
#include "ubake/ahd.h"

static const double Y0 = 0.282094791773878, Y1 = 0.488602511902920;

static void fib(int i, int n, float out[3])
{
  double z = 1.0 - (2.0 * i + 1.0) / n, r = sqrt(fmax(0.0, 1.0 - z * z));
  double phi = i * M_PI * (3.0 - sqrt(5.0));
  out[0] = (float)(r * cos(phi));
  out[1] = (float)(r * sin(phi));
  out[2] = (float)z;
}

/* bake/pass.c's store step for one channel set: SH from the delta, then the cosine-lobe
 * correction making E_SH(n) = I_z (double), stored as float. */
static void baked_sh(const float w[3], const float n[3], double I, float out_sh[12])
{
  double sh[12] = {0};
  double y[4] = {Y0, Y1 * w[1], Y1 * w[2], Y1 * w[0]};
  for (int k = 0; k < 4; k++)
    for (int c = 0; c < 3; c++)
      sh[k * 3 + c] = I * (c == 1 ? 1.0 : 0.5) * y[k]; /* green brightest: colour matters */
  const double K = M_PI * M_PI * Y0 * Y0 + (2.0 * M_PI / 3.0) * (2.0 * M_PI / 3.0) * Y1 * Y1;
  const double h0 = Y0 * M_PI / K, h1 = Y1 * (2.0 * M_PI / 3.0) / K;
  double wn = (double)w[0] * n[0] + (double)w[1] * n[1] + (double)w[2] * n[2];
  for (int c = 0; c < 3; c++) {
    double e_sh = M_PI * Y0 * sh[c] + (2.0 * M_PI / 3.0) * Y1 *
                                          (sh[3 + c] * n[1] + sh[6 + c] * n[2] + sh[9 + c] * n[0]);
    double iz = (c == 1 ? 1.0 : 0.5) * I * fmax(0.0, wn);
    double delta = iz - e_sh;
    sh[c] += delta * h0;
    sh[3 + c] += delta * h1 * n[1];
    sh[6 + c] += delta * h1 * n[2];
    sh[9 + c] += delta * h1 * n[0];
  }
  for (int i = 0; i < 12; i++)
    out_sh[i] = (float)sh[i];
}

int main(void)
{
  const double scales[] = {1.0, 1e5, 1e10, 1e15, 1e19, 1e20, 1e25, 1e30};
  const int NW = 96, NN = 24, NQ = 200;
  for (int half = 0; half < 3; half++) /* 0: float, 1: stored as half, 2: packed AHD */
  for (size_t si = 0; si < sizeof scales / sizeof scales[0]; si++) {
    double I = scales[si];
    size_t checked = 0, nonfinite = 0, negative = 0, above = 0, along_bad = 0, sh1_bad = 0;
    size_t saturated = 0;
    double worst_along = 0.0, worst_above = 0.0;
    for (int iw = 0; iw < NW; iw++) {
      float w[3];
      fib(iw, NW, w);
      for (int in = 0; in < NN + 3; in++) {
        float n[3];
        if (in < NN)
          fib(in, NN, n);
        else if (in == NN) /* n = w, n = -w, n ⊥ w */
          memcpy(n, w, sizeof n);
        else if (in == NN + 1)
          n[0] = -w[0], n[1] = -w[1], n[2] = -w[2];
        else {
          float t[3] = {w[1] - w[2], w[2] - w[0], w[0] - w[1]};
          float l = sqrtf(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
          n[0] = t[0] / l, n[1] = t[1] / l, n[2] = t[2] / l;
        }
        float sh[12];
        baked_sh(w, n, I, sh);
        if (half == 1)
          for (int k = 0; k < 12; k++) {
            float v = sh[k] > UB_HALF_MAX ? UB_HALF_MAX : (sh[k] < -UB_HALF_MAX ? -UB_HALF_MAX : sh[k]);
            sh[k] = ub_half_to_float(ub_half_from_float(v));
          }
        ub_ahd ahd;
        ub_ahd_encode(sh, n, &ahd);
        double wn = (double)w[0] * n[0] + (double)w[1] * n[1] + (double)w[2] * n[2];
        if (half == 2) { /* the row's largest value: coefficients and I_z along n */
          double mx = I * fmax(0.0, wn);
          for (int k = 0; k < 12; k++)
            mx = fmax(mx, fabs((double)sh[k]));
          const float sc = ub_ahd_pack_scale(mx);
          ub_ahd_packed p;
          ub_ahd_pack(&ahd, 1.0f / sc, &p);
          for (int c = 0; c < 3; c++)
            saturated += p.ambient[c] == 0x7bffu || p.directional[c] == 0x7bffu;
          ub_ahd_unpack(&p, sc, &ahd);
        }
        for (int iq = 0; iq <= NQ; iq++) {
          float q[3], e[3], e1[3];
          if (iq < NQ)
            fib(iq, NQ, q);
          else
            memcpy(q, n, sizeof q);
          ub_ahd_irradiance(&ahd, q, e);
          ub_sh1_irradiance(sh, q, e1);
          for (int c = 0; c < 3; c++) {
            double Ic = (c == 1 ? 1.0 : 0.5) * I;
            checked++;
            nonfinite += !isfinite(e[c]) || !isfinite(e1[c]);
            negative += e[c] < 0.0f || e1[c] < 0.0f;
            double over = (e[c] - Ic) / Ic;
            worst_above = fmax(worst_above, over);
            /* half rounding: 2^-11 of the coefficients; packed: of the colours */
            double slack = half == 2 ? 2e-3 : half ? 1e-3 : 1e-5;
            above += e[c] > Ic * (1.0 + slack);
            sh1_bad += e1[c] > Ic * (1.0 + slack);
            if (iq == NQ) { /* along the stored normal: exact */
              double expect = Ic * fmax(0.0, wn);
              double err = fabs(e[c] - expect);
              worst_along = fmax(worst_along, err / Ic);
              double tol = half ? 2e-3 * Ic : 1e-4 * expect + 1e-6 * Ic;
              if (half == 2) /* colours and direction rounded: 2^-11 of C_a + C_d */
                tol = 2e-3 * Ic;
              if ((!half || I <= 1e5) && !(err <= tol)) {
                if (along_bad < 3)
                  fprintf(stderr, "  I=%g w.n=%.4f ch %d: E(n) = %.9g, exact %.9g\n", I, wn, c,
                          e[c], expect);
                along_bad++;
              }
            }
          }
        }
      }
    }
    printf("SH L1 delta (%s), I = %g: %zu checks; non-finite %zu, negative %zu, above I %zu (worst "
           "%.2e relative), along n worst |error|/I %.2e (%zu beyond tolerance); SH1 decode "
           "above I %zu\n",
           half == 2 ? "packed AHD" : half ? "stored as half" : "float", I, checked, nonfinite,
           negative, above, worst_above, worst_along, along_bad, sh1_bad);
    if (half == 2)
      printf("  packed AHD: %zu colours saturated (want 0)\n", saturated);
    ASSERT_TRUE(saturated == 0);
    ASSERT_TRUE(nonfinite == 0);
    ASSERT_TRUE(negative == 0);
    ASSERT_TRUE(above == 0);
    ASSERT_TRUE(along_bad == 0);
    ASSERT_TRUE(sh1_bad == 0);
    (void)hard_bake;
  }
  TEST_MAIN_END();
}
