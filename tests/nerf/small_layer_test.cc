// The kernels in the target's tiling (AVX-512 where the target has it, AVX2 otherwise).
#define SMALL_LAYER_SUITE SmallLayer
#include "nerf/small_layer_cases.h"
