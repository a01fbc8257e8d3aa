/* bake/reference.h — the brute-force reference path tracer: ground truth for accuracy.
 *
 * What it is: an unbiased Monte Carlo estimate of the irradiance E (W/m², linear RGB) at
 * one point for one normal, for exactly the quantity the baker stores (DESIGN §3, the
 * paper's eq. 1):
 *   - direct light from `static` punctual lights (shadow rays), emissive triangles
 *     (next-event estimation by area sampling, front side only) and the constant sky
 *     (rays that escape);
 *   - plus every path with >= 1 diffuse bounce, from every light class, `primary` lights
 *     included (their direct term at the receiver is never counted: the game draws it).
 * Bounce counting: direct = 0 bounces; max_bounces = N keeps paths with up to N diffuse
 * reflections between the light and the receiver, so in a furnace (emission Le, albedo ρ
 * everywhere) E = π·Le·Σ_{k=0..N} ρ^k. Surfaces are Lambertian on both sides (the side
 * facing the incoming ray reflects); emission is counted only by next-event estimation,
 * never when a bounce ray hits an emitter. The receiver is assumed on the front side of
 * the normal: rays leave from the position offset by ub_rt_offset_point along it.
 *
 * Sampling: cosine-weighted bounces, next-event estimation at every surface vertex,
 * Russian roulette after bounce 3 (unlimited bounces only). Every random number is
 * ub_hash4(seed, path, vertex depth, dimension); paths are traced in fixed blocks whose
 * partial sums are merged in block order, so results are bit-identical for any thread
 * count.
 *
 * Lifecycle: nothing to create; one call per estimate. Thread safety: the call is
 * re-entrant; it only reads scene, rt and em (which may be shared) and parallelises
 * itself with OpenMP. The log callback is called from the calling thread only.
 */
#ifndef UBAKE_BAKE_REFERENCE_H
#define UBAKE_BAKE_REFERENCE_H

#include <stdint.h>

#include "bake/lights.h"
#include "bake/rt.h"
#include "ubake/scene.h"

#define UB_REFERENCE_DEFAULT_SPP 4096u
/* Most paths per call (2^30: hours of tracing at one point); more is rejected. */
#define UB_REFERENCE_MAX_SPP (1u << 30)
#define UB_REFERENCE_UNLIMITED UINT32_MAX
/* Largest |coordinate| of a receiver position, metres: the level loader's limit for
 * vertices and lights (ubake/scene.h). */
#define UB_REFERENCE_MAX_COORDINATE UB_SCENE_MAX_COORDINATE

typedef struct ub_reference_params {
  float position[3];       /* world, metres, each |x| <= UB_REFERENCE_MAX_COORDINATE; on
                            * (or near) a surface, or in free space */
  float normal[3];         /* irradiance is for this orientation; normalised here, must be non-zero */
  uint32_t spp;            /* paths (0 = default 4096), at most UB_REFERENCE_MAX_SPP */
  uint32_t seed;
  uint32_t max_bounces;    /* diffuse bounces after the receiver; UB_REFERENCE_UNLIMITED = Russian roulette */
  const float *dls_weight; /* NULL = every dynamic light set at weight 1; else scene->dls_count × 3 RGB */
  int threads;             /* 0 = OpenMP default */
} ub_reference_params;

/* Defaults: position 0, normal +Y, spp 4096, seed 0, unlimited bounces, all DLS at 1,
 * threads 0. */
void ub_reference_params_init(ub_reference_params *out_params);

/* Estimates E at params->position for params->normal.
 * rt: built over the geometry state to render (any mask); em: the emissive triangles of
 * that same state, or NULL to build them here from the whole scene. (ub_emitters_build
 * takes no mask: an emissive triangle left out of rt would still be sampled.) out_rgb: W/m²; out_stderr: per-channel standard error of
 * the mean (sample standard deviation of the path estimates / sqrt(spp); 0 when spp = 1).
 * Non-finite path estimates are dropped (counted as 0) and reported as one warning.
 * Errors: UB_ERR_INVALID_ARGUMENT for a non-finite position or one with a coordinate
 * beyond ±UB_REFERENCE_MAX_COORDINATE, a zero/non-finite normal, spp above
 * UB_REFERENCE_MAX_SPP or a non-finite DLS weight; UB_ERR_INVALID_DATA for a light whose
 * dls index is out of range; UB_ERR_OUT_OF_MEMORY. On error the outputs are left
 * untouched. */
ub_result ub_reference_irradiance(const ub_scene *scene, const ub_rt *rt,
                                  const ub_emitters *em, const ub_reference_params *params,
                                  float out_rgb[3], float out_stderr[3], const ub_log *log);

/* Incident radiance at params->position as SH L2 (27 floats, coefficient-major RGB,
 * W/(m²·sr), the GLG's convention, ubake/sh.h), for the same path classes as
 * ub_reference_irradiance: what a noise-free probe at that point would hold, so that
 * ub_sh2_irradiance of it is the best any L2 probe can answer there (the GLG's
 * representation floor). The receiver normal varies per path over a spherical Fibonacci
 * lattice (rotated by the seed) and each path's irradiance estimate E_k is projected:
 * L_lm ≈ 4π·E_k·Y_lm(n_k)/A_l, unbiased because ∫E(n)·Y_lm(n) dn = A_l·L_lm. Not
 * windowed (ub_sh2_window it as the GLG does). params->normal only picks where the
 * un-windowed L2 irradiance out_l2_rgb = Σ A_l·L_lm·Y_lm(normal) and its standard error
 * out_l2_stderr are evaluated. Same cost per path as ub_reference_irradiance; errors as
 * there. */
ub_result ub_reference_radiance_sh(const ub_scene *scene, const ub_rt *rt,
                                   const ub_emitters *em, const ub_reference_params *params,
                                   float out_sh[27], float out_l2_rgb[3],
                                   float out_l2_stderr[3], const ub_log *log);

#endif
