// The injection's ray search, one compiled pass over every ray (see ray_search_cpu.cpp).
#pragma once

#include <ATen/core/Tensor.h>

#include <vector>

namespace stealth_ns {

// (index [M] int64 of the chosen sample, its density [M] float32, its penalty [M] float32) per ray
std::vector<at::Tensor> ray_search(
    const at::Tensor &origins, const at::Tensor &dirs, const at::Tensor &t_min, const at::Tensor &t_max,
    const at::Tensor &frac, const at::Tensor &values, const at::Tensor &grid_origin, double voxel_size,
    double outside, const at::Tensor &viewmats, const at::Tensor &Ks, const std::vector<at::Tensor> &bounds,
    const at::Tensor &support_viewmats, const at::Tensor &support_Ks,
    const std::vector<at::Tensor> &support_bounds, double near_plane, int64_t tie_break, double tie_tol
);

}  // namespace stealth_ns
