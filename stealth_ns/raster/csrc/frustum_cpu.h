// How close each point comes to a camera that has it in view, on the CPU (see frustum_cpu.cpp).
#pragma once

#include <ATen/core/Tensor.h>

namespace stealth_ns {

// float64 [P]: for each of the points [P, 3] (float64), the smallest z / depths[v] over the cameras v
// (viewmats [V, 4, 4], Ks [V, 3, 3], sizes [V, 2] width and height, depths [V], all float64) that have
// it in front (z > 0) and inside the image; +inf where none has; 0 for a non-finite point
at::Tensor frustum_depth_ratios(const at::Tensor &points, const at::Tensor &viewmats, const at::Tensor &Ks,
                                const at::Tensor &sizes, const at::Tensor &depths);

}  // namespace stealth_ns
