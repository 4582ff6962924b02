// How many cameras see each 3D point, on the CPU (see visibility_cpu.cpp).
#pragma once

#include <ATen/core/Tensor.h>

#include <vector>

namespace stealth_ns {

// int32 [P]: for each of the points [P, 3], the cameras (viewmats [J, 4, 4], Ks [J, 3, 3], J depth-bound
// maps [H_j, W_j]) that see it
at::Tensor count_seeing(const at::Tensor &points, const at::Tensor &viewmats, const at::Tensor &Ks,
                        const std::vector<at::Tensor> &bounds, double near_plane);

}  // namespace stealth_ns
