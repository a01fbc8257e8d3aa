/* Hard case: light filtered under a closed door or a wall standing on the floor (issue 5's
 * base leak). A floor texel next to the sunroom's closed 5 cm leaf spans both sides; plain
 * bilinear filtering blended the lit texel beyond the leaf into the room's floor: 1.57 W/m²
 * 5 cm inside the leaf (0.003 in the room, 4.9 outside). The baker now stores texel links
 * (lightmaps/layout.c texel_links, runtime/texel_links.h): neighbours whose lifted sample
 * points are separated by geometry are not blended, by the run-time or by the baker's own
 * lightmap reads.
 * Asserted, draft quality:
 * - sunroom, door closed (sealed room): floor points 1, 2, 5, 10, 15 cm inside the leaf at
 *   x = -0.4, 0, 0.4 read < 1% of the sunlit ground outside (0, 0, 4);
 * - sunroom, outside the leaf: ground at z = 2.65 and 2.8 (the doorway's recess and past
 *   it) not below 0.9x the reference - 3 s.e.;
 * - door_rooms, door closed (lamp in room A, reference 0 in room B): room B's floor 15,
 *   25 and 35 cm from the shared wall's centre, across the door (z = -0.3, 0, 0.3) and
 *   beside it (z = 1.2), reads < 2% of room A's floor at the mirrored point (was 43% at
 *   (0.15, 0, 1.2); now 0.45-0.99%).
 * Printed, not asserted: door_rooms 5 cm from the wall's centre (2.5 cm from its face),
 *   inside a texel centred under the wall whose samples lie in room A (97% of room A):
 *   that texel can only hold one side's light (needs a chart seam, or texels no wider than
 *   the wall). It is also where room B's residual ~1% comes from: the bake's gather rays
 *   from room B's wall base read it. */
#include "bake/reference.h"
#include "bake/lights.h"
#include "bake/rt.h"
#include "hard_util.h"

static double query(ub_runtime *rt, float x, float y, float z)
{
  float p[3] = {x, y, z}, n[3] = {0, 1, 0}, e[3], d;
  ASSERT_OK(ub_runtime_query_lightmap(rt, p, n, e, &d));
  return e[1];
}

int main(void)
{
  hard_init("door_leak");
  char gltf[1100];
  ub_bake_options o;
  ub_bake_stats st;

  /* 1. sunroom: the closed leaf's inner face at z = 2.5 */
  ASSERT_TRUE(hard_genlevel("sunroom", "sunroom", "", gltf, sizeof gltf));
  hard_options(&o, UB_QUALITY_DRAFT, 4, 0.0f);
  ub_runtime *rt = hard_bake(gltf, &o, &st);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    TEST_MAIN_END();
  double out = query(rt, 0.0f, 0.0f, 4.0f);
  printf("sunroom: outside ground (0, 0, 4) %.4g W/m^2\n", out);
  ASSERT_TRUE(out > 1.0);
  const float xs[3] = {-0.4f, 0.0f, 0.4f}, ds[5] = {0.01f, 0.02f, 0.05f, 0.10f, 0.15f};
  double worst = 0.0;
  for (int i = 0; i < 3; i++)
    for (int k = 0; k < 5; k++) {
      double e = query(rt, xs[i], 0.0f, 2.5f - ds[k]);
      ASSERT_TRUE(isfinite(e) && e >= 0.0);
      if (!(e < 0.01 * out))
        fprintf(stderr, "  leak at (%.2f, 0, %.2f): %.4g W/m^2 (%.3g of outside)\n", xs[i],
                2.5f - ds[k], e, e / out);
      ASSERT_TRUE(e < 0.01 * out);
      worst = fmax(worst, e / out);
    }
  printf("sunroom: 15 floor points 1-15 cm inside the closed leaf: worst %.3e of outside\n", worst);
  hard_ref hr;
  ASSERT_TRUE(hard_ref_open(gltf, &hr));
  const float zo[3] = {2.56f, 2.65f, 2.8f};
  for (int k = 0; hr.em && k < 3; k++) {
    float p[3] = {0.0f, 0.01f, zo[k]}, n[3] = {0, 1, 0}, ref[3], se[3];
    ASSERT_TRUE(hard_ref_irradiance(&hr, p, n, 4096, 51 + (uint32_t)k, ref, se));
    double e = query(rt, 0.0f, 0.0f, zo[k]);
    printf("sunroom: ground outside the leaf (0, 0, %.2f): bake %.4g, reference %.4g +- %.2g "
           "(%+.1f%%)%s\n", zo[k], e, ref[1], se[1], 100.0 * (e - ref[1]) / ref[1],
           k == 0 ? " (not asserted: 1 cm behind the leaf, a texel straddling it)" : "");
    if (k > 0)
      ASSERT_TRUE(e > 0.9 * ref[1] - 3.0 * se[1]);
  }
  hard_ref_close(&hr);
  ub_runtime_free(rt);

  /* 2. door_rooms: the shared wall and closed leaf centred on x = 0, 5 cm thick */
  ASSERT_TRUE(hard_genlevel("door_rooms", "door_rooms", "", gltf, sizeof gltf));
  hard_options(&o, UB_QUALITY_DRAFT, 4, 0.0f);
  rt = hard_bake(gltf, &o, &st);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    TEST_MAIN_END();
  const float zs[4] = {-0.3f, 0.0f, 0.3f, 1.2f}, xb[4] = {0.05f, 0.15f, 0.25f, 0.35f};
  worst = 0.0;
  for (int i = 0; i < 4; i++)
    for (int k = 0; k < 4; k++) {
      double b = query(rt, xb[k], 0.0f, zs[i]), a = query(rt, -xb[k], 0.0f, zs[i]);
      ASSERT_TRUE(isfinite(b) && b >= 0.0 && a > 0.0);
      if (getenv("UB_VERBOSE"))
        printf("  room B (%.2f, 0, %.2f) %.4g, room A %.4g (%.3g)\n", xb[k], zs[i], b, a, b / a);
      if (k == 0) {
        if (k == 0)
          printf("door_rooms: room B (%.2f, 0, %.2f) %.4g vs room A %.4g (%.3g; not asserted)\n",
                 xb[k], zs[i], b, a, b / a);
        continue;
      }
      if (!(b < 0.02 * a))
        fprintf(stderr, "  leak at (%.2f, 0, %.2f): %.4g W/m^2, room A %.4g\n", xb[k], zs[i], b, a);
      ASSERT_TRUE(b < 0.02 * a);
      worst = fmax(worst, b / a);
    }
  printf("door_rooms: room B floor 15-35 cm from the shared wall: worst %.3e of room A\n",
         worst);
  ub_runtime_free(rt);
  TEST_MAIN_END();
}
