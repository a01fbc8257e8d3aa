/* Per-texel error estimates (bake/pass.h texel_se, DIR/NAME_error<i>.exr) against the
 * error actually made, and adaptive sampling (--target-error) against its target.
 *
 * Measured error: a bake minus a converged bake of the same settings but another seed
 * and far more gather rays (same texel layout, same fixed bounce count, so the difference
 * is sampling noise only). Both bakes are noisy and independent, so per texel
 *   E[(E_a − E_c)²] = se_a² + se_c² + q²,
 * q² being the rounding of both values to half floats in the EXR (ulp²/12 each; it
 * matters only on sunroom's quietest texels, ~0.03%). The test compares RMS |E_a − E_c|
 * with RMS √(se_a² + se_c² + q²), both relative to max(E_c, floor) (ub_rel_error), over
 * lit texels: the estimate passes if the ratio is within [1/2, 2] (issue 7: "within 2×").
 * Per-texel bins, held to [1/2.5, 2.5]: quartiles of the converged bake's relative s.e.
 * (how noisy a texel is by its place in the level, independent of bake a's luck). Not of
 * bake a's own estimate: on cornell at 64 rays the bounce light is heavy-tailed (gather
 * rays that hit the ceiling next to the lamp carry much of it), so a texel whose samples
 * missed those hits has both a low value and a low variance estimate; binning by the
 * estimate sorts texels by that luck (lowest bin ~3× under, top bin ~0.85×, aggregate
 * still 0.94). The looser bin tolerance: a quarter of cornell is ~150 texels of such a
 * heavy-tailed error.
 *
 * Adaptive: cornell at 256 base rays with --target-error T = 5%. If every texel's standard
 * error is ≤ T and the error is roughly normal, |error| ≤ 1.96·σ for 95% of the texels;
 * the measured error also holds the converged bake's own error σ_c, so
 *   p95(measured) ≤ 1.96 · √(T² + σ_c²)
 * with σ_c the converged bake's RMS relative s.e. (about 2% here, so the bound is about
 * 2.1·T). Texels that reach the round cap first, and the noise of the neighbour-based
 * plan, take some of it: the test allows 10% over that bound. It also checks the adaptive
 * bake beats the uniform one at the same base rays.
 *
 * Budgets are draft-sized (cornell 618 texels; sunroom at 2× its texel size) so the whole
 * test runs within a minute on 2 cores. Outputs stay in UB_BUILD/test_out/errest/. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bake/pass.h"
#include "lightmaps/image.h"
#include "test_util.h"
#include "ubake/bake.h"

static void quiet_log(void *user, ub_log_level level, const char *msg)
{
  (void)user;
  if (level <= UB_LOG_WARNING)
    fprintf(stderr, "%s\n", msg);
}
static const ub_log g_log = {quiet_log, NULL};

typedef struct bake_cfg {
  const char *level;
  uint32_t gather_rays, seed;
  int bounces;
  float texel_size;
  double target;
} bake_cfg;

/* A bake's error map (atlas 0..n): per covered pixel, E and se. */
typedef struct emap {
  uint32_t n;
  float *e, *se;
  double seconds;
  uint64_t rays;
} emap;

static int bake(const char *build, const char *tag, const bake_cfg *c, emap *out)
{
  memset(out, 0, sizeof *out);
  char level[1024], dir[1024];
  snprintf(level, sizeof level, "%s/levels/%s.gltf", build, c->level);
  snprintf(dir, sizeof dir, "%s/test_out/errest/%s", build, tag);
  ub_bake_options o;
  ub_bake_options_default(&o);
  o.quality = UB_QUALITY_DRAFT;
  o.out_dir = dir;
  o.threads = 0;
  o.seed = c->seed;
  o.gather_rays = c->gather_rays;
  o.bounces = c->bounces;
  o.texel_size = c->texel_size;
  o.target_error = c->target;
  ub_bake_stats st;
  ub_result r = ub_bake_level(level, &o, &g_log, &st);
  if (r != UB_OK) {
    fprintf(stderr, "%s: bake failed (%d)\n", tag, (int)r);
    return 0;
  }
  out->seconds = st.total_seconds;
  out->rays = st.rays_total;
  for (uint32_t a = 0; a < st.atlases; a++) {
    char path[1100];
    snprintf(path, sizeof path, "%s/%s_error%u.exr", dir, c->level, a);
    ub_image *im = NULL;
    if (ub_image_read_exr(path, &g_log, &im) != UB_OK)
      return 0;
    int ce = ub_image_channel(im, "E"), cc = ub_image_channel(im, "covered"),
        cs = ub_image_channel(im, "se");
    if (ce < 0 || cc < 0 || cs < 0) {
      ub_image_free(im);
      return 0;
    }
    size_t npx = (size_t)im->width * im->height;
    out->e = realloc(out->e, (out->n + npx) * sizeof(float));
    out->se = realloc(out->se, (out->n + npx) * sizeof(float));
    for (size_t p = 0; p < npx; p++) {
      const float *px = im->data + p * im->channels;
      if (px[cc] > 0.5f) {
        out->e[out->n] = px[ce];
        out->se[out->n] = px[cs];
        out->n++;
      }
    }
    ub_image_free(im);
  }
  printf("  %-22s %5u texels  %.2f s  %.2f M rays\n", tag, out->n, out->seconds,
         out->rays * 1e-6);
  return out->n > 0;
}

static void emap_free(emap *m)
{
  free(m->e);
  free(m->se);
}

static int cmp_double(const void *a, const void *b)
{
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

/* Variance of rounding x to a half float: ulp²/12, ulp = 2^(exponent − 10). */
static double half_q2(float x)
{
  if (!(x > 0.0f))
    return 0.0;
  int ex;
  frexpf(x, &ex); /* x = m · 2^ex, m in [0.5, 1): half's ulp is 2^(ex − 11) */
  double ulp = ldexp(1.0, ex - 11);
  return ulp * ulp / 12.0;
}

/* Estimate vs measured for bake a against converged c. */
static void check_estimate(const char *what, const emap *a, const emap *c)
{
  ASSERT_TRUE(a->n == c->n);
  if (a->n != c->n)
    return;
  uint32_t n = a->n;
  double floor_e = ub_err_floor(c->e, n), mean = floor_e / UB_ERR_FLOOR;
  double *pred = malloc(n * sizeof *pred), *meas = malloc(n * sizeof *meas);
  double *key = malloc(n * sizeof *key), *sgn = malloc(n * sizeof *sgn);
  uint32_t m = 0;
  double sp = 0, sm = 0, sa = 0;
  for (uint32_t i = 0; i < n; i++) {
    if (!(c->e[i] > UB_ERR_LIT * mean))
      continue;
    double den = c->e[i] > floor_e ? c->e[i] : floor_e;
    pred[m] = sqrt((double)a->se[i] * a->se[i] + (double)c->se[i] * c->se[i] +
                   half_q2(a->e[i]) + half_q2(c->e[i])) / den;
    meas[m] = fabs((double)a->e[i] - c->e[i]) / den;
    sgn[m] = ((double)a->e[i] - c->e[i]) / den;
    ASSERT_TRUE(isfinite(pred[m]) && isfinite(meas[m]));
    sp += pred[m] * pred[m];
    sm += meas[m] * meas[m];
    sa += (double)a->se[i] * a->se[i] / (den * den);
    key[m] = c->se[i] / den;
    m++;
  }
  ASSERT_TRUE(m > 100);
  double rp = sqrt(sp / m), rm = sqrt(sm / m), ratio = rm / rp;
  printf("%s: %u lit texels, RMS relative error measured %.3f%%, predicted %.3f%% "
         "(this bake's own estimate %.3f%%), measured/predicted %.2f\n",
         what, m, 100 * rm, 100 * rp, 100 * sqrt(sa / m), ratio);
  ASSERT_TRUE(ratio >= 0.5 && ratio <= 2.0);
  /* Quartile bins of the predicted error. */
  double *ck = malloc(m * sizeof *ck);
  memcpy(ck, key, m * sizeof *ck);
  qsort(key, m, sizeof *key, cmp_double);
  double edge[5] = {-1, key[m / 4], key[m / 2], key[3 * m / 4], INFINITY};
  for (int b = 0; b < 4; b++) {
    double bp = 0, bm = 0, bs = 0;
    uint32_t k = 0;
    for (uint32_t i = 0; i < m; i++)
      if (ck[i] > edge[b] && ck[i] <= edge[b + 1]) {
        bp += pred[i] * pred[i];
        bm += meas[i] * meas[i];
        bs += sgn[i];
        k++;
      }
    if (k < 30 || !(bp > 0.0))
      continue;
    double br = sqrt(bm / bp);
    printf("  bin %d (%u texels, predicted %.3f%%): measured/predicted %.2f, mean signed "
           "error %+.3f%%\n", b, k, 100 * sqrt(bp / k), br, 100 * bs / k);
    ASSERT_TRUE(br >= 1 / 2.5 && br <= 2.5);
  }
  free(pred);
  free(meas);
  free(key);
  free(ck);
  free(sgn);
}

/* p95 of the measured relative error of a against c over lit texels. */
static double p95_measured(const emap *a, const emap *c, double *rms_conv)
{
  uint32_t n = a->n < c->n ? a->n : c->n;
  double floor_e = ub_err_floor(c->e, n), mean = floor_e / UB_ERR_FLOOR;
  double *v = malloc((n + 1) * sizeof *v);
  uint32_t m = 0;
  double s2 = 0;
  for (uint32_t i = 0; i < n; i++) {
    if (!(c->e[i] > UB_ERR_LIT * mean))
      continue;
    double den = c->e[i] > floor_e ? c->e[i] : floor_e;
    v[m++] = fabs((double)a->e[i] - c->e[i]) / den;
    s2 += (double)c->se[i] * c->se[i] / (den * den);
  }
  qsort(v, m, sizeof *v, cmp_double);
  double p = m ? v[(size_t)((m - 1) * 0.95)] : NAN;
  *rms_conv = m ? sqrt(s2 / m) : NAN;
  free(v);
  return p;
}

int main(int argc, char **argv)
{
  const char *build = getenv("UB_BUILD");
  if (!build)
    build = ".";
  const char *only = argc > 1 ? argv[1] : NULL;
  if (only && !strcmp(only, "pair") && argc >= 10) {
    /* Diagnostic: LEVEL BOUNCES TEXEL RAYS_A SEED_A TARGET_A RAYS_B SEED_B TARGET_B. */
    bake_cfg a = {argv[2], (uint32_t)atoi(argv[5]), (uint32_t)atoi(argv[6]), atoi(argv[3]),
                  (float)atof(argv[4]), atof(argv[7])};
    bake_cfg c = {argv[2], (uint32_t)atoi(argv[8]), (uint32_t)atoi(argv[9]), atoi(argv[3]),
                  (float)atof(argv[4]), argc > 10 ? atof(argv[10]) : 0.0};
    emap ma, mc;
    if (bake(build, "pair_a", &a, &ma) && bake(build, "pair_b", &c, &mc))
      check_estimate("pair", &ma, &mc);
    emap_free(&ma);
    emap_free(&mc);
    TEST_MAIN_END();
  }

  emap conv;
  memset(&conv, 0, sizeof conv);
  int need_conv = !only || !strcmp(only, "cornell") || !strcmp(only, "adaptive");
  bake_cfg cc = {"cornell", 4096, 2, 4, 0.0f, 0.0};
  if (need_conv && !bake(build, "cornell_conv", &cc, &conv))
    ASSERT_TRUE(0);
  if (conv.n && (!only || !strcmp(only, "cornell"))) {
    printf("cornell (64 gather rays vs 4096, 4 bounces)\n");
    bake_cfg a = {"cornell", 64, 1, 4, 0.0f, 0.0};
    emap ma;
    if (bake(build, "cornell_a", &a, &ma))
      check_estimate("cornell", &ma, &conv);
    else
      ASSERT_TRUE(0);
    emap_free(&ma);
  }
  if (!only || !strcmp(only, "sunroom")) {
    printf("sunroom (32 gather rays vs 256, 0.5 m texels, 3 bounces)\n");
    bake_cfg a = {"sunroom", 32, 1, 3, 0.5f, 0.0};
    bake_cfg c = {"sunroom", 256, 2, 3, 0.5f, 0.0};
    emap ma, mc;
    if (bake(build, "sunroom_a", &a, &ma) && bake(build, "sunroom_conv", &c, &mc))
      check_estimate("sunroom", &ma, &mc);
    else
      ASSERT_TRUE(0);
    emap_free(&ma);
    emap_free(&mc);
  }
  if (conv.n && (!only || !strcmp(only, "adaptive"))) {
    const double T = 0.05;
    printf("cornell adaptive (target %.1f%%, 256 base gather rays, 4 bounces)\n", 100 * T);
    bake_cfg u = {"cornell", 256, 3, 4, 0.0f, 0.0};
    bake_cfg a = {"cornell", 256, 3, 4, 0.0f, T};
    emap mu, ma;
    if (bake(build, "adaptive_uniform", &u, &mu) && bake(build, "adaptive", &a, &ma)) {
      double sc, su, sa;
      double pu = p95_measured(&mu, &conv, &su);
      double pa = p95_measured(&ma, &conv, &sa);
      (void)p95_measured(&conv, &conv, &sc);
      double bound = 1.1 * 1.96 * sqrt(T * T + sc * sc);
      printf("cornell: p95 measured relative error: uniform %.2f%% (%.2f M rays), adaptive "
             "%.2f%% (%.2f M rays); bound 1.1 x 1.96 x sqrt(T^2 + sc^2) = %.2f%% with the "
             "converged bake's RMS s.e. sc = %.2f%%\n",
             100 * pu, mu.rays * 1e-6, 100 * pa, ma.rays * 1e-6, 100 * bound, 100 * sc);
      ASSERT_TRUE(sc <= T / 1.5); /* else the bound says little */
      ASSERT_TRUE(pa <= bound);
      ASSERT_TRUE(pa < pu);
    } else {
      ASSERT_TRUE(0);
    }
    emap_free(&mu);
    emap_free(&ma);
  }
  emap_free(&conv);
  TEST_MAIN_END();
}
