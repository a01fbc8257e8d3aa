/* Guided sampling toward boxes (doors/guide.h): MIS weights sum to one for any direction,
 * every box pdf integrates to one over the sphere, and the mixture estimator is unbiased.
 * Integrals are Monte Carlo with N uniform-sphere samples; the tolerance is 5 standard
 * errors of that estimate (printed). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "bake/lights.h"
#include "doors/guide.h"

static float urand(uint32_t *s)
{
  *s = *s * 1664525u + 1013904223u;
  return (float)(*s >> 8) * (1.0f / 16777216.0f);
}

static void sphere_dir(float u1, float u2, float w[3])
{
  double z = 1.0 - 2.0 * u1, r = sqrt(fmax(0.0, 1.0 - z * z)), ph = 2.0 * M_PI * u2;
  w[0] = (float)(r * cos(ph));
  w[1] = (float)(r * sin(ph));
  w[2] = (float)z;
}

int main(void)
{
  int fails = 0;
  /* A thin door-like box, a fat box and a box around the shading point. */
  ub_obb box[3];
  float ax[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  float r = (float)(1.0 / sqrt(2.0));
  float rot[3][3] = {{r, 0, r}, {0, 1, 0}, {-r, 0, r}};
  ub_obb_make((float[3]){0.0f, 1.0f, 3.0f}, ax, (float[3]){0.5f, 1.0f, 0.0f}, &box[0]);
  ub_obb_make((float[3]){2.0f, 0.5f, 1.0f}, rot, (float[3]){0.7f, 0.5f, 0.3f}, &box[1]);
  ub_obb_make((float[3]){0.1f, 0.2f, 0.0f}, ax, (float[3]){0.5f, 0.5f, 0.5f}, &box[2]);
  const float x[3] = {0.0f, 0.0f, 0.0f};
  const float n[3] = {0.0f, 1.0f, 0.0f};
  const uint32_t N = 2000000;
  uint32_t seed = 12345;

  /* 1. Each box pdf integrates to one over the sphere. Thin box: its pdf is large in a
   * small solid angle, so use importance: integrate p over the sphere by sampling the box
   * itself is circular; instead check ∫p dω with uniform-sphere samples and a stated
   * s.e. */
  for (int b = 0; b < 3; b++) {
    double s = 0.0, s2 = 0.0;
    for (uint32_t i = 0; i < N; i++) {
      float w[3];
      sphere_dir(urand(&seed), urand(&seed), w);
      double v = ub_obb_pdf(&box[b], x, w) * 4.0 * M_PI;
      s += v;
      s2 += v * v;
    }
    double mean = s / N, se = sqrt(fmax(0.0, s2 / N - mean * mean) / N);
    int ok = fabs(mean - 1.0) <= 5.0 * se + 1e-3;
    printf("box %d: integral of pdf = %.4f (s.e. %.4f)%s\n", b, mean, se, ok ? "" : "  FAIL");
    fails += !ok;
  }

  /* 2. MIS weights sum to one for random directions (above the horizon). */
  ub_guide g;
  double bw[3] = {2.0, 1.0, 0.5};
  ub_guide_init(&g, box, 3, bw, 0.3);
  double worst = 0.0;
  for (uint32_t i = 0; i < 100000; i++) {
    float w[3];
    sphere_dir(urand(&seed), urand(&seed), w);
    if (w[1] <= 0.0f)
      continue;
    double sum = 0.0;
    for (uint32_t s = 0; s <= g.box_count; s++)
      sum += ub_guide_weight(&g, s, x, n, w);
    worst = fmax(worst, fabs(sum - 1.0));
  }
  printf("MIS weights: worst |sum - 1| = %.2e over 1e5 directions\n", worst);
  if (!(worst < 1e-9)) {
    printf("FAIL: weights do not sum to one\n");
    fails++;
  }

  /* 3. The mixture pdf integrates to one over the hemisphere and the estimator of the
   * hemisphere's solid angle and of the cosine integral (2π and π) is unbiased. */
  {
    double s = 0.0, s2 = 0.0;
    for (uint32_t i = 0; i < N; i++) {
      float w[3];
      sphere_dir(urand(&seed), urand(&seed), w);
      double v = ub_guide_pdf(&g, x, n, w) * 4.0 * M_PI;
      s += v;
      s2 += v * v;
    }
    double mean = s / N, se = sqrt(fmax(0.0, s2 / N - mean * mean) / N);
    /* Box directions below the horizon carry no pdf: the mixture integrates to 1 minus the
     * boxes' share below the horizon; box 2 straddles the horizon (half its volume below). */
    double below = 0.0;
    for (uint32_t i = 0; i < N / 4; i++) {
      float w[3];
      sphere_dir(urand(&seed), urand(&seed), w);
      if (w[1] <= 0.0f)
        for (uint32_t j = 0; j < g.box_count; j++)
          below += g.prob[1 + j] * ub_obb_pdf(&g.box[j], x, w) * 4.0 * M_PI;
    }
    below /= N / 4;
    int ok = fabs(mean + below - 1.0) <= 5.0 * se + 2e-3;
    printf("mixture pdf: hemisphere integral %.4f + below-horizon share %.4f = %.4f "
           "(s.e. %.4f)%s\n", mean, below, mean + below, se, ok ? "" : "  FAIL");
    fails += !ok;
  }
  {
    double s = 0.0, s2 = 0.0, c = 0.0, c2 = 0.0;
    for (uint32_t i = 0; i < N; i++) {
      float u[4] = {urand(&seed), urand(&seed), urand(&seed), urand(&seed)};
      float w[3];
      double p = ub_guide_sample(&g, x, n, u, w);
      double v = 0.0, vc = 0.0;
      if (p > 0.0 && w[1] > 0.0f) {
        v = 1.0 / p;
        vc = w[1] / p;
      }
      s += v;
      s2 += v * v;
      c += vc;
      c2 += vc * vc;
    }
    double m = s / N, se = sqrt(fmax(0.0, s2 / N - m * m) / N);
    double mc = c / N, sec = sqrt(fmax(0.0, c2 / N - mc * mc) / N);
    int ok = fabs(m - 2.0 * M_PI) <= 5.0 * se && fabs(mc - M_PI) <= 5.0 * sec;
    printf("mixture estimator: solid angle %.4f (2pi = %.4f, s.e. %.4f), cosine integral "
           "%.4f (pi, s.e. %.4f)%s\n", m, 2.0 * M_PI, se, mc, sec, ok ? "" : "  FAIL");
    fails += !ok;
  }
  /* 4. A sampled box direction hits its box; the ray interval is inside. */
  {
    int bad = 0;
    for (uint32_t i = 0; i < 10000; i++) {
      float p[3], u[3] = {urand(&seed), urand(&seed), urand(&seed)};
      ub_obb_point(&box[1], u, p);
      if (!ub_obb_contains(&box[1], p))
        bad++;
      float d[3] = {p[0] - x[0], p[1] - x[1], p[2] - x[2]};
      float l = sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
      float w[3] = {d[0] / l, d[1] / l, d[2] / l}, t0, t1;
      if (!ub_obb_ray(&box[1], x, w, &t0, &t1) || t0 > l * 1.0001f || t1 < l * 0.9999f)
        bad++;
    }
    printf("box points inside and on their rays: %d bad of 10000\n", bad);
    fails += bad != 0;
  }
  /* 5. Fit: an OBB of points on a rotated plate contains them all and is thin. */
  {
    float pts[3 * 400];
    for (int i = 0; i < 400; i++) {
      float a = urand(&seed) * 2 - 1, b = urand(&seed) * 2 - 1;
      pts[3 * i + 0] = 1.0f + r * a;
      pts[3 * i + 1] = 2.0f + b;
      pts[3 * i + 2] = -r * a;
    }
    ub_obb o;
    int ok = ub_obb_fit(pts, 400, 0.01f, &o);
    for (int i = 0; i < 400 && ok; i++)
      ok = ub_obb_contains(&o, pts + 3 * i);
    double thin = fmin(o.h[0], fmin(o.h[1], o.h[2]));
    ok = ok && thin < 0.02;
    printf("fit: half extents %.3f %.3f %.3f%s\n", o.h[0], o.h[1], o.h[2], ok ? "" : "  FAIL");
    fails += !ok;
    float nanp[3] = {NAN, 0, 0};
    if (ub_obb_fit(nanp, 1, 0.0f, &o)) {
      printf("FAIL: fit accepted NaN\n");
      fails++;
    }
  }
  printf("%s\n", fails ? "FAILED" : "ok");
  return fails ? 1 : 0;
}
