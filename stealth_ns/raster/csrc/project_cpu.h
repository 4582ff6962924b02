// Projection and SH colour of 3D Gaussians on the CPU (see project_cpu.cpp).
#pragma once

#include <ATen/core/Tensor.h>

#include <vector>

namespace stealth_ns {

// (radii [C,N] int32, means2d [C,N,2], depths [C,N], conics [C,N,3])
std::vector<at::Tensor> project_fwd(
    const at::Tensor &means, const at::Tensor &quats, const at::Tensor &scales,
    const at::Tensor &viewmats, const at::Tensor &Ks, int64_t width, int64_t height, double eps2d,
    double near_plane, double far_plane, double radius_clip
);

// (v_means [N,3], v_quats [N,4], v_scales [N,3]); Gaussians with radius 0 get no gradient.
std::vector<at::Tensor> project_bwd(
    const at::Tensor &means, const at::Tensor &quats, const at::Tensor &scales,
    const at::Tensor &viewmats, const at::Tensor &Ks, int64_t width, int64_t height, double eps2d,
    const at::Tensor &radii, const at::Tensor &v_means2d, const at::Tensor &v_depths,
    const at::Tensor &v_conics
);

// SH coefficients are given as dc [N,3] (degree 0) and rest [N,K-1,3] (degrees 1..3), as nerfstudio stores them.
// colours [C,N,3] = max(SH(degree, means - camera centre, coeffs) + 0.5, 0); 0 where radius is 0.
at::Tensor sh_fwd(
    const at::Tensor &means, const at::Tensor &viewmats, const at::Tensor &dc, const at::Tensor &rest,
    int64_t degree, const at::Tensor &radii
);

// (v_dc [N,3], v_rest [N,K-1,3], v_means [N,3])
std::vector<at::Tensor> sh_bwd(
    const at::Tensor &means, const at::Tensor &viewmats, const at::Tensor &dc, const at::Tensor &rest,
    int64_t degree, const at::Tensor &radii, const at::Tensor &v_colors
);

}  // namespace stealth_ns
