// The kernels in the AVX2 tiling: this unit is built without AVX-512 (tests/CMakeLists.txt), so a
// machine with AVX-512 checks the tiling that machines without it run. There it repeats the unit
// above.
#define SMALL_LAYER_SUITE SmallLayerAvx2
#include "nerf/small_layer_cases.h"
