// The number of floats in one vector register of the build's target, for the kernels' GCC vector
// extensions: 16 with AVX-512, 8 elsewhere.  Vectors wider than a register are not free: without
// AVX-512, GCC compiles the comparisons and selects of 64-byte vectors lane by lane, a branch per lane
// (Zen 3 AVX2, 2 threads: the 1-MP training step 1093.6 ms with 16-lane vectors in the rasterizer,
// projection and SSIM, 197.5 ms with one register's width; docs/training_step.md, "The build for
// processors without AVX-512").  The lane count changes no result.
#pragma once

#if defined(__AVX512F__)
#define STEALTH_NS_FLOAT_LANES 16
#else
#define STEALTH_NS_FLOAT_LANES 8
#endif
