/* Hard case: MIS with zero-pdf strategies. Level mis_edge: a black 4×4 m floor (albedo 0,
 * so direct light only) and emitters of radiance Le = 1 (albedo 0) placed where a sampling
 * strategy has zero pdf: em_coplanar (in the floor's plane, sharing its edge x = 2: seen
 * exactly edge-on from every floor point, cosines 0 at both ends), em_touching (vertical,
 * its bottom edge on the floor: distance → 0), em_edgeon (a triangle in the plane z = 1.8,
 * touching the floor), em_away (facing away from the floor) and em_below (under the floor,
 * facing its back). Emitter sampling divides by cos at the emitter and by the distance;
 * gather rays see emitters at cos 0: no 0/0 may leak out.
 * Closed form at a floor point: E = Le/2·|Σ_i Θ_i n·Γ_i| over the emitter polygons whose
 * front faces the point (Lambert's polygon formula; nothing occludes them for the points
 * used). Asserted: bake succeeds; every texel finite, ≥ 0, ≤ π·Le (the most any receiver
 * can get here); nothing clamped; floor texels more than 0.3 m from the touching emitters
 * (and 0.1 m from their planes),
 * against the closed form at their centre: no bias (their mean within 1%), Monte Carlo
 * scatter bounded (mean |error| < 10%, each within 50% + 0.005 W/m²: at high quality the
 * far texels, lit by emitters of 0.01 sr, scatter ~6%); texels on em_coplanar itself finite
 * and bounded. */
#include "hard_util.h"

typedef struct poly {
  int n;
  double v[4][3];
  double nrm[3]; /* emitting side */
} poly;

static const poly emitters[2] = {
    {4, {{-1, 0, -0.5}, {-1, 0, 0.5}, {-1, 1, 0.5}, {-1, 1, -0.5}}, {1, 0, 0}}, /* em_touching */
    {3, {{0.5, 0, 1.8}, {1.5, 0, 1.8}, {1.0, 0.8, 1.8}}, {0, 0, -1}}};         /* em_edgeon */

static double lambert(const double p[3], const double n[3], double le)
{
  double e = 0.0;
  for (int k = 0; k < 2; k++) {
    const poly *P = &emitters[k];
    double side = (p[0] - P->v[0][0]) * P->nrm[0] + (p[1] - P->v[0][1]) * P->nrm[1] +
                  (p[2] - P->v[0][2]) * P->nrm[2];
    if (!(side > 0.0))
      continue; /* behind the emitter (or in its plane) */
    double s = 0.0;
    for (int i = 0; i < P->n; i++) {
      const double *a = P->v[i], *b = P->v[(i + 1) % P->n];
      double va[3] = {a[0] - p[0], a[1] - p[1], a[2] - p[2]};
      double vb[3] = {b[0] - p[0], b[1] - p[1], b[2] - p[2]};
      double la = sqrt(va[0] * va[0] + va[1] * va[1] + va[2] * va[2]);
      double lb = sqrt(vb[0] * vb[0] + vb[1] * vb[1] + vb[2] * vb[2]);
      double c[3] = {va[1] * vb[2] - va[2] * vb[1], va[2] * vb[0] - va[0] * vb[2],
                     va[0] * vb[1] - va[1] * vb[0]};
      double lc = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
      if (!(lc > 0) || !(la > 0) || !(lb > 0))
        continue;
      double cosang = (va[0] * vb[0] + va[1] * vb[1] + va[2] * vb[2]) / (la * lb);
      double th = acos(fmax(-1.0, fmin(1.0, cosang)));
      s += th * (n[0] * c[0] + n[1] * c[1] + n[2] * c[2]) / lc;
    }
    e += 0.5 * le * fabs(s);
  }
  return e;
}

int main(void)
{
  hard_init("mis_edge");
  const double le = 1.0;
  char gltf[1100];
  ASSERT_TRUE(hard_genlevel("mis_edge", "mis_edge", "", gltf, sizeof gltf));
  ub_bake_options o;
  hard_options(&o, UB_QUALITY_HIGH, -1, 0.1f);
  ub_bake_stats st;
  ub_runtime *rt = hard_bake(gltf, &o, &st);
  ASSERT_TRUE(rt != NULL);
  if (!rt)
    TEST_MAIN_END();
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  size_t n = 0, bad = 0, nfloor = 0, off = 0, ncop = 0;
  double emax = 0.0, worst = 0.0, sum_rel = 0.0, cop_max = 0.0, sum_e = 0.0, sum_x = 0.0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    hard_texels tx;
    if (!hard_texels_get(rt, a, &tx))
      continue;
    for (size_t i = 0; i < (size_t)tx.w * tx.h; i++) {
      if (tx.coverage[i] != 1)
        continue;
      n++;
      for (int c = 0; c < 3; c++) {
        float e = tx.e[3 * i + c];
        bad += !isfinite(e) || e < 0.0f || e > M_PI * le;
        emax = fmax(emax, e);
      }
      const float *p = tx.pos + 3 * i, *nn = tx.normal + 3 * i;
      if (!(fabsf(p[1]) < 1e-3f && nn[1] > 0.99f))
        continue;
      double e = tx.e[3 * i + 1];
      if (p[0] > 2.0f) { /* texels of em_coplanar */
        ncop++;
        cop_max = fmax(cop_max, e);
        continue;
      }
      /* floor texels away from the emitters' contact lines (the field is steep there) */
      double dt = fabs(p[0] + 1.0) + fmax(0.0, fabs(p[2]) - 0.5);
      double dg = fabs(p[2] - 1.8) + fmax(0.0, fabs(p[0] - 1.0) - 0.5);
      /* and away from the emitters' planes, where a texel straddles lit and unlit sides */
      if (fabsf(p[0]) > 1.999f || fabsf(p[2]) > 1.999f || dt < 0.3 || dg < 0.3 || p[2] > 1.7f ||
          fabsf(p[0] + 1.0f) < 0.1f)
        continue;
      double q[3] = {p[0], p[1], p[2]}, up[3] = {0, 1, 0};
      double expect = lambert(q, up, le);
      double err = fabs(e - expect);
      nfloor++;
      sum_e += e;
      sum_x += expect;
      sum_rel += expect > 0.02 ? err / expect : 0.0;
      worst = fmax(worst, expect > 0.02 ? err / expect : 0.0);
      if (!(err <= 0.5 * expect + 0.005) && off++ < 5)
        fprintf(stderr, "  floor texel (%.2f %.2f): E = %.5f, closed form %.5f\n", p[0], p[2], e,
                expect);
    }
    hard_texels_free(&tx);
  }
  double mean_rel = nfloor ? sum_rel / nfloor : 1.0;
  printf("mis_edge: floor mean E %.5f vs closed form %.5f (%.2f%%)\n", sum_e / nfloor, sum_x / nfloor, 100 * (sum_e - sum_x) / sum_x);
  printf("mis_edge: %zu texels, max E %.4f (bound pi*Le = %.4f), %zu non-finite/negative/above; "
         "%zu floor texels vs Lambert: mean |error| %.2f%%, worst %.2f%%, %zu beyond 50%%; %zu "
         "texels on the coplanar emitter, max E %.4f; clamped %llu; non-finite in .ubk %llu\n",
         n, emax, M_PI * le, bad, nfloor, 100 * mean_rel, 100 * worst, off, ncop, cop_max,
         (unsigned long long)st.clamped_values, (unsigned long long)hard_nonfinite(bf));
  ASSERT_TRUE(n > 1000 && bad == 0);
  ASSERT_TRUE(nfloor > 500 && off == 0);
  ASSERT_TRUE(mean_rel < 0.10);
  ASSERT_NEAR(sum_e, sum_x, 0.0, 0.01);
  ASSERT_TRUE(ncop > 50);
  ASSERT_TRUE(st.clamped_values == 0);
  ASSERT_TRUE(hard_nonfinite(bf) == 0);
  ub_runtime_free(rt);
  TEST_MAIN_END();
}
