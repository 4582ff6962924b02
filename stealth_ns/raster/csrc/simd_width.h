// The number of floats in one vector register of the build's target, for the kernels' GCC vector
// extensions: 16 with AVX-512, 8 with AVX2, 4 elsewhere (SSE, NEON).  Vectors wider than a register are
// not free: GCC compiles their comparisons and selects lane by lane, a scalar compare per lane
// (timings: docs/cpu_rasterizer.md; docs/training_step.md, "The build for processors without
// AVX-512" and "aarch64 and other processors with 4-float registers").  The lane count changes no
// result (tests/test_portable_build.py).
#pragma once

#if defined(__AVX512F__)
#define STEALTH_NS_FLOAT_LANES 16
#elif defined(__AVX2__)
#define STEALTH_NS_FLOAT_LANES 8
#else
#define STEALTH_NS_FLOAT_LANES 4  // 16-byte registers: SSE, NEON (aarch64), and the rest
#endif
