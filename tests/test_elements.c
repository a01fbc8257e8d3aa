/* Doors, objects and combinations in the .ubk and the run-time (section ELEM):
 * bake hallway (two sets) at draft, add elements whose records copy the sets' data, write
 * and reload, then check
 * - the round trip keeps kinds, parents and every record value;
 * - each element is applied with its documented weight: a set w, a door t, an object
 *   v − 1, a combination the product of its parents' applied weights — the raw GLG SH
 *   equal base + Σ weight·record to float rounding, for several states;
 * - returning to the default state gives the identical probes (no drift);
 * - bad values and hostile records are refused (a combination's parent out of range, a
 *   parent that is itself a combination, kinds out of order, a repeated name). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "test_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/runtime.h"

static void copy_record(const ub_bakefile_record *src, ub_bakefile_record *dst, uint32_t kind,
                        const char *name, int32_t p0, int32_t p1)
{
  *dst = *src; /* shares the arrays: the caller frees only the original */
  snprintf(dst->name, sizeof dst->name, "%s", name);
  dst->kind = kind;
  dst->parent[0] = p0;
  dst->parent[1] = p1;
}

/* Expected raw GLG SH: base + Σ applied_e · record_e. */
static double check_state(const ub_runtime *rt, const ub_bakefile *bf, const float applied[][3],
                          uint32_t n)
{
  const float *cur = ub_runtime_glg_probe_sh(rt, 0);
  size_t np = bf->glg_probe_count;
  double *want = malloc(np * 27 * sizeof *want);
  for (size_t i = 0; i < np * 27; i++)
    want[i] = bf->glg_sh[i];
  for (uint32_t e = 0; e < n; e++) {
    const ub_bakefile_record *r = e < bf->dls_count ? &bf->dls[e] : &bf->elems[e - bf->dls_count];
    for (uint32_t k = 0; k < r->probe_count; k++)
      for (int j = 0; j < 27; j++)
        want[27 * (size_t)r->probe_index[k] + j] += applied[e][j % 3] * r->probe_sh[27 * k + j];
  }
  double worst = 0.0;
  for (size_t i = 0; i < np * 27; i++) {
    double err = fabs(cur[i] - want[i]) / (1e-6 + fabs(want[i]));
    worst = err > worst ? err : worst;
  }
  free(want);
  return worst;
}

static int rejects(const ub_bakefile *bf, const char *path)
{
  if (ub_bakefile_write(bf, path, NULL) != UB_OK)
    return 1; /* the writer's own read-back refused it */
  ub_bakefile *back = NULL;
  ub_result r = ub_bakefile_read(path, NULL, &back);
  ub_bakefile_free(back);
  return r == UB_ERR_INVALID_DATA;
}

int main(void)
{
  const char *b = getenv("UB_BUILD");
  char build[512], level[1024], dir[1024], path[1100], bad[1100];
  snprintf(build, sizeof build, "%s", b ? b : "build");
  snprintf(level, sizeof level, "%s/levels/hallway.gltf", build);
  snprintf(dir, sizeof dir, "%s/test_out/elements", build);
  ub_bake_options o;
  ub_bake_options_default(&o);
  o.quality = UB_QUALITY_DRAFT;
  o.out_dir = dir;
  ub_bake_stats st;
  ub_result r = ub_bake_level(level, &o, NULL, &st);
  ASSERT_OK(r);
  if (r != UB_OK)
    TEST_MAIN_END();
  ub_bakefile *bf = NULL;
  ASSERT_OK(ub_bakefile_read(st.ubk_path, NULL, &bf));
  if (!bf || bf->dls_count != 2 || !bf->glg_probe_count) {
    fprintf(stderr, "hallway: expected two sets and a GLG\n");
    ub_bakefile_free(bf);
    return 1;
  }
  /* Elements: door "front" (data of set 0), object "crate" (set 1), combination
   * front × set 0 (data of set 1), object × object is not allowed with one object, so
   * also a second object "barrel" (set 0) and the pair crate × barrel. */
  ub_bakefile_record el[5];
  copy_record(&bf->dls[0], &el[0], UB_ELEMENT_DOOR, "front", -1, -1);
  copy_record(&bf->dls[1], &el[1], UB_ELEMENT_OBJECT, "crate", -1, -1);
  copy_record(&bf->dls[0], &el[2], UB_ELEMENT_OBJECT, "barrel", -1, -1);
  copy_record(&bf->dls[1], &el[3], UB_ELEMENT_COMBO, "front*hall_a", 2, 0);
  copy_record(&bf->dls[0], &el[4], UB_ELEMENT_COMBO, "crate*barrel", 3, 4);
  bf->elems = el;
  bf->elem_count = 5;
  /* Triangle roles: triangle 0 the door's closed leaf, 1 its open pose, 2 the crate. */
  uint32_t *role = calloc(bf->triangle_count, sizeof *role);
  role[0] = (UB_TRI_ROLE_DOOR_CLOSED << 24) | 0;
  role[1] = (UB_TRI_ROLE_DOOR_OPEN << 24) | 0;
  role[2] = (UB_TRI_ROLE_OBJECT << 24) | 1;
  bf->tri_role = role;
  snprintf(path, sizeof path, "%s/elements.ubk", dir);
  snprintf(bad, sizeof bad, "%s/elements_bad.ubk", dir);
  ASSERT_OK(ub_bakefile_write(bf, path, NULL));

  /* Round trip. */
  ub_bakefile *back = NULL;
  ASSERT_OK(ub_bakefile_read(path, NULL, &back));
  if (back) {
    ASSERT_TRUE(back->elem_count == 5);
    for (uint32_t e = 0; e < 5 && back->elem_count == 5; e++) {
      const ub_bakefile_record *x = &back->elems[e], *y = &el[e];
      ASSERT_TRUE(x->kind == y->kind && x->parent[0] == y->parent[0] &&
                  x->parent[1] == y->parent[1] && !strcmp(x->name, y->name));
      ASSERT_TRUE(x->texel_count == y->texel_count && x->probe_count == y->probe_count);
      /* Same half-precision data as the set it copies, read back the same way. */
      const ub_bakefile_record *z = &back->dls[e == 1 || e == 3 ? 1 : 0];
      ASSERT_TRUE(!memcmp(x->probe_sh, z->probe_sh, (size_t)x->probe_count * 27 * sizeof(float)));
      ASSERT_TRUE(!memcmp(x->texel_sh, z->texel_sh, (size_t)x->texel_count * 12 * sizeof(float)));
    }
  }

  /* Weights. Elements in the run-time's numbering: sets 0, 1; then elems 2..6. */
  ub_runtime *rt = NULL;
  ASSERT_OK(ub_runtime_load(path, NULL, &rt));
  if (rt && back) {
    ASSERT_TRUE(ub_runtime_element_count(rt) == 5);
    int32_t door = ub_runtime_element_find(rt, UB_ELEMENT_DOOR, "front");
    int32_t crate = ub_runtime_element_find(rt, UB_ELEMENT_OBJECT, "crate");
    int32_t barrel = ub_runtime_element_find(rt, UB_ELEMENT_OBJECT, "barrel");
    ASSERT_TRUE(door == 0 && crate == 1 && barrel == 2);
    ASSERT_TRUE(ub_runtime_element_find(rt, UB_ELEMENT_DOOR, "crate") == -1);
    ASSERT_TRUE(ub_runtime_set_element(rt, 3, 1.0f) == UB_ERR_INVALID_ARGUMENT); /* combo */
    ASSERT_TRUE(ub_runtime_set_element(rt, 0, 1.5f) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(ub_runtime_set_element(rt, 0, NAN) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_TRUE(ub_runtime_set_element(rt, 9, 0.5f) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_NEAR(ub_runtime_door_fraction(0.0f), 0.0, 1e-7, 0);
    ASSERT_NEAR(ub_runtime_door_fraction((float)M_PI / 3), 0.5, 1e-6, 0);
    ASSERT_NEAR(ub_runtime_door_fraction(2.0f), 1.0, 0, 0);
    /* Which triangles the state shows. */
    ASSERT_TRUE(ub_runtime_triangle_shown(rt, 0) && !ub_runtime_triangle_shown(rt, 1) &&
                ub_runtime_triangle_shown(rt, 2) && ub_runtime_triangle_shown(rt, 3));
    ASSERT_OK(ub_runtime_set_element(rt, 0, 0.75f));
    ASSERT_OK(ub_runtime_set_element(rt, 1, 0.25f));
    ASSERT_TRUE(!ub_runtime_triangle_shown(rt, 0) && ub_runtime_triangle_shown(rt, 1) &&
                !ub_runtime_triangle_shown(rt, 2) && ub_runtime_triangle_shown(rt, 3));
    float val = -1.0f;
    ASSERT_OK(ub_runtime_element_value(rt, 0, &val));
    ASSERT_NEAR(val, 0.75, 0, 0);
    ASSERT_TRUE(ub_runtime_element_value(rt, 3, &val) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_OK(ub_runtime_set_element(rt, 0, 0.0f));
    ASSERT_OK(ub_runtime_set_element(rt, 1, 1.0f));
    ASSERT_OK(ub_runtime_update(rt, NULL));

    const float *g0 = ub_runtime_glg_probe_sh(rt, 0);
    size_t nsh = (size_t)back->glg_probe_count * 27;
    float *start = malloc(nsh * sizeof *start);
    memcpy(start, g0, nsh * sizeof *start);
    /* Default: sets 1, door closed (0), objects shown (applied 0), combos 0. */
    float def[7][3] = {{1, 1, 1}, {1, 1, 1}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
    double e0 = check_state(rt, back, def, 7);
    printf("default state: worst relative error %.2e\n", e0);
    ASSERT_TRUE(e0 < 1e-5);

    const float tint[3] = {0.5f, 1.0f, 2.0f};
    ASSERT_OK(ub_runtime_set_dls(rt, 0, tint));
    ASSERT_OK(ub_runtime_set_element(rt, (uint32_t)door, 0.5f));
    ASSERT_OK(ub_runtime_set_element(rt, (uint32_t)crate, 0.25f));
    ASSERT_OK(ub_runtime_set_element(rt, (uint32_t)barrel, 0.0f));
    ASSERT_OK(ub_runtime_update(rt, NULL));
    float st1[7][3] = {{0.5f, 1, 2}, {1, 1, 1}, {0.5f, 0.5f, 0.5f}, {-0.75f, -0.75f, -0.75f},
                       {-1, -1, -1}, {0.25f, 0.5f, 1}, {0.75f, 0.75f, 0.75f}};
    double e1 = check_state(rt, back, st1, 7);
    printf("tinted set, door half open, objects faded/hidden: worst relative error %.2e\n", e1);
    ASSERT_TRUE(e1 < 1e-5);

    /* Back to the default: identical bits. */
    const float one[3] = {1, 1, 1};
    ASSERT_OK(ub_runtime_set_dls(rt, 0, one));
    ASSERT_OK(ub_runtime_set_element(rt, (uint32_t)door, 0.0f));
    ASSERT_OK(ub_runtime_set_element(rt, (uint32_t)crate, 1.0f));
    ASSERT_OK(ub_runtime_set_element(rt, (uint32_t)barrel, 1.0f));
    ASSERT_OK(ub_runtime_update(rt, NULL));
    ASSERT_TRUE(!memcmp(start, ub_runtime_glg_probe_sh(rt, 0), nsh * sizeof *start));
    free(start);
  }
  ub_runtime_free(rt);
  ub_bakefile_free(back);

  /* Hostile records. */
  el[3].parent[0] = 9; /* out of range */
  ASSERT_TRUE(rejects(bf, bad));
  el[3].parent[0] = 2;
  el[4].parent[1] = 5; /* a combination as parent */
  ASSERT_TRUE(rejects(bf, bad));
  el[4].parent[1] = 4;
  el[4].parent[0] = 4; /* the same parent twice */
  ASSERT_TRUE(rejects(bf, bad));
  el[4].parent[0] = 3;
  el[1].kind = UB_ELEMENT_DOOR; /* door after object: kinds out of order */
  el[0].kind = UB_ELEMENT_OBJECT;
  ASSERT_TRUE(rejects(bf, bad));
  el[0].kind = UB_ELEMENT_DOOR;
  el[1].kind = UB_ELEMENT_OBJECT;
  snprintf(el[2].name, sizeof el[2].name, "crate"); /* repeated object name */
  ASSERT_TRUE(rejects(bf, bad));
  snprintf(el[2].name, sizeof el[2].name, "barrel");
  role[2] = (UB_TRI_ROLE_DOOR_CLOSED << 24) | 1; /* a door role on an object */
  ASSERT_TRUE(rejects(bf, bad));
  role[2] = (UB_TRI_ROLE_OBJECT << 24) | 7; /* no such element */
  ASSERT_TRUE(rejects(bf, bad));
  role[2] = (UB_TRI_ROLE_OBJECT << 24) | 1;
  ASSERT_OK(ub_bakefile_write(bf, bad, NULL)); /* and fine again */
  bf->elems = NULL;
  bf->elem_count = 0;
  ub_bakefile_free(bf); /* frees role */
  TEST_MAIN_END();
}
