// Densification statistics of one training step on the CPU (see densify_cpu.cpp).
#pragma once

#include <ATen/core/Tensor.h>

namespace stealth_ns {

// Adds one step's statistics in place, for every camera c that sees Gaussian n (radii[c, n] > 0):
// grad2d[n] += |grads[c, n] * (scale_x, scale_y)|, count[n] += 1, and, when max_radii is given,
// max_radii[n] = max(max_radii[n] before this call, radii[c, n] / size) (the last such camera's value).
void densify_stats(at::Tensor &grad2d, at::Tensor &count, const std::optional<at::Tensor> &max_radii,
                   const at::Tensor &grads, const at::Tensor &radii, double scale_x, double scale_y,
                   double size);

}  // namespace stealth_ns
