// Projection and SH colour of 3D Gaussians on the CPU (see project_cpu.cpp).
#pragma once

#include <torch/extension.h>

#include <vector>

namespace stealth_ns {

// (radii [C,N] int32, means2d [C,N,2], depths [C,N], conics [C,N,3])
std::vector<torch::Tensor> project_fwd(
    const torch::Tensor &means, const torch::Tensor &quats, const torch::Tensor &scales,
    const torch::Tensor &viewmats, const torch::Tensor &Ks, int64_t width, int64_t height, double eps2d,
    double near_plane, double far_plane, double radius_clip
);

// (v_means [N,3], v_quats [N,4], v_scales [N,3]); Gaussians with radius 0 get no gradient.
std::vector<torch::Tensor> project_bwd(
    const torch::Tensor &means, const torch::Tensor &quats, const torch::Tensor &scales,
    const torch::Tensor &viewmats, const torch::Tensor &Ks, int64_t width, int64_t height, double eps2d,
    const torch::Tensor &radii, const torch::Tensor &v_means2d, const torch::Tensor &v_depths,
    const torch::Tensor &v_conics
);

// SH coefficients are given as dc [N,3] (degree 0) and rest [N,K-1,3] (degrees 1..3), as nerfstudio stores them.
// colours [C,N,3] = max(SH(degree, means - camera centre, coeffs) + 0.5, 0); 0 where radius is 0.
torch::Tensor sh_fwd(
    const torch::Tensor &means, const torch::Tensor &viewmats, const torch::Tensor &dc, const torch::Tensor &rest,
    int64_t degree, const torch::Tensor &radii
);

// (v_dc [N,3], v_rest [N,K-1,3], v_means [N,3])
std::vector<torch::Tensor> sh_bwd(
    const torch::Tensor &means, const torch::Tensor &viewmats, const torch::Tensor &dc, const torch::Tensor &rest,
    int64_t degree, const torch::Tensor &radii, const torch::Tensor &v_colors
);

}  // namespace stealth_ns
