/* runtime/crc32.h — CRC-32 (IEEE 802.3 / zlib / PNG: reflected polynomial 0xEDB88320,
 * initial value and final XOR 0xFFFFFFFF), used by the .ubk format (docs/FORMAT.md).
 *
 * Incremental: crc = ub_crc32_update(0, a, na); crc = ub_crc32_update(crc, b, nb); gives
 * the CRC of a followed by b. ub_crc32_update(0, "123456789", 9) == 0xCBF43926.
 * Pure functions; thread safe.
 */
#ifndef UBAKE_RUNTIME_CRC32_H
#define UBAKE_RUNTIME_CRC32_H

#include <stddef.h>
#include <stdint.h>

uint32_t ub_crc32_update(uint32_t crc, const void *data, size_t size);

#endif
