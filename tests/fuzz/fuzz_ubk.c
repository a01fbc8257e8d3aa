/* tests/fuzz/fuzz_ubk.c — libFuzzer target for the .ubk reader (ub_bakefile_read_memory).
 * Seeds: tests/fuzz/corpus-fuzz_ubk (written by test_bakefile with UB_WRITE_FUZZ_CORPUS).
 * Any input must be accepted or rejected without a crash, a leak, undefined behaviour or a
 * huge allocation (run with the default -malloc_limit_mb / -rss_limit_mb). */
#include <stddef.h>
#include <stdint.h>

#include "ubake/bakefile.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
  ub_bakefile *bf = NULL;
  if (ub_bakefile_read_memory(data, size, "fuzz.ubk", NULL, &bf) == UB_OK)
    ub_bakefile_free(bf);
  return 0;
}
