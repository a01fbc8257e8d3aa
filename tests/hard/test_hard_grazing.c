/* Hard case: a directional light grazing a plane at 89.9° from its normal (level
 * grazing, see grazing_case.h): E = I·cos(89.9°) within 1% + 1e-4 W/m², no NaN, nothing
 * clamped. Azimuth 30° crosses the quads' edges obliquely, azimuth 0° runs along them. */
#include "grazing_case.h"

int main(void)
{
  hard_init("grazing");
  grazing_case(89.9, 30.0, 1000.0);
  grazing_case(89.9, 0.0, 1000.0);
  TEST_MAIN_END();
}
