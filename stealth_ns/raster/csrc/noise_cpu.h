// Counter-based standard normal deviates (SplitMix64 + Box-Muller) and the attack's noisy uint8 image,
// on the CPU (see noise_cpu.cpp).
#pragma once

#include <ATen/core/Tensor.h>

namespace stealth_ns {

// [count] float32 standard normal deviates of stream `key` (element i depends on key and i alone)
at::Tensor normal_draw(int64_t count, int64_t key);

// clamp(round_half_even(image + float(sigma) * normal_draw(image.numel(), key)), 0, 255) as uint8
at::Tensor noisy_u8(const at::Tensor &image, double sigma, int64_t key);

}  // namespace stealth_ns
