/* tests/hard/grazing_case.h — one grazing-light bake and its checks, shared by
 * test_hard_grazing (89.9°), test_hard_grazing_extreme (89.99°) and test_hard_sun_range. */
#ifndef UBAKE_TESTS_HARD_GRAZING_CASE_H
#define UBAKE_TESTS_HARD_GRAZING_CASE_H

#include "hard_util.h"

/* Level grazing (black plane, albedo 0: direct light only), directional light of
 * I W/m² (1000 in the grazing tests) at angle_deg from the normal. Closed form everywhere: E = I·cos(angle).
 * Asserted: every covered texel and every query finite, ≥ 0, within 1% + 1e-4 W/m², never
 * above I·cos·1.01 + 1e-4; nothing clamped, no non-finite value in the .ubk. */
static inline void grazing_case(double angle_deg, double azim_deg, double I)
{
  char gltf[1100], base[64], params[256];
  snprintf(base, sizeof base, "grazing_%g_%g_%g", angle_deg, azim_deg, I);
  for (char *p = base; *p; p++)
    if (*p == '.')
      *p = 'p';
  snprintf(params, sizeof params, "angle=%.17g azim=%.17g sun=%g size=4 n=4", angle_deg,
           azim_deg, I);
  ASSERT_TRUE(hard_genlevel("grazing", base, params, gltf, sizeof gltf));
  ub_bake_options o;
  hard_options(&o, UB_QUALITY_DRAFT, -1, 0.25f);
  ub_bake_stats st;
  ub_runtime *rt = hard_bake(gltf, &o, &st);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return;
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  const double expect = I * cos(angle_deg * M_PI / 180.0);
  const double tol = 1e-4 + 0.01 * expect;
  double worst = 0.0, emin = INFINITY, emax = -INFINITY;
  size_t n = 0, bad = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    hard_texels tx;
    if (!hard_texels_get(rt, a, &tx))
      continue;
    for (size_t i = 0; i < (size_t)tx.w * tx.h; i++) {
      if (tx.coverage[i] != 1)
        continue;
      for (int c = 0; c < 3; c++) {
        double e = tx.e[3 * i + c];
        double err = fabs(e - expect);
        worst = fmax(worst, err);
        emin = fmin(emin, e);
        emax = fmax(emax, e);
        if (!(err <= tol) || !isfinite(e)) {
          if (bad < 3)
            fprintf(stderr, "  texel %zu of atlas %u at (%.3f %.3f %.3f): E = %.6g, expected %.6g\n",
                    i, a, tx.pos[3 * i], tx.pos[3 * i + 1], tx.pos[3 * i + 2], e, expect);
          bad++;
        }
      }
      n++;
    }
    hard_texels_free(&tx);
  }
  /* queries across the plane, including its edges and corners */
  size_t qbad = 0;
  for (int i = 0; i <= 8; i++)
    for (int j = 0; j <= 8; j++) {
      float p[3] = {-2.0f + 0.5f * i, 0.0f, -2.0f + 0.5f * j}, nrm[3] = {0, 1, 0}, rgb[3], d;
      ASSERT_OK(ub_runtime_query_lightmap(rt, p, nrm, rgb, &d));
      if (!(fabs(rgb[1] - expect) <= tol) || !isfinite(rgb[1])) {
        if (qbad < 3)
          fprintf(stderr, "  query (%.2f 0 %.2f): E = %.6g, expected %.6g\n", p[0], p[2], rgb[1],
                  expect);
        qbad++;
      }
    }
  printf("light %g W/m^2 at %.2f deg (azimuth %g): %zu texels, E in [%.6g, %.6g], closed form %.6g, "
         "worst |error| %.3g (%.3f%%), clamped %llu (report %lld), non-finite in .ubk %llu\n",
         I, angle_deg, azim_deg, n, emin, emax, expect, worst, 100.0 * worst / expect,
         (unsigned long long)st.clamped_values, hard_report_clamped(st.ubk_path),
         (unsigned long long)hard_nonfinite(bf));
  ASSERT_TRUE(n > 0);
  ASSERT_TRUE(bad == 0);
  ASSERT_TRUE(qbad == 0);
  ASSERT_TRUE(emin >= 0.0);
  ASSERT_TRUE(emax <= expect * 1.01 + 1e-4);
  ASSERT_TRUE(hard_nonfinite(bf) == 0);
  ASSERT_TRUE(st.clamped_values == 0);
  ub_runtime_free(rt);
}

#endif
