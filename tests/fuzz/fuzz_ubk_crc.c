/* tests/fuzz/fuzz_ubk_crc.c — libFuzzer target for the .ubk reader past its checksums.
 * fuzz_ubk feeds raw mutations, which the per-section CRC-32s reject before any parsing
 * (its coverage stalls at the header checks). This target first rewrites every section
 * CRC whose payload lies inside the input, then the header CRC (docs/FORMAT.md), so the
 * mutations reach the section parsers and the validation after them.
 * Seeds: tests/fuzz/corpus-fuzz_ubk_crc (copies of the fuzz_ubk seeds). */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "runtime/crc32.h"
#include "ubake/bakefile.h"

static uint32_t rd32(const uint8_t *p)
{
  return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static uint64_t rd64(const uint8_t *p)
{
  return (uint64_t)rd32(p) | (uint64_t)rd32(p + 4) << 32;
}
static void wr32(uint8_t *p, uint32_t v)
{
  for (int i = 0; i < 4; i++)
    p[i] = (uint8_t)(v >> (8 * i));
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
  uint8_t *buf = malloc(size ? size : 1);
  if (!buf)
    return 0;
  memcpy(buf, data, size);
  if (size >= 16) {
    uint64_t n = rd32(buf + 8);
    if (n <= (size - 16) / 32) {
      for (uint64_t i = 0; i < n; i++) {
        uint8_t *e = buf + 16 + 32 * i;
        uint64_t off = rd64(e + 8), len = rd64(e + 16);
        if (off <= size && len <= size - off)
          wr32(e + 24, ub_crc32_update(0, buf + off, (size_t)len));
      }
      uint32_t crc = ub_crc32_update(0, buf, 12);
      crc = ub_crc32_update(crc, buf + 16, (size_t)(32 * n));
      wr32(buf + 12, crc);
    }
  }
  ub_bakefile *bf = NULL;
  if (ub_bakefile_read_memory(buf, size, "fuzz.ubk", NULL, &bf) == UB_OK)
    ub_bakefile_free(bf);
  free(buf);
  return 0;
}
