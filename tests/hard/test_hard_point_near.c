/* Hard case: a point light 1 mm (and 0.01 mm) above a black plane (level plane_point with
 * h = 0.001 / 1e-5, size 2 m, albedo 0: direct light only).
 * Analytic irradiance E(r) = I·h/(h²+r²)^{3/2} ≤ I/h² (the value right under the light).
 * A texel is a point or area sample of E, so it is far below I/h² unless a sample point
 * sits right under the light. Asserted: every covered texel and every query finite, ≥ 0,
 * ≤ I/h² (analytic maximum); at h = 1 mm the texel under the light > 0 and texels more
 * than 3 texels from the light's foot within the range of E over their footprint (−5%,
 * +1%); no non-finite value in the .ubk. The clamped count of the report is printed.
 * At h = 10 µm the light is below the sample points (they sit one ray epsilon, 1e-5 of the
 * level's extent = 20 µm, above the plane), so the plane receives nothing: only the
 * bounds are asserted there (see tests/hard/README.md). */
#include "hard_util.h"

static void near_case(const char *base, double h, ub_quality q, int strict)
{
  const double I = 10.0;
  const float texel = 0.05f;
  char gltf[1100], params[256];
  snprintf(params, sizeof params, "h=%.17g intensity=%g size=2 n=1", h, I);
  ASSERT_TRUE(hard_genlevel("plane_point", base, params, gltf, sizeof gltf));
  ub_bake_options o;
  hard_options(&o, q, -1, texel);
  ub_bake_stats st;
  ub_runtime *rt = hard_bake(gltf, &o, &st);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return;
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  const double emax_analytic = I / (h * h);
  double emax = 0.0, emin = INFINITY, worst_far = 0.0, e_foot = 0.0;
  size_t n = 0, nonfinite = 0, above = 0, far_bad = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    hard_texels tx;
    if (!hard_texels_get(rt, a, &tx))
      continue;
    for (size_t i = 0; i < (size_t)tx.w * tx.h; i++) {
      if (tx.coverage[i] != 1)
        continue;
      n++;
      const float *p = tx.pos + 3 * i;
      double r = sqrt((double)p[0] * p[0] + (double)p[2] * p[2]);
      for (int c = 0; c < 3; c++) {
        double e = tx.e[3 * i + c];
        nonfinite += !isfinite(e);
        emin = fmin(emin, e);
        emax = fmax(emax, e);
        above += e > emax_analytic;
      }
      double e = tx.e[3 * i + 1];
      if (fabs(p[0]) < 0.5 * texel && fabs(p[2]) < 0.5 * texel)
        e_foot = fmax(e_foot, e);
      if (r > 3.0 * texel && r < 0.9) {
        /* E is monotone in r: a texel (any sample inside its footprint, half diagonal
         * 0.71 texel) lies between E at the footprint's far and near edges. Slack: 5%
         * below (sample points sit a ray epsilon above the plane: height h − ε), 1% above. */
        double lo = I * h / pow(h * h + pow(r + 0.75 * texel, 2), 1.5);
        double hi = I * h / pow(h * h + pow(r - 0.75 * texel, 2), 1.5);
        double rel = e < lo ? (lo - e) / lo : (e > hi ? (e - hi) / hi : 0.0);
        worst_far = fmax(worst_far, rel);
        if (!(e >= 0.95 * lo && e <= 1.01 * hi) && far_bad++ < 3)
          fprintf(stderr, "  texel at r = %.4f: E = %.6g, analytic over its footprint [%.6g, %.6g]\n",
                  r, e, lo, hi);
      }
    }
    hard_texels_free(&tx);
  }
  /* queries at the foot of the light and around it */
  double qmax = 0.0;
  size_t qbad = 0;
  for (int i = -4; i <= 4; i++)
    for (int j = -4; j <= 4; j++) {
      float p[3] = {0.0125f * i, 0.0f, 0.0125f * j}, nrm[3] = {0, 1, 0}, rgb[3], d;
      ASSERT_OK(ub_runtime_query_lightmap(rt, p, nrm, rgb, &d));
      for (int c = 0; c < 3; c++) {
        qmax = fmax(qmax, rgb[c]);
        qbad += !isfinite(rgb[c]) || rgb[c] < 0.0f || rgb[c] > emax_analytic;
      }
    }
  printf("point light at h = %g m (%s): %zu texels, E in [%.4g, %.4g], texel at the foot %.4g, "
         "query max %.4g, analytic max I/h^2 = %.4g; texels beyond 3 texels: worst %.2f%% outside their footprint range; "
         "clamped %llu (report.json clamped_values %lld); non-finite in .ubk %llu\n",
         h, ub_quality_name(q), n, emin, emax, e_foot, qmax, emax_analytic, 100 * worst_far,
         (unsigned long long)st.clamped_values, hard_report_clamped(st.ubk_path),
         (unsigned long long)hard_nonfinite(bf));
  ASSERT_TRUE(n > 0);
  ASSERT_TRUE(nonfinite == 0);
  ASSERT_TRUE(emin >= 0.0);
  ASSERT_TRUE(above == 0);
  if (strict) {
    ASSERT_TRUE(e_foot > 0.0);
    ASSERT_TRUE(far_bad == 0);
  }
  ASSERT_TRUE(qbad == 0);
  ASSERT_TRUE(hard_nonfinite(bf) == 0);
  ub_runtime_free(rt);
}

int main(void)
{
  hard_init("point_near");
  near_case("point_1mm_draft", 1e-3, UB_QUALITY_DRAFT, 1);
  near_case("point_1mm_fast", 1e-3, UB_QUALITY_FAST, 1);
  near_case("point_10um", 1e-5, UB_QUALITY_DRAFT, 0);
  TEST_MAIN_END();
}
