/* ubake/llg.h — local light grids (UberBake §2.2): evaluating a model's LLG.
 *
 * What it is: an LLG is an oriented box around one model holding a regular grid of SH L2
 * radiance probes (W/(m²·sr), the ubake/sh.h layout), plus, per model vertex, the
 * model's self-visibility as monochrome SH L2 (9 floats) and a self-inter-reflection
 * irradiance S (RGB, W/m², along the vertex normal).
 * A surface point is shaded by
 *   E(n) = max(0, irradiance_n( trunc_L2( L(p) · V(p) ) )) + S(p)
 * where L(p) is the trilinear interpolation of the grid at p, V(p) and S(p) interpolated
 * from the vertices, and the product of two SH L2 functions is taken with
 * the real-SH triple-product (Gaunt) tensor, truncated back to L2, before the cosine
 * convolution (the paper: "multiplied into the interpolated radiance before the cosine
 * convolution").
 *
 * Conventions (docs/FORMAT.md, section LLGM):
 *   - box: centre c, three orthonormal axes a_0..a_2 (rows of axes[9]), half extents h;
 *   - grid: dims[i] ≥ 2 probes along axis i, on the box corners and evenly in between:
 *     probe (x, y, z) sits at c + Σ_i a_i·(−h_i + 2h_i·idx_i/(dims_i − 1)) and is number
 *     (z·dims[1] + y)·dims[0] + x;
 *   - probes store radiance of the model's surroundings WITHOUT the model itself (the
 *     model is transparent to its own probes), so self-occlusion is only in V;
 *   - V(ω) = 0 where a ray from the vertex in direction ω (within its normal's hemisphere)
 *     hits the model itself, 1 elsewhere (also below the hemisphere, so an unoccluded
 *     vertex has V ≡ 1 exactly and shades exactly like the grid alone);
 *   - S: the light the model's own surfaces reflect onto the vertex (the directions V
 *     removes), baked after the grid (probes/llg.h).
 *
 * Pure functions, no allocation, thread safe. Part of the run-time library.
 */
#ifndef UBAKE_LLG_H
#define UBAKE_LLG_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define UB_LLG_VIS_COEFFS 9

/* out = trunc_L2(L · V): L is SH L2 × RGB (27 floats), V monochrome SH L2 (9 floats).
 * out must not alias L. */
void ub_llg_sh_product(const float L[27], const float V[9], float out[27]);

/* Rotation of monochrome SH L2 (9 coefficients) by an orthogonal 3×3 matrix R (row-major;
 * reflections allowed): out_M (9×9, row-major) maps the coefficients of f to those of
 * g(ω) = f(Rᵀω), i.e. f carried along by R. Exact (up to rounding): the projection
 * integrals have degree-4 integrands, summed over the 12 icosahedron vertices (a spherical
 * 5-design). Used for instances sharing one self-visibility (docs/FORMAT.md, LLGM). */
void ub_llg_sh_rotation(const float R[9], float out_M[81]);
/* out = M · in (9 coefficients); out must not alias in. */
void ub_llg_sh_rotate(const float M[81], const float in[9], float out[9]);

/* Trilinear interpolation of the grid's probes at world point p (clamped to the box).
 * probe_sh: dims[0]·dims[1]·dims[2] × 27 floats. */
void ub_llg_grid_sample(const float center[3], const float axes[9], const float half[3],
                        const uint32_t dims[3], const float *probe_sh, const float p[3],
                        float out_sh[27]);

/* The probes ub_llg_grid_sample blends at p and their weights: out_sh = Σ_c w[c]·probe
 * idx[c] over the returned count (≤ 8; the same weights, the same order). */
uint32_t ub_llg_grid_corners(const float center[3], const float axes[9], const float half[3],
                             const uint32_t dims[3], const float p[3], uint32_t idx[8],
                             float w[8]);

/* World position of probe (ix, iy, iz). */
void ub_llg_probe_position(const float center[3], const float axes[9], const float half[3],
                           const uint32_t dims[3], uint32_t ix, uint32_t iy, uint32_t iz,
                           float out_p[3]);

/* Distance (metres) from p to the box (0 inside). */
float ub_llg_box_distance(const float center[3], const float axes[9], const float half[3],
                          const float p[3]);

/* Irradiance (W/m², ≥ 0) for unit normal n from radiance SH L (27 floats), times
 * self-visibility vis (9 floats, or NULL: none), plus self (3 floats, or NULL: 0). */
void ub_llg_irradiance(const float L[27], const float *vis, const float *self, const float n[3],
                       float out_rgb[3]);
/* Its last step: the SH irradiance e clamped to ≥ 0 (non-finite → 0) per channel, plus
 * self where that is finite and positive (self NULL: none). out_rgb may alias e. */
void ub_llg_irradiance_finish(const float e[3], const float *self, float out_rgb[3]);

/* The irradiance as weights on the radiance: for every L, Σ_i w[i]·L[3i + c] is channel c
 * of ub_sh2_irradiance(ub_llg_sh_product(L, vis), n) in exact arithmetic (vis NULL: of
 * ub_sh2_irradiance(L, n)), before ub_llg_irradiance's clamp and self term. For many
 * radiance functions at one point and normal (a grid's corners): 9 weights once instead
 * of a product per function. */
void ub_llg_irradiance_weights(const float *vis, const float n[3], float w[9]);

#ifdef __cplusplus
}
#endif
#endif
