/* Hard case: a 5 cm wall between a lit and a dark room (level two_rooms: light in room A,
 * x < -0.025; room B, x > 0.025, sealed). Lightmaps only (GLG near the wall: the lead's
 * part; LLG: not implemented). test_bake checks 5 points next to the wall; this case adds
 * grazing points right at the junctions on the dark side: the wall/floor and wall/ceiling
 * edges, exactly on the edge and 1 mm, 1 cm, 5 cm from it along each surface, with the
 * surface normal and with the 45° bisector normal. Each is compared with the mirrored
 * point in room A. Asserted: every dark/lit ratio < 1%; every texel of room B's surfaces
 * (x > 0.025 m, facing into B) below 1% of room A's median texel; all finite, ≥ 0. */
#include "hard_util.h"

typedef struct pt {
  float p[3], n[3];
  const char *what;
} pt;

int main(void)
{
  hard_init("two_rooms");
  char gltf[1100];
  snprintf(gltf, sizeof gltf, "%s/levels/two_rooms.gltf", hard_build);
  const float t2 = 0.025f; /* half wall thickness */
  /* 8 bounces: a leak shows from the first bounce on; the per-texel auto-stop runs this
   * level to 24 draft bounces (26 s), mostly refining room A. */
  ub_bake_options o;
  hard_options(&o, UB_QUALITY_DRAFT, 8, 0.1f);
  ub_bake_stats st;
  ub_runtime *rt = hard_bake(gltf, &o, &st);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    TEST_MAIN_END();
  const ub_bakefile *bf = ub_runtime_bakefile(rt);

  pt pts[256];
  int np = 0;
  const float zs[] = {-1.9f, -1.13f, -0.41f, 0.0f, 0.37f, 1.21f, 1.9f};
  const float ds[] = {0.0f, 0.001f, 0.01f, 0.05f};
  const float s = 0.70710678f;
  for (int iz = 0; iz < 7; iz++)
    for (int id = 0; id < 4; id++) {
      float z = zs[iz], d = ds[id];
      pts[np++] = (pt){{t2 + d, 0.0f, z}, {0, 1, 0}, "floor at the wall"};
      pts[np++] = (pt){{t2, d, z}, {1, 0, 0}, "wall at the floor"};
      pts[np++] = (pt){{t2 + d, d, z}, {s, s, 0}, "floor/wall corner, bisector"};
      pts[np++] = (pt){{t2 + d, 3.0f, z}, {0, -1, 0}, "ceiling at the wall"};
      pts[np++] = (pt){{t2, 3.0f - d, z}, {1, 0, 0}, "wall at the ceiling"};
      pts[np++] = (pt){{t2 + d, 3.0f - d, z}, {s, -s, 0}, "ceiling/wall corner, bisector"};
    }
  double worst = 0.0, lit_min = INFINITY;
  int fails = 0;
  for (int i = 0; i < np; i++) {
    float b[3], a[3], db, da;
    float pa[3] = {-pts[i].p[0], pts[i].p[1], pts[i].p[2]};
    float na[3] = {-pts[i].n[0], pts[i].n[1], pts[i].n[2]};
    ASSERT_OK(ub_runtime_query_lightmap(rt, pts[i].p, pts[i].n, b, &db));
    ASSERT_OK(ub_runtime_query_lightmap(rt, pa, na, a, &da));
    int ok = isfinite(b[1]) && isfinite(a[1]) && b[1] >= 0.0f && a[1] > 0.0f;
    double ratio = a[1] > 0 ? b[1] / a[1] : 1.0;
    worst = fmax(worst, ratio);
    lit_min = fmin(lit_min, a[1]);
    if (!ok || !(ratio < 0.01)) {
      if (fails++ < 8)
        fprintf(stderr, "  leak at (%.3f %.3f %.3f) %s: dark %.5g lit %.5g (ratio %.3g)\n",
                pts[i].p[0], pts[i].p[1], pts[i].p[2], pts[i].what, b[1], a[1], ratio);
    }
  }
  printf("two_rooms junctions: %d points, worst dark/lit ratio %.3e (lit side min %.4g W/m^2)\n",
         np, worst, lit_min);
  ASSERT_TRUE(fails == 0);

  /* Every texel facing into room B versus room A's median texel. */
  double *lit = NULL;
  size_t nlit = 0, cap = 0, ndark = 0, nonfinite = 0, negative = 0;
  double dark_max = 0.0;
  float dark_at[3] = {0, 0, 0};
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    hard_texels tx;
    if (!hard_texels_get(rt, a, &tx))
      continue;
    for (size_t i = 0; i < (size_t)tx.w * tx.h; i++) {
      if (tx.coverage[i] != 1)
        continue;
      const float *p = tx.pos + 3 * i, *n = tx.normal + 3 * i;
      double e = tx.e[3 * i + 1];
      nonfinite += !isfinite(e);
      negative += e < 0.0;
      /* inside room A: x in (-4.025, -0.025), y in (0,3), |z| < 2, facing inward */
      int in_a = p[0] < -t2 + 1e-3 && p[0] > -4.025f - 1e-3 && p[1] > -1e-3 && p[1] < 3.001f &&
                 fabsf(p[2]) < 2.001f;
      int in_b = p[0] > t2 - 1e-3 && p[0] < 4.025f + 1e-3 && p[1] > -1e-3 && p[1] < 3.001f &&
                 fabsf(p[2]) < 2.001f;
      /* the shared wall's faces at x = ±t2 count for the room they face */
      if (fabsf(p[0] - t2) < 1e-3 && n[0] < 0.5f)
        in_b = 0;
      if (fabsf(p[0] + t2) < 1e-3 && n[0] > -0.5f)
        in_a = 0;
      if (in_a) {
        if (nlit == cap) {
          cap = cap ? 2 * cap : 4096;
          lit = realloc(lit, cap * sizeof *lit);
        }
        lit[nlit++] = e;
      } else if (in_b) {
        ndark++;
        if (e > dark_max) {
          dark_max = e;
          memcpy(dark_at, p, sizeof dark_at);
        }
      }
    }
    hard_texels_free(&tx);
  }
  for (size_t i = 1; i < nlit; i++)
    for (size_t j = i; j > 0 && lit[j - 1] > lit[j]; j--) {
      double t = lit[j];
      lit[j] = lit[j - 1];
      lit[j - 1] = t;
    }
  double med = nlit ? lit[nlit / 2] : 0.0;
  printf("two_rooms texels: %zu in room A (median E %.4g), %zu in room B (max E %.4g at %.3f "
         "%.3f %.3f, %.2e of A's median); non-finite %zu, negative %zu\n",
         nlit, med, ndark, dark_max, dark_at[0], dark_at[1], dark_at[2],
         med > 0 ? dark_max / med : 0.0, nonfinite, negative);
  ASSERT_TRUE(nlit > 1000 && ndark > 1000);
  ASSERT_TRUE(dark_max < 0.01 * med);
  ASSERT_TRUE(nonfinite == 0 && negative == 0);
  free(lit);
  ub_runtime_free(rt);

  /* The GLG's leak planes (probes/leak.h): one entry per distinct plane, shared by the
   * tets along a wall, and every tet's plane still cuts one of its edges (a corner on
   * each side, or on it): the sharing kept each tet its own plane. */
  ub_bakefile *file = NULL;
  ASSERT_OK(ub_bakefile_read(st.ubk_path, &hard_log, &file));
  if (file) {
    const uint32_t K = file->glg_plane_count, T = file->glg_tet_count;
    uint32_t with = 0, dup = 0, uncut = 0;
    for (uint32_t i = 0; i < K; i++)
      for (uint32_t j = i + 1; j < K; j++)
        dup += !memcmp(file->glg_planes + 4 * (size_t)i, file->glg_planes + 4 * (size_t)j,
                       4 * sizeof(float));
    for (uint32_t t = 0; t < T; t++) {
      uint32_t k = file->glg_plane_of[t];
      if (k == 0xFFFFFFFFu)
        continue;
      with++;
      ASSERT_TRUE(k < K);
      if (k >= K)
        break;
      const float *pl = file->glg_planes + 4 * (size_t)k;
      int below = 0, above = 0;
      for (int c = 0; c < 4; c++) {
        const float *x = file->glg_positions + 3 * (size_t)file->glg_tets[4 * (size_t)t + c];
        double s = (double)pl[0] * x[0] + (double)pl[1] * x[1] + (double)pl[2] * x[2] + pl[3];
        below += s <= 1e-4;
        above += s >= -1e-4;
      }
      uncut += !(below && above);
    }
    printf("leak planes: %u tets, %u with a plane, %u planes (%u equal pairs), %u tets whose "
           "plane cuts none of their edges\n", T, with, K, dup, uncut);
    ASSERT_TRUE(with > 0 && K > 0 && K < with);
    ASSERT_TRUE(dup == 0 && uncut == 0);
    ub_bakefile_free(file);
  }
  TEST_MAIN_END();
}
