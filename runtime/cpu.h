/* runtime/cpu.h — which SIMD paths this CPU and OS allow, from CPUID: AVX (with the OS
 * saving the ymm registers: OSXSAVE and XCR0 bits 1–2), F16C, AVX2 and AVX-512F (with the
 * OS saving the opmask and zmm registers, XCR0 bits 5–7). One test for every run-time
 * kernel that picks a path at run time (blend.c's half decode, glg.c's queries,
 * lightmaps/ahd.c's 8- and 16-lane encoders); clang's __builtin_cpu_supports knows no
 * "f16c". The environment variable UB_NO_AVX512 (set, not "0") hides AVX-512: the
 * encoder then takes its AVX path (A/B runs, test_ahd_avx; a CPU that clocks down under
 * zmm work). Cheap but not free (CPUID traps in some VMs): callers cache the answer.
 */
#ifndef UBAKE_RUNTIME_CPU_H
#define UBAKE_RUNTIME_CPU_H

#include <stdatomic.h>
#include <string.h>

#define UB_CPU_AVX 1u
#define UB_CPU_F16C 2u /* only with UB_CPU_AVX (the conversions use ymm registers) */
#define UB_CPU_AVX2 4u /* only with UB_CPU_AVX */
#define UB_CPU_AVX512 8u /* AVX-512F, only with UB_CPU_AVX */

#if defined(__x86_64__) && defined(__GNUC__)
#include <cpuid.h>
#include <stdlib.h>

static inline unsigned ub_cpu_features(void)
{
  unsigned a, b, c, d;
  if (!__get_cpuid(1, &a, &b, &c, &d))
    return 0;
  const unsigned need = (1u << 27) | (1u << 28); /* OSXSAVE, AVX */
  if ((c & need) != need)
    return 0;
  unsigned lo, hi;
  __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));
  (void)hi;
  if ((lo & 6u) != 6u)
    return 0; /* the OS does not save xmm and ymm */
  unsigned f = UB_CPU_AVX | ((c >> 29 & 1u) ? UB_CPU_F16C : 0u);
  if (__get_cpuid_max(0, NULL) >= 7) {
    __cpuid_count(7, 0, a, b, c, d);
    f |= (b >> 5 & 1u) ? UB_CPU_AVX2 : 0u;
    const char *no = getenv("UB_NO_AVX512");
    if ((b >> 16 & 1u) && (lo & 0xe6u) == 0xe6u && !(no && *no && strcmp(no, "0") != 0))
      f |= UB_CPU_AVX512;
  }
  return f;
}
#else
static inline unsigned ub_cpu_features(void)
{
  return 0;
}
#endif

/* ub_cpu_features(), asked once per translation unit and kept (atomic: any thread may be
 * first; they all find the same answer). For hot paths that cannot cache it in an object
 * made beforehand (the AHD encoder, the bake file reader). */
static inline unsigned ub_cpu_features_cached(void)
{
  static _Atomic unsigned cached = ~0u;
  unsigned f = atomic_load_explicit(&cached, memory_order_relaxed);
  if (f == ~0u) {
    f = ub_cpu_features();
    atomic_store_explicit(&cached, f, memory_order_relaxed);
  }
  return f;
}

#endif
