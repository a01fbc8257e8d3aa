/* tests/test_rt_util.h — run-time helpers shared by tests (after test_util.h). */
#ifndef UBAKE_TEST_RT_UTIL_H
#define UBAKE_TEST_RT_UTIL_H

#include <stdlib.h>

#include "ubake/ahd.h"
#include "ubake/bakefile.h"
#include "ubake/runtime.h"

/* Every atlas's packed AHD, one after the other (ub_runtime_atlas_ahd). */
static ub_ahd_packed *ahd_snapshot(const ub_runtime *rt, const ub_bakefile *bf)
{
  size_t n = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++)
    n += (size_t)bf->atlases[a].width * bf->atlases[a].height;
  ub_ahd_packed *s = malloc((n ? n : 1) * sizeof *s);
  ASSERT_TRUE(s != NULL);
  n = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    ASSERT_OK(ub_runtime_atlas_ahd(rt, a, s + n));
    n += (size_t)bf->atlases[a].width * bf->atlases[a].height;
  }
  return s;
}

#endif
