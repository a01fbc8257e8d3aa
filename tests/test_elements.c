/* Doors, objects and combinations in the .ubk and the run-time (section ELEM):
 * bake hallway (two sets) at draft, add elements whose records copy the sets' data, write
 * and reload, then check
 * - the round trip keeps kinds, parents and every record value;
 * - each element is applied with its documented weight: a set w, a door t, an object
 *   v − 1, a combination the product of its parents' applied weights — the raw GLG SH
 *   equal base + Σ weight·record to half rounding (the GLG's compact store), and bit for
 *   bit the store a float blend of the file's records gives, for several states;
 * - returning to the default state gives the identical probes (no drift);
 * - bad values and hostile records are refused (a combination's parent out of range, a
 *   parent that is itself a combination, kinds out of order, a repeated name). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "runtime/blend.h"
#include "runtime/texel_sh.h"
#include "test_util.h"
#include "test_rt_util.h"
#include "ubake/bake.h"
#include "ubake/bakefile.h"
#include "ubake/glg.h"
#include "ubake/ahd.h"
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

/* The run-time's raw GLG SH (probe × 27, malloc'd). */
static float *glg_now(const ub_runtime *rt, size_t np)
{
  float *cur = malloc((np * 27 + 1) * sizeof *cur);
  if (cur && ub_runtime_glg_probe_sh(rt, 0, cur) != UB_OK) {
    free(cur);
    return NULL;
  }
  return cur;
}

/* Expected raw GLG SH: base + Σ applied_e · record_e; the worst error relative to the
 * value (the store rounds each value to half: ≤ 2^-11 plus the float sums). */
static double check_state(const ub_runtime *rt, const ub_bakefile *bf, const float applied[][3],
                          uint32_t n)
{
  size_t np = bf->glg_probe_count;
  float *cur = glg_now(rt, np);
  if (!cur)
    return 1.0;
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
  free(cur);
  return worst;
}

/* The run-time keeps record values in half (the file's precision). GLG probe records are
 * the file's halves times a power of two, so re-rounding them to half is exact: the
 * run-time's raw GLG SH must equal, bit for bit, a blend of the file's float records with
 * the same weights (same kernel family, same float operations) put through a compact
 * GLG store of its own. */
static int glg_equals_float_blend(const ub_runtime *rt, const ub_bakefile *bf,
                                  const float applied[][3], uint32_t n)
{
  size_t np = bf->glg_probe_count;
  ub_blend_record *recs = calloc(n, sizeof *recs);
  float *out = malloc(np * 27 * sizeof *out);
  for (uint32_t e = 0; e < n; e++) {
    const ub_bakefile_record *r = e < bf->dls_count ? &bf->dls[e] : &bf->elems[e - bf->dls_count];
    recs[e].receivers = r->probe_index;
    recs[e].values = r->probe_sh;
    recs[e].count = r->probe_count;
  }
  ub_blend_desc d = {"GLG float records", (uint32_t)np, 27, bf->glg_sh, UB_BLEND_FLOAT32, n,
                     recs, 0, 0};
  ub_blend *b = NULL;
  int same = 0;
  if (ub_blend_create(&d, NULL, out, &b) == UB_OK) {
    for (uint32_t e = 0; e < n; e++)
      ub_blend_set_weight(b, e, applied[e]);
    ub_blend_update_all(b, NULL, NULL, out, NULL);
    ub_glg_desc gd = {.probe_count = (uint32_t)np, .positions = bf->glg_positions, .sh = out,
                      .tet_count = bf->glg_tet_count, .tets = bf->glg_tets,
                      .neigh = bf->glg_neigh, .compact = 1};
    ub_glg g;
    float *cur = glg_now(rt, np);
    if (cur && ub_glg_init(&g, &gd, NULL) == UB_OK) {
      same = 1;
      for (uint32_t q = 0; q < np && same; q++) {
        float row[27];
        ub_glg_probe_sh(&g, q, 0, row);
        same = !memcmp(row, cur + 27 * (size_t)q, sizeof row);
      }
      ub_glg_release(&g);
    }
    free(cur);
  }
  ub_blend_free(b);
  free(out);
  free(recs);
  return same;
}

/* Lightmap texels (records in half, in the file's I_z form): the irradiance decoded along
 * each covered texel's normal against base + Σ applied·record from the file's floats.
 * Returns the worst error relative to |base I_z| + Σ|applied·record I_z| (what half
 * rounding of each stored I_z is relative to: ≤ 2^-11 each). */
static double check_texels(const ub_runtime *rt, const ub_bakefile *bf, const float applied[][3],
                           uint32_t n)
{
  uint64_t pixels = ub_bakefile_atlas_pixels(bf);
  double *sum = calloc(pixels * 12, sizeof *sum), *mag = calloc(pixels * 3, sizeof *mag);
  float (*nrm)[3] = calloc(pixels, sizeof *nrm);
  uint8_t *ok = calloc(pixels, 1);
  uint64_t p0 = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    for (size_t i = 0; i < (size_t)at->width * at->height; i++) {
      /* covered texels; padding shows one of them (check_padding) */
      ok[p0 + i] = at->coverage[i] == 1 && ub_texel_normal(&at->normal[3 * i], nrm[p0 + i]);
      for (int k = 0; k < 12; k++)
        sum[(p0 + i) * 12 + k] = at->sh[i * 12 + k];
    }
    p0 += (uint64_t)at->width * at->height;
  }
  for (uint64_t p = 0; p < pixels; p++) {
    float f[12];
    for (int k = 0; k < 12; k++)
      f[k] = (float)sum[p * 12 + k];
    for (int c = 0; c < 3 && ok[p]; c++)
      mag[p * 3 + c] = fabs(M_PI * 0.282094791773878143 * f[c] + ub_texel_sh_linear(f, nrm[p], c));
  }
  for (uint32_t e = 0; e < n; e++) {
    const ub_bakefile_record *r = e < bf->dls_count ? &bf->dls[e] : &bf->elems[e - bf->dls_count];
    for (uint32_t i = 0; i < r->texel_count; i++) {
      uint64_t p = r->texel_index[i];
      const float *v = &r->texel_sh[12 * (size_t)i];
      for (int k = 0; k < 12; k++)
        sum[p * 12 + k] += (double)applied[e][k % 3] * v[k];
      for (int c = 0; c < 3 && ok[p]; c++)
        mag[p * 3 + c] += fabs(applied[e][c] * (M_PI * 0.282094791773878143 * v[c] +
                                                ub_texel_sh_linear(v, nrm[p], c)));
    }
  }
  double worst = 0.0;
  p0 = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    for (uint32_t y = 0; y < at->height; y++)
      for (uint32_t x = 0; x < at->width; x++) {
        uint64_t p = p0 + (uint64_t)y * at->width + x;
        if (!ok[p])
          continue;
        float f[12], got[3];
        for (int k = 0; k < 12; k++)
          f[k] = (float)sum[p * 12 + k];
        if (ub_runtime_texel_irradiance(rt, a, x, y, nrm[p], got) != UB_OK)
          return INFINITY;
        for (int c = 0; c < 3; c++) {
          double want = M_PI * 0.282094791773878143 * f[c] + ub_texel_sh_linear(f, nrm[p], c);
          double err = fabs(got[c] - fmax(want, 0.0)) / (mag[p * 3 + c] + 1e-6);
          worst = err > worst ? err : worst;
        }
      }
    p0 += (uint64_t)at->width * at->height;
  }
  free(sum);
  free(mag);
  free(nrm);
  free(ok);
  return worst;
}

/* Every padding pixel (coverage 2) shows a covered texel at its smallest Chebyshev
 * distance to any covered texel, bit for bit (its irradiance for any normal is that
 * texel's); empty pixels have none. Returns the pixels that do not; *out_padding: how many
 * padding pixels there are. */
static int check_padding(const ub_runtime *rt, const ub_bakefile *bf, uint64_t *out_padding)
{
  int bad = 0;
  uint64_t np = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    const int64_t w = at->width, h = at->height;
    for (int64_t y = 0; y < h; y++)
      for (int64_t x = 0; x < w; x++) {
        const uint8_t c = at->coverage[y * w + x];
        uint32_t sx = 0, sy = 0;
        ub_result r = ub_runtime_texel_source(rt, a, (uint32_t)x, (uint32_t)y, &sx, &sy);
        if (c == 0) {
          bad += r != UB_ERR_NOT_BAKED;
          continue;
        }
        if (r != UB_OK) {
          bad++;
          continue;
        }
        if (c == 1) {
          bad += sx != x || sy != y;
          continue;
        }
        np++;
        int64_t best = INT64_MAX; /* smallest Chebyshev distance to a covered texel */
        for (int64_t d = 1; d <= 16 && best == INT64_MAX; d++)
          for (int64_t yy = y - d; yy <= y + d; yy++)
            for (int64_t xx = x - d; xx <= x + d; xx++)
              if (yy >= 0 && xx >= 0 && yy < h && xx < w && at->coverage[yy * w + xx] == 1)
                best = d;
        const int64_t dx = llabs((int64_t)sx - x), dy = llabs((int64_t)sy - y);
        if (at->coverage[(int64_t)sy * w + sx] != 1 || (dx > dy ? dx : dy) != best)
          bad++;
        float n[3], g0[3], g1[3];
        const float ns[2][3] = {{0.0f, 1.0f, 0.0f}, {0.6f, 0.0f, -0.8f}};
        for (int k = 0; k < 2; k++) {
          memcpy(n, ns[k], sizeof n);
          if (ub_runtime_texel_irradiance(rt, a, (uint32_t)x, (uint32_t)y, n, g0) != UB_OK ||
              ub_runtime_texel_irradiance(rt, a, sx, sy, n, g1) != UB_OK ||
              memcmp(g0, g1, sizeof g0) != 0)
            bad++;
        }
      }
  }
  *out_padding = np;
  return bad;
}

/* The packed AHD a game uploads (ub_runtime_atlas_ahd, ub_runtime_texel_ahd): empty pixels
 * zero and NOT_BAKED, padding the bits of its source texel, every covered texel's decoded
 * irradiance (stored normal, and a fixed one) within the packing's bound of
 * ub_runtime_texel_irradiance (the float AHD): 2^-10 of C_a + C_d. Returns the failures;
 * *out_worst: the worst error in units of that bound. */
static int check_packed(const ub_runtime *rt, const ub_bakefile *bf, double *out_worst)
{
  int bad = 0;
  double worst = 0.0;
  const float scale = ub_runtime_ahd_scale(rt);
  bad += !(scale >= 1.0f) || frexpf(scale, &(int){0}) != 0.5f; /* a power of two ≥ 1 */
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    const uint32_t w = at->width, h = at->height;
    ub_ahd_packed *img = malloc((size_t)w * h * sizeof *img), one;
    ASSERT_TRUE(img != NULL);
    ASSERT_OK(ub_runtime_atlas_ahd(rt, a, img));
    static const ub_ahd_packed zero;
    for (uint32_t y = 0; y < h; y++)
      for (uint32_t x = 0; x < w; x++) {
        const ub_ahd_packed *p = &img[(size_t)y * w + x];
        const uint8_t c = at->coverage[(size_t)y * w + x];
        ub_result r = ub_runtime_texel_ahd(rt, a, x, y, &one);
        if (c == 0) {
          bad += r != UB_ERR_NOT_BAKED || memcmp(p, &zero, sizeof zero) != 0;
          continue;
        }
        uint32_t sx, sy;
        if (r != UB_OK || memcmp(p, &one, sizeof one) != 0 ||
            ub_runtime_texel_source(rt, a, x, y, &sx, &sy) != UB_OK ||
            memcmp(p, &img[(size_t)sy * w + sx], sizeof *p) != 0) {
          bad++;
          continue;
        }
        if (c != 1)
          continue;
        ub_ahd d;
        ub_ahd_unpack(p, scale, &d);
        float ns[2][3] = {{0.0f, 1.0f, 0.0f}, {0.6f, 0.0f, -0.8f}};
        if (ub_runtime_texel_normal(rt, a, x, y, ns[0]) != UB_OK ||
            !(ns[0][0] != 0.0f || ns[0][1] != 0.0f || ns[0][2] != 0.0f))
          ns[0][1] = 1.0f;
        for (int k = 0; k < 2; k++) {
          float e[3], g[3];
          ub_ahd_irradiance(&d, ns[k], e);
          bad += ub_runtime_texel_irradiance(rt, a, x, y, ns[k], g) != UB_OK;
          for (int ch = 0; ch < 3; ch++) {
            double tol = ldexp(d.ambient[ch] + d.directional[ch], -10) + ldexp(scale, -24);
            double q = fabs((double)e[ch] - g[ch]) / tol;
            worst = q > worst ? q : worst;
          }
        }
      }
    free(img);
  }
  *out_worst = worst;
  return bad + (worst > 1.0);
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
    /* the geometry changes with the lighting, at the update (it changed at the set, so a
     * query between the two met the open door's geometry with the closed door's light) */
    ASSERT_TRUE(ub_runtime_triangle_shown(rt, 0) && !ub_runtime_triangle_shown(rt, 1) &&
                ub_runtime_triangle_shown(rt, 2) && ub_runtime_triangle_shown(rt, 3));
    ASSERT_OK(ub_runtime_update(rt, NULL));
    ASSERT_TRUE(!ub_runtime_triangle_shown(rt, 0) && ub_runtime_triangle_shown(rt, 1) &&
                !ub_runtime_triangle_shown(rt, 2) && ub_runtime_triangle_shown(rt, 3));
    float val = -1.0f;
    ASSERT_OK(ub_runtime_element_value(rt, 0, &val));
    ASSERT_NEAR(val, 0.75, 0, 0);
    ASSERT_TRUE(ub_runtime_element_value(rt, 3, &val) == UB_ERR_INVALID_ARGUMENT);
    ASSERT_OK(ub_runtime_set_element(rt, 0, 0.0f));
    ASSERT_OK(ub_runtime_set_element(rt, 1, 1.0f));
    ASSERT_OK(ub_runtime_update(rt, NULL));

    size_t nsh = (size_t)back->glg_probe_count * 27;
    float *start = glg_now(rt, back->glg_probe_count);
    ASSERT_TRUE(start != NULL);
    ub_ahd_packed *ahd_start = ahd_snapshot(rt, back); /* the packed AHD, compared below */
    /* Default: sets 1, door closed (0), objects shown (applied 0), combos 0. */
    float def[7][3] = {{1, 1, 1}, {1, 1, 1}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
    double e0 = check_state(rt, back, def, 7);
    printf("default state: worst relative error %.2e\n", e0);
    ASSERT_TRUE(e0 < ldexp(1.0, -11) * 1.01 + 1e-5);
    ASSERT_TRUE(glg_equals_float_blend(rt, back, def, 7));
    double t0 = check_texels(rt, back, def, 7);
    printf("default state, texels (half records): worst error %.2e of the I_z magnitudes\n", t0);
    ASSERT_TRUE(t0 < 1e-3);
    uint64_t npad = 0;
    int bad_pad = check_padding(rt, back, &npad);
    printf("default state: %d of %llu padding pixels do not show a nearest covered texel\n",
           bad_pad, (unsigned long long)npad);
    ASSERT_TRUE(bad_pad == 0 && npad > 0);
    double pk = 0.0;
    int bad_pk = check_packed(rt, back, &pk);
    printf("default state: packed AHD, %d failures, worst %.3f of the packing's bound\n",
           bad_pk, pk);
    ASSERT_TRUE(bad_pk == 0 && pk > 0.0);

    /* An update that changes nothing changes no texel (test_estate: the changed texels) */
    ub_runtime_update_stats ust;
    ASSERT_OK(ub_runtime_update(rt, &ust));
    ASSERT_TRUE(ust.texels_reencoded == 0 && ub_runtime_changed_texel_count(rt) == 0);

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
    ASSERT_TRUE(e1 < ldexp(1.0, -11) * 1.01 + 1e-5);
    ASSERT_TRUE(glg_equals_float_blend(rt, back, st1, 7));
    double t1 = check_texels(rt, back, st1, 7);
    printf("same state, texels (half records): worst error %.2e of the I_z magnitudes\n", t1);
    ASSERT_TRUE(t1 < 1e-3);
    bad_pad = check_padding(rt, back, &npad);
    ASSERT_TRUE(bad_pad == 0 && npad > 0);
    bad_pk = check_packed(rt, back, &pk);
    printf("tinted state: packed AHD, %d failures, worst %.3f of the packing's bound\n",
           bad_pk, pk);
    ASSERT_TRUE(bad_pk == 0 && pk > 0.0);

    /* Back to the default: identical bits. */
    const float one[3] = {1, 1, 1};
    ASSERT_OK(ub_runtime_set_dls(rt, 0, one));
    ASSERT_OK(ub_runtime_set_element(rt, (uint32_t)door, 0.0f));
    ASSERT_OK(ub_runtime_set_element(rt, (uint32_t)crate, 1.0f));
    ASSERT_OK(ub_runtime_set_element(rt, (uint32_t)barrel, 1.0f));
    ASSERT_OK(ub_runtime_update(rt, NULL));
    float *end = glg_now(rt, back->glg_probe_count);
    ASSERT_TRUE(end && !memcmp(start, end, nsh * sizeof *start));
    {
      /* the stored AHD too: it depends on the state only, not on the updates before */
      ub_ahd_packed *ahd_end = ahd_snapshot(rt, back);
      const size_t np = atlas_pixels(back, back->atlas_count);
      ASSERT_TRUE(!memcmp(ahd_start, ahd_end, np * sizeof *ahd_end));
      free(ahd_end);
      free(ahd_start);
    }
    free(end);
    free(start);
  }
  ub_runtime_free(rt);
  rt = NULL;

  /* The load state kept (UB_RUNTIME_KEEP_STATE) with a door, objects and combinations: a
   * run-time with it and one without through the same changes, the atlases bit for bit
   * after every update; returning to the load state copies every texel back. A third
   * without the base state's AHD (UB_RUNTIME_NO_BASE_AHD): the same bits, none copied from
   * the base, where the default copies the texels whose elements are all at 0. */
  ub_runtime *ra = NULL, *rk = NULL, *rn = NULL;
  ASSERT_OK(ub_runtime_load(path, NULL, &ra));
  ASSERT_OK(ub_runtime_load_ex(path, NULL, UB_RUNTIME_KEEP_STATE, &rk));
  ASSERT_OK(ub_runtime_load_ex(path, NULL, UB_RUNTIME_NO_BASE_AHD, &rn));
  if (ra && rk && rn && back) {
    /* (element, value) steps: door opened half and fully, crate hidden, barrel faded,
     * each back to its load value (door 0, objects 1), then all at once */
    const struct { int32_t e; float v; } steps[] = {
        {0, 0.5f}, {0, 0.0f}, {1, 0.0f}, {0, 1.0f}, {1, 1.0f}, {0, 0.0f}, {2, 0.3f},
        {1, 0.0f}, {0, 0.7f}, {2, 1.0f}, {1, 1.0f}, {0, 0.0f}};
    int bad_ahd = 0, bad_base = 0;
    uint64_t kept = 0, texels = 0, last_kept = 0, last_texels = 0, based = 0;
    for (size_t k = 0; k < sizeof steps / sizeof steps[0]; k++) {
      ASSERT_OK(ub_runtime_set_element(ra, (uint32_t)steps[k].e, steps[k].v));
      ASSERT_OK(ub_runtime_set_element(rk, (uint32_t)steps[k].e, steps[k].v));
      ASSERT_OK(ub_runtime_set_element(rn, (uint32_t)steps[k].e, steps[k].v));
      ub_runtime_update_stats sa, sk, sn;
      ASSERT_OK(ub_runtime_update(ra, &sa));
      ASSERT_OK(ub_runtime_update(rk, &sk));
      ASSERT_OK(ub_runtime_update(rn, &sn));
      bad_ahd += !same_atlases(ra, rk, back) || sa.texels_reencoded != sk.texels_reencoded;
      bad_base += !same_atlases(ra, rn, back) || sa.texels_reencoded != sn.texels_reencoded ||
                  sn.texels_base != 0;
      based += sa.texels_base;
      kept += sk.texels_kept;
      texels += sk.texels_reencoded;
      last_kept = sk.texels_kept;
      last_texels = sk.texels_reencoded;
    }
    printf("kept load state with a door, objects and combinations: %d of %zu updates differ "
           "(want 0); %llu of %llu texels copied back, %llu of %llu at the last (all back)\n",
           bad_ahd, sizeof steps / sizeof steps[0], (unsigned long long)kept,
           (unsigned long long)texels, (unsigned long long)last_kept,
           (unsigned long long)last_texels);
    ASSERT_TRUE(bad_ahd == 0 && kept > 0 && kept < texels);
    ASSERT_TRUE(last_texels > 0 && last_kept == last_texels);
    /* then every set off, the door opened and shut: the texels no object or set still
     * changes go back to the base state (objects shown and doors shut apply 0) */
    uint64_t based_end = 0;
    for (int k = 0; k < 3; k++) {
      const float off[3] = {0.0f, 0.0f, 0.0f};
      for (uint32_t d = 0; k == 0 && d < ub_runtime_dls_count(ra); d++) {
        ASSERT_OK(ub_runtime_set_dls(ra, d, off));
        ASSERT_OK(ub_runtime_set_dls(rn, d, off));
      }
      if (k > 0) {
        ASSERT_OK(ub_runtime_set_element(ra, 0, k == 1 ? 1.0f : 0.0f));
        ASSERT_OK(ub_runtime_set_element(rn, 0, k == 1 ? 1.0f : 0.0f));
      }
      ub_runtime_update_stats sa, sn;
      ASSERT_OK(ub_runtime_update(ra, &sa));
      ASSERT_OK(ub_runtime_update(rn, &sn));
      bad_base += !same_atlases(ra, rn, back) || sa.texels_reencoded != sn.texels_reencoded ||
                  sn.texels_base != 0;
      based += sa.texels_base;
      based_end += k == 2 ? sa.texels_base : 0;
    }
    printf("base state's AHD with a door, objects and combinations: %d of %zu updates differ "
           "from a run-time without (want 0); %llu texels copied from the base, %llu when the "
           "door shut with every set off\n",
           bad_base, sizeof steps / sizeof steps[0] + 3, (unsigned long long)based,
           (unsigned long long)based_end);
    ASSERT_TRUE(bad_base == 0 && based_end > 0);
  }
  ub_runtime_free(ra);
  ub_runtime_free(rk);
  ub_runtime_free(rn);
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
