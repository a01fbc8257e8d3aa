/* Run-time lightmap queries under show/hide state (issue 6), on levels/inn at draft:
 * - a point on a shown object's surface is answered by that surface;
 * - hidden, the object's surface no longer answers: ub_runtime_query_lightmap takes the
 *   closest SHOWN surface, ub_runtime_query_lightmap_ex says a hidden one was closer and
 *   names its element, ub_runtime_lightmap_at refuses the hidden triangle;
 * - on the floor under a hidden barrel the query equals the floor's own lightmap (the
 *   analytic answer: the same triangle, the same bilinear sample) and matches `reference`
 *   with the barrel removed within 3 s.e. + 5% (the objects tests' tolerance);
 * - showing the object again gives back the first answer bit for bit. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bake/geomstate.h"
#include "bake/lights.h"
#include "bake/reference.h"
#include "bake/rt.h"
#include "test_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/runtime.h"
#include "ubake/scene.h"

/* The up-facing floor (y = 0) triangle under p and p's barycentrics on it; -1 if none. */
static int64_t floor_triangle(const ub_bakefile *f, const float p[3], float *b1, float *b2)
{
  for (uint32_t t = 0; t < f->triangle_count; t++) {
    if (f->tri_atlas[t] < 0 || (f->tri_role && f->tri_role[t]))
      continue;
    const float *a = f->positions + 3 * f->indices[3 * t], *b = f->positions + 3 * f->indices[3 * t + 1];
    const float *c = f->positions + 3 * f->indices[3 * t + 2];
    if (fabsf(a[1]) > 1e-4f || fabsf(b[1]) > 1e-4f || fabsf(c[1]) > 1e-4f)
      continue;
    double e1x = b[0] - a[0], e1z = b[2] - a[2], e2x = c[0] - a[0], e2z = c[2] - a[2];
    double det = e1x * e2z - e2x * e1z;
    if (!(det < -1e-12)) /* up-facing: counter-clockwise seen from +y */
      continue;
    double px = p[0] - a[0], pz = p[2] - a[2];
    double u = (px * e2z - e2x * pz) / det, v = (e1x * pz - px * e1z) / det;
    if (u < 0 || v < 0 || u + v > 1)
      continue;
    *b1 = (float)u;
    *b2 = (float)v;
    return t;
  }
  return -1;
}

static int role_element(const ub_bakefile *f, uint32_t t)
{
  return f->tri_role && f->tri_role[t] ? (int)(f->tri_role[t] & 0xFFFFFFu) : -1;
}

int main(void)
{
  const char *b = getenv("UB_BUILD");
  char build[512], level[1024], dir[1024];
  snprintf(build, sizeof build, "%s", b ? b : "build");
  snprintf(level, sizeof level, "%s/levels/inn.gltf", build);
  snprintf(dir, sizeof dir, "%s/test_out/runtime_query", build);
  ub_bake_options o;
  ub_bake_options_default(&o);
  o.quality = UB_QUALITY_DRAFT;
  o.out_dir = dir;
  o.texel_size = 0.2f;
  ub_bake_stats st;
  ub_result r = ub_bake_level(level, &o, NULL, &st);
  ASSERT_OK(r);
  ub_runtime *rt = NULL;
  if (r == UB_OK)
    ASSERT_OK(ub_runtime_load(st.ubk_path, NULL, &rt));
  if (!rt)
    TEST_MAIN_END();
  const ub_bakefile *f = ub_runtime_bakefile(rt);
  int32_t barrel = ub_runtime_element_find(rt, UB_ELEMENT_OBJECT, "barrel_1");
  ASSERT_TRUE(barrel >= 0 && f->tri_role != NULL);
  if (barrel < 0 || !f->tri_role)
    TEST_MAIN_END();

  /* 1. On barrel_1's top (x 1.2..1.6, y 1.0, z -1.2..-0.8), shown. */
  const float top[3] = {1.4f, 1.0f, -1.0f}, up[3] = {0, 1, 0};
  float shown_rgb[3], rgb[3];
  ub_runtime_lightmap_hit h;
  ASSERT_OK(ub_runtime_query_lightmap_ex(rt, top, up, shown_rgb, &h));
  printf("barrel_1 shown: triangle %u (element %d) at %.3g m: %g %g %g\n", h.triangle,
         role_element(f, h.triangle), h.distance, shown_rgb[0], shown_rgb[1], shown_rgb[2]);
  ASSERT_TRUE(role_element(f, h.triangle) == barrel && h.distance < 1e-4f && !h.hidden_closer);
  uint32_t top_tri = h.triangle;
  ASSERT_TRUE(shown_rgb[0] > 0.0f && shown_rgb[1] > 0.0f && shown_rgb[2] > 0.0f);

  /* 2. Hidden: another (shown) surface answers, and the query says a hidden one was closer. */
  ASSERT_OK(ub_runtime_set_element(rt, (uint32_t)barrel, 0.0f));
  ASSERT_OK(ub_runtime_update(rt, NULL));
  ASSERT_OK(ub_runtime_query_lightmap_ex(rt, top, up, rgb, &h));
  printf("barrel_1 hidden: triangle %u (element %d) at %.3g m; hidden triangle %u (element %d) "
         "at %.3g m: %g %g %g\n", h.triangle, role_element(f, h.triangle), h.distance,
         h.hidden_triangle, h.hidden_element, h.hidden_distance, rgb[0], rgb[1], rgb[2]);
  ASSERT_TRUE(ub_runtime_triangle_shown(rt, h.triangle));
  ASSERT_TRUE(role_element(f, h.triangle) != barrel);
  ASSERT_TRUE(h.distance > 0.3f); /* barrel_2's top, the nearest shown surface, is 0.57 m off */
  ASSERT_TRUE(h.hidden_closer && h.hidden_element == barrel && h.hidden_distance < 1e-4f);
  ASSERT_TRUE(!ub_runtime_triangle_shown(rt, h.hidden_triangle));
  float d_plain = -1.0f, rgb2[3];
  ASSERT_OK(ub_runtime_query_lightmap(rt, top, up, rgb2, &d_plain));
  ASSERT_TRUE(!memcmp(rgb, rgb2, sizeof rgb) && d_plain == h.distance);
  ASSERT_TRUE(ub_runtime_lightmap_at(rt, top_tri, 0.3f, 0.3f, up, rgb2) == UB_ERR_INVALID_ARGUMENT);

  /* 3. The floor under the hidden barrel (the barrel's bottom face lay on it): the floor's
   * own lightmap, exactly, and the reference with the barrel removed. */
  const float under[3] = {1.4f, 0.0f, -1.0f};
  float fb1 = 0, fb2 = 0, flo[3] = {0, 0, 0};
  int64_t ft = floor_triangle(f, under, &fb1, &fb2);
  ASSERT_TRUE(ft >= 0);
  if (ft >= 0)
    ASSERT_OK(ub_runtime_lightmap_at(rt, (uint32_t)ft, fb1, fb2, up, flo));
  ASSERT_OK(ub_runtime_query_lightmap_ex(rt, under, up, rgb, &h));
  printf("floor under hidden barrel_1: query %g %g %g (triangle %u), floor lightmap %g %g %g "
         "(triangle %lld); hidden surface as close: %d\n", rgb[0], rgb[1], rgb[2], h.triangle,
         flo[0], flo[1], flo[2], (long long)ft, h.hidden_closer);
  ASSERT_TRUE(role_element(f, h.triangle) < 0 && h.distance < 1e-4f);
  for (int c = 0; c < 3; c++)
    ASSERT_NEAR(rgb[c], flo[c], 0, 1e-5);

  ub_scene *scene = NULL;
  ub_rt *tracer = NULL;
  ASSERT_OK(ub_scene_load(level, NULL, &scene));
  if (scene) {
    ub_reference_params rp;
    ub_reference_params_init(&rp);
    memcpy(rp.position, under, sizeof rp.position);
    memcpy(rp.normal, up, sizeof rp.normal);
    rp.spp = 4096;
    rp.seed = 7;
    /* The reference with barrel_1 removed (its geometry masked out), every set at 1. */
    uint8_t shown[64];
    memset(shown, 1, sizeof shown);
    int32_t so = -1;
    for (uint32_t k = 0; k < scene->object_count; k++)
      if (!strcmp(scene->object_names[k], "barrel_1"))
        so = (int32_t)k;
    ASSERT_TRUE(so >= 0 && scene->object_count <= sizeof shown);
    if (so >= 0)
      shown[so] = 0;
    ub_geom_state gs = {NULL, shown};
    uint8_t *mask = ub_geom_mask(scene, &gs);
    ub_emitters *em = NULL;
    float ref[3] = {-1, -1, -1}, se[3] = {0, 0, 0};
    ASSERT_TRUE(mask != NULL);
    if (mask && ub_rt_create(scene, mask, NULL, &tracer) == UB_OK &&
        ub_emitters_build(scene, &em) == UB_OK)
      ASSERT_OK(ub_reference_irradiance(scene, tracer, em, &rp, ref, se, NULL));
    ub_emitters_free(em);
    free(mask);
    printf("reference with barrel_1 removed: %g %g %g (s.e. %g %g %g)\n", ref[0], ref[1], ref[2],
           se[0], se[1], se[2]);
    for (int c = 0; c < 3; c++)
      ASSERT_NEAR(rgb[c], ref[c], 3.0 * se[c], 0.05);
  }

  /* 4. Shown again: the first answer, bit for bit. */
  ASSERT_OK(ub_runtime_set_element(rt, (uint32_t)barrel, 1.0f));
  ASSERT_OK(ub_runtime_update(rt, NULL));
  ASSERT_OK(ub_runtime_query_lightmap_ex(rt, top, up, rgb, &h));
  ASSERT_TRUE(h.triangle == top_tri && !h.hidden_closer && !memcmp(rgb, shown_rgb, sizeof rgb));
  ASSERT_OK(ub_runtime_lightmap_at(rt, top_tri, 0.3f, 0.3f, up, rgb2));

  ub_rt_free(tracer);
  ub_scene_free(scene);
  ub_runtime_free(rt);
  TEST_MAIN_END();
}
