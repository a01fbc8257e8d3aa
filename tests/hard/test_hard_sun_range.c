/* Hard case: a photometric sun. DESIGN §3 treats lux as W/m², so a clear-sky sun is
 * ~1e5 W/m². Level grazing with angle = 0 (black plane, sun along the normal) and
 * sun = 1e5 and 1.2e5 W/m²: E = sun on every texel. Asserted: every texel and query within
 * 1% of the closed form after the round trip through the .ubk, finite, never above it.
 *
 * KNOWN FAILURE (runtime/bakefile.c, tests/hard/README.md bug 7): the .ubk stores texel
 * values as half floats clamped to ±65504 (the writer warns "half value(s) beyond the half
 * range clamped"), so a 1e5 W/m² sunlit texel reads back as 65504 (−34%). */
#include "grazing_case.h"

int main(void)
{
  hard_init("sun_range");
  grazing_case(0.0, 0.0, 1e5);
  grazing_case(0.0, 0.0, 1.2e5);
  TEST_MAIN_END();
}
