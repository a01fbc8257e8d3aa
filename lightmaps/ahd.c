/* lightmaps/ahd.c — SH L1 projection/irradiance and the ambient/highlight/direction
 * encoding (Sloan & Silvennoinen 2018). Run-time library: pure math, no scene, no Embree.
 *
 * The L1 irradiance of one channel is linear in the normal: E(n') = a + b·n', with
 * a = π·Y00·L00 (the mean over the sphere) and b = (2π/3)·0.488603·(L11, L1-1, L10).
 * AHD replaces it by C_a + C_d·max(0, d·n'), d the luminance-weighted direction of b.
 * The irradiance along the surface normal, I_z = E_SH(n), must stay exact, so
 * C_a = I_z − C_d·dz (dz = d·n) and one unknown is left: C_d is the least-squares fit of
 * E over the sphere under that constraint. With g(n') = max(0, d·n') − dz and t = d·n'
 * uniform on [-1, 1] (<1> = 1, <t> = 0, <t²> = 1/3, <max(0,t)> = 1/4, <t·max(0,t)> =
 * <max(0,t)²> = 1/6):
 *     C_d = (β/6 − (b·n)(1/4 − dz)) / (1/6 − dz/2 + dz²),   β = b·d,
 * the denominator is ≥ 5/48. For light from one direction (b = β·d, and β ≤ 2a for
 * positive radiance) C_a = a − β·dz²/(4·denominator) ≥ a − 0.4·β ≥ 0.2·a, so the clamps
 * below (C_d ≥ 0; C_a ≥ 0, then C_d = (I_z − C_a)/dz) act only on colour channels whose
 * light comes from elsewhere than d, or on negative (delta) inputs.
 * When dz ≤ UB_AHD_DZ_GUARD (the light is grazing or behind the surface) everything goes
 * to ambient: C_a = I_z, C_d = 0, d = n. Decoding is exact along n in every case, and a
 * decoder storing (C_a, d, I_z) recovers C_d = (I_z − C_a)/(d·n) with d·n > guard.
 * Measured error for other normals: tests/test_ahd.c.
 */
#include "ubake/ahd.h"

#include <math.h>
#include <stddef.h>

#include "runtime/cpu.h"
#include "runtime/half.h"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define AHD_HAVE_AVX 1
#endif

#define UB_SH_Y0 0.282094791773878f /* 1/(2√π) */
#define UB_SH_Y1 0.488602511902920f /* √3/(2√π) */
#define UB_PI 3.14159265358979f

/* Below this d·n the direction is grazing or below the surface: ambient only. */
#define UB_AHD_DZ_GUARD 1e-2f
/* Linear band magnitude, relative to the mean irradiance, under which the direction is
 * noise and the normal is used instead. */
#define UB_AHD_DIR_REL_EPS 1e-6f

/* Rec. 709 luminance weights for the shared direction. */
static const float k_lum[3] = {0.2126f, 0.7152f, 0.0722f};

static float finite_or_zero(float x)
{
  return isfinite(x) ? x : 0.0f;
}

/* Unit copy of n; (0, 0, 1) for a zero or non-finite vector. */
static void safe_unit(const float n[3], float out[3])
{
  float x = finite_or_zero(n[0]), y = finite_or_zero(n[1]), z = finite_or_zero(n[2]);
  float l = sqrtf(x * x + y * y + z * z);
  if (!(l > 1e-20f)) {
    out[0] = 0.0f;
    out[1] = 0.0f;
    out[2] = 1.0f;
    return;
  }
  out[0] = x / l;
  out[1] = y / l;
  out[2] = z / l;
}

/* Per channel: mean term a[c] and linear vector b[c] (x, y, z) of the L1 irradiance. */
static void sh1_irradiance_terms(const float sh[12], float a[3], float b[3][3])
{
  const float ka = UB_PI * UB_SH_Y0;
  const float kb = (2.0f * UB_PI / 3.0f) * UB_SH_Y1;
  for (int c = 0; c < 3; c++) {
    a[c] = ka * finite_or_zero(sh[0 * 3 + c]);
    b[c][0] = kb * finite_or_zero(sh[3 * 3 + c]); /* Y11 ∝ x */
    b[c][1] = kb * finite_or_zero(sh[1 * 3 + c]); /* Y1-1 ∝ y */
    b[c][2] = kb * finite_or_zero(sh[2 * 3 + c]); /* Y10 ∝ z */
  }
}

void ub_sh1_add(float sh[12], const float w[3], const float L[3], float wt)
{
  const float y[4] = {UB_SH_Y0, UB_SH_Y1 * w[1], UB_SH_Y1 * w[2], UB_SH_Y1 * w[0]};
  for (int k = 0; k < 4; k++)
    for (int c = 0; c < 3; c++)
      sh[k * 3 + c] += wt * L[c] * y[k];
}

void ub_sh1_irradiance(const float sh[12], const float n[3], float out_rgb[3])
{
  float a[3], b[3][3], u[3];
  sh1_irradiance_terms(sh, a, b);
  safe_unit(n, u);
  for (int c = 0; c < 3; c++) {
    float e = a[c] + b[c][0] * u[0] + b[c][1] * u[1] + b[c][2] * u[2];
    out_rgb[c] = e > 0.0f ? e : 0.0f;
  }
}

/* The encoding from the L1 terms and the unit normal n; iz_in: the irradiance along n per
 * channel when the caller has it (else a + b·n). */
static void ahd_encode_terms(const float a[3], const float b[3][3], const float *iz_in,
                             const float n[3], ub_ahd *out_ahd);

void ub_ahd_encode(const float sh[12], const float normal[3], ub_ahd *out_ahd)
{
  float a[3], b[3][3], n[3];
  sh1_irradiance_terms(sh, a, b);
  safe_unit(normal, n);
  ahd_encode_terms(a, b, NULL, n, out_ahd);
}

void ub_ahd_encode_iz(const float sh_iz[12], const float unit_normal[3], ub_ahd *out_ahd)
{
  float a[3], b[3][3], iz[3];
  sh1_irradiance_terms(sh_iz, a, b); /* a: scaled I_z, replaced below */
  for (int c = 0; c < 3; c++) {
    iz[c] = finite_or_zero(sh_iz[c]);
    a[c] = iz[c] - (b[c][0] * unit_normal[0] + b[c][1] * unit_normal[1] +
                    b[c][2] * unit_normal[2]);
  }
  ahd_encode_terms(a, b, iz, unit_normal, out_ahd);
}

static void ahd_encode_terms(const float a[3], const float b[3][3], const float *iz_in,
                             const float n[3], ub_ahd *out_ahd)
{

  /* Shared direction: luminance-weighted linear band. */
  float bl[3] = {0.0f, 0.0f, 0.0f};
  float al = 0.0f;
  for (int c = 0; c < 3; c++) {
    al += k_lum[c] * fabsf(a[c]);
    for (int i = 0; i < 3; i++)
      bl[i] += k_lum[c] * b[c][i];
  }
  float blen = sqrtf(bl[0] * bl[0] + bl[1] * bl[1] + bl[2] * bl[2]);
  float d[3];
  if (blen > UB_AHD_DIR_REL_EPS * al && blen > 1e-30f) {
    float inv_blen = 1.0f / blen;
    d[0] = bl[0] * inv_blen;
    d[1] = bl[1] * inv_blen;
    d[2] = bl[2] * inv_blen;
  } else {
    d[0] = n[0];
    d[1] = n[1];
    d[2] = n[2];
  }
  float dz = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
  int ambient_only = !(dz > UB_AHD_DZ_GUARD);
  if (ambient_only) {
    d[0] = n[0];
    d[1] = n[1];
    d[2] = n[2];
  }

  /* one division each for the three channels (the run-time re-encodes every touched
   * texel on an update) */
  float inv_den = ambient_only ? 0.0f : 1.0f / (1.0f / 6.0f - 0.5f * dz + dz * dz);
  float inv_dz = ambient_only ? 0.0f : 1.0f / dz;
  for (int c = 0; c < 3; c++) {
    float iz = iz_in ? iz_in[c] : a[c] + b[c][0] * n[0] + b[c][1] * n[1] + b[c][2] * n[2];
    if (!(iz > 0.0f))
      iz = 0.0f; /* the SH irradiance is clamped the same way */
    float ca, cd;
    if (ambient_only) {
      ca = iz;
      cd = 0.0f;
    } else {
      float beta = b[c][0] * d[0] + b[c][1] * d[1] + b[c][2] * d[2];
      float bn = b[c][0] * n[0] + b[c][1] * n[1] + b[c][2] * n[2];
      /* least squares over the sphere with I_z held exact (see the top comment) */
      float cd0 = (beta * (1.0f / 6.0f) - bn * (0.25f - dz)) * inv_den;
      if (!(cd0 > 0.0f))
        cd0 = 0.0f;
      ca = iz - cd0 * dz;
      if (ca < 0.0f)
        ca = 0.0f;
      cd = (iz - ca) * inv_dz; /* dz > guard: finite; 0 ≤ cd ≤ cd0 (to rounding) */
      if (!(cd > 0.0f))
        cd = 0.0f;
    }
    out_ahd->ambient[c] = ca;
    out_ahd->directional[c] = cd;
  }
  out_ahd->direction[0] = d[0];
  out_ahd->direction[1] = d[1];
  out_ahd->direction[2] = d[2];
}

/* A colour value for ub_ahd_packed: value / scale (inv_scale = 1/scale, a power of two:
 * exact) in half, rounded to nearest even; saturated at the largest half (and NaN to it,
 * as minps does in the AVX path). */
static uint16_t pack_colour(float v, float inv_scale)
{
  float x = v * inv_scale;
  if (!(x <= UB_HALF_MAX))
    x = UB_HALF_MAX;
  return ub_half_from_float(x);
}

/* Unit direction d → octahedral (u, v) ∈ [-1, 1]² as snorm16 (rounded in the current
 * rounding mode, as cvtps2dq does: to nearest unless the caller changed it); a zero or
 * non-finite direction gives (0, 0) (the encoder's directions are unit: the AVX path
 * tests for zero only). */
/* The octahedral fold of the lower hemisphere (its own inverse): (u, v) →
 * ((1 − |v|)·sign u, (1 − |u|)·sign v), sign 0 = +1. */
static void oct_fold(float *u, float *v)
{
  const float nu = (1.0f - fabsf(*v)) * (*u >= 0.0f ? 1.0f : -1.0f);
  const float nv = (1.0f - fabsf(*u)) * (*v >= 0.0f ? 1.0f : -1.0f);
  *u = nu;
  *v = nv;
}

static void pack_direction(const float d[3], int16_t out[2])
{
  float s = (fabsf(d[0]) + fabsf(d[1])) + fabsf(d[2]), inv = 1.0f / s;
  float u = d[0] * inv, v = d[1] * inv;
  if (!(s > 0.0f) || !(s < INFINITY)) /* zero, or not finite (NaN, ±Inf): no direction */
    u = v = 0.0f;
  if (d[2] < 0.0f)
    oct_fold(&u, &v);
  out[0] = (int16_t)lrintf(u * 32767.0f);
  out[1] = (int16_t)lrintf(v * 32767.0f);
}

float ub_ahd_pack_scale(double row_max)
{
  float s = 1.0f;
  if (!(row_max > 0.0) || !isfinite(row_max))
    return s;
  while (row_max * 64.0 > (double)UB_HALF_MAX * s && s < 1e30f)
    s *= 2.0f;
  return s;
}

void ub_ahd_pack(const ub_ahd *in, float inv_scale, ub_ahd_packed *out)
{
  for (int c = 0; c < 3; c++) {
    out->ambient[c] = pack_colour(in->ambient[c], inv_scale);
    out->directional[c] = pack_colour(in->directional[c], inv_scale);
  }
  pack_direction(in->direction, out->oct);
}

void ub_ahd_unpack(const ub_ahd_packed *in, float scale, ub_ahd *out)
{
  for (int c = 0; c < 3; c++) {
    out->ambient[c] = ub_half_to_float(in->ambient[c]) * scale;
    out->directional[c] = ub_half_to_float(in->directional[c]) * scale;
  }
  float u = fmaxf((float)in->oct[0] / 32767.0f, -1.0f);
  float v = fmaxf((float)in->oct[1] / 32767.0f, -1.0f);
  float z = 1.0f - fabsf(u) - fabsf(v);
  if (z < 0.0f)
    oct_fold(&u, &v);
  float l = sqrtf(u * u + v * v + z * z);
  out->direction[0] = u / l;
  out->direction[1] = v / l;
  out->direction[2] = z / l;
}

/* ub_ahd_encode_iz then ub_ahd_pack: the bits every packed encoder gives. */
static void encode_packed(const float sh_iz[12], const float unit_normal[3], float inv_scale,
                          ub_ahd_packed *out)
{
  ub_ahd a;
  ub_ahd_encode_iz(sh_iz, unit_normal, &a);
  ub_ahd_pack(&a, inv_scale, out);
}

/* encode_packed on eight texels (rows[j], normal j of nrm, out[j]). */
static void encode8_packed_scalar(const float *const rows[8], const float *nrm, float inv_scale,
                                  ub_ahd_packed *const out[8])
{
  for (int j = 0; j < 8; j++)
    encode_packed(rows[j], nrm + 3 * j, inv_scale, out[j]);
}

#if defined(AHD_HAVE_AVX)
/* In-register 8 × 8 transpose: r[j] holds 8 floats of row j; afterwards r[k] holds element
 * k of every row (its own inverse). */
__attribute__((target("avx"))) static inline void transpose8_avx(__m256 r[8])
{
  __m256 t[8], u[8];
  #pragma GCC unroll 8
  for (int i = 0; i < 8; i += 2) {
    t[i] = _mm256_unpacklo_ps(r[i], r[i + 1]);
    t[i + 1] = _mm256_unpackhi_ps(r[i], r[i + 1]);
  }
  #pragma GCC unroll 8
  for (int i = 0; i < 8; i += 4) {
    u[i] = _mm256_shuffle_ps(t[i], t[i + 2], 0x44);
    u[i + 1] = _mm256_shuffle_ps(t[i], t[i + 2], 0xEE);
    u[i + 2] = _mm256_shuffle_ps(t[i + 1], t[i + 3], 0x44);
    u[i + 3] = _mm256_shuffle_ps(t[i + 1], t[i + 3], 0xEE);
  }
  #pragma GCC unroll 8
  for (int i = 0; i < 4; i++) {
    r[i] = _mm256_permute2f128_ps(u[i], u[i + 4], 0x20);
    r[i + 4] = _mm256_permute2f128_ps(u[i], u[i + 4], 0x31);
  }
}

/* ub_ahd_encode_iz on K groups of 8 texels in the lanes of AVX registers: every operation,
 * its operands and their order as in the scalar code (IEEE single, no FMA), branches as
 * blends, so each lane gives the scalar bits. rows[8g + j]: texel j of group g, 12 floats;
 * nrm: 8K × 3 unit normals; o[g]: group g's AHD in lanes. Texels move into and out of the
 * lanes by register transposes (8 × 8 and 8 × 4), not through memory element by element.
 * The groups go through each step in lockstep: one group's work is a chain of dependent
 * long-latency operations (a sqrt, then divisions); side by side, one group's work can
 * fill the other's waits. On the bench machine (Zen 3) that gained only 7–8% in cache
 * (bench_ahd): the encode is mostly bound by its ~470 instructions per 8 texels.
 * Returns a bit per group whose input is not all finite, or whose finite values sum to
 * ±Inf (its o is then garbage: the caller encodes those texels one by one, which gives
 * the bits as the scalar code's finite_or_zero wants). */
#define AHD_MAX_K 2
#define AHD_FOR_G _Pragma("GCC unroll 4") for (int g = 0; g < K; g++)
/* K groups of eight texels into lanes: t[g][k] coefficient k, n0..n2[g] the normals. */
__attribute__((target("avx"), always_inline)) static inline void
lanes_load_k(const int K, const float *const *rows, const float *nrm, __m256 t[][12],
             __m256 *n0, __m256 *n1, __m256 *n2)
{
  AHD_FOR_G {
    const float *const *rw = rows + 8 * g;
    __m256 *tg = t[g];
    __m256 hi[4];
    #pragma GCC unroll 8
    for (int j = 0; j < 8; j++)
      tg[j] = _mm256_loadu_ps(rw[j]);
    transpose8_avx(tg);
    #pragma GCC unroll 8
    for (int j = 0; j < 4; j++)
      hi[j] = _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(rw[j] + 8)),
                                   _mm_loadu_ps(rw[j + 4] + 8), 1);
    __m256 a0 = _mm256_unpacklo_ps(hi[0], hi[1]), a1 = _mm256_unpackhi_ps(hi[0], hi[1]);
    __m256 a2 = _mm256_unpacklo_ps(hi[2], hi[3]), a3 = _mm256_unpackhi_ps(hi[2], hi[3]);
    /* lanes 0-3 hold texels 0-3 and lanes 4-7 texels 4-7 in that order already */
    tg[8] = _mm256_shuffle_ps(a0, a2, 0x44);
    tg[9] = _mm256_shuffle_ps(a0, a2, 0xEE);
    tg[10] = _mm256_shuffle_ps(a1, a3, 0x44);
    tg[11] = _mm256_shuffle_ps(a1, a3, 0xEE);
  }
  /* the normals (8 × 3 contiguous floats a group) into x, y, z lanes by shuffles */
  AHD_FOR_G {
    const float *ng = nrm + 24 * g;
    __m256 m03 = _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(ng)),
                                      _mm_loadu_ps(ng + 12), 1); /* x0y0z0x1 x4y4z4x5 */
    __m256 m14 = _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(ng + 4)),
                                      _mm_loadu_ps(ng + 16), 1); /* y1z1x2y2 y5z5x6y6 */
    __m256 m25 = _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(ng + 8)),
                                      _mm_loadu_ps(ng + 20), 1); /* z2x3y3z3 z6x7y7z7 */
    __m256 xy = _mm256_shuffle_ps(m14, m25, _MM_SHUFFLE(2, 1, 3, 2)); /* x2y2x3y3 */
    __m256 yz = _mm256_shuffle_ps(m03, m14, _MM_SHUFFLE(1, 0, 2, 1)); /* y0z0y1z1 */
    n0[g] = _mm256_shuffle_ps(m03, xy, _MM_SHUFFLE(2, 0, 3, 0));
    n1[g] = _mm256_shuffle_ps(yz, xy, _MM_SHUFFLE(3, 1, 2, 0));
    n2[g] = _mm256_shuffle_ps(yz, m25, _MM_SHUFFLE(3, 0, 3, 1));
  }
}

__attribute__((target("avx"), always_inline)) static inline unsigned
encode_lanes_k(const int K, const float *const *rows, const float *nrm, __m256 o[][9])
{
  __m256 t[AHD_MAX_K][12], n0[AHD_MAX_K], n1[AHD_MAX_K], n2[AHD_MAX_K];
  lanes_load_k(K, rows, nrm, t, n0, n1, n2);
  const __m256 zero = _mm256_setzero_ps();
  const __m256 absm = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
  unsigned bad = 0;
  AHD_FOR_G {
    /* x·0 is ±0 for a finite x, NaN for ±Inf and NaN: with every input finite (the rule)
     * the scalar code's finite_or_zero changes nothing, else the eight go to it. The sum
     * of a lane's 12 values times 0 is NaN when one of them is not finite, and also when
     * finite values near FLT_MAX sum to ±Inf: those eight then go to the scalar code as
     * well, which gives the same bits, only slower. */
    __m256 s[6];
    #pragma GCC unroll 8
    for (int j = 0; j < 6; j++)
      s[j] = _mm256_add_ps(t[g][2 * j], t[g][2 * j + 1]);
    __m256 all = _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(s[0], s[1]), _mm256_add_ps(s[2], s[3])),
                               _mm256_add_ps(s[4], s[5]));
    all = _mm256_mul_ps(all, zero);
    if (_mm256_movemask_ps(_mm256_cmp_ps(all, all, _CMP_UNORD_Q)))
      bad |= 1u << g;
  }
  if (bad == (1u << K) - 1)
    return bad;
#define AHD_ABS(x) _mm256_and_ps((x), absm)
/* m ? b : a for whole-lane compare masks m. Not _mm256_blendv_ps: GCC folds that into a
 * sign-bit select, which without AVX2 it lowers lane by lane through integer registers
 * (perf: a third of this function's time before). */
#define AHD_SEL(a, b, m) _mm256_or_ps(_mm256_and_ps((m), (b)), _mm256_andnot_ps((m), (a)))
/* x > 0 ? x : 0 (NaN and −0 give +0), and x < 0 ? 0 : x (NaN and −0 kept): maxps returns
 * its second operand unless the first is greater */
#define AHD_POS(x) _mm256_max_ps((x), zero)
#define AHD_NONNEG(x) _mm256_max_ps(zero, (x))
#define AHD_DOT(a0, a1, a2, b0, b1, b2)                                                  \
  _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(a0, b0), _mm256_mul_ps(a1, b1)),            \
                _mm256_mul_ps(a2, b2))
  const __m256 kb = _mm256_set1_ps((2.0f * UB_PI / 3.0f) * UB_SH_Y1);
  __m256 b[AHD_MAX_K][3][3], iz[AHD_MAX_K][3], al[AHD_MAX_K], bl[AHD_MAX_K][3];
  AHD_FOR_G {
    __m256 a[3];
    #pragma GCC unroll 8
    for (int c = 0; c < 3; c++) {
      b[g][c][0] = _mm256_mul_ps(kb, t[g][9 + c]);
      b[g][c][1] = _mm256_mul_ps(kb, t[g][3 + c]);
      b[g][c][2] = _mm256_mul_ps(kb, t[g][6 + c]);
      iz[g][c] = t[g][c];
      a[c] = _mm256_sub_ps(iz[g][c],
                           AHD_DOT(b[g][c][0], b[g][c][1], b[g][c][2], n0[g], n1[g], n2[g]));
    }
    al[g] = zero;
    bl[g][0] = bl[g][1] = bl[g][2] = zero;
    #pragma GCC unroll 8
    for (int c = 0; c < 3; c++) {
      __m256 k = _mm256_set1_ps(k_lum[c]);
      al[g] = _mm256_add_ps(al[g], _mm256_mul_ps(k, AHD_ABS(a[c])));
      #pragma GCC unroll 8
      for (int i = 0; i < 3; i++)
        bl[g][i] = _mm256_add_ps(bl[g][i], _mm256_mul_ps(k, b[g][c][i]));
    }
  }
  __m256 blen[AHD_MAX_K];
  AHD_FOR_G
    blen[g] = _mm256_sqrt_ps(AHD_DOT(bl[g][0], bl[g][1], bl[g][2], bl[g][0], bl[g][1], bl[g][2]));
  __m256 d0[AHD_MAX_K], d1[AHD_MAX_K], d2[AHD_MAX_K], dz[AHD_MAX_K], dir[AHD_MAX_K];
  AHD_FOR_G {
    __m256 use_b = _mm256_and_ps(
        _mm256_cmp_ps(blen[g], _mm256_mul_ps(_mm256_set1_ps(UB_AHD_DIR_REL_EPS), al[g]),
                      _CMP_GT_OQ),
        _mm256_cmp_ps(blen[g], _mm256_set1_ps(1e-30f), _CMP_GT_OQ));
    __m256 inv_blen = _mm256_div_ps(_mm256_set1_ps(1.0f), blen[g]);
    d0[g] = AHD_SEL(n0[g], _mm256_mul_ps(bl[g][0], inv_blen), use_b);
    d1[g] = AHD_SEL(n1[g], _mm256_mul_ps(bl[g][1], inv_blen), use_b);
    d2[g] = AHD_SEL(n2[g], _mm256_mul_ps(bl[g][2], inv_blen), use_b);
  }
  AHD_FOR_G {
    dz[g] = AHD_DOT(d0[g], d1[g], d2[g], n0[g], n1[g], n2[g]);
    dir[g] = _mm256_cmp_ps(dz[g], _mm256_set1_ps(UB_AHD_DZ_GUARD), _CMP_GT_OQ);
    d0[g] = AHD_SEL(n0[g], d0[g], dir[g]);
    d1[g] = AHD_SEL(n1[g], d1[g], dir[g]);
    d2[g] = AHD_SEL(n2[g], d2[g], dir[g]);
  }
  const __m256 one = _mm256_set1_ps(1.0f), sixth = _mm256_set1_ps(1.0f / 6.0f);
  __m256 inv_den[AHD_MAX_K], inv_dz[AHD_MAX_K];
  AHD_FOR_G {
    __m256 den = _mm256_add_ps(_mm256_sub_ps(sixth, _mm256_mul_ps(_mm256_set1_ps(0.5f), dz[g])),
                               _mm256_mul_ps(dz[g], dz[g]));
    inv_den[g] = _mm256_and_ps(_mm256_div_ps(one, den), dir[g]);
    inv_dz[g] = _mm256_and_ps(_mm256_div_ps(one, dz[g]), dir[g]);
  }
  AHD_FOR_G {
    __m256 q = _mm256_sub_ps(_mm256_set1_ps(0.25f), dz[g]);
    /* o: the struct's 9 floats per texel in lanes (ambient, direction, directional) */
    o[g][3] = d0[g];
    o[g][4] = d1[g];
    o[g][5] = d2[g];
    #pragma GCC unroll 8
    for (int c = 0; c < 3; c++) {
      __m256 z = AHD_POS(iz[g][c]);
      __m256 beta = AHD_DOT(b[g][c][0], b[g][c][1], b[g][c][2], d0[g], d1[g], d2[g]);
      __m256 bn = AHD_DOT(b[g][c][0], b[g][c][1], b[g][c][2], n0[g], n1[g], n2[g]);
      __m256 cd0 = _mm256_mul_ps(
          _mm256_sub_ps(_mm256_mul_ps(beta, sixth), _mm256_mul_ps(bn, q)), inv_den[g]);
      cd0 = AHD_POS(cd0);
      __m256 ca = AHD_NONNEG(_mm256_sub_ps(z, _mm256_mul_ps(cd0, dz[g])));
      __m256 cd = AHD_POS(_mm256_mul_ps(_mm256_sub_ps(z, ca), inv_dz[g]));
      o[g][c] = AHD_SEL(z, ca, dir[g]);
      o[g][6 + c] = _mm256_and_ps(cd, dir[g]);
    }
  }
#undef AHD_ABS
#undef AHD_POS
#undef AHD_NONNEG
#undef AHD_SEL
#undef AHD_DOT
  return bad;
}

/* encode_lanes_k for one group, then the eight AHD out of the lanes by a register
 * transpose. */
__attribute__((target("avx"))) static void encode_iz8_avx(const float *const rows[8],
                                                          const float *nrm, ub_ahd *const out[8])
{
  __m256 og[1][9], *o = og[0];
  if (encode_lanes_k(1, rows, nrm, og)) {
    for (int j = 0; j < 8; j++)
      ub_ahd_encode_iz(rows[j], nrm + 3 * j, out[j]);
    return;
  }
  _Static_assert(sizeof(ub_ahd) == 9 * sizeof(float), "ub_ahd is 9 floats");
  __m128 lo8 = _mm256_castps256_ps128(o[8]), hi8 = _mm256_extractf128_ps(o[8], 1);
  __m128 last[8] = {lo8, _mm_shuffle_ps(lo8, lo8, 1), _mm_shuffle_ps(lo8, lo8, 2),
                    _mm_shuffle_ps(lo8, lo8, 3), hi8, _mm_shuffle_ps(hi8, hi8, 1),
                    _mm_shuffle_ps(hi8, hi8, 2), _mm_shuffle_ps(hi8, hi8, 3)};
  transpose8_avx(o);
  #pragma GCC unroll 8
  for (int j = 0; j < 8; j++) {
    float *dst = (float *)out[j]; /* ambient, direction, directional: 9 floats */
    _mm256_storeu_ps(dst, o[j]);
    _mm_store_ss(dst + 8, last[j]);
  }
}

/* Eight packed texels out of lanes: an 8 × 8 transpose of 16-bit words, wg[k] lane j →
 * texel j word k. */
__attribute__((target("avx"), always_inline)) static inline void
store_words8(const __m128i wg[8], ub_ahd_packed *const *og)
{
  __m128i a0 = _mm_unpacklo_epi16(wg[0], wg[1]), a1 = _mm_unpackhi_epi16(wg[0], wg[1]);
  __m128i a2 = _mm_unpacklo_epi16(wg[2], wg[3]), a3 = _mm_unpackhi_epi16(wg[2], wg[3]);
  __m128i a4 = _mm_unpacklo_epi16(wg[4], wg[5]), a5 = _mm_unpackhi_epi16(wg[4], wg[5]);
  __m128i a6 = _mm_unpacklo_epi16(wg[6], wg[7]), a7 = _mm_unpackhi_epi16(wg[6], wg[7]);
  __m128i b0 = _mm_unpacklo_epi32(a0, a2), b1 = _mm_unpackhi_epi32(a0, a2);
  __m128i b2 = _mm_unpacklo_epi32(a1, a3), b3 = _mm_unpackhi_epi32(a1, a3);
  __m128i b4 = _mm_unpacklo_epi32(a4, a6), b5 = _mm_unpackhi_epi32(a4, a6);
  __m128i b6 = _mm_unpacklo_epi32(a5, a7), b7 = _mm_unpackhi_epi32(a5, a7);
  _mm_storeu_si128((__m128i *)(void *)og[0], _mm_unpacklo_epi64(b0, b4));
  _mm_storeu_si128((__m128i *)(void *)og[1], _mm_unpackhi_epi64(b0, b4));
  _mm_storeu_si128((__m128i *)(void *)og[2], _mm_unpacklo_epi64(b1, b5));
  _mm_storeu_si128((__m128i *)(void *)og[3], _mm_unpackhi_epi64(b1, b5));
  _mm_storeu_si128((__m128i *)(void *)og[4], _mm_unpacklo_epi64(b2, b6));
  _mm_storeu_si128((__m128i *)(void *)og[5], _mm_unpackhi_epi64(b2, b6));
  _mm_storeu_si128((__m128i *)(void *)og[6], _mm_unpacklo_epi64(b3, b7));
  _mm_storeu_si128((__m128i *)(void *)og[7], _mm_unpackhi_epi64(b3, b7));
}

/* K groups' lanes (encode_lanes_k) packed (ub_ahd_pack's bits): the six colours through
 * F16C, the direction octahedral as in pack_direction, and each group's eight 16-byte
 * texels out of the lanes by a transpose of 16-bit words; out[8g + j]: texel j of group
 * g. Groups in skip (bits) are left alone. In lockstep like encode_lanes_k. */
__attribute__((target("avx,f16c"), always_inline)) static inline void
pack_lanes_k(const int K, __m256 o[][9], unsigned skip, float inv_scale,
             ub_ahd_packed *const *out)
{
  _Static_assert(sizeof(ub_ahd_packed) == 16, "ub_ahd_packed is 16 bytes");
  const __m256 invs = _mm256_set1_ps(inv_scale), hmax = _mm256_set1_ps(UB_HALF_MAX);
  const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f);
  const __m256 absm = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
  __m128i w[AHD_MAX_K][8];
  static const int col[6] = {0, 1, 2, 6, 7, 8}; /* ambient, directional */
  AHD_FOR_G {
    #pragma GCC unroll 6
    for (int k = 0; k < 6; k++) /* minps: NaN → the second operand, as pack_colour */
      w[g][k] = _mm256_cvtps_ph(_mm256_min_ps(_mm256_mul_ps(o[g][col[k]], invs), hmax),
                                _MM_FROUND_TO_NEAREST_INT);
  }
  __m256 s[AHD_MAX_K], ok[AHD_MAX_K], inv[AHD_MAX_K];
  AHD_FOR_G {
    __m256 ax = _mm256_and_ps(o[g][3], absm), ay = _mm256_and_ps(o[g][4], absm);
    s[g] = _mm256_add_ps(_mm256_add_ps(ax, ay), _mm256_and_ps(o[g][5], absm));
    ok[g] = _mm256_cmp_ps(s[g], zero, _CMP_GT_OQ);
    inv[g] = _mm256_div_ps(one, s[g]);
  }
  AHD_FOR_G {
    __m256 u = _mm256_and_ps(_mm256_mul_ps(o[g][3], inv[g]), ok[g]);
    __m256 v = _mm256_and_ps(_mm256_mul_ps(o[g][4], inv[g]), ok[g]);
    __m256 low = _mm256_cmp_ps(o[g][5], zero, _CMP_LT_OQ);
    const __m256 m1 = _mm256_set1_ps(-1.0f);
    __m256 geu = _mm256_cmp_ps(u, zero, _CMP_GE_OQ), gev = _mm256_cmp_ps(v, zero, _CMP_GE_OQ);
    __m256 su = _mm256_or_ps(_mm256_and_ps(geu, one), _mm256_andnot_ps(geu, m1));
    __m256 sv = _mm256_or_ps(_mm256_and_ps(gev, one), _mm256_andnot_ps(gev, m1));
    __m256 nu = _mm256_mul_ps(_mm256_sub_ps(one, _mm256_and_ps(v, absm)), su);
    __m256 nv = _mm256_mul_ps(_mm256_sub_ps(one, _mm256_and_ps(u, absm)), sv);
    u = _mm256_or_ps(_mm256_and_ps(low, nu), _mm256_andnot_ps(low, u));
    v = _mm256_or_ps(_mm256_and_ps(low, nv), _mm256_andnot_ps(low, v));
    const __m256 k = _mm256_set1_ps(32767.0f);
    __m256i iu = _mm256_cvtps_epi32(_mm256_mul_ps(u, k));
    __m256i iv = _mm256_cvtps_epi32(_mm256_mul_ps(v, k));
    w[g][6] = _mm_packs_epi32(_mm256_castsi256_si128(iu), _mm256_extractf128_si256(iu, 1));
    w[g][7] = _mm_packs_epi32(_mm256_castsi256_si128(iv), _mm256_extractf128_si256(iv, 1));
  }
  AHD_FOR_G {
    if (!(skip & (1u << g)))
      store_words8(w[g], out + 8 * g);
  }
}

/* encode_lanes_k then pack_lanes_k for one group. */
__attribute__((target("avx,f16c"))) static void encode_iz8_packed_avx(const float *const rows[8],
                                                                    const float *nrm,
                                                                    float inv_scale,
                                                                    ub_ahd_packed *const out[8])
{
  __m256 o[1][9];
  if (encode_lanes_k(1, rows, nrm, o)) {
    encode8_packed_scalar(rows, nrm, inv_scale, out);
    return;
  }
  pack_lanes_k(1, o, 0, inv_scale, out);
}

/* The same for two groups side by side (rows, out: 16; nrm: 48 floats). */
__attribute__((target("avx,f16c"))) static void encode_iz16_packed_avx(const float *const rows[16],
                                                                     const float *nrm,
                                                                     float inv_scale,
                                                                     ub_ahd_packed *const out[16])
{
  __m256 o[2][9];
  unsigned bad = encode_lanes_k(2, rows, nrm, o);
  if (bad != 3u)
    pack_lanes_k(2, o, bad, inv_scale, out);
  for (int g = 0; g < 2; g++)
    if (bad & (1u << g))
      encode8_packed_scalar(rows + 8 * g, nrm + 24 * g, inv_scale, out + 8 * g);
}

/* encode_iz16_packed_avx in the sixteen lanes of AVX-512 registers, for sixteen texels
 * stored one after the other (sh: 16 × 12 floats, nrm: 16 × 3, out: 16): the same
 * operations in the same order (IEEE single; no FMA: contraction is off here, as AVX-512
 * brings FMA), the blends as mask moves, so each lane still gives the scalar bits
 * (test_ahd). Half the encode's arithmetic instructions per texel of the AVX pair.
 * Texels come in and go out by AVX-512 permutes of whole registers: the twelve registers
 * of rows become twelve coefficient registers in 48 two-source permutes and unpacks (the
 * 8-lane transposes of the pair took ~100 such lane moves, and with the arithmetic's own
 * 512-bit operations they share the one shuffle port of Intel's cores), the normals in 6
 * and the packed texels go out through a 4 × 4 transpose of 32-bit words. Lane p holds
 * texel ahd_pi(p) = 4·(p mod 4) + p / 4: the order the register transposes give, the same
 * on the way out. */
#if !defined(__clang__) /* GCC fuses the intrinsics' mul + add where FMA is on */
#pragma GCC push_options
#pragma GCC optimize("fp-contract=off")
#endif
/* Permute indices. Rows 4m..4m+3 are registers 3m..3m+2 (48 floats, twelve 128-bit
 * quarters; quarter 3i + s holds coefficients 4s..4s+3 of row i): ahd_row_ix[s] gathers
 * quarter s of the four rows into the four quarters of one register, first from registers
 * 3m and 3m+1, then ([s][1]) the rest from 3m+2. ahd_nrm_ix[k]: component k of the normals
 * in lane order, from the first two of the three normal registers, then from the third. */
static const int32_t ahd_row_ix[3][2][16] __attribute__((aligned(64))) = {
    {{0, 1, 2, 3, 12, 13, 14, 15, 24, 25, 26, 27, 0, 0, 0, 0},
     {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 20, 21, 22, 23}},
    {{4, 5, 6, 7, 16, 17, 18, 19, 28, 29, 30, 31, 0, 0, 0, 0},
     {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 24, 25, 26, 27}},
    {{8, 9, 10, 11, 20, 21, 22, 23, 0, 0, 0, 0, 0, 0, 0, 0},
     {0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 28, 29, 30, 31}}};
static const int32_t ahd_nrm_ix[3][2][16] __attribute__((aligned(64))) = {
    {{0, 12, 24, 0, 3, 15, 27, 0, 6, 18, 30, 0, 9, 21, 0, 0},
     {0, 1, 2, 20, 4, 5, 6, 23, 8, 9, 10, 26, 12, 13, 17, 29}},
    {{1, 13, 25, 0, 4, 16, 28, 0, 7, 19, 31, 0, 10, 22, 0, 0},
     {0, 1, 2, 21, 4, 5, 6, 24, 8, 9, 10, 27, 12, 13, 18, 30}},
    {{2, 14, 26, 0, 5, 17, 29, 0, 8, 20, 0, 0, 11, 23, 0, 0},
     {0, 1, 2, 22, 4, 5, 6, 25, 8, 9, 16, 28, 12, 13, 19, 31}}};
#define AHD_IX(tab) _mm512_load_si512((const void *)(tab))
/* Two 16-bit planes (16 words each) as the 32-bit words lo | hi << 16. */
#define AHD_PAIR(lo, hi)                                                                 \
  _mm512_or_si512(_mm512_cvtepu16_epi32(lo), _mm512_slli_epi32(_mm512_cvtepu16_epi32(hi), 16))
__attribute__((target("avx,f16c,avx512f"))) static void
encode16_packed_avx512(const float *sh, const float *nrm, float inv_scale, ub_ahd_packed *out)
{
#if defined(__clang__)
#pragma clang fp contract(off)
#endif
  __m512 t[12], n0, n1, n2;
  #pragma GCC unroll 4
  for (int m = 0; m < 4; m++) {
    const float *z = sh + 48 * m;
    const __m512 z0 = _mm512_loadu_ps(z), z1 = _mm512_loadu_ps(z + 16),
                 z2 = _mm512_loadu_ps(z + 32);
    #pragma GCC unroll 3
    for (int q = 0; q < 3; q++) /* a[q][m]: quarter q of rows 4m..4m+3 */
      t[4 * q + m] = _mm512_permutex2var_ps(
          _mm512_permutex2var_ps(z0, AHD_IX(ahd_row_ix[q][0]), z1), AHD_IX(ahd_row_ix[q][1]),
          z2);
  }
  #pragma GCC unroll 3
  for (int q = 0; q < 3; q++) { /* 4 × 4 transposes within 128-bit quarters */
    __m512 *a = t + 4 * q;
    __m512 u0 = _mm512_unpacklo_ps(a[0], a[1]), u1 = _mm512_unpackhi_ps(a[0], a[1]);
    __m512 u2 = _mm512_unpacklo_ps(a[2], a[3]), u3 = _mm512_unpackhi_ps(a[2], a[3]);
    a[0] = _mm512_shuffle_ps(u0, u2, 0x44);
    a[1] = _mm512_shuffle_ps(u0, u2, 0xEE);
    a[2] = _mm512_shuffle_ps(u1, u3, 0x44);
    a[3] = _mm512_shuffle_ps(u1, u3, 0xEE);
  }
  {
    const __m512 m0 = _mm512_loadu_ps(nrm), m1 = _mm512_loadu_ps(nrm + 16),
                 m2 = _mm512_loadu_ps(nrm + 32);
    __m512 nn[3];
    #pragma GCC unroll 3
    for (int k = 0; k < 3; k++)
      nn[k] = _mm512_permutex2var_ps(
          _mm512_permutex2var_ps(m0, AHD_IX(ahd_nrm_ix[k][0]), m1), AHD_IX(ahd_nrm_ix[k][1]),
          m2);
    n0 = nn[0];
    n1 = nn[1];
    n2 = nn[2];
  }
  const __m512 zero = _mm512_setzero_ps();
  { /* the finite check of encode_lanes_k: any group with a bad lane goes the AVX way */
    __m512 sm[6];
    #pragma GCC unroll 12
    for (int j = 0; j < 6; j++)
      sm[j] = _mm512_add_ps(t[2 * j], t[2 * j + 1]);
    __m512 all = _mm512_add_ps(_mm512_add_ps(_mm512_add_ps(sm[0], sm[1]),
                                             _mm512_add_ps(sm[2], sm[3])),
                               _mm512_add_ps(sm[4], sm[5]));
    all = _mm512_mul_ps(all, zero);
    if (_mm512_cmp_ps_mask(all, all, _CMP_UNORD_Q)) {
      const float *rows[16];
      ub_ahd_packed *po[16];
      for (int j = 0; j < 16; j++) {
        rows[j] = sh + 12 * j;
        po[j] = out + j;
      }
      encode_iz16_packed_avx(rows, nrm, inv_scale, po);
      return;
    }
  }
#define AHD_DOT(a0, a1, a2, b0, b1, b2)                                                  \
  _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(a0, b0), _mm512_mul_ps(a1, b1)),            \
                _mm512_mul_ps(a2, b2))
  const __m512 kb = _mm512_set1_ps((2.0f * UB_PI / 3.0f) * UB_SH_Y1);
  __m512 b[3][3], iz[3], a[3], al = zero, bl[3] = {zero, zero, zero};
  #pragma GCC unroll 12
  for (int c = 0; c < 3; c++) {
    b[c][0] = _mm512_mul_ps(kb, t[9 + c]);
    b[c][1] = _mm512_mul_ps(kb, t[3 + c]);
    b[c][2] = _mm512_mul_ps(kb, t[6 + c]);
    iz[c] = t[c];
    a[c] = _mm512_sub_ps(iz[c], AHD_DOT(b[c][0], b[c][1], b[c][2], n0, n1, n2));
  }
  #pragma GCC unroll 12
  for (int c = 0; c < 3; c++) {
    __m512 k = _mm512_set1_ps(k_lum[c]);
    al = _mm512_add_ps(al, _mm512_mul_ps(k, _mm512_abs_ps(a[c])));
    #pragma GCC unroll 12
    for (int i = 0; i < 3; i++)
      bl[i] = _mm512_add_ps(bl[i], _mm512_mul_ps(k, b[c][i]));
  }
  __m512 blen = _mm512_sqrt_ps(AHD_DOT(bl[0], bl[1], bl[2], bl[0], bl[1], bl[2]));
  __mmask16 use_b =
      _mm512_cmp_ps_mask(blen, _mm512_mul_ps(_mm512_set1_ps(UB_AHD_DIR_REL_EPS), al),
                         _CMP_GT_OQ) &
      _mm512_cmp_ps_mask(blen, _mm512_set1_ps(1e-30f), _CMP_GT_OQ);
  __m512 inv_blen = _mm512_div_ps(_mm512_set1_ps(1.0f), blen);
  __m512 d0 = _mm512_mask_mov_ps(n0, use_b, _mm512_mul_ps(bl[0], inv_blen));
  __m512 d1 = _mm512_mask_mov_ps(n1, use_b, _mm512_mul_ps(bl[1], inv_blen));
  __m512 d2 = _mm512_mask_mov_ps(n2, use_b, _mm512_mul_ps(bl[2], inv_blen));
  __m512 dz = AHD_DOT(d0, d1, d2, n0, n1, n2);
  __mmask16 dir = _mm512_cmp_ps_mask(dz, _mm512_set1_ps(UB_AHD_DZ_GUARD), _CMP_GT_OQ);
  d0 = _mm512_mask_mov_ps(n0, dir, d0);
  d1 = _mm512_mask_mov_ps(n1, dir, d1);
  d2 = _mm512_mask_mov_ps(n2, dir, d2);
  const __m512 one = _mm512_set1_ps(1.0f), sixth = _mm512_set1_ps(1.0f / 6.0f);
  __m512 den = _mm512_add_ps(_mm512_sub_ps(sixth, _mm512_mul_ps(_mm512_set1_ps(0.5f), dz)),
                             _mm512_mul_ps(dz, dz));
  __m512 inv_den = _mm512_maskz_mov_ps(dir, _mm512_div_ps(one, den));
  __m512 inv_dz = _mm512_maskz_mov_ps(dir, _mm512_div_ps(one, dz));
  __m512 q = _mm512_sub_ps(_mm512_set1_ps(0.25f), dz);
  __m512 o[9]; /* ambient, direction, directional in lanes */
  o[3] = d0;
  o[4] = d1;
  o[5] = d2;
  #pragma GCC unroll 12
  for (int c = 0; c < 3; c++) { /* max(x, 0) / max(0, x): maxps's operand rule as AVX */
    __m512 z = _mm512_max_ps(iz[c], zero);
    __m512 beta = AHD_DOT(b[c][0], b[c][1], b[c][2], d0, d1, d2);
    __m512 bn = AHD_DOT(b[c][0], b[c][1], b[c][2], n0, n1, n2);
    __m512 cd0 = _mm512_mul_ps(
        _mm512_sub_ps(_mm512_mul_ps(beta, sixth), _mm512_mul_ps(bn, q)), inv_den);
    cd0 = _mm512_max_ps(cd0, zero);
    __m512 ca = _mm512_max_ps(zero, _mm512_sub_ps(z, _mm512_mul_ps(cd0, dz)));
    __m512 cd = _mm512_max_ps(_mm512_mul_ps(_mm512_sub_ps(z, ca), inv_dz), zero);
    o[c] = _mm512_mask_mov_ps(z, dir, ca);
    o[6 + c] = _mm512_maskz_mov_ps(dir, cd);
  }
#undef AHD_DOT
  /* pack_lanes_k's arithmetic on sixteen lanes */
  const __m512 invs = _mm512_set1_ps(inv_scale), hmax = _mm512_set1_ps(UB_HALF_MAX);
  __m256i h[6];
  static const int col[6] = {0, 1, 2, 6, 7, 8}; /* ambient, directional */
  #pragma GCC unroll 12
  for (int k = 0; k < 6; k++)
    h[k] = _mm512_cvtps_ph(_mm512_min_ps(_mm512_mul_ps(o[col[k]], invs), hmax),
                           _MM_FROUND_TO_NEAREST_INT);
  __m512 sa = _mm512_add_ps(_mm512_add_ps(_mm512_abs_ps(o[3]), _mm512_abs_ps(o[4])),
                            _mm512_abs_ps(o[5]));
  __mmask16 ok = _mm512_cmp_ps_mask(sa, zero, _CMP_GT_OQ);
  __m512 inv = _mm512_div_ps(one, sa);
  __m512 u = _mm512_maskz_mov_ps(ok, _mm512_mul_ps(o[3], inv));
  __m512 v = _mm512_maskz_mov_ps(ok, _mm512_mul_ps(o[4], inv));
  __mmask16 low = _mm512_cmp_ps_mask(o[5], zero, _CMP_LT_OQ);
  const __m512 m1 = _mm512_set1_ps(-1.0f);
  __m512 su = _mm512_mask_mov_ps(m1, _mm512_cmp_ps_mask(u, zero, _CMP_GE_OQ), one);
  __m512 sv = _mm512_mask_mov_ps(m1, _mm512_cmp_ps_mask(v, zero, _CMP_GE_OQ), one);
  __m512 nu = _mm512_mul_ps(_mm512_sub_ps(one, _mm512_abs_ps(v)), su);
  __m512 nv = _mm512_mul_ps(_mm512_sub_ps(one, _mm512_abs_ps(u)), sv);
  u = _mm512_mask_mov_ps(u, low, nu);
  v = _mm512_mask_mov_ps(v, low, nv);
  const __m512 k16 = _mm512_set1_ps(32767.0f);
  /* snorm16 as pack_direction's saturating conversion, in 32-bit lanes */
  const __m512i smin = _mm512_set1_epi32(-32768), smax = _mm512_set1_epi32(32767);
  __m512i iu = _mm512_min_epi32(_mm512_max_epi32(_mm512_cvtps_epi32(_mm512_mul_ps(u, k16)), smin), smax);
  __m512i iv = _mm512_min_epi32(_mm512_max_epi32(_mm512_cvtps_epi32(_mm512_mul_ps(v, k16)), smin), smax);
  /* the texels' four 32-bit words in lanes, then a 4 × 4 transpose within each quarter:
   * register m holds texels 4m..4m+3 (ahd_pi) */
  __m512i w0 = AHD_PAIR(h[0], h[1]), w1 = AHD_PAIR(h[2], h[3]), w2 = AHD_PAIR(h[4], h[5]);
  __m512i w3 = _mm512_or_si512(_mm512_and_si512(iu, _mm512_set1_epi32(0xffff)),
                               _mm512_slli_epi32(iv, 16));
  __m512i e0 = _mm512_unpacklo_epi32(w0, w1), e1 = _mm512_unpackhi_epi32(w0, w1);
  __m512i e2 = _mm512_unpacklo_epi32(w2, w3), e3 = _mm512_unpackhi_epi32(w2, w3);
  _mm512_storeu_si512((void *)out, _mm512_unpacklo_epi64(e0, e2));
  _mm512_storeu_si512((void *)(out + 4), _mm512_unpackhi_epi64(e0, e2));
  _mm512_storeu_si512((void *)(out + 8), _mm512_unpacklo_epi64(e1, e3));
  _mm512_storeu_si512((void *)(out + 12), _mm512_unpackhi_epi64(e1, e3));
}
#undef AHD_IX
#undef AHD_PAIR
#if !defined(__clang__)
#pragma GCC pop_options
#endif
#endif

void ub_ahd_encode_iz8_rows(const float *const rows[8], const float *unit_normals,
                            ub_ahd *const out[8])
{
#if defined(AHD_HAVE_AVX)
  if (ub_cpu_features_cached() & UB_CPU_AVX) {
    encode_iz8_avx(rows, unit_normals, out);
    return;
  }
#endif
  for (int j = 0; j < 8; j++)
    ub_ahd_encode_iz(rows[j], unit_normals + 3 * j, out[j]);
}

void ub_ahd_encode_iz8(const float *sh_iz, const float *unit_normals, ub_ahd *out_ahd)
{
  const float *rows[8];
  ub_ahd *out[8];
  for (int j = 0; j < 8; j++) {
    rows[j] = sh_iz + 12 * j;
    out[j] = out_ahd + j;
  }
  ub_ahd_encode_iz8_rows(rows, unit_normals, out);
}

void ub_ahd_irradiance(const ub_ahd *ahd, const float n[3], float out_rgb[3])
{
  float u[3];
  safe_unit(n, u);
  float t = ahd->direction[0] * u[0] + ahd->direction[1] * u[1] + ahd->direction[2] * u[2];
  if (!(t > 0.0f))
    t = 0.0f;
  for (int c = 0; c < 3; c++) {
    float e = ahd->ambient[c] + ahd->directional[c] * t;
    out_rgb[c] = e > 0.0f ? e : 0.0f;
  }
}

void ub_ahd_encode_iz8_rows_packed(const float *const rows[8], const float *unit_normals,
                                   float inv_scale, ub_ahd_packed *const out[8])
{
#if defined(AHD_HAVE_AVX)
  const unsigned need = UB_CPU_AVX | UB_CPU_F16C;
  if ((ub_cpu_features_cached() & need) == need) {
    encode_iz8_packed_avx(rows, unit_normals, inv_scale, out);
    return;
  }
#endif
  encode8_packed_scalar(rows, unit_normals, inv_scale, out);
}

void ub_ahd_encode_iz8_packed(const float *sh_iz, const float *unit_normals, float inv_scale,
                              ub_ahd_packed *out_packed)
{
  const float *rows[8];
  ub_ahd_packed *out[8];
  for (int j = 0; j < 8; j++) {
    rows[j] = sh_iz + 12 * j;
    out[j] = out_packed + j;
  }
  ub_ahd_encode_iz8_rows_packed(rows, unit_normals, inv_scale, out);
}

void ub_ahd_encode_iz_packed_n(const float *sh_iz, const float *unit_normals, float inv_scale,
                               ub_ahd_packed *out_packed, size_t count)
{
  size_t i = 0;
#if defined(AHD_HAVE_AVX)
  const unsigned need = UB_CPU_AVX | UB_CPU_F16C, f = ub_cpu_features_cached();
  if ((f & need) == need)
    for (; i + 16 <= count; i += 16) {
      if (f & UB_CPU_AVX512) {
        encode16_packed_avx512(sh_iz + 12 * i, unit_normals + 3 * i, inv_scale,
                               out_packed + i);
        continue;
      }
      const float *rows[16];
      ub_ahd_packed *out[16];
      for (int j = 0; j < 16; j++) {
        rows[j] = sh_iz + 12 * (i + j);
        out[j] = out_packed + i + j;
      }
      encode_iz16_packed_avx(rows, unit_normals + 3 * i, inv_scale, out);
    }
#endif
  for (; i + 8 <= count; i += 8)
    ub_ahd_encode_iz8_packed(sh_iz + 12 * i, unit_normals + 3 * i, inv_scale, out_packed + i);
  for (; i < count; i++)
    encode_packed(sh_iz + 12 * i, unit_normals + 3 * i, inv_scale, out_packed + i);
}
