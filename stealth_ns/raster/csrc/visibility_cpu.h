// How many cameras see each 3D point, on the CPU (see visibility_cpu.cpp).
#pragma once

#include <ATen/core/Tensor.h>

#include <vector>

namespace stealth_ns {

// int32 [P]: for each of the points [P, 3], the cameras (viewmats [J, 4, 4], Ks [J, 3, 3], depths and
// alphas J maps [H_j, W_j]) that see it
at::Tensor count_seeing(const at::Tensor &points, const at::Tensor &viewmats, const at::Tensor &Ks,
                        const std::vector<at::Tensor> &depths, const std::vector<at::Tensor> &alphas,
                        double margin, double near_plane, double surface_alpha);

}  // namespace stealth_ns
