/* runtime/texel_sh.h — how a lightmap texel's SH L1 is stored in the .ubk.
 *
 * The baker makes each texel's SH exact along its normal (the irradiance I_z). Under
 * grazing light that exactness is a near-cancellation: the coefficients are ~1000× the
 * irradiance they encode along n, and rounding them to half floats (2^-11) would move I_z
 * by up to 14% at 89.99°. So the file stores I_z (per channel) in place of the DC
 * coefficient L00 for every texel with a usable normal, and the reader rebuilds
 *   L00 = (I_z − (2π/3)·Y1·(L1·n)) / (π·Y00)
 * with the normal n the run-time encodes with (the stored normal, normalised by
 * ub_texel_normal): the irradiance along n is then I_z to half precision of I_z itself.
 * Linear in the light, so sparse records (DLSR) use the same form with their pixel's
 * normal. Header-only: the writer, reader and run-time share one arithmetic.
 */
#ifndef UBAKE_RUNTIME_TEXEL_SH_H
#define UBAKE_RUNTIME_TEXEL_SH_H

#include <math.h>

#define UB_TEXEL_MIN_NORMAL_LENGTH 0.5 /* shorter stored normals count as "no normal" */

/* Unit normal from a stored one; 0 when it is unusable (non-finite or too short). */
static inline int ub_texel_normal(const float n[3], float out[3])
{
  if (!isfinite(n[0]) || !isfinite(n[1]) || !isfinite(n[2]))
    return 0;
  double l = sqrt((double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2]);
  if (!(l >= UB_TEXEL_MIN_NORMAL_LENGTH))
    return 0;
  double inv = 1.0 / l; /* one division (a run-time update calls this per touched texel) */
  for (int i = 0; i < 3; i++)
    out[i] = (float)(n[i] * inv);
  return 1;
}

/* Linear band's irradiance along unit n for channel c (SH L1 order y, z, x). */
static inline double ub_texel_sh_linear(const float sh[12], const float n[3], int c)
{
  return (2.0 * M_PI / 3.0) * 0.488602511902919921 *
         ((double)sh[3 + c] * n[1] + (double)sh[6 + c] * n[2] + (double)sh[9 + c] * n[0]);
}

/* In place: L00 → I_z along unit n (before writing). */
static inline void ub_texel_sh_pack(float sh[12], const float n[3])
{
  for (int c = 0; c < 3; c++)
    sh[c] = (float)(M_PI * 0.282094791773878143 * sh[c] + ub_texel_sh_linear(sh, n, c));
}

/* In place: I_z → L00 along unit n (after reading). */
static inline void ub_texel_sh_unpack(float sh[12], const float n[3])
{
  for (int c = 0; c < 3; c++)
    sh[c] = (float)((sh[c] - ub_texel_sh_linear(sh, n, c)) / (M_PI * 0.282094791773878143));
}

#endif
