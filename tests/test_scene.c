/* tests/test_scene.c — the glTF loader (bake/gltf_load.cpp, bake/scene.c).
 *
 * Hand-written levels in tests/data/ (hierarchy, tags, textures), a .glb written here,
 * bad inputs in tests/data/bad/ (each must fail with the right code, one log line naming
 * the file, *out_scene untouched), and the real OpenArena levels (counts, lights, finite
 * data, bounds, load time) when they are present.
 */
#include "ubake/scene.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "test_util.h"

/* ---- log capture ---- */
typedef struct capture {
  int errors, warnings;
  char error[1024];
  char warn_all[8192];
} capture;

static void capture_fn(void *user, ub_log_level level, const char *msg)
{
  capture *c = user;
  if (level == UB_LOG_ERROR) {
    c->errors++;
    snprintf(c->error, sizeof c->error, "%s", msg);
  } else if (level == UB_LOG_WARNING) {
    c->warnings++;
    size_t n = strlen(c->warn_all);
    snprintf(c->warn_all + n, sizeof c->warn_all - n, "%s\n", msg);
  }
}

static ub_scene *load_ok(const char *path, capture *cap)
{
  memset(cap, 0, sizeof *cap);
  ub_log log = {capture_fn, cap};
  ub_scene *s = NULL;
  ub_result r = ub_scene_load(path, &log, &s);
  if (r != UB_OK)
    fprintf(stderr, "loading %s: %s: %s\n", path, ub_result_string(r), cap->error);
  ASSERT_TRUE(r == UB_OK);
  ASSERT_TRUE(cap->errors == 0);
  return r == UB_OK ? s : NULL;
}

static char g_data[2048];

static const char *data_path(const char *name)
{
  static char buf[8][4096];
  static int slot;
  char *p = buf[slot++ % 8];
  snprintf(p, 4096, "%s/%.2000s", g_data, name);
  return p;
}

static void find_data_dir(void)
{
  const char *src = getenv("UB_SOURCE");
  if (src && *src) {
    snprintf(g_data, sizeof g_data, "%s/tests/data", src);
    return;
  }
  /* CMake compiles with an absolute __FILE__ */
  snprintf(g_data, sizeof g_data, "%s", __FILE__);
  char *slash = strrchr(g_data, '/');
  if (slash)
    snprintf(slash, sizeof g_data - (size_t)(slash - g_data), "/data");
  else
    snprintf(g_data, sizeof g_data, "tests/data");
}

static double now_s(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void geometric_normal(const ub_scene *s, uint32_t t, double g[3])
{
  const float *a = s->positions + 3 * (size_t)s->indices[3 * (size_t)t];
  const float *b = s->positions + 3 * (size_t)s->indices[3 * (size_t)t + 1];
  const float *c = s->positions + 3 * (size_t)s->indices[3 * (size_t)t + 2];
  double e1[3], e2[3];
  for (int i = 0; i < 3; i++) {
    e1[i] = (double)b[i] - a[i];
    e2[i] = (double)c[i] - a[i];
  }
  g[0] = e1[1] * e2[2] - e1[2] * e2[1];
  g[1] = e1[2] * e2[0] - e1[0] * e2[2];
  g[2] = e1[0] * e2[1] - e1[1] * e2[0];
}

/* Invariants every loaded scene must satisfy; returns how many triangles have a
 * geometric normal disagreeing with their first vertex normal. */
static uint32_t check_invariants(const ub_scene *s)
{
  ASSERT_TRUE(s->path != NULL);
  ASSERT_TRUE(s->triangle_count > 0 && s->vertex_count > 0);
  ASSERT_TRUE(s->degenerate_count < s->triangle_count);
  int bad_pos = 0, bad_nrm = 0, bad_uv = 0, outside = 0;
  for (uint32_t v = 0; v < s->vertex_count; v++) {
    const float *p = s->positions + 3 * (size_t)v, *n = s->normals + 3 * (size_t)v;
    const float *uv = s->uv1 + 2 * (size_t)v;
    for (int i = 0; i < 3; i++)
      if (!isfinite(p[i]) || !isfinite(n[i]))
        bad_pos++;
    double l = sqrt((double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2]);
    if (fabs(l - 1.0) > 1e-4)
      bad_nrm++;
    if (!(uv[0] >= 0 && uv[0] <= 1 && uv[1] >= 0 && uv[1] <= 1))
      bad_uv++;
  }
  ASSERT_TRUE(bad_pos == 0);
  ASSERT_TRUE(bad_nrm == 0);
  ASSERT_TRUE(bad_uv == 0);
  uint32_t degenerate = 0, disagree = 0;
  int bad_ref = 0;
  for (uint32_t t = 0; t < s->triangle_count; t++) {
    for (int k = 0; k < 3; k++) {
      uint32_t i = s->indices[3 * (size_t)t + (size_t)k];
      if (i >= s->vertex_count) {
        bad_ref++;
        continue;
      }
      for (int r = 0; r < 3; r++) {
        float x = s->positions[3 * (size_t)i + (size_t)r];
        if (x < s->bounds_min[r] || x > s->bounds_max[r])
          outside++;
      }
    }
    if (s->tri_material[t] >= s->material_count || s->tri_node[t] >= s->node_count)
      bad_ref++;
    if (s->tri_flags[t] & UB_TRI_DEGENERATE) {
      degenerate++;
      continue;
    }
    double g[3];
    geometric_normal(s, t, g);
    const float *n = s->normals + 3 * (size_t)s->indices[3 * (size_t)t];
    if (g[0] * n[0] + g[1] * n[1] + g[2] * n[2] <= 0.0)
      disagree++;
  }
  ASSERT_TRUE(bad_ref == 0);
  ASSERT_TRUE(outside == 0);
  ASSERT_TRUE(degenerate == s->degenerate_count);
  /* bounds are tight: some vertex touches each face of the box */
  for (int r = 0; r < 3; r++) {
    int lo = 0, hi = 0;
    for (uint32_t t = 0; t < s->triangle_count; t++)
      for (int k = 0; k < 3; k++) {
        float x = s->positions[3 * (size_t)s->indices[3 * (size_t)t + (size_t)k] + (size_t)r];
        lo |= x == s->bounds_min[r];
        hi |= x == s->bounds_max[r];
      }
    ASSERT_TRUE(lo && hi);
  }
  /* nodes partition the triangles in order */
  uint32_t next = 0;
  for (uint32_t n = 0; n < s->node_count; n++) {
    const ub_node *nd = &s->nodes[n];
    ASSERT_TRUE(nd->name != NULL);
    ASSERT_TRUE(nd->first_triangle == next);
    next += nd->triangle_count;
    for (uint32_t t = nd->first_triangle; t < nd->first_triangle + nd->triangle_count; t++)
      if (s->tri_node[t] != n)
        bad_ref++;
    ASSERT_TRUE(nd->door < (int32_t)s->door_count && nd->door_open < (int32_t)s->door_count &&
                nd->semidynamic < (int32_t)s->object_count);
    ASSERT_TRUE(nd->texel_size >= 0.0f && isfinite(nd->texel_size));
  }
  ASSERT_TRUE(next == s->triangle_count);
  ASSERT_TRUE(bad_ref == 0);
  for (uint32_t m = 0; m < s->material_count; m++) {
    const ub_material *mt = &s->materials[m];
    ASSERT_TRUE(mt->name != NULL);
    for (int c = 0; c < 3; c++) {
      ASSERT_TRUE(mt->albedo[c] >= 0.0f && mt->albedo[c] <= 0.999f);
      ASSERT_TRUE(mt->emission[c] >= 0.0f && isfinite(mt->emission[c]));
    }
  }
  for (uint32_t l = 0; l < s->light_count; l++) {
    const ub_light *L = &s->lights[l];
    double dl = 0;
    for (int c = 0; c < 3; c++) {
      ASSERT_TRUE(isfinite(L->position[c]) && isfinite(L->direction[c]));
      ASSERT_TRUE(isfinite(L->intensity[c]) && L->intensity[c] >= 0.0f);
      dl += (double)L->direction[c] * L->direction[c];
    }
    ASSERT_NEAR(dl, 1.0, 1e-5, 0);
    ASSERT_TRUE(L->node >= 0 && (uint32_t)L->node < s->node_count);
    ASSERT_TRUE(L->dls >= -1 && L->dls < (int32_t)s->dls_count);
    ASSERT_TRUE(L->cos_outer <= L->cos_inner);
    ASSERT_TRUE(L->range >= 0.0f);
  }
  ASSERT_TRUE(s->texel_size > 0.0f && s->glg_spacing > 0.0f);
  ASSERT_TRUE(ub_scene_extent(s) > 0.0f);
  ASSERT_TRUE(ub_scene_area(s) > 0.0);
  return disagree;
}

static int count_lights(const ub_scene *s, ub_light_type type)
{
  int n = 0;
  for (uint32_t l = 0; l < s->light_count; l++)
    n += s->lights[l].type == type;
  return n;
}

static int count_emissive(const ub_scene *s)
{
  int n = 0;
  for (uint32_t m = 0; m < s->material_count; m++)
    n += s->materials[m].emission[0] + s->materials[m].emission[1] +
             s->materials[m].emission[2] > 0.0f;
  return n;
}

static uint32_t count_uv1(const ub_scene *s)
{
  uint32_t n = 0;
  for (uint32_t t = 0; t < s->triangle_count; t++)
    n += (s->tri_flags[t] & UB_TRI_HAS_UV1) != 0;
  return n;
}

/* ---- real levels ---- */
static void test_real_levels(void)
{
  const char *dir = getenv("UB_REAL_LEVELS");
  if (!dir || !*dir)
    dir = "/work/shared/levels/real";
  char path[4096];
  snprintf(path, sizeof path, "%s/kaos/kaos.gltf", dir);
  if (access(path, R_OK) != 0) {
    printf("real levels not found in %s (set UB_REAL_LEVELS): skipped\n", dir);
    return;
  }
  struct {
    const char *name;
    uint32_t triangles, uv1, points, directional, emissive, disagree;
  } lv[] = {
      /* counts from levels/real/README.md and the files themselves; oa_dm4 has two
       * 2 m × 1 mm slivers (triangles 1221, 1310) lying flat in y = -6 while their
       * vertex normals say "wall": not degenerate by area, but their geometric normal is
       * perpendicular to the authored one */
      {"oa_dm4/oa_dm4.gltf", 4089, 4080, 0, 1, 3, 2},
      {"q3dm6ish/q3dm6ish.gltf", 2505, 2505, 30, 1, 0, 0},
      {"kaos/kaos.gltf", 46798, 46798, 30, 1, 7, 0},
  };
  for (size_t i = 0; i < sizeof lv / sizeof lv[0]; i++) {
    snprintf(path, sizeof path, "%s/%s", dir, lv[i].name);
    capture cap;
    double t0 = now_s();
    ub_scene *s = load_ok(path, &cap);
    double dt = now_s() - t0;
    printf("%s: %u triangles, %u degenerate, %u lights, %.3f s\n", lv[i].name,
           s ? s->triangle_count : 0, s ? s->degenerate_count : 0, s ? s->light_count : 0, dt);
    if (!s)
      continue;
    ASSERT_TRUE(cap.warnings == 0); /* q3_* extras are ignored silently */
    ASSERT_TRUE(s->triangle_count == lv[i].triangles);
    ASSERT_TRUE(count_uv1(s) == lv[i].uv1);
    ASSERT_TRUE(s->degenerate_count == 0); /* the converter dropped them */
    ASSERT_TRUE(s->skipped_primitives == 0);
    ASSERT_TRUE(count_lights(s, UB_LIGHT_POINT) == (int)lv[i].points);
    ASSERT_TRUE(count_lights(s, UB_LIGHT_DIRECTIONAL) == (int)lv[i].directional);
    ASSERT_TRUE(s->light_count == lv[i].points + lv[i].directional);
    ASSERT_TRUE(count_emissive(s) == (int)lv[i].emissive);
    ASSERT_TRUE(!s->has_sky);
    ASSERT_TRUE(s->door_count == 0 && s->dls_count == 0 && s->object_count == 0);
    ASSERT_NEAR(s->texel_size, 0.25, 0, 0);
    ASSERT_NEAR(s->glg_spacing, 2.0, 0, 0);
    ASSERT_TRUE(check_invariants(s) == lv[i].disagree); /* normals agree with winding */
    /* the load time is printed, not asserted: tests make no timed assertions (bench_bake
     * reports the loader's seconds) */
    for (uint32_t l = 0; l < s->light_count; l++)
      if (s->lights[l].type == UB_LIGHT_DIRECTIONAL) /* the sun shines straight down */
        ASSERT_NEAR(s->lights[l].direction[1], -1.0, 1e-6, 0);
    if (i == 0) {
      /* extras.avg_albedo_linear of material 0 = [0.0577, 0.0273, 0.0092]: our linear
       * mean of the sRGB texture must agree */
      ASSERT_NEAR(s->materials[0].albedo[0], 0.0577, 0.001, 0.02);
      ASSERT_NEAR(s->materials[0].albedo[1], 0.0273, 0.001, 0.02);
      ASSERT_NEAR(s->materials[0].albedo[2], 0.0092, 0.001, 0.02);
      ASSERT_NEAR(s->bounds_min[0], -8.25, 1e-4, 0);
      ASSERT_NEAR(s->bounds_max[2], 39.0, 1e-4, 0);
      /* sun: color [1, 0.2019, 0.2003] x 32/255 lux */
      ASSERT_NEAR(s->lights[0].intensity[0], 0.12549019607843137, 1e-6, 0);
      ASSERT_NEAR(s->lights[0].intensity[1], 0.2019 * 0.12549019607843137, 1e-6, 0);
      /* skulllight01: emissiveFactor [1, 0.9871, 0.0002] x strength 0.294 */
      ASSERT_NEAR(s->materials[6].emission[0], 0.29411764705882354, 1e-6, 0);
      ASSERT_NEAR(s->materials[6].emission[1], 0.9871 * 0.29411764705882354, 1e-6, 0);
    }
    if (i == 1) {
      /* light_0: 1000 * 7500 * 0.03125^2 / 255 cd at (-5, 18, 0) */
      ASSERT_NEAR(s->lights[0].intensity[0], 28.722426470588236, 1e-4, 0);
      ASSERT_NEAR(s->lights[0].position[1], 18.0, 1e-6, 0);
      ASSERT_TRUE(strcmp(s->nodes[s->lights[0].node].name, "light_0") == 0);
      ASSERT_TRUE(s->nodes[s->lights[0].node].triangle_count == 0);
    }
    if (i == 2) {
      ASSERT_NEAR(s->bounds_max[0] - s->bounds_min[0], 80.0, 1e-3, 0); /* 80 x 43 x 81 m */
      ASSERT_NEAR(s->bounds_max[1] - s->bounds_min[1], 43.0, 1e-3, 0);
      ASSERT_NEAR(s->bounds_max[2] - s->bounds_min[2], 80.75, 1e-3, 0);
      ASSERT_NEAR(ub_scene_extent(s), 80.75, 1e-3, 0);
    }
    ub_scene_free(s);
  }
}

/* ---- hierarchy: TRS, negative scale, matrix, flat normals, other scenes ---- */
static void expect_vertex(const ub_scene *s, uint32_t t, int k, double x, double y, double z)
{
  const float *p = s->positions + 3 * (size_t)s->indices[3 * (size_t)t + (size_t)k];
  ASSERT_NEAR(p[0], x, 1e-5, 0);
  ASSERT_NEAR(p[1], y, 1e-5, 0);
  ASSERT_NEAR(p[2], z, 1e-5, 0);
}

static void test_hierarchy(void)
{
  capture cap;
  ub_scene *s = load_ok(data_path("hierarchy.gltf"), &cap);
  if (!s)
    return;
  ASSERT_TRUE(cap.warnings == 0);
  /* root (T 10,0,0 · R 90° about Y · S 2) → child, mirror; matrix; other_scene excluded */
  ASSERT_TRUE(s->node_count == 3 && s->triangle_count == 3);
  ASSERT_TRUE(strcmp(s->nodes[0].name, "child") == 0 && s->nodes[0].gltf_index == 1);
  ASSERT_TRUE(strcmp(s->nodes[1].name, "mirror") == 0);
  ASSERT_TRUE(strcmp(s->nodes[2].name, "matrix") == 0);
  /* child: local (x, y+1, z) ×2, then (x,y,z) → (z, y, -x), then +10 x */
  expect_vertex(s, 0, 0, 10, 2, 0);
  expect_vertex(s, 0, 1, 10, 2, -2);
  expect_vertex(s, 0, 2, 10, 4, 0);
  const float *n = s->normals + 3 * (size_t)s->indices[0];
  ASSERT_NEAR(n[0], 1.0, 1e-6, 0);
  ASSERT_NEAR(n[2], 0.0, 1e-6, 0);
  /* mirror (scale -1,1,1): the file's order (10,0,0) (10,0,2) (10,2,0) faces -x;
   * the loader flips it so it faces +x like its normal */
  expect_vertex(s, 1, 0, 10, 0, 0);
  expect_vertex(s, 1, 1, 10, 2, 0);
  expect_vertex(s, 1, 2, 10, 0, 2);
  n = s->normals + 3 * (size_t)s->indices[3];
  ASSERT_NEAR(n[0], 1.0, 1e-6, 0);
  double g[3];
  geometric_normal(s, 1, g);
  ASSERT_TRUE(g[0] > 0.0);
  /* matrix node, no NORMAL: flat geometric normal +z, z offset 5 */
  expect_vertex(s, 2, 0, 0, 0, 5);
  n = s->normals + 3 * (size_t)s->indices[6];
  ASSERT_NEAR(n[2], 1.0, 1e-6, 0);
  ASSERT_TRUE(check_invariants(s) == 0);
  ASSERT_NEAR(s->bounds_min[2], -2.0, 0, 0);
  ASSERT_NEAR(s->bounds_max[0], 10.0, 0, 0);
  ASSERT_NEAR(s->bounds_max[2], 5.0, 0, 0);
  ASSERT_NEAR(ub_scene_area(s), 2.0 + 2.0 + 0.5, 1e-6, 0);
  ASSERT_NEAR(ub_scene_extent(s), 10.0, 0, 0);
  /* no material anywhere: one glTF default material */
  ASSERT_TRUE(s->material_count == 1);
  ASSERT_NEAR(s->materials[0].albedo[1], 0.999, 1e-6, 0);
  ub_scene_free(s);
}

/* ---- tags, lights, materials, sky ---- */
static void test_tags(void)
{
  capture cap;
  ub_scene *s = load_ok(data_path("tags.gltf"), &cap);
  if (!s)
    return;
  check_invariants(s);
  /* warnings: ubake_foo (node), ubake_bar (scene), the points primitive; not q3_whatever */
  ASSERT_TRUE(cap.warnings == 3);
  ASSERT_TRUE(strstr(cap.warn_all, "node 0 'floor'") && strstr(cap.warn_all, "ubake_foo"));
  ASSERT_TRUE(strstr(cap.warn_all, "ubake_bar") != NULL);
  ASSERT_TRUE(strstr(cap.warn_all, "mode 0") != NULL);
  ASSERT_TRUE(strstr(cap.warn_all, "q3_whatever") == NULL);
  ASSERT_TRUE(strstr(cap.warn_all, "tags.gltf") != NULL);

  ASSERT_TRUE(s->triangle_count == 4);
  ASSERT_TRUE(s->degenerate_count == 1 && (s->tri_flags[2] & UB_TRI_DEGENERATE));
  ASSERT_TRUE(s->skipped_primitives == 1);
  ASSERT_TRUE(count_uv1(s) == 1 && (s->tri_flags[1] & UB_TRI_HAS_UV1));
  const float *uv = s->uv1 + 2 * (size_t)s->indices[3 + 1];
  ASSERT_NEAR(uv[0], 1.0, 0, 0);

  /* names deduplicated, indices on the nodes */
  ASSERT_TRUE(s->door_count == 1 && strcmp(s->door_names[0], "d1") == 0);
  ASSERT_TRUE(s->object_count == 1 && strcmp(s->object_names[0], "crate") == 0);
  ASSERT_TRUE(s->dls_count == 2 && strcmp(s->dls_names[0], "hall") == 0 &&
              strcmp(s->dls_names[1], "sunset") == 0);
  ASSERT_TRUE(s->node_count == 7);
  const ub_node *floor = &s->nodes[0], *open = &s->nodes[1], *crate = &s->nodes[2];
  ASSERT_TRUE(strcmp(floor->name, "floor") == 0 && floor->receiver == UB_RECEIVER_LLG);
  ASSERT_TRUE(floor->door == 0 && floor->door_open == -1 && floor->semidynamic == -1);
  ASSERT_NEAR(floor->texel_size, 0.0, 0, 0);
  ASSERT_TRUE(open->door == -1 && open->door_open == 0 && open->receiver == UB_RECEIVER_LIGHTMAP);
  ASSERT_NEAR(open->texel_size, 0.1, 1e-7, 0);
  /* crate_part inherits its parent group's tags */
  ASSERT_TRUE(strcmp(crate->name, "crate_part") == 0 && crate->gltf_index == 3);
  ASSERT_TRUE(crate->semidynamic == 0 && crate->receiver == UB_RECEIVER_NONE);
  ASSERT_TRUE(crate->triangle_count == 2);

  /* scene extras win over root extras; root extras fill what the scene lacks */
  ASSERT_TRUE(s->has_sky);
  ASSERT_NEAR(s->sky[0], 0.1, 1e-7, 0);
  ASSERT_NEAR(s->sky[2], 0.3, 1e-7, 0);
  ASSERT_NEAR(s->glg_spacing, 3.0, 0, 0);
  ASSERT_NEAR(s->texel_size, 0.5, 0, 0);

  /* materials: glow (emissive strength 5), plain, dim_glow, appended default */
  ASSERT_TRUE(s->material_count == 4);
  ASSERT_NEAR(s->materials[0].albedo[0], 0.5, 1e-7, 0);
  ASSERT_NEAR(s->materials[0].albedo[1], 0.25, 1e-7, 0);
  ASSERT_NEAR(s->materials[0].albedo[2], 0.999, 1e-7, 0); /* 1.5 clamped */
  ASSERT_NEAR(s->materials[0].emission[0], 5.0, 1e-6, 0);
  ASSERT_NEAR(s->materials[0].emission[1], 2.5, 1e-6, 0);
  ASSERT_NEAR(s->materials[0].emission[2], 1.25, 1e-6, 0);
  ASSERT_NEAR(s->materials[1].emission[0], 0.0, 0, 0);
  ASSERT_NEAR(s->materials[2].emission[1], 0.5, 1e-7, 0); /* default strength 1 */
  ASSERT_TRUE(strcmp(s->materials[3].name, "default") == 0);
  ASSERT_TRUE(s->tri_material[2] == 3 && s->tri_material[3] == 2);

  /* lights */
  ASSERT_TRUE(s->light_count == 4);
  const ub_light *lamp = &s->lights[0], *spot = &s->lights[1], *sun = &s->lights[2],
                 *spot2 = &s->lights[3];
  ASSERT_TRUE(lamp->type == UB_LIGHT_POINT && lamp->cls == UB_LIGHT_PRIMARY && lamp->dls == 0);
  ASSERT_NEAR(lamp->intensity[0], 10.0, 1e-6, 0);
  ASSERT_NEAR(lamp->intensity[1], 5.0, 1e-6, 0);
  ASSERT_NEAR(lamp->intensity[2], 2.5, 1e-6, 0);
  ASSERT_NEAR(lamp->position[0], 1.0, 0, 0);
  ASSERT_NEAR(lamp->position[2], 3.0, 0, 0);
  ASSERT_NEAR(lamp->range, 7.0, 0, 0);
  ASSERT_NEAR(lamp->cos_inner, 1.0, 0, 0);
  ASSERT_NEAR(lamp->cos_outer, -1.0, 0, 0);
  ASSERT_TRUE(strcmp(s->nodes[lamp->node].name, "lamp") == 0);
  ASSERT_TRUE(s->nodes[lamp->node].receiver == UB_RECEIVER_NONE);
  ASSERT_TRUE(spot->type == UB_LIGHT_SPOT && spot->cls == UB_LIGHT_STATIC && spot->dls == 0);
  ASSERT_NEAR(spot->cos_inner, cos(0.2), 1e-6, 0);
  ASSERT_NEAR(spot->cos_outer, cos(0.5), 1e-6, 0);
  ASSERT_NEAR(spot->direction[1], -1.0, 1e-6, 0); /* -Z rotated -90° about X: down */
  ASSERT_NEAR(spot->position[1], 5.0, 0, 0);
  ASSERT_NEAR(spot->intensity[1], 2.0, 0, 0);
  ASSERT_TRUE(sun->type == UB_LIGHT_DIRECTIONAL && sun->dls == 1);
  ASSERT_NEAR(sun->direction[2], -1.0, 1e-7, 0);
  ASSERT_NEAR(sun->intensity[0], 3.0, 0, 0);
  ASSERT_TRUE(spot2->type == UB_LIGHT_SPOT && spot2->dls == -1);
  ASSERT_NEAR(spot2->cos_inner, 1.0, 1e-7, 0);           /* innerConeAngle default 0 */
  ASSERT_NEAR(spot2->cos_outer, cos(M_PI / 4), 1e-6, 0); /* outerConeAngle default π/4 */
  ASSERT_NEAR(spot2->intensity[0], 1.0, 0, 0);
  ub_scene_free(s);
}

/* tags.gltf's text with `from` replaced by `to` (once; NULL when from is not there). */
static char *tags_variant(const char *from, const char *to)
{
  FILE *f = fopen(data_path("tags.gltf"), "rb");
  if (!f)
    return NULL;
  static char text[65536];
  size_t n = fread(text, 1, sizeof text - 1, f);
  fclose(f);
  text[n] = '\0';
  char *at = strstr(text, from);
  if (!at)
    return NULL;
  size_t lf = strlen(from), lt = strlen(to);
  char *out = malloc(n - lf + lt + 1);
  if (!out)
    return NULL;
  memcpy(out, text, (size_t)(at - text));
  memcpy(out + (at - text), to, lt);
  strcpy(out + (at - text) + lt, at + lf);
  return out;
}

/* Loads a tags.gltf variant from memory: the result, its messages in *cap. */
static ub_result load_variant(const char *from, const char *to, capture *cap)
{
  memset(cap, 0, sizeof *cap);
  char *text = tags_variant(from, to);
  ASSERT_TRUE(text != NULL);
  if (!text)
    return UB_ERR_IO;
  ub_log log = {capture_fn, cap};
  ub_scene *s = NULL;
  ub_result r = ub_scene_load_memory(text, strlen(text), "variant.gltf", &log, &s);
  ub_scene_free(s);
  free(text);
  return r;
}

/* Names of sets, doors and objects fit the .ubk's 63 bytes or the load fails naming the
 * node; tags naming what the level lacks warn, naming the node. */
static void test_tag_names(void)
{
  capture cap;
  char name[80], to[128];
  memset(name, 'x', 63);
  name[63] = '\0';
  snprintf(to, sizeof to, "\"ubake_dls\": \"%s\"", name);
  ASSERT_TRUE(load_variant("\"ubake_dls\": \"sunset\"", to, &cap) == UB_OK);
  strcat(name, "y"); /* 64 bytes */
  snprintf(to, sizeof to, "\"ubake_dls\": \"%s\"", name);
  ASSERT_TRUE(load_variant("\"ubake_dls\": \"sunset\"", to, &cap) == UB_ERR_INVALID_DATA);
  printf("  64-byte set name: %s\n", cap.error);
  ASSERT_TRUE(strstr(cap.error, "'sun'") && strstr(cap.error, "64 bytes") &&
              strstr(cap.error, "at most 63"));
  snprintf(to, sizeof to, "\"ubake_door_open\": \"%s\"", name);
  ASSERT_TRUE(load_variant("\"ubake_door_open\": \"d1\"", to, &cap) == UB_ERR_INVALID_DATA);
  ASSERT_TRUE(strstr(cap.error, "'floor_open'") && strstr(cap.error, "ubake_door_open"));
  snprintf(to, sizeof to, "\"ubake_semidynamic\": \"%s\"", name);
  ASSERT_TRUE(load_variant("\"ubake_semidynamic\": \"crate\"", to, &cap) ==
              UB_ERR_INVALID_DATA);
  ASSERT_TRUE(strstr(cap.error, "'group'") && strstr(cap.error, "ubake_semidynamic"));

  /* light and emission beyond UB_SCENE_MAX_INTENSITY: refused, naming the light or the
   * material and the limit (1e38 W/sr loaded, then clamped 34,542 halves of the .ubk) */
  ASSERT_TRUE(load_variant("\"intensity\": 10,", "\"intensity\": 1e21,", &cap) ==
              UB_ERR_INVALID_DATA);
  printf("  a light of 1e21: %s\n", cap.error);
  ASSERT_TRUE(strstr(cap.error, "beyond the limit of 1e+20") != NULL);
  ASSERT_TRUE(load_variant("\"intensity\": 10,", "\"intensity\": 1e19,", &cap) == UB_OK);
  ASSERT_TRUE(load_variant("\"emissiveStrength\": 5", "\"emissiveStrength\": 1e21", &cap) ==
              UB_ERR_INVALID_DATA);
  ASSERT_TRUE(strstr(cap.error, "emission") && strstr(cap.error, "beyond the limit"));

  /* tags.gltf itself warns 3 times (test_tags); each variant adds one warning */
  ASSERT_TRUE(load_variant("\"ubake_door\": \"d1\",",
                           "\"ubake_door\": \"d1\", \"ubake_combine\": \"hall, nope\",", &cap) ==
              UB_OK);
  printf("  combine with an unknown name: %d warnings\n", cap.warnings);
  ASSERT_TRUE(cap.warnings == 4 && strstr(cap.warn_all, "node \"floor\": ubake_combine names "
                                                        "\"nope\", which is neither"));
  ASSERT_TRUE(strstr(cap.warn_all, "\"hall\"") == NULL); /* a set: fine */
  /* on a group: its mesh node inherits the tag and is named (a group of N meshes warns
   * once: check_tag_references says each typo once) */
  ASSERT_TRUE(load_variant("\"ubake_semidynamic\": \"crate\",",
                           "\"ubake_semidynamic\": \"crate\", \"ubake_combine\": \"d1\",", &cap) ==
              UB_OK);
  ASSERT_TRUE(cap.warnings == 4 &&
              strstr(cap.warn_all, "node \"crate_part\": ubake_combine on a node that is not a door"));
  ASSERT_TRUE(load_variant("\"ubake_light\": \"primary\",",
                           "\"ubake_light\": \"primary\", \"ubake_combine\": \"d1\",", &cap) ==
              UB_OK);
  ASSERT_TRUE(cap.warnings == 4 &&
              strstr(cap.warn_all, "node \"lamp\": ubake_combine on a node that is not a door"));
  ASSERT_TRUE(load_variant("\"ubake_door\": \"d1\",", "\"ubake_door\": \"d2\",", &cap) == UB_OK);
  ASSERT_TRUE(cap.warnings == 4 && strstr(cap.warn_all, "door \"d1\" has an open leaf") &&
              strstr(cap.warn_all, "not baked"));
}

/* ---- textures: linear mean of sRGB texels; missing image → warning, mean 1 ---- */
static const double kSrgb128 = 0.21586050011389926; /* sRGB 128/255 in linear */

static void test_textures(void)
{
  capture cap;
  ub_scene *s = load_ok(data_path("texture.gltf"), &cap);
  if (!s)
    return;
  check_invariants(s);
  /* 2×1 PNG: (255,255,255), (0,128,0) */
  ASSERT_NEAR(s->materials[0].albedo[0], 0.5 * 0.5, 1e-6, 0);
  ASSERT_NEAR(s->materials[0].albedo[1], (1.0 + kSrgb128) / 2, 1e-6, 0);
  ASSERT_NEAR(s->materials[0].albedo[2], 0.5, 1e-6, 0);
  ASSERT_NEAR(s->materials[1].albedo[0], 0.3, 1e-7, 0);
  ASSERT_NEAR(s->materials[2].emission[1], (1.0 + kSrgb128) / 2, 1e-6, 0);
  ASSERT_TRUE(cap.warnings == 1 && strstr(cap.warn_all, "missing_texture.png") != NULL);
  ub_scene_free(s);
}

/* ---- .glb written here: triangle + image in the BIN chunk ---- */
static const unsigned char kPng[] = {
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44,
    0x52, 0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00, 0x01, 0x08, 0x02, 0x00, 0x00, 0x00, 0x7b,
    0x40, 0xe8, 0xdd, 0x00, 0x00, 0x00, 0x0f, 0x49, 0x44, 0x41, 0x54, 0x78, 0x9c, 0x63, 0xf8,
    0xff, 0xff, 0x3f, 0x43, 0x03, 0x03, 0x00, 0x0f, 0xf8, 0x03, 0x7e, 0xac, 0x09, 0x94, 0x1c,
    0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82};

static void put_u32(unsigned char *p, uint32_t v)
{
  p[0] = (unsigned char)v;
  p[1] = (unsigned char)(v >> 8);
  p[2] = (unsigned char)(v >> 16);
  p[3] = (unsigned char)(v >> 24);
}

/* Writes a .glb; image_view_len overrides the image bufferView's length (to corrupt it). */
static int write_glb(const char *path, uint32_t image_view_len)
{
  unsigned char bin[256];
  memset(bin, 0, sizeof bin);
  const float pos[9] = {0, 0, 0, 1, 0, 0, 0, 0, -1}; /* faces +y */
  const uint32_t idx[3] = {0, 1, 2};
  memcpy(bin, pos, sizeof pos);            /* 0..36 */
  memcpy(bin + 36, idx, sizeof idx);       /* 36..48 */
  memcpy(bin + 48, kPng, sizeof kPng);     /* 48.. */
  uint32_t bin_len = (uint32_t)(48 + sizeof kPng + 3) & ~3u;
  char json[2048];
  int jl = snprintf(json, sizeof json,
                    "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
                    "\"nodes\":[{\"name\":\"glb_node\",\"mesh\":0}],"
                    "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},"
                    "\"indices\":1,\"material\":0}]}],"
                    "\"materials\":[{\"pbrMetallicRoughness\":{\"baseColorTexture\":{\"index\":0}}}],"
                    "\"textures\":[{\"source\":0}],"
                    "\"images\":[{\"bufferView\":2,\"mimeType\":\"image/png\"}],"
                    "\"buffers\":[{\"byteLength\":%u}],"
                    "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":36},"
                    "{\"buffer\":0,\"byteOffset\":36,\"byteLength\":12},"
                    "{\"buffer\":0,\"byteOffset\":48,\"byteLength\":%u}],"
                    "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":3,"
                    "\"type\":\"VEC3\"},{\"bufferView\":1,\"componentType\":5125,\"count\":3,"
                    "\"type\":\"SCALAR\"}]}",
                    bin_len, image_view_len);
  while (jl % 4)
    json[jl++] = ' ';
  unsigned char hdr[20], bhdr[8];
  memcpy(hdr, "glTF", 4);
  put_u32(hdr + 4, 2);
  put_u32(hdr + 8, 12 + 8 + (uint32_t)jl + 8 + bin_len);
  put_u32(hdr + 12, (uint32_t)jl);
  memcpy(hdr + 16, "JSON", 4);
  put_u32(bhdr, bin_len);
  memcpy(bhdr + 4, "BIN\0", 4);
  FILE *f = fopen(path, "wb");
  if (!f)
    return -1;
  fwrite(hdr, 1, 20, f);
  fwrite(json, 1, (size_t)jl, f);
  fwrite(bhdr, 1, 8, f);
  fwrite(bin, 1, bin_len, f);
  return fclose(f);
}

static void expect_failure(const char *path, ub_result want, const char *needle);

static void test_glb(void)
{
  char dir[] = "/tmp/ubake_test_scene_XXXXXX";
  if (!mkdtemp(dir)) {
    ASSERT_TRUE(0);
    return;
  }
  char path[256], bad[256];
  snprintf(path, sizeof path, "%s/level.glb", dir);
  snprintf(bad, sizeof bad, "%s/bad_image_view.glb", dir);
  ASSERT_OK(write_glb(path, (uint32_t)sizeof kPng));
  ASSERT_OK(write_glb(bad, 100000));
  capture cap;
  ub_scene *s = load_ok(path, &cap);
  if (s) {
    check_invariants(s);
    ASSERT_TRUE(cap.warnings == 0);
    ASSERT_TRUE(s->triangle_count == 1 && s->vertex_count == 3);
    ASSERT_TRUE(strcmp(s->nodes[0].name, "glb_node") == 0);
    ASSERT_NEAR(s->normals[1], 1.0, 1e-7, 0); /* flat normal: +y */
    ASSERT_NEAR(s->materials[0].albedo[0], 0.5, 1e-6, 0);
    ASSERT_NEAR(s->materials[0].albedo[1], (1.0 + kSrgb128) / 2, 1e-6, 0);
    ASSERT_TRUE(s->tri_flags[0] == 0);
    ub_scene_free(s);
  }
  /* an image bufferView running past the BIN chunk is refused before it is read */
  expect_failure(bad, UB_ERR_INVALID_DATA, "bufferView");
  unlink(path);
  unlink(bad);
  rmdir(dir);
}

/* ---- bad inputs ---- */
static void expect_failure(const char *path, ub_result want, const char *needle)
{
  capture cap;
  memset(&cap, 0, sizeof cap);
  ub_log log = {capture_fn, &cap};
  ub_scene sentinel_storage;
  ub_scene *s = &sentinel_storage; /* must stay untouched */
  ub_result r = ub_scene_load(path, &log, &s);
  if (r != want)
    fprintf(stderr, "%s: got %s, want %s (%s)\n", path, ub_result_string(r),
            ub_result_string(want), cap.error);
  ASSERT_TRUE(r == want);
  ASSERT_TRUE(s == &sentinel_storage);
  ASSERT_TRUE(cap.errors == 1 && cap.warnings == 0);
  const char *base = strrchr(path, '/');
  base = base ? base + 1 : path;
  ASSERT_TRUE(strstr(cap.error, base) != NULL);
  ASSERT_TRUE(strchr(cap.error, '\n') == NULL);
  if (!strstr(cap.error, needle))
    fprintf(stderr, "message \"%s\" lacks \"%s\"\n", cap.error, needle);
  ASSERT_TRUE(strstr(cap.error, needle) != NULL);
}

static void test_bad_inputs(void)
{
  struct {
    const char *file;
    ub_result want;
    const char *needle;
  } cases[] = {
      {"bad/does_not_exist.gltf", UB_ERR_IO, "cannot open"},
      {"bad/broken_json.gltf", UB_ERR_INVALID_DATA, "parse error"},
      {"bad/accessor_range.gltf", UB_ERR_INVALID_DATA, "node 0 'n0': POSITION accessor 0"},
      {"bad/bufferview_missing.gltf", UB_ERR_INVALID_DATA, "bufferView 9"},
      {"bad/index_range.gltf", UB_ERR_INVALID_DATA, "indices accessor 2"},
      {"bad/nan_position.gltf", UB_ERR_INVALID_DATA, "node 0 'n0': POSITION accessor 0 vertex 2"},
      {"bad/bad_receiver.gltf", UB_ERR_INVALID_DATA, "node 0 'n0': ubake_receiver"},
      {"bad/bad_texel_size.gltf", UB_ERR_INVALID_DATA, "node 0 'n0': ubake_texel_size"},
      {"bad/no_geometry.gltf", UB_ERR_INVALID_DATA, "no geometry"},
      {"bad/degenerate_only.gltf", UB_ERR_INVALID_DATA, "no geometry"},
      {"bad/truncated.glb", UB_ERR_INVALID_DATA, "glTF binary"},
  };
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++)
    expect_failure(data_path(cases[i].file), cases[i].want, cases[i].needle);
  /* the messages carry the offending value */
  capture cap;
  memset(&cap, 0, sizeof cap);
  ub_log log = {capture_fn, &cap};
  ub_scene *s = NULL;
  ASSERT_TRUE(ub_scene_load(data_path("bad/bad_receiver.gltf"), &log, &s) == UB_ERR_INVALID_DATA);
  ASSERT_TRUE(strstr(cap.error, "banana") != NULL);
  ASSERT_TRUE(ub_scene_load(data_path("bad/bad_texel_size.gltf"), &log, &s) == UB_ERR_INVALID_DATA);
  ASSERT_TRUE(strstr(cap.error, "big") != NULL);
  ASSERT_TRUE(s == NULL);
  /* a directory is not a level */
  expect_failure(g_data, UB_ERR_IO, "cannot read");
  /* nor is a device: refused before reading (/dev/zero was read until the 4 GB cap), nor a
   * FIFO (with no writer, opening it blocked) */
  expect_failure("/dev/zero", UB_ERR_IO, "not a regular file");
  {
    char dir[] = "/tmp/ubake_test_scene_XXXXXX", fifo[128];
    ASSERT_TRUE(mkdtemp(dir) != NULL);
    snprintf(fifo, sizeof fifo, "%s/level.gltf", dir);
    ASSERT_TRUE(mkfifo(fifo, 0600) == 0);
    expect_failure(fifo, UB_ERR_IO, "not a regular file");
    unlink(fifo);
    rmdir(dir);
  }
  /* a buffer file missing: an I/O error naming it, not "invalid glTF" */
  {
    char dir[] = "/tmp/ubake_test_scene_XXXXXX", path[128];
    ASSERT_TRUE(mkdtemp(dir) != NULL);
    snprintf(path, sizeof path, "%s/uv_zero_area.gltf", dir);
    FILE *in = fopen(data_path("uv_zero_area.gltf"), "rb"), *out = fopen(path, "wb");
    ASSERT_TRUE(in && out);
    char buf[4096];
    size_t n;
    while (in && out && (n = fread(buf, 1, sizeof buf, in)) > 0)
      fwrite(buf, 1, n, out);
    if (in)
      fclose(in);
    if (out)
      fclose(out);
    expect_failure(path, UB_ERR_IO, "cannot read a file it refers to: File not found : "
                                    "uv_zero_area.bin");
    unlink(path);
    rmdir(dir);
  }
  /* caller bugs and NULL-safety */
  ASSERT_TRUE(ub_scene_load(NULL, NULL, &s) == UB_ERR_INVALID_ARGUMENT);
  ASSERT_TRUE(ub_scene_load(data_path("hierarchy.gltf"), NULL, NULL) == UB_ERR_INVALID_ARGUMENT);
  ub_scene_free(NULL);
  ASSERT_TRUE(ub_scene_extent(NULL) == 0.0f && ub_scene_area(NULL) == 0.0);
  /* no log at all is fine */
  ASSERT_TRUE(ub_scene_load(data_path("bad/index_range.gltf"), NULL, &s) == UB_ERR_INVALID_DATA);
  ASSERT_TRUE(s == NULL);
}

int main(void)
{
  find_data_dir();
  test_hierarchy();
  test_tags();
  test_tag_names();
  test_textures();
  test_glb();
  test_bad_inputs();
  test_real_levels();
  TEST_MAIN_END();
}
