/* runtime/half.h — IEEE 754 binary16 ("half") <-> binary32 conversion for the .ubk format.
 *
 * ub_half_from_float rounds to nearest, ties to even, exactly as IEEE 754 requires:
 * overflow (|x| >= 65520) gives ±Inf, values below the smallest subnormal half (2^-24)
 * round to a subnormal or ±0, NaN stays NaN (quiet, sign kept). ub_half_to_float is exact.
 * Relative precision of a normal half: 2^-11 (11 significant bits); absolute precision
 * of a subnormal: 2^-25. Bit operations only: independent of the FPU rounding mode and
 * of FTZ/DAZ. Pure functions; thread safe.
 */
#ifndef UBAKE_RUNTIME_HALF_H
#define UBAKE_RUNTIME_HALF_H

#include <stdint.h>
#include <string.h>

#define UB_HALF_MAX 65504.0f

static inline uint16_t ub_half_from_float(float f)
{
  uint32_t x;
  memcpy(&x, &f, sizeof x);
  uint16_t sign = (uint16_t)((x >> 16) & 0x8000u);
  uint32_t ax = x & 0x7fffffffu;

  if (ax > 0x7f800000u) /* NaN: quiet, keep the top payload bits */
    return (uint16_t)(sign | 0x7e00u | ((ax >> 13) & 0x3ffu));
  if (ax >= 0x477ff000u) /* >= 65520 = half-way between 65504 and 2^16: rounds to Inf */
    return (uint16_t)(sign | 0x7c00u);
  if (ax < 0x38800000u) { /* below 2^-14: half subnormal (or zero) */
    if (ax <= 0x33000000u) /* <= 2^-25: rounds to zero (2^-25 ties to even = 0) */
      return sign;
    uint32_t e = ax >> 23;                      /* 102 .. 112 */
    uint32_t m = (ax & 0x7fffffu) | 0x800000u;  /* value = m · 2^(e-150) */
    uint32_t shift = 126u - e;                  /* half units of 2^-24: m >> shift */
    uint32_t q = m >> shift;
    uint32_t rem = m & ((1u << shift) - 1u);
    uint32_t halfway = 1u << (shift - 1u);
    if (rem > halfway || (rem == halfway && (q & 1u)))
      q++; /* may carry into the smallest normal 0x0400: still the right encoding */
    return (uint16_t)(sign | q);
  }
  /* Normal: rebias the exponent (127 -> 15) and round the 13 dropped mantissa bits. A
   * carry out of the mantissa correctly bumps the exponent. */
  uint32_t h = (ax - 0x38000000u) >> 13;
  uint32_t rem = ax & 0x1fffu;
  if (rem > 0x1000u || (rem == 0x1000u && (h & 1u)))
    h++;
  return (uint16_t)(sign | h);
}

static inline float ub_half_to_float(uint16_t h)
{
  uint32_t sign = (uint32_t)(h & 0x8000u) << 16;
  uint32_t e = (h >> 10) & 0x1fu;
  uint32_t m = h & 0x3ffu;
  uint32_t x;
  if (e == 0) {
    /* zero or subnormal: m · 2^-24, exact in binary32 */
    float f = (float)m * 5.9604644775390625e-8f;
    memcpy(&x, &f, sizeof x);
    x |= sign;
  } else if (e == 31) {
    x = sign | 0x7f800000u | (m << 13);
  } else {
    x = sign | ((e + 112u) << 23) | (m << 13);
  }
  float out;
  memcpy(&out, &x, sizeof out);
  return out;
}

/* Non-zero for a finite half (not Inf, not NaN). */
static inline int ub_half_is_finite(uint16_t h)
{
  return (h & 0x7c00u) != 0x7c00u;
}

#endif
