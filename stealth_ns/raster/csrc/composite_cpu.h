// A rendered image composited onto its background and clamped to [0, 1], and the gradient of that, on
// the CPU (see composite_cpu.cpp).
#pragma once

#include <ATen/core/Tensor.h>

#include <vector>

namespace stealth_ns {

// clamp(render + (1 - alpha) * background, 0, 1): render [..., D], alpha [..., 1], background [D]
at::Tensor composite_fwd(const at::Tensor &render, const at::Tensor &alpha, const at::Tensor &background);

// (v_render [..., D], v_alpha [..., 1]) from the upstream gradient v_rgb [..., D]
std::vector<at::Tensor> composite_bwd(const at::Tensor &render, const at::Tensor &alpha,
                                      const at::Tensor &background, const at::Tensor &v_rgb);

}  // namespace stealth_ns
