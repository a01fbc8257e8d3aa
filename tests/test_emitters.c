/* Emitter picks by what a receiver sees of them (bake/lights.h ub_emitters_local_cdf)
 * against picks by power alone (ub_pass_desc.emitters_by_power), on cornell_lamps: the
 * emissive box, its 0.5 m ceiling patch at Le 10 and four 0.12 m wall lamps 25 cm up at
 * Le 2 (each 1/87 of the patch's power), bounce 0 only (the emitters' direct light, with
 * the gather rays' MIS hits on them), 16 seeds of each rule:
 * - the tables: cumulative, ending at 1, every emitter with at least
 *   UB_EMITTERS_POWER_SHARE of its power share, the left lamp at least 10× its power share
 *   from the floor in front of it, and the power table for a receiver facing away from
 *   every emitter or beyond UB_EMITTERS_LOCAL_MAX emitters;
 * - the same expectation: per lit texel the two rules' means over the seeds differ by more
 *   than 5 standard errors (from the seeds' spread) at no more than 2% of the texels (the
 *   power rule's rare lamp samples make its spread heavy-tailed), and the mean difference
 *   over the texels is within 3 standard errors of the mean;
 * - less noise: one bake's relative standard deviation (the seeds' spread over the mean),
 *   averaged over the lit texels, at most half the power rule's; within 30 cm of a lamp,
 *   where the lamp's own nearness dominates (area samples of a close source), no more. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pass_level.h"
#include "test_util.h"

static char g_build[512];

static void desc_init(const level *L, const uint8_t *en, uint32_t seed, int by_power,
                      ub_pass_desc *pd)
{
  level_desc_init(L, en, pd);
  pd->emissive = 1;
  pd->gather_rays = 32;
  pd->bounces = 0;
  pd->seed = seed;
  pd->emitters_by_power = by_power;
}

/* Whether texel t's first sample point is within r of a wall lamp's centre. */
static int near_lamp(const level *L, const float *centres, uint32_t nl, uint32_t t, float r)
{
  const float *p = L->lm->texel_pos + 3 * (size_t)t;
  for (uint32_t k = 0; k < nl; k++) {
    float d2 = 0.0f;
    for (int j = 0; j < 3; j++)
      d2 += (p[j] - centres[3 * k + j]) * (p[j] - centres[3 * k + j]);
    if (d2 <= r * r)
      return 1;
  }
  return 0;
}

static void test_tables(const level *L)
{
  const ub_emitters *em = L->em;
  uint32_t E = em->count;
  float *cdf = malloc((E + 1) * sizeof *cdf);
  /* on the floor 20 cm in front of the left-wall lamp (x = -0.999, y 0.19..0.31,
   * z 0.44..0.56, facing +x) */
  const float p[3] = {-0.8f, 0.0f, 0.5f}, n[3] = {0.0f, 1.0f, 0.0f};
  const float *c = ub_emitters_local_cdf(em, p, n, cdf);
  ASSERT_TRUE(c == cdf);
  ASSERT_TRUE(c[E - 1] == 1.0f);
  double lamp_l = 0.0, lamp_g = 0.0;
  for (uint32_t i = 0; i < E; i++) {
    float pl = c[i] - (i ? c[i - 1] : 0.0f), pg = em->cdf[i] - (i ? em->cdf[i - 1] : 0.0f);
    ASSERT_TRUE(pl >= 0.0f);
    ASSERT_TRUE(pl >= 0.99f * UB_EMITTERS_POWER_SHARE * pg);
    if (fabsf(em->corner[9 * (size_t)i] + 0.999f) < 1e-3f) { /* the left-wall lamp */
      lamp_l += pl;
      lamp_g += pg;
    }
  }
  printf("emitter tables: %u emitters; on the floor in front of the left-wall lamp it has p "
         "%.3f (by power %.4f)\n",
         E, lamp_l, lamp_g);
  ASSERT_TRUE(lamp_g > 0.0 && lamp_l >= 10.0 * lamp_g);
  /* facing away from every emitter (under the floor, facing down): the power table */
  const float q[3] = {0.0f, -0.5f, 0.0f}, qn[3] = {0.0f, -1.0f, 0.0f};
  ASSERT_TRUE(ub_emitters_local_cdf(em, q, qn, cdf) == em->cdf);
  /* beyond the local limit: the power table */
  ub_emitters many = *em;
  many.count = UB_EMITTERS_LOCAL_MAX + 1;
  ASSERT_TRUE(ub_emitters_local_cdf(&many, p, n, cdf) == many.cdf);
  free(cdf);
}

#define SEEDS 16

static void test_picks(void)
{
  level L;
  if (!level_open(g_build, "cornell_lamps", &L))
    return;
  test_tables(&L);
  /* the wall lamps' centres: their triangles' corner means, two triangles a lamp */
  float centres[12];
  uint32_t nl = 0;
  for (uint32_t i = 0; i < L.em->count && nl < 4; i++) {
    if (L.em->area[i] > 0.01f)
      continue; /* the ceiling patch */
    const float *v = L.em->corner + 9 * (size_t)i;
    float c[3];
    for (int j = 0; j < 3; j++)
      c[j] = (v[j] + v[3 + j] + v[6 + j]) / 3.0f;
    int seen = 0;
    for (uint32_t k = 0; k < nl; k++)
      seen |= fabsf(c[0] - centres[3 * k]) + fabsf(c[2] - centres[3 * k + 2]) < 0.2f;
    if (!seen)
      memcpy(centres + 3 * nl++, c, sizeof c);
  }
  ASSERT_TRUE(nl == 4);
  const uint32_t T = L.lm->texel_count;
  uint8_t *en = calloc(L.s->light_count + 1, 1);
  /* per picking rule, per texel: the sum and the sum of squares of E over the seeds */
  double *acc = calloc((size_t)T * 4 + 1, sizeof *acc);
  uint64_t shadow[2] = {0, 0};
  for (int bp = 0; bp < 2; bp++)
    for (uint32_t sd = 0; sd < SEEDS; sd++) {
      ub_pass_desc pd;
      ub_pass_result r;
      desc_init(&L, en, 3u + 100u * sd, bp, &pd);
      ASSERT_OK(ub_pass_run(&pd, NULL, &r));
      for (uint32_t t = 0; r.iz && t < T; t++) {
        double e = r.iz[3 * (size_t)t + 1];
        acc[4 * (size_t)t + 2 * bp] += e;
        acc[4 * (size_t)t + 2 * bp + 1] += e * e;
      }
      shadow[bp] += r.rays_shadow;
      ub_pass_result_free(&r);
    }
  /* per texel: each rule's mean and the standard error of that mean (from the seeds'
   * spread), and the seeds' spread relative to the mean: the noise of one bake */
  double diff = 0.0, var = 0.0, rel[2][2] = {{0, 0}, {0, 0}}; /* [rule][near, all] */
  uint32_t far = 0, m = 0, mn = 0;
  for (uint32_t t = 0; t < T; t++) {
    double mean[2], se2[2], sdv[2];
    for (int bp = 0; bp < 2; bp++) {
      double s1 = acc[4 * (size_t)t + 2 * bp], s2 = acc[4 * (size_t)t + 2 * bp + 1];
      mean[bp] = s1 / SEEDS;
      double v = (s2 - s1 * s1 / SEEDS) / (SEEDS - 1);
      sdv[bp] = v > 0.0 ? sqrt(v) : 0.0;
      se2[bp] = (v > 0.0 ? v : 0.0) / SEEDS;
    }
    if (!(mean[0] + mean[1] > 0.0) || !(se2[0] + se2[1] > 0.0))
      continue;
    const int near = near_lamp(&L, centres, nl, t, 0.3f);
    diff += mean[0] - mean[1];
    var += se2[0] + se2[1];
    far += fabs(mean[0] - mean[1]) > 5.0 * sqrt(se2[0] + se2[1]);
    m++;
    mn += near;
    for (int bp = 0; bp < 2; bp++) {
      double x = sdv[bp] / (0.5 * (mean[0] + mean[1]));
      rel[bp][1] += x;
      rel[bp][0] += near ? x : 0.0;
    }
  }
  double bias = m ? diff / m : 0.0, se = m ? sqrt(var) / m : 0.0;
  for (int bp = 0; bp < 2; bp++) {
    rel[bp][0] /= mn ? mn : 1;
    rel[bp][1] /= m ? m : 1;
  }
  printf("cornell_lamps bounce 0, %d seeds each: %u lit texels (%u within 30 cm of a lamp); "
         "local minus power picks %.4g W/m² mean (3 s.e. of the mean %.4g), %u texels beyond "
         "5 s.e.; one bake's relative standard deviation near the lamps %.1f%% local vs "
         "%.1f%% by power, over all %.1f%% vs %.1f%%; shadow rays %llu vs %llu\n",
         SEEDS, m, mn, bias, 3 * se, far, 100 * rel[0][0], 100 * rel[1][0], 100 * rel[0][1],
         100 * rel[1][1], (unsigned long long)shadow[0], (unsigned long long)shadow[1]);
  ASSERT_TRUE(m > 0 && mn > 0);
  ASSERT_TRUE(fabs(bias) <= 3.0 * se);
  ASSERT_TRUE(far <= m / 50);
  ASSERT_TRUE(rel[0][1] <= 0.5 * rel[1][1]);
  ASSERT_TRUE(rel[0][0] <= rel[1][0]);
  free(acc);
  free(en);
  level_close(&L);
}

int main(void)
{
  const char *b = getenv("UB_BUILD");
  snprintf(g_build, sizeof g_build, "%s", b ? b : "build");
  test_picks();
  TEST_MAIN_END();
}
