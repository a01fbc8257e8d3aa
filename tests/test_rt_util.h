/* tests/test_rt_util.h — run-time helpers shared by tests (after test_util.h). */
#ifndef UBAKE_TEST_RT_UTIL_H
#define UBAKE_TEST_RT_UTIL_H

#include <stdlib.h>
#include <string.h>

#include "ubake/ahd.h"
#include "ubake/bakefile.h"
#include "ubake/runtime.h"

/* The pixels of atlases [0, atlas_end), one after the other (atlas_end = atlas_count: all). */
static inline size_t atlas_pixels(const ub_bakefile *bf, uint32_t atlas_end)
{
  size_t n = 0;
  for (uint32_t a = 0; a < atlas_end && a < bf->atlas_count; a++)
    n += (size_t)bf->atlases[a].width * bf->atlases[a].height;
  return n;
}

/* Every atlas's packed AHD, one after the other (ub_runtime_atlas_ahd). */
static ub_ahd_packed *ahd_snapshot(const ub_runtime *rt, const ub_bakefile *bf)
{
  const size_t n = atlas_pixels(bf, bf->atlas_count);
  ub_ahd_packed *s = malloc((n ? n : 1) * sizeof *s);
  ASSERT_TRUE(s != NULL);
  for (uint32_t a = 0; a < bf->atlas_count; a++)
    ASSERT_OK(ub_runtime_atlas_ahd(rt, a, s + atlas_pixels(bf, a)));
  return s;
}

/* 1 when a and b hold the same packed AHD in every atlas (bf: a's file; b's has the same
 * atlases), bit for bit. */
static inline int same_atlases(const ub_runtime *a, const ub_runtime *b, const ub_bakefile *bf)
{
  const size_t n = atlas_pixels(bf, bf->atlas_count);
  ub_ahd_packed *sa = ahd_snapshot(a, bf), *sb = ahd_snapshot(b, bf);
  const int same = sa && sb && memcmp(sa, sb, n * sizeof *sa) == 0;
  free(sa);
  free(sb);
  return same;
}

#endif
