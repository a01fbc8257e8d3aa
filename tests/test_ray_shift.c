/* Per-receiver gather rays (ub_pass_desc.texel_ray_shift / probe_ray_shift, what a DLS
 * full pass uses where a set's light is faint, bake/dls.c):
 * - a shift array of zeros gives the bits of no array;
 * - furnace (closed cube, rho 0.5, Le 1, 2 bounces): with every texel at a quarter of the
 *   rays and with shifts 0..3 in turn, the mean irradiance is within 0.5% of the closed
 *   form π·Le·(1 + ρ + ρ²) and no more texels off it by over 4 of their own standard
 *   errors + 1% than without shifts (one corner texel at 64 rays; the
 *   gathers read a uniform image, so a wrong MIS weight — the full count where a receiver
 *   traced fewer — shows as a bias of 10% or more);
 * - cornell (point light, closed, 2 bounces; next-event estimation at bounce 1, texel
 *   lights): shifts 0..3 in turn over texels and 3 over interior GLG probes against no
 *   shift: the gather rays drop by exactly 2 bounces × Σ (N − N_r); no bias (the mean
 *   difference within 3 standard errors of the mean), texels and probes within 5
 *   standard errors of each other except 0.5% at most; the traced rays are fewer;
 * - cornell's expectations, over 96 seeds: the same with 1/4 of the rays as with all
 *   (test_expectation);
 * - later bounces with fewer rays (ub_pass_desc.bounce_full_rays = 0, bounce_shifts): the
 *   rule's values (ub_pass_bounce_shift), and cornell at 6 bounces over 48 seeds: the same
 *   expectations as every bounce at full rays, with fewer gather rays
 *   (test_late_expectation). A shift chosen from a bounce's own noisy results leaves each
 *   bounce's estimate unbiased; this is where that claim is checked.
 * - the store left out (ub_pass_desc.no_store, the DLS influence passes): cornell with GLG
 *   probes, a texel subset and each bounce's I_z kept gives the influence measures, bounce
 *   energies and ray counts bit for bit as with the store, and no stored arrays
 *   (test_no_store).
 * - outside texels looked for among candidates (ub_pass_desc.outside_candidates, the DLS
 *   full passes): cornell, an influence-like pass over three texels in four, then a pass
 *   over half of those lit at the others by the first pass's bounces: the same SH and I_z
 *   bits with the candidate list as without (test_outside_candidates). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pass_level.h"
#include "test_util.h"
#include "ubake/bake.h"
#include "ubake/scene.h"

static char g_build[512];

static void desc_init(const level *L, const uint8_t *en, ub_pass_desc *pd)
{
  level_desc_init(L, en, pd);
}

static void test_furnace(void)
{
  level L;
  if (!level_open(g_build, "furnace", &L))
    return;
  uint32_t T = L.lm->texel_count;
  uint8_t *en = calloc(L.s->light_count + 1, 1);
  uint8_t *sh = calloc((size_t)T + 1, 1);
  ub_pass_desc pd;
  desc_init(&L, en, &pd);
  pd.emissive = 1;
  ub_pass_result plain, zero;
  ASSERT_OK(ub_pass_run(&pd, NULL, &plain));
  pd.texel_ray_shift = sh; /* all zero */
  ASSERT_OK(ub_pass_run(&pd, NULL, &zero));
  ASSERT_TRUE(memcmp(plain.sh, zero.sh, (size_t)T * 12 * sizeof(float)) == 0);
  ASSERT_TRUE(memcmp(plain.iz, zero.iz, (size_t)T * 3 * sizeof(float)) == 0);
  ub_pass_result_free(&zero);
  double rho = L.s->materials[0].albedo[1];
  double expect = M_PI * (1.0 + rho + rho * rho);
  /* the unshifted pass's own outliers (a corner texel's bounce-0 emitter samples) */
  uint32_t bad0 = 0;
  for (uint32_t t = 0; t < T; t++)
    bad0 += !(fabs(plain.iz[3 * (size_t)t + 1] - expect) <= 4.0 * plain.texel_se[t] + 0.01 * expect);
  for (int pattern = 0; pattern < 2; pattern++) {
    for (uint32_t t = 0; t < T; t++)
      sh[t] = pattern == 0 ? 2 : (uint8_t)(t % 4);
    ub_pass_result r;
    ASSERT_OK(ub_pass_run(&pd, NULL, &r));
    double sum = 0.0, worst = 0.0;
    uint32_t bad = 0;
    for (uint32_t t = 0; t < T; t++) {
      double e = r.iz[3 * (size_t)t + 1], dev = fabs(e - expect);
      sum += e;
      worst = fmax(worst, dev / expect);
      bad += !(dev <= 4.0 * r.texel_se[t] + 0.01 * expect);
    }
    double mean = sum / T;
    printf("furnace, shifts %s: mean E %.5f, closed form %.5f (%.3f%%), worst texel %.2f%%, "
           "%u of %u texels outside 4 s.e. + 1%% (unshifted %u); gather rays %llu vs %llu "
           "unshifted\n",
           pattern == 0 ? "all 2" : "0..3", mean, expect, 100 * (mean - expect) / expect,
           100 * worst, bad, T, bad0, (unsigned long long)r.rays_gather,
           (unsigned long long)plain.rays_gather);
    ASSERT_NEAR(mean, expect, 0.0, 0.005);
    ASSERT_TRUE(bad <= bad0);
    ASSERT_TRUE(r.rays_gather < plain.rays_gather);
    ub_pass_result_free(&r);
  }
  ub_pass_result_free(&plain);
  free(sh);
  free(en);
  level_close(&L);
}

/* z-scores of a against b with their own standard errors: the share beyond 5 and the
 * mean difference against 3 standard errors of the mean. */
static void compare(const char *what, const float *a, const float *sa, const float *b,
                    const float *sb, size_t n, size_t stride)
{
  double diff = 0.0, var = 0.0;
  size_t far = 0, m = 0;
  for (size_t i = 0; i < n; i++) {
    double d = (double)a[i * stride] - b[i * stride];
    double v = (double)sa[i] * sa[i] + (double)sb[i] * sb[i];
    if (!(v > 0.0))
      continue;
    diff += d;
    var += v;
    far += fabs(d) > 5.0 * sqrt(v);
    m++;
  }
  double bias = m ? diff / m : 0.0, se = m ? sqrt(var) / m : 0.0;
  printf("cornell %s: %zu receivers, mean difference %.3g (3 s.e. of the mean %.3g), %zu "
         "beyond 5 s.e.\n",
         what, m, bias, 3 * se, far);
  ASSERT_TRUE(m > 0);
  ASSERT_TRUE(fabs(bias) <= 3.0 * se);
  ASSERT_TRUE(far <= m / 200);
}

static void test_cornell(void)
{
  level L;
  if (!level_open(g_build, "cornell", &L))
    return;
  uint32_t T = L.lm->texel_count;
  ASSERT_TRUE(L.s->light_count > 0);
  uint8_t *en = calloc(L.s->light_count + 1, 1);
  memset(en, 1, L.s->light_count);
  /* interior probes on a 4 x 4 x 4 grid inside the 2 m box */
  enum { P = 64 };
  float pos[P * 3];
  for (int i = 0; i < P; i++) {
    pos[3 * i] = -0.75f + 0.5f * (float)(i % 4);
    pos[3 * i + 1] = 0.25f + 0.5f * (float)(i / 4 % 4);
    pos[3 * i + 2] = -0.75f + 0.5f * (float)(i / 16);
  }
  uint8_t *tsh = calloc((size_t)T + 1, 1), psh[P];
  ub_pass_desc pd;
  desc_init(&L, en, &pd);
  pd.probe_count = P;
  pd.probe_pos = pos;
  pd.probe_rays = 128;
  ub_pass_result plain, r;
  ASSERT_OK(ub_pass_run(&pd, NULL, &plain));
  uint64_t saved = 0;
  for (uint32_t t = 0; t < T; t++) {
    tsh[t] = (uint8_t)(t % 4);
    saved += 64u - (64u >> tsh[t]);
  }
  for (int i = 0; i < P; i++) {
    psh[i] = 3;
    saved += 128u - 16u;
  }
  pd.texel_ray_shift = tsh;
  pd.probe_ray_shift = psh;
  pd.pass_id = 2; /* other random numbers: independent estimates */
  ASSERT_OK(ub_pass_run(&pd, NULL, &r));
  printf("cornell: gather rays %llu shifted vs %llu, %llu fewer (expected 2 bounces x %llu), "
         "bounces %u / %u\n",
         (unsigned long long)r.rays_gather, (unsigned long long)plain.rays_gather,
         (unsigned long long)(plain.rays_gather - r.rays_gather), (unsigned long long)saved,
         r.bounces, plain.bounces);
  ASSERT_TRUE(r.bounces == 2 && plain.bounces == 2);
  ASSERT_TRUE(plain.rays_gather - r.rays_gather == 2 * saved);
  compare("texels (green irradiance)", r.iz + 1, r.texel_se, plain.iz + 1, plain.texel_se, T, 3);
  /* probes: DC irradiance (the luminance of their direct + indirect) */
  float pa[P], pb[P];
  for (int i = 0; i < P; i++) {
    pa[i] = r.probe_direct[i] + r.probe_indirect[i];
    pb[i] = plain.probe_direct[i] + plain.probe_indirect[i];
  }
  compare("probes (DC irradiance)", pa, r.probe_se, pb, plain.probe_se, P, 1);
  ub_pass_result_free(&r);
  ub_pass_result_free(&plain);
  free(tsh);
  free(en);
  level_close(&L);
}

/* GLG probes for cornell: a 3 × 3 × 3 grid inside the box (pos: 27 × 3 floats). */
#define CORNELL_PROBES 27
static void cornell_probe_grid(float *pos)
{
  for (int i = 0; i < CORNELL_PROBES; i++) {
    pos[3 * i] = -0.6f + 0.6f * (float)(i % 3);
    pos[3 * i + 1] = 0.4f + 0.6f * (float)(i / 3 % 3);
    pos[3 * i + 2] = -0.6f + 0.6f * (float)(i / 9);
  }
}

/* cornell with every light enabled (*en: the caller frees it) and its probe grid in pos;
 * 0 when the level cannot be opened (reported by level_open). */
static int cornell_open(level *L, uint8_t **en, float *pos)
{
  if (!level_open(g_build, "cornell", L))
    return 0;
  *en = calloc(L->s->light_count + 1, 1);
  memset(*en, 1, L->s->light_count);
  cornell_probe_grid(pos);
  return 1;
}

/* Cornell's expectations over S seeds, two arms: arm 0 the variant, arm 1 the reference.
 * late = 0: the variant gives texels 1/4 and probes 1/8 of the rays (pass shifts), at 2
 * bounces; late = 1: 6 bounces, the variant with later bounces' fewer rays (the default),
 * the reference with every bounce at full rays. Per receiver (texels' I_z green, probes'
 * indirect) the means may differ by more than 5 standard errors at one receiver at most,
 * and the level's total irradiance by at most 4; the variant traces fewer gather rays. */
static void expectation_ab(int S, int late, uint32_t pid0, const char *what)
{
  enum { P = CORNELL_PROBES };
  level L;
  uint8_t *en;
  float pos[P * 3];
  if (!cornell_open(&L, &en, pos))
    return;
  uint32_t T = L.lm->texel_count;
  uint8_t *tsh = malloc((size_t)T + 1), psh[P];
  memset(tsh, 2, (size_t)T + 1);
  memset(psh, 3, sizeof psh);
  size_t nrec = (size_t)T + P;
  double *sum[2], *sq[2];
  uint64_t gathers[2] = {0, 0};
  for (int a = 0; a < 2; a++) {
    sum[a] = calloc(nrec, sizeof(double));
    sq[a] = calloc(nrec, sizeof(double));
  }
  double tot[2] = {0, 0}, tot2[2] = {0, 0};
  for (int a = 0; a < 2; a++)
    for (int k = 0; k < S; k++) {
      ub_pass_desc pd;
      desc_init(&L, en, &pd);
      pd.probe_count = P;
      pd.probe_pos = pos;
      pd.probe_rays = 128;
      pd.no_error_estimate = 1;
      pd.pass_id = pid0 + 100 * (uint32_t)a + (uint32_t)k;
      if (late) {
        pd.bounces = 6;
        pd.bounce_full_rays = a;
      } else if (a == 0) {
        pd.texel_ray_shift = tsh;
        pd.probe_ray_shift = psh;
      }
      ub_pass_result r;
      ASSERT_OK(ub_pass_run(&pd, NULL, &r));
      gathers[a] += r.rays_gather;
      double t = 0.0;
      for (size_t i = 0; i < nrec; i++) {
        double v = i < T ? r.iz[3 * i + 1] : r.probe_indirect[i - T];
        sum[a][i] += v;
        sq[a][i] += v * v;
        if (i < T)
          t += v;
      }
      tot[a] += t;
      tot2[a] += t * t;
      ub_pass_result_free(&r);
    }
  size_t far = 0, m = 0;
  double worst = 0.0;
  for (size_t i = 0; i < nrec; i++) {
    double ma = sum[0][i] / S, mb = sum[1][i] / S;
    double va = (sq[0][i] / S - ma * ma) / (S - 1), vb = (sq[1][i] / S - mb * mb) / (S - 1);
    double v = (va > 0 ? va : 0) + (vb > 0 ? vb : 0);
    if (!(v > 0.0))
      continue;
    double z = fabs(ma - mb) / sqrt(v);
    worst = fmax(worst, z);
    far += z > 5.0;
    m++;
  }
  double ma = tot[0] / S, mb = tot[1] / S;
  double v = (tot2[0] / S - ma * ma) / (S - 1) + (tot2[1] / S - mb * mb) / (S - 1);
  double zt = v > 0 ? (ma - mb) / sqrt(v) : 0.0;
  printf("cornell, %d seeds, %s: %zu receivers, %zu beyond 5 s.e. (worst %.1f), total "
         "irradiance %.3f%% apart (z %.2f), gathers %.1f%%\n",
         S, what, m, far, worst, 100 * (ma - mb) / mb, zt,
         gathers[1] ? 100.0 * (double)gathers[0] / (double)gathers[1] : 0.0);
  ASSERT_TRUE(m > T / 2);
  ASSERT_TRUE(far <= 1);
  ASSERT_TRUE(fabs(zt) <= 4.0);
  ASSERT_TRUE(gathers[0] < gathers[1]);
  for (int a = 0; a < 2; a++) {
    free(sum[a]);
    free(sq[a]);
  }
  free(tsh);
  free(en);
  level_close(&L);
}

/* Expectations: cornell over S = 96 seeds with every texel at 1/4 of the rays (16: the
 * strongest lock below) and every probe at 1/8, against the same seeds' count at full
 * rays. Each receiver's difference of means is compared with the spread of its own S
 * values (the per-seed noise, measured, not estimated): at most one of 624 receivers
 * beyond 5 standard errors (the same test between two unshifted arms: worst 3.0), and
 * the level's total irradiance within 4. Before the gathers' sample points were
 * decoupled from their direction grid (ray j used point j mod 4, so at 16 rays each point
 * saw one elevation band), 16 texels fell beyond 5 (texel 73: −22%). */
static void test_expectation(void)
{
  expectation_ab(96, 0, 100, "1/4 of the rays vs full");
}

static void test_bounce_shift_rule(void)
{
  ASSERT_TRUE(ub_pass_bounce_shift(1.0, 1.0, 0) == 0);
  ASSERT_TRUE(ub_pass_bounce_shift(1.0, 0.6, 0) == 0);
  ASSERT_TRUE(ub_pass_bounce_shift(1.0, 0.5, 0) == 1);  /* exactly half: one step */
  ASSERT_TRUE(ub_pass_bounce_shift(1.0, 0.3, 0) == 1);
  ASSERT_TRUE(ub_pass_bounce_shift(1.0, 0.25, 0) == 2);
  ASSERT_TRUE(ub_pass_bounce_shift(1.0, 1e-6, 0) == UB_BOUNCE_RAY_SHIFT_MAX); /* capped */
  ASSERT_TRUE(ub_pass_bounce_shift(1.0, 0.0, 0) == UB_BOUNCE_RAY_SHIFT_MAX);  /* went dark */
  ASSERT_TRUE(ub_pass_bounce_shift(1.0, -0.1, 0) == UB_BOUNCE_RAY_SHIFT_MAX);
  ASSERT_TRUE(ub_pass_bounce_shift(0.0, 0.0, 0) == 0); /* no light yet: keeps its rays */
  ASSERT_TRUE(ub_pass_bounce_shift(0.0, 0.0, 1) == 1);
  ASSERT_TRUE(ub_pass_bounce_shift(1.0, 0.3, 1) == 2); /* with a DLS pass shift */
  ASSERT_TRUE(ub_pass_bounce_shift(1.0, 0.01, 1) == 2);
  ASSERT_TRUE(ub_pass_bounce_shift(1.0, 0.01, 3) == 3); /* a larger pass shift stays */
}

/* A shift chosen from a bounce's own noisy results leaves each bounce's estimate
 * unbiased: cornell at 6 bounces, 48 seeds each way (expectation_ab). */
static void test_late_expectation(void)
{
  expectation_ab(48, 1, 500, "6 bounces, later bounces with fewer rays vs full");
}

/* A pass like a DLS influence pass (ub_dls_bake): 16 gather rays over the texels sub[0..n),
 * each bounce's I_z kept, no error estimates. */
static void influence_desc(const level *L, const uint8_t *en, const uint32_t *sub, uint32_t n,
                           uint32_t pass_id, ub_pass_desc *pd)
{
  desc_init(L, en, pd);
  pd->gather_rays = 16;
  pd->texel_subset = sub;
  pd->texel_subset_count = n;
  pd->keep_bounce_iz = 2;
  pd->no_error_estimate = 1;
  pd->pass_id = pass_id;
}

/* Arrays of n floats equal bit for bit (both NULL counts as equal). */
static int same_floats(const float *a, const float *b, size_t n)
{
  if (!a || !b)
    return a == b;
  return memcmp(a, b, n * sizeof *a) == 0;
}

static void test_no_store(void)
{
  enum { P = CORNELL_PROBES };
  level L;
  uint8_t *en;
  float pos[P * 3];
  if (!cornell_open(&L, &en, pos))
    return;
  uint32_t T = L.lm->texel_count;
  uint32_t *sub = malloc(((size_t)T + 1) * sizeof *sub), ns = 0;
  for (uint32_t t = 0; t < T; t++)
    if (t % 3 != 1) /* two texels in three, as an influence pass's candidates */
      sub[ns++] = t;
  ub_pass_result r[2];
  for (int a = 0; a < 2; a++) {
    ub_pass_desc pd;
    influence_desc(&L, en, sub, ns, 7, &pd);
    pd.probe_count = P;
    pd.probe_pos = pos;
    pd.probe_rays = 32;
    pd.no_store = a;
    ASSERT_OK(ub_pass_run(&pd, NULL, &r[a]));
  }
  ASSERT_TRUE(r[0].sh && r[0].iz && r[0].probe_sh && r[0].texel_bounce_iz);
  ASSERT_TRUE(!r[1].sh && !r[1].iz && !r[1].probe_sh && !r[1].llg_sh && !r[1].texel_se &&
              !r[1].probe_se);
  ASSERT_TRUE(same_floats(r[0].texel_direct, r[1].texel_direct, T));
  ASSERT_TRUE(same_floats(r[0].texel_indirect, r[1].texel_indirect, T));
  ASSERT_TRUE(same_floats(r[0].texel_bounce_iz, r[1].texel_bounce_iz, (size_t)T * 3 * 2));
  ASSERT_TRUE(same_floats(r[0].probe_direct, r[1].probe_direct, P));
  ASSERT_TRUE(same_floats(r[0].probe_indirect, r[1].probe_indirect, P));
  ASSERT_TRUE(r[0].bounces == r[1].bounces && r[0].rays_gather == r[1].rays_gather &&
              r[0].rays_shadow == r[1].rays_shadow);
  ASSERT_TRUE(memcmp(r[0].bounce_energy, r[1].bounce_energy, sizeof r[0].bounce_energy) == 0);
  double lit = 0.0;
  for (uint32_t t = 0; t < T; t++)
    lit += r[1].texel_indirect[t] > 0.0f;
  ASSERT_TRUE(lit > 0.5 * ns); /* the measures are there, not zeros on both sides */
  printf("cornell, no store: %u of %u texels, %u probes: influence measures bit for bit, "
         "%.0f texels with indirect light\n", ns, T, (unsigned)P, lit);
  ub_pass_result_free(&r[0]);
  ub_pass_result_free(&r[1]);
  free(sub);
  free(en);
  level_close(&L);
}

static void test_outside_candidates(void)
{
  enum { P = CORNELL_PROBES };
  level L;
  uint8_t *en;
  float pos[P * 3];
  if (!cornell_open(&L, &en, pos))
    return;
  uint32_t T = L.lm->texel_count;
  uint32_t *cand = malloc(((size_t)T + 1) * sizeof *cand), *kept = malloc(((size_t)T + 1) * sizeof *kept);
  uint32_t nc = 0, nk = 0;
  for (uint32_t t = 0; t < T; t++)
    if (t % 4 != 3) {
      cand[nc++] = t;
      if (t % 2 == 0)
        kept[nk++] = t;
    }
  ub_pass_desc pd;
  influence_desc(&L, en, cand, nc, 8, &pd);
  pd.no_store = 1;
  ub_pass_result inf, r[2];
  ASSERT_OK(ub_pass_run(&pd, NULL, &inf));
  uint32_t lit = 0; /* outside texels (candidates, not kept) with an estimate */
  for (uint32_t i = 0; i < nc; i++) {
    const float *v = inf.texel_bounce_iz + 3 * (size_t)cand[i];
    lit += cand[i] % 2 != 0 && (v[0] != 0.0f || v[1] != 0.0f || v[2] != 0.0f);
  }
  for (int a = 0; a < 2; a++) {
    desc_init(&L, en, &pd);
    pd.gather_rays = 16;
    pd.texel_subset = kept;
    pd.texel_subset_count = nk;
    pd.outside_bounce_iz = inf.texel_bounce_iz;
    pd.outside_bounces = 2;
    pd.outside_candidates = a ? cand : NULL;
    pd.outside_candidate_count = a ? nc : 0;
    pd.no_error_estimate = 1;
    pd.pass_id = 9;
    ASSERT_OK(ub_pass_run(&pd, NULL, &r[a]));
  }
  ASSERT_TRUE(lit > nk / 4);
  ASSERT_TRUE(same_floats(r[0].sh, r[1].sh, (size_t)T * 12));
  ASSERT_TRUE(same_floats(r[0].iz, r[1].iz, (size_t)T * 3));
  ASSERT_TRUE(r[0].rays_gather == r[1].rays_gather && r[0].rays_shadow == r[1].rays_shadow);
  printf("cornell, outside candidates: %u kept of %u candidates, %u outside texels lit: SH "
         "and I_z bit for bit\n", nk, nc, lit);
  ub_pass_result_free(&inf);
  ub_pass_result_free(&r[0]);
  ub_pass_result_free(&r[1]);
  free(cand);
  free(kept);
  free(en);
  level_close(&L);
}

int main(void)
{
  const char *b = getenv("UB_BUILD");
  snprintf(g_build, sizeof g_build, "%s", b ? b : "build");
  test_furnace();
  test_cornell();
  test_expectation();
  test_bounce_shift_rule();
  test_late_expectation();
  test_no_store();
  test_outside_candidates();
  TEST_MAIN_END();
}
