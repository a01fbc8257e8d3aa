/* Light evaluation, emissive-triangle sampling and hash-based random numbers. */
#include "bake/lights.h"

#include <assert.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Distances below this are treated as this (metres): a light 1 mm from a surface stays
 * finite and bounded by the analytic value at 0.1 mm. */
#define UB_LIGHT_MIN_DIST 1e-4f

int ub_light_incident(const ub_light *light, const float p[3], float out_dir[3],
                      float *out_dist, float out_e[3])
{
  if (light->type == UB_LIGHT_DIRECTIONAL) {
    out_dir[0] = -light->direction[0];
    out_dir[1] = -light->direction[1];
    out_dir[2] = -light->direction[2];
    *out_dist = INFINITY;
    memcpy(out_e, light->intensity, 3 * sizeof(float));
    return 1;
  }
  float d[3] = {light->position[0] - p[0], light->position[1] - p[1], light->position[2] - p[2]};
  float d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
  float dist = sqrtf(d2);
  if (!(dist > 0.0f)) {
    out_dir[0] = 0.0f;
    out_dir[1] = 1.0f;
    out_dir[2] = 0.0f;
  } else {
    out_dir[0] = d[0] / dist;
    out_dir[1] = d[1] / dist;
    out_dir[2] = d[2] / dist;
  }
  *out_dist = dist;
  float de = fmaxf(dist, UB_LIGHT_MIN_DIST);
  float atten = 1.0f / (de * de);
  if (light->range > 0.0f) {
    if (dist >= light->range)
      return 0;
    float r = dist / light->range;
    float w = 1.0f - r * r * r * r;
    atten *= w * w;
  }
  if (light->type == UB_LIGHT_SPOT) {
    /* KHR_lights_punctual: smooth falloff between the cones, squared. */
    float cd = -(out_dir[0] * light->direction[0] + out_dir[1] * light->direction[1] +
                 out_dir[2] * light->direction[2]);
    if (cd <= light->cos_outer)
      return 0;
    float scale = 1.0f / fmaxf(1e-3f, light->cos_inner - light->cos_outer);
    float a = (cd - light->cos_outer) * scale;
    a = a < 0.0f ? 0.0f : (a > 1.0f ? 1.0f : a);
    atten *= a * a;
  }
  out_e[0] = light->intensity[0] * atten;
  out_e[1] = light->intensity[1] * atten;
  out_e[2] = light->intensity[2] * atten;
  return 1;
}

static float luminance(const float c[3])
{
  return 0.2126f * c[0] + 0.7152f * c[1] + 0.0722f * c[2];
}

static void tri_corners(const ub_scene *s, uint32_t t, const float **a, const float **b,
                        const float **c)
{
  *a = s->positions + 3 * s->indices[3 * t + 0];
  *b = s->positions + 3 * s->indices[3 * t + 1];
  *c = s->positions + 3 * s->indices[3 * t + 2];
}

static void tri_cross(const ub_scene *s, uint32_t t, float out[3])
{
  const float *a, *b, *c;
  tri_corners(s, t, &a, &b, &c);
  float e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
  float e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
  out[0] = e1[1] * e2[2] - e1[2] * e2[1];
  out[1] = e1[2] * e2[0] - e1[0] * e2[2];
  out[2] = e1[0] * e2[1] - e1[1] * e2[0];
}

ub_result ub_emitters_build(const ub_scene *scene, ub_emitters **out_em)
{
  ub_emitters *em = calloc(1, sizeof *em);
  if (!em)
    return UB_ERR_OUT_OF_MEMORY;
  uint32_t n = 0;
  for (uint32_t t = 0; t < scene->triangle_count; t++) {
    if (scene->tri_flags[t] & UB_TRI_DEGENERATE)
      continue;
    if (luminance(scene->materials[scene->tri_material[t]].emission) > 0.0f)
      n++;
  }
  em->count = n;
  if (n) {
    em->tri = malloc(n * sizeof *em->tri);
    em->cdf = malloc(n * sizeof *em->cdf);
    em->area = malloc(n * sizeof *em->area);
    em->corner = malloc((size_t)n * 9 * sizeof *em->corner);
    em->normal = malloc((size_t)n * 3 * sizeof *em->normal);
    if (!em->tri || !em->cdf || !em->area || !em->corner || !em->normal) {
      ub_emitters_free(em);
      return UB_ERR_OUT_OF_MEMORY;
    }
    double sum = 0.0;
    uint32_t k = 0;
    double *acc = malloc(n * sizeof *acc);
    if (!acc) {
      ub_emitters_free(em);
      return UB_ERR_OUT_OF_MEMORY;
    }
    for (uint32_t t = 0; t < scene->triangle_count; t++) {
      if (scene->tri_flags[t] & UB_TRI_DEGENERATE)
        continue;
      float lum = luminance(scene->materials[scene->tri_material[t]].emission);
      if (!(lum > 0.0f))
        continue;
      float cr[3];
      tri_cross(scene, t, cr);
      float area = 0.5f * sqrtf(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
      em->tri[k] = t;
      em->area[k] = area;
      const float *v[3];
      tri_corners(scene, t, &v[0], &v[1], &v[2]);
      for (int j = 0; j < 3; j++) {
        memcpy(em->corner + 9 * (size_t)k + 3 * j, v[j], 3 * sizeof(float));
        em->normal[3 * (size_t)k + j] = area > 0.0f ? cr[j] / (2.0f * area) : 0.0f;
      }
      sum += (double)area * lum * M_PI;
      acc[k] = sum;
      k++;
    }
    em->total_power = sum;
    for (uint32_t i = 0; i < n; i++)
      em->cdf[i] = sum > 0.0 ? (float)(acc[i] / sum) : (float)(i + 1) / (float)n;
    em->cdf[n - 1] = 1.0f;
    free(acc);
  }
  *out_em = em;
  return UB_OK;
}

void ub_emitters_free(ub_emitters *em)
{
  if (!em)
    return;
  free(em->tri);
  free(em->cdf);
  free(em->area);
  free(em->corner);
  free(em->normal);
  free(em);
}

void ub_emitters_sample(const ub_emitters *em, const ub_scene *scene, float u0, float u1,
                        float u2, float out_p[3], float out_n[3], float out_le[3],
                        float *out_pdf_area)
{
  ub_emitters_sample_cdf(em, em->cdf, scene, u0, u1, u2, out_p, out_n, out_le, out_pdf_area);
}

const float *ub_emitters_local_cdf(const ub_emitters *em, const float p[3], const float *n,
                                   float *cdf)
{
  const uint32_t E = em->count;
  if (E > UB_EMITTERS_LOCAL_MAX)
    return em->cdf;
  double sum = 0.0;
  for (uint32_t i = 0; i < E; i++) { /* the local weights, as cumulative sums */
    const float *v = em->corner + 9 * (size_t)i, *ne = em->normal + 3 * (size_t)i;
    double w = 0.0;
    float d[3][3];
    for (int j = 0; j < 3; j++)
      for (int k = 0; k < 3; k++)
        d[j][k] = v[3 * j + k] - p[k]; /* receiver to corner j */
    const int front = !n || n[0] * d[0][0] + n[1] * d[0][1] + n[2] * d[0][2] > 0.0f ||
                      n[0] * d[1][0] + n[1] * d[1][1] + n[2] * d[1][2] > 0.0f ||
                      n[0] * d[2][0] + n[1] * d[2][1] + n[2] * d[2][2] > 0.0f;
    if (front && ne[0] * d[0][0] + ne[1] * d[0][1] + ne[2] * d[0][2] < 0.0f) {
      double c2 = 0.0;
      for (int k = 0; k < 3; k++) {
        double m = ((double)d[0][k] + d[1][k] + d[2][k]) / 3.0;
        c2 += m * m;
      }
      const double g = (double)em->cdf[i] - (i ? em->cdf[i - 1] : 0.0f);
      w = g / (c2 > em->area[i] ? c2 : (double)em->area[i]);
    }
    sum += w;
    cdf[i] = (float)sum;
  }
  if (!(sum > 0.0) || !isfinite(sum))
    return em->cdf;
  const double a = (1.0 - UB_EMITTERS_POWER_SHARE) / sum;
  for (uint32_t i = 0; i < E; i++) /* mixed with the power shares */
    cdf[i] = (float)(a * cdf[i] + UB_EMITTERS_POWER_SHARE * em->cdf[i]);
  cdf[E - 1] = 1.0f;
  return cdf;
}

void ub_emitters_sample_cdf(const ub_emitters *em, const float *cdf, const ub_scene *scene,
                            float u0, float u1, float u2, float out_p[3], float out_n[3],
                            float out_le[3], float *out_pdf_area)
{
  assert(em->count > 0);
  uint32_t lo = ub_cdf_pick(cdf, em->count, u0);
  float prev = lo ? cdf[lo - 1] : 0.0f;
  float p_tri = cdf[lo] - prev;
  const float *a = em->corner + 9 * (size_t)lo, *b = a + 3, *c = a + 6;
  float su = sqrtf(u1);
  float b0 = 1.0f - su, b1 = u2 * su, b2 = 1.0f - b0 - b1;
  for (int i = 0; i < 3; i++)
    out_p[i] = b0 * a[i] + b1 * b[i] + b2 * c[i];
  memcpy(out_n, em->normal + 3 * (size_t)lo, 3 * sizeof(float));
  memcpy(out_le, scene->materials[scene->tri_material[em->tri[lo]]].emission,
         3 * sizeof(float));
  *out_pdf_area = em->area[lo] > 0.0f ? p_tri / em->area[lo] : 0.0f;
}

void ub_onb(const float n[3], float out_t[3], float out_b[3])
{
  /* Duff et al. 2017, branchless orthonormal basis. */
  float sign = copysignf(1.0f, n[2]);
  float a = -1.0f / (sign + n[2]);
  float b = n[0] * n[1] * a;
  out_t[0] = 1.0f + sign * n[0] * n[0] * a;
  out_t[1] = sign * b;
  out_t[2] = -sign * n[0];
  out_b[0] = b;
  out_b[1] = sign + n[1] * n[1] * a;
  out_b[2] = -n[1];
}

void ub_sample_cosine(const float n[3], float u1, float u2, float out_dir[3])
{
  float r = sqrtf(u1);
  float phi = 2.0f * (float)M_PI * u2;
  float x = r * cosf(phi), y = r * sinf(phi);
  float z = sqrtf(fmaxf(0.0f, 1.0f - u1));
  float t[3], b[3];
  ub_onb(n, t, b);
  for (int i = 0; i < 3; i++)
    out_dir[i] = x * t[i] + y * b[i] + z * n[i];
}
