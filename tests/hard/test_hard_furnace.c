/* Hard case: a furnace that (almost) never loses energy. Level furnace (closed 2 m cube,
 * inward faces, one quad per face, Le = 1 everywhere) with rho = 1.0 (the loader clamps
 * albedo to 0.999) and rho = 0.999.
 * Closed form after N bounces: E_N = π·Le·Σ_{k=0..N} ρ^k (ρ = 0.999 as loaded), which is
 * below π·Le·(N+1) and, for N = ∞, π·Le/(1−ρ) = 1000π.
 * Asserted: the loaded albedo is 0.999 for rho = 1; the default auto-stop (bounces = -1)
 * terminates with N ≤ 64 (UB_BAKE_MAX_BOUNCES); every texel finite, ≥ 0 and within 2% of
 * E_N for the N reached (E_N is the analytic maximum; texels scatter ~±0.8% from the
 * emitter sampling of bounce 0 at fast quality, more than π·Le·(N+1) − E_N for small N, so that bound is
 * asserted on the mean); rho = 1 and 0.999 give the same result; a fixed N = 8 gives E_8. */
#include "hard_util.h"

static double closed_form(double rho, unsigned n)
{
  double s = 0.0;
  for (unsigned k = 0; k <= n; k++)
    s += pow(rho, k);
  return M_PI * s;
}

static double furnace_case(const char *base, const char *params, int bounces)
{
  char gltf[1100];
  ASSERT_TRUE(hard_genlevel("furnace", base, params, gltf, sizeof gltf));
  ub_scene *scene = NULL;
  ASSERT_OK(ub_scene_load(gltf, NULL, &scene));
  double rho = scene ? scene->materials[0].albedo[0] : 0.0;
  printf("  %s: loaded albedo %.6f\n", base, rho);
  ASSERT_NEAR(rho, 0.999, 1e-6, 0.0);
  ub_scene_free(scene);
  ub_bake_options o;
  hard_options(&o, UB_QUALITY_FAST, bounces, 0.25f);
  ub_bake_stats st;
  ub_runtime *rt = hard_bake(gltf, &o, &st);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return -1.0;
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  unsigned N = st.bounces;
  double expect = closed_form(rho, N), bound = M_PI * (N + 1);
  double sum = 0.0, emin = INFINITY, emax = -INFINITY;
  size_t n = 0, bad = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    for (uint32_t y = 0; y < at->height; y++)
      for (uint32_t x = 0; x < at->width; x++) {
        size_t i = (size_t)y * at->width + x;
        if (at->coverage[i] != 1)
          continue;
        float rgb[3], nn[3];
        ub_runtime_texel_normal(rt, a, x, y, nn);
        ub_runtime_texel_irradiance(rt, a, x, y, nn, rgb);
        for (int c = 0; c < 3; c++)
          bad += !isfinite(rgb[c]) || rgb[c] < 0.0f || !(fabs(rgb[c] - expect) <= 0.02 * expect);
        sum += rgb[1];
        emin = fmin(emin, rgb[1]);
        emax = fmax(emax, rgb[1]);
        n++;
      }
  }
  double mean = n ? sum / n : 0.0;
  printf("furnace %s (bounces %d): N = %u bounces baked, %zu texels, E in [%.4f, %.4f], mean "
         "%.4f, closed form E_N %.4f (%.3f%%), bound pi(N+1) = %.2f, E_inf = %.1f; bounce energy "
         "last/first %.4f; clamped %llu; %zu texels beyond 2%%\n",
         base, bounces, N, n, emin, emax, mean, expect, 100 * (mean - expect) / expect, bound,
         M_PI / (1 - rho), st.bounce_energy[0] > 0 ? st.bounce_energy[N] / st.bounce_energy[0] : 0,
         (unsigned long long)st.clamped_values, bad);
  ASSERT_TRUE(N <= UB_BAKE_MAX_BOUNCES);
  if (bounces >= 0)
    ASSERT_TRUE(N == (unsigned)bounces);
  /* Auto-stop at ρ = 0.999 cannot converge within the cap: the bake says so, and its tail
   * estimate matches the closed form's missing part E_∞ − E_N within 10%. */
  if (bounces < 0) {
    double missing = (M_PI / (1 - rho) - expect) / expect;
    printf("  bounce cap reached: missing %.4g (estimated) vs %.4g (closed form)\n",
           st.bounce_cap_tail, missing);
    ASSERT_TRUE(N == UB_BAKE_MAX_BOUNCES);
    ASSERT_NEAR(st.bounce_cap_tail, missing, 0.0, 0.1);
  } else {
    ASSERT_TRUE(st.bounce_cap_tail == 0.0);
  }
  ASSERT_TRUE(n > 0 && bad == 0);
  ASSERT_NEAR(mean, expect, 0.0, 0.02);
  ASSERT_TRUE(mean <= bound);
  ASSERT_TRUE(hard_nonfinite(bf) == 0);
  ub_runtime_free(rt);
  return mean;
}

int main(void)
{
  hard_init("furnace");
  double e1 = furnace_case("furnace_rho1", "rho=1 n=1", -1);
  double e2 = furnace_case("furnace_rho0999", "rho=0.999 n=1", -1);
  printf("furnace: rho=1 (clamped) mean %.6f, rho=0.999 mean %.6f\n", e1, e2);
  ASSERT_NEAR(e1, e2, 0.0, 1e-6);
  furnace_case("furnace_rho1_b8", "rho=1 n=1", 8);
  TEST_MAIN_END();
}
