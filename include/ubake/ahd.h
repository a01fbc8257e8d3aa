/* ubake/ahd.h — ambient/highlight/direction lightmap encoding (Sloan & Silvennoinen 2018).
 *
 * A texel's incident radiance is baked as SH L1 (4 coefficients per channel, real
 * orthonormal, order Y00, Y1-1, Y10, Y11 = (y, z, x) with the usual constants). AHD keeps
 * an RGB ambient C_a, a unit direction d and an RGB directional colour C_d, chosen so the
 * irradiance along the surface normal n is exact:
 *   E(n') = C_a + C_d · max(0, d·n')   (both C_a, C_d ≥ 0)
 *   with I_z = E_SH(n) and C_d = (I_z − C_a) / (d·n), d·n guarded.
 * Pure functions; thread safe.
 */
#ifndef UBAKE_AHD_H
#define UBAKE_AHD_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct ub_ahd {
  float ambient[3];   /* W/m² */
  float direction[3]; /* unit */
  float directional[3]; /* W/m² */
} ub_ahd;

/* sh: 4 × 3 floats, coefficient-major: sh[k*3 + c] for coefficient k, channel c.
 * Radiance SH, W/(m²·sr). normal: unit surface normal. */
void ub_ahd_encode(const float sh[12], const float normal[3], ub_ahd *out_ahd);
/* The same from SH whose DC slots sh_iz[0..2] hold I_z, the irradiance (W/m²) along
 * unit_normal per channel, in place of L00 (the run-time's packed texel form): no
 * unpacking, and I_z is kept as given. unit_normal must be unit length. */
void ub_ahd_encode_iz(const float sh_iz[12], const float unit_normal[3], ub_ahd *out_ahd);
/* Eight texels at once: sh_iz 8 × 12 floats, unit_normals 8 × 3, out 8 AHD; the same bits
 * as eight ub_ahd_encode_iz calls (AVX when the CPU has it, else those calls). */
void ub_ahd_encode_iz8(const float *sh_iz, const float *unit_normals, ub_ahd *out_ahd);
/* The same on texels where they are: rows[j] texel j's 12 floats, out[j] its AHD (any
 * addresses; an out must not overlap a row). */
void ub_ahd_encode_iz8_rows(const float *const rows[8], const float *unit_normals,
                            ub_ahd *const out[8]);
/* The run-time's stored AHD texel, 16 bytes, laid out for a GPU texture: ambient and
 * directional RGB as IEEE half of value / scale (scale a power of two ≥ 1, the same for a
 * whole lightmap: ub_runtime_ahd_scale; relative error ≤ 2^-11, saturated at 65504·scale),
 * the direction octahedral-mapped to [-1, 1]² (u = x/(|x|+|y|+|z|), v likewise, folded
 * when z < 0) as snorm16 (angular error below 1e-4 rad). */
typedef struct ub_ahd_packed {
  uint16_t ambient[3];     /* half */
  uint16_t directional[3]; /* half */
  int16_t oct[2];          /* snorm16 */
} ub_ahd_packed;
/* The scale for texels whose SH values (W/m², any coefficient, the I_z form's too) are at
 * most row_max: the smallest power of two ≥ 1 that keeps 64 × row_max within the half
 * range (an AHD colour can exceed its SH values, C_d up to ~10× them, and sets add up);
 * 1 for row_max ≤ 1023, and for a zero or non-finite row_max. The run-time's rule. */
float ub_ahd_pack_scale(double row_max);
/* in → packed; inv_scale = 1 / scale. */
void ub_ahd_pack(const ub_ahd *in, float inv_scale, ub_ahd_packed *out);
/* packed → AHD (direction renormalised to unit length). */
void ub_ahd_unpack(const ub_ahd_packed *in, float scale, ub_ahd *out);
/* ub_ahd_encode_iz8 / _rows, packed: the bits of ub_ahd_encode_iz then ub_ahd_pack (AVX
 * and F16C when the CPU has them). */
void ub_ahd_encode_iz8_packed(const float *sh_iz, const float *unit_normals, float inv_scale,
                              ub_ahd_packed *out_packed);
void ub_ahd_encode_iz8_rows_packed(const float *const rows[8], const float *unit_normals,
                                   float inv_scale, ub_ahd_packed *const out[8]);
/* count contiguous texels (sh_iz: count × 12, unit_normals: count × 3), packed: the bits
 * of ub_ahd_encode_iz then ub_ahd_pack for each. With AVX + F16C, sixteen at a time (AVX-512:
 * in the lanes of one register set, loaded and stored by whole-register permutes; AVX: two
 * interleaved groups of eight, the encode's latency hidden), then eight, then one by one. */
void ub_ahd_encode_iz_packed_n(const float *sh_iz, const float *unit_normals, float inv_scale,
                               ub_ahd_packed *out_packed, size_t count);
/* Irradiance (W/m²) for any unit normal n'. */
void ub_ahd_irradiance(const ub_ahd *ahd, const float n[3], float out_rgb[3]);
/* Irradiance from the SH L1 directly (cosine convolution), W/m², never negative. */
void ub_sh1_irradiance(const float sh[12], const float n[3], float out_rgb[3]);
/* Adds radiance L (W/(m²·sr)) arriving from unit direction w (pointing away from the
 * receiver) with weight wt into sh (projection estimator: sh += wt·L·Y(w)). */
void ub_sh1_add(float sh[12], const float w[3], const float L[3], float wt);

#ifdef __cplusplus
}
#endif
#endif
