/* runtime/fpmode.h — the run-time's updates compute with FTZ and DAZ off (restored after),
 * so the half decodes are exact and no result depends on the caller's floating-point
 * mode (a game thread, or a job system's worker, may run with them set). MXCSR is per
 * thread: every thread doing update work enters the mode itself. Nesting is harmless
 * (an inner enter finds the bits clear and its leave changes nothing).
 */
#ifndef UBAKE_RUNTIME_FPMODE_H
#define UBAKE_RUNTIME_FPMODE_H

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

static inline unsigned ub_fp_mode_enter(void)
{
#if defined(__SSE2__)
  unsigned csr = _mm_getcsr();
  if (csr & 0x8040u)
    _mm_setcsr(csr & ~0x8040u);
  return csr;
#else
  return 0;
#endif
}

static inline void ub_fp_mode_leave(unsigned csr)
{
#if defined(__SSE2__)
  if (csr & 0x8040u)
    _mm_setcsr(csr);
#else
  (void)csr;
#endif
}

#endif
