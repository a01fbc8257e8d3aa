/* runtime/bigalloc.h — large allocations on transparent huge pages where the system gives
 * them on request (Linux THP in "madvise" mode, Debian's default): one page fault per
 * 2 MiB instead of one per 4 KiB. `ubake info --memory` on the full ESTATE file faulted
 * ~580k pages, 3.8 s of system time of its 9.2 s, and the run-time's load took 6.3 s on
 * the AMD EPYC VM (2026-12-05); with these allocations 3.3-3.7 s (~190k faults), as
 * with THP for every allocation ("always").
 *
 * ub_big_alloc(n): malloc(n), but from n >= UB_BIG_ALLOC_MIN aligned to 2 MiB and
 * advised MADV_HUGEPAGE; ub_big_calloc(count, size): the same, zeroed, NULL when the
 * product overflows. Both are freed with free() and may be realloc'ed (losing the
 * advice). Where MADV_HUGEPAGE is unknown they are malloc and calloc.
 */
#ifndef UBAKE_RUNTIME_BIGALLOC_H
#define UBAKE_RUNTIME_BIGALLOC_H

#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#if defined(__linux__)
#include <sys/mman.h>
#endif

#define UB_BIG_ALLOC_MIN ((size_t)4 << 20)
#define UB_BIG_PAGE ((size_t)2 << 20)

static inline void *ub_big_alloc(size_t n)
{
#if defined(MADV_HUGEPAGE)
  if (n >= UB_BIG_ALLOC_MIN) {
    void *p = NULL;
    if (posix_memalign(&p, UB_BIG_PAGE, n))
      return NULL;
    madvise(p, n & ~(UB_BIG_PAGE - 1), MADV_HUGEPAGE); /* (advice: its failure is harmless) */
    return p;
  }
#endif
  return malloc(n ? n : 1);
}

static inline void *ub_big_calloc(size_t count, size_t size)
{
  if (size && count > SIZE_MAX / size)
    return NULL;
  const size_t n = count * size;
#if defined(MADV_HUGEPAGE)
  if (n >= UB_BIG_ALLOC_MIN) {
    void *p = ub_big_alloc(n);
    if (p)
      memset(p, 0, n);
    return p;
  }
#endif
  return calloc(count ? count : 1, size ? size : 1);
}

#endif
