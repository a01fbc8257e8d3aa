/* ubake/sh.h — real spherical harmonics up to L2 for light probes (GLG, LLG).
 *
 * Conventions (DESIGN §3): real, orthonormal SH in the usual (l,m) order, 9 coefficients
 * per colour channel, stored coefficient-major: sh[k*3 + c] for coefficient k, channel c
 * (27 floats). For a unit direction (x, y, z):
 *   k=0 Y00  = 0.282095            k=4 Y2-2 = 1.092548 xy
 *   k=1 Y1-1 = 0.488603 y          k=5 Y2-1 = 1.092548 yz
 *   k=2 Y10  = 0.488603 z          k=6 Y20  = 0.315392 (3z² − 1)
 *   k=3 Y11  = 0.488603 x          k=7 Y21  = 1.092548 xz
 *                                  k=8 Y22  = 0.546274 (x² − y²)
 * The first 4 coefficients are exactly the SH L1 layout of ubake/ahd.h.
 * Probes store incident radiance, W/(m²·sr). Irradiance for a unit normal n is the
 * cosine convolution E(n) = Σ Â_l L_lm Y_lm(n), Â_0 = π, Â_1 = 2π/3, Â_2 = π/4.
 *
 * Windowing: an L2 projection of a non-negative radiance function can give negative
 * irradiance for some normals (ringing). ub_sh2_window() scales the l=1 and l=2 bands by
 * the smallest window that makes the irradiance non-negative for every normal; the DC
 * term is never changed for a channel whose DC is ≥ 0. Probes are windowed once (by the
 * baker, or after the run-time re-blends them); since irradiance is linear in the SH,
 * any convex combination of windowed probes (barycentric interpolation) is again
 * non-negative everywhere.
 *
 * Pure functions, no allocation, thread safe. Part of the run-time library.
 */
#ifndef UBAKE_SH_H
#define UBAKE_SH_H

#ifdef __cplusplus
extern "C" {
#endif

#define UB_SH2_COEFFS 9
#define UB_SH2_FLOATS 27

/* Cosine-lobe convolution factors per band. */
#define UB_SH_A0 3.14159265358979f /* π */
#define UB_SH_A1 2.09439510239320f /* 2π/3 */
#define UB_SH_A2 0.78539816339745f /* π/4 */

/* Windowing keeps min irradiance ≥ UB_SH2_WINDOW_MARGIN × (DC irradiance), a tiny margin
 * so that evaluating the windowed SH in float never dips below zero by rounding. */
#define UB_SH2_WINDOW_MARGIN 1e-5f

/* ub_sh2_window() result bits (per channel c = 0, 1, 2). */
#define UB_SH2_WINDOWED(c) (1u << (c))     /* bands l ≥ 1 were attenuated */
#define UB_SH2_ZEROED(c) (1u << (4 + (c))) /* DC < 0 or non-finite: channel set to 0 */

/* The 9 basis functions at unit direction dir (not normalised here). */
void ub_sh2_eval_basis(const float dir[3], float out_basis[9]);

/* sh = 0. */
void ub_sh2_zero(float sh[27]);

/* Adds radiance L (W/(m²·sr)) arriving from unit direction dir (pointing away from the
 * receiver) with estimator weight wt (e.g. 4π/N for N uniform sphere samples, or 1 for a
 * delta of unit solid-angle integral): sh += wt · L · Y(dir). */
void ub_sh2_add(float sh[27], const float dir[3], const float L[3], float wt);

/* acc += w · sh. */
void ub_sh2_madd(float acc[27], const float sh[27], float w);

/* sh *= s. */
void ub_sh2_scale(float sh[27], float s);

/* out = (1 − t)·a + t·b. out may alias a or b. */
void ub_sh2_lerp(const float a[27], const float b[27], float t, float out[27]);

/* Pads an SH L1 (ubake/ahd.h layout, 4 × 3 floats) to L2 with zero l=2 band. */
void ub_sh2_from_sh1(const float sh1[12], float out_sh2[27]);

/* Irradiance (W/m²) for unit normal n, per channel. Linear in sh: the value is signed and
 * can be negative for un-windowed SH; callers that need a physical value clamp at 0. */
void ub_sh2_irradiance(const float sh[27], const float n[3], float out_rgb[3]);
/* The weights ub_sh2_irradiance puts on the 9 coefficients for unit normal n: the cosine
 * lobe's band factors times the basis at n (E_c = Σ_k out_w[k]·sh[3k + c]). */
void ub_sh2_irradiance_basis(const float n[3], float out_w[9]);

/* Minimum over all unit normals of ub_sh2_irradiance, per channel (W/m²). Solved exactly
 * (the L2 irradiance restricted to the sphere is a quadratic, so this is a trust-region
 * subproblem; its dual gives a certified lower bound accurate to ~1e-12 relative). */
void ub_sh2_irradiance_min(const float sh[27], float out_min_rgb[3]);

/* Deringing window, in place. Per channel with DC irradiance E0 = π·Y00·L00 > 0, band
 * weights w1 = 1 − t/2, w2 = 1 − t (l=2 fades twice as fast as l=1) with the smallest
 * t ∈ [0, 1] such that min_n E(n) ≥ UB_SH2_WINDOW_MARGIN·E0. At t = 1 (w1 = ½, w2 = 0)
 * the irradiance of ANY non-negative radiance function is ≥ 0, so for physical input the
 * DC term is always kept exactly. When no t ∈ [0, 1] reaches the margin (input that is not
 * a non-negative function, e.g. Monte Carlo noise, or a delta-like lobe whose minimum at
 * t = 1 is exactly 0), w2 = 0 and w1 goes from ½ down to what is needed (0 at worst).
 * A channel with DC < 0 or any non-finite coefficient is set to zero.
 * Cost: two closed-form sufficient tests, E0 ≥ |b| + √(2/3)·‖M‖_F (M traceless; a few
 * ns) and the trust-region dual at ≤ 4 points without an eigendecomposition (~50 ns),
 * pass nearly every probe that needs no window; otherwise one exact minimum (~1 µs) and,
 * if windowing is needed, a Newton search on the concave minimum-vs-window curve (~3
 * more minima; phase 2 in closed form).
 * Returns UB_SH2_WINDOWED / UB_SH2_ZEROED bits (0 = unchanged). */
unsigned ub_sh2_window(float sh[27]);

/* The window ub_sh2_window() would apply, without applying it: per channel the l=1 and
 * l=2 band weights (1, 1 for a channel left unchanged, 0, 0 for a zeroed one, with
 * w1 = 1 − t/2 in both phases). Same result bits. */
unsigned ub_sh2_window_weights(const float sh[27], float out_w1[3], float out_w2[3]);

/* The same window found by the original bracketing search (regula falsi / golden section,
 * ~10–40 exact minima per channel) and the looser test E0 ≥ |b| + ‖M‖_F: the reference
 * the tests compare ub_sh2_window with (the window parameter agrees to ~1e-7). */
unsigned ub_sh2_window_reference(float sh[27]);

#ifdef __cplusplus
}
#endif
#endif
