/* bake/lights.h — light evaluation shared by the baker and the reference path tracer.
 *
 * Units (DESIGN §3): point/spot intensity W/sr, directional W/m² at normal incidence,
 * emission W/(m²·sr). Spot cones and range windowing per KHR_lights_punctual.
 * ub_emitters is built once from a scene (emissive triangles with a power CDF);
 * it is read-only afterwards and thread safe. Free with ub_emitters_free (NULL-safe).
 */
#ifndef UBAKE_BAKE_LIGHTS_H
#define UBAKE_BAKE_LIGHTS_H

#include <stdint.h>

#include "ubake/scene.h"

/* Incident light at point p from a punctual light (ignoring visibility).
 * out_dir: unit direction from p toward the light; out_dist: distance to the light
 * (INFINITY for directional); out_e: irradiance (W/m²) on a surface facing the light
 * (cosine NOT applied). Returns 0 when the light cannot reach p (outside the cone or
 * range), 1 otherwise. Near-zero distances are guarded: the result is finite. */
int ub_light_incident(const ub_light *light, const float p[3], float out_dir[3],
                      float *out_dist, float out_e[3]);

typedef struct ub_emitters {
  uint32_t count;
  uint32_t *tri;     /* emissive triangle indices */
  float *cdf;        /* count: cumulative power, last = 1 */
  float *area;       /* count: m² */
  float *corner;     /* count × 9: the triangle's corners */
  float *normal;     /* count × 3: unit normal of the emitting side */
  double total_power; /* Σ area × luminance(emission) × π, W (luminance-weighted) */
} ub_emitters;

ub_result ub_emitters_build(const ub_scene *scene, ub_emitters **out_em);
void ub_emitters_free(ub_emitters *em);

/* Samples a point on an emissive triangle with probability ∝ power (em->cdf), or by the
 * cumulative probabilities cdf (count entries, last = 1: ub_emitters_local_cdf).
 * u0 picks the triangle, (u1, u2) the point. out_pdf_area: pdf w.r.t. area (1/m²)
 * for the chosen point (i.e. p(tri) / area(tri)). out_n: unit geometric normal (the
 * emitting side), out_le: emitted radiance. */
void ub_emitters_sample(const ub_emitters *em, const ub_scene *scene, float u0, float u1,
                        float u2, float out_p[3], float out_n[3], float out_le[3],
                        float *out_pdf_area);
void ub_emitters_sample_cdf(const ub_emitters *em, const float *cdf, const ub_scene *scene,
                            float u0, float u1, float u2, float out_p[3], float out_n[3],
                            float out_le[3], float *out_pdf_area);

/* The emitters' selection probabilities seen from a receiver at p (unit normal n, NULL
 * for a probe), as cumulative sums into cdf (count floats; returned), or em->cdf when
 * there are more than UB_EMITTERS_LOCAL_MAX emitters. Power alone picks a level's bright
 * fixtures for every receiver, so one next to a weak lamp samples that lamp a few times
 * in a thousand, each sample then weighing hundreds of times its mean: fireflies
 * (oa_dm4's walls next to its skull lights, 300× between neighbouring texels at draft).
 * Here an emitter's share is its power over max(d², area) (d: from p to its centroid),
 * zero where it lies wholly behind the receiver's plane or faces away from p, and at
 * least UB_EMITTERS_POWER_SHARE of its power share, so every emitter keeps a probability
 * (the gather rays' MIS weights take the same table: unbiased either way). A pure
 * function of (p, n). */
#define UB_EMITTERS_LOCAL_MAX 512u
#define UB_EMITTERS_POWER_SHARE 0.125f
const float *ub_emitters_local_cdf(const ub_emitters *em, const float p[3], const float *n,
                                   float *cdf);

/* Hash-based random numbers (DESIGN §3): a pure function of its inputs. ub_hash4 chains
 * one mixing step per input (lowbias32-style integer mixing, Wellons) from UB_HASH_SEED,
 * so a loop drawing many numbers whose first inputs agree (a receiver's gather rays: all
 * but the ray index) can mix those once and finish each number with one ub_hash_mix: the
 * same bits for a quarter of the work. Inline: a pass hashes several times per ray. */
#define UB_HASH_SEED 0x9E3779B9u
static inline uint32_t ub_hash_mix(uint32_t h, uint32_t v)
{
  h ^= v + 0x7F4A7C15u + (h << 6) + (h >> 2);
  h ^= h >> 16;
  h *= 0x7FEB352Du;
  h ^= h >> 15;
  h *= 0x846CA68Bu;
  h ^= h >> 16;
  return h;
}
static inline uint32_t ub_hash4(uint32_t a, uint32_t b, uint32_t c, uint32_t d)
{
  return ub_hash_mix(ub_hash_mix(ub_hash_mix(ub_hash_mix(UB_HASH_SEED, a), b), c), d);
}
/* Uniform float in [0, 1) from a hash. */
static inline float ub_u01(uint32_t h) { return (float)(h >> 8) * (1.0f / 16777216.0f); }
/* The entry u falls into of a cumulative table (n > 0 entries, non-decreasing, last 1):
 * the first i with cdf[i] > u (n − 1 when none). */
static inline uint32_t ub_cdf_pick(const float *cdf, uint32_t n, float u)
{
  uint32_t lo = 0, hi = n - 1;
  while (lo < hi) {
    uint32_t mid = lo + (hi - lo) / 2;
    if (cdf[mid] > u)
      hi = mid;
    else
      lo = mid + 1;
  }
  return lo;
}

/* Sampling helpers. */
void ub_sample_cosine(const float n[3], float u1, float u2, float out_dir[3]);
void ub_onb(const float n[3], float out_t[3], float out_b[3]);

#endif
