/* Hard case found by test_hard_tjunction: lightmap queries between texels under a uniform
 * sky. Level sky_plane (black 20×20 m plane, sky L = (0.5, 0.7, 1.0)), baked as test_bake
 * does (fast, texel 0.5 m) and at draft. Closed form everywhere: E = π·L.
 * Asserted: every covered texel within 1% of π·L (it is: 0.0x%), and every lightmap query
 * on a grid across the plane within 2% of π·L.
 *
 * KNOWN FAILURE (run-time + baker, see tests/hard/README.md): queries are up to 18% (fast)
 * and 37% (draft) off although every texel is exact along its normal. (1) The run-time
 * filters the AHD parameters (ambient, direction, directional) bilinearly
 * (runtime/runtime.c sample_ahd); AHD is non-linear, so the blend of four texels that are
 * each exact along n is not exact along n when their directions differ. (2) They differ
 * because the baker's SH L1 estimate has unbounded variance in its tangential components
 * (bake/pass.c gather_block: Y(w)·L/(N·pdf) with the cosine pdf, so ~tanθ per ray). */
#include "hard_util.h"

static void filter_case(ub_quality q, float texel, double tol)
{
  char gltf[1100];
  snprintf(gltf, sizeof gltf, "%s/levels/sky_plane.gltf", hard_build);
  ub_bake_options o;
  hard_options(&o, q, -1, texel);
  ub_bake_stats st;
  ub_runtime *rt = hard_bake(gltf, &o, &st);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    return;
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  const double expect = M_PI * 0.7; /* green */
  double tworst = 0.0, qworst = 0.0, qsum = 0.0;
  size_t tn = 0, qn = 0, qoff = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    hard_texels tx;
    if (!hard_texels_get(rt, a, &tx))
      continue;
    for (size_t i = 0; i < (size_t)tx.w * tx.h; i++)
      if (tx.coverage[i] == 1) {
        tworst = fmax(tworst, fabs(tx.e[3 * i + 1] - expect) / expect);
        tn++;
      }
    hard_texels_free(&tx);
  }
  float wx = 0, wz = 0, we = 0;
  for (float x = -9.3f; x < 9.5f; x += 0.171f)
    for (float z = -9.3f; z < 9.5f; z += 0.237f) {
      float p[3] = {x, 0, z}, n[3] = {0, 1, 0}, rgb[3], d;
      ASSERT_OK(ub_runtime_query_lightmap(rt, p, n, rgb, &d));
      double dev = fabs(rgb[1] - expect) / expect;
      if (dev > qworst)
        qworst = dev, wx = x, wz = z, we = rgb[1];
      qsum += dev;
      qoff += dev > tol;
      qn++;
    }
  printf("query filter (%s, texel %.2f m): %zu texels, worst %.3f%% off pi*L; %zu queries, mean "
         "|error| %.3f%%, worst %.3f%% (E = %.4f at %.2f, %.2f, closed form %.4f), %zu beyond "
         "%.0f%%\n",
         ub_quality_name(q), texel, tn, 100 * tworst, qn, 100 * qsum / qn, 100 * qworst, we, wx,
         wz, expect, qoff, 100 * tol);
  ASSERT_TRUE(tworst < 0.01);
  ASSERT_TRUE(qoff == 0);
  ub_runtime_free(rt);
}

int main(void)
{
  hard_init("query_filter");
  filter_case(UB_QUALITY_FAST, 0.5f, 0.02);
  filter_case(UB_QUALITY_DRAFT, 0.5f, 0.02);
  TEST_MAIN_END();
}
