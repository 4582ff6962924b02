// Rasterize-to-pixels and tile intersection of 3D Gaussians on the CPU (see rasterize_cpu.cpp).
#pragma once

#include <ATen/core/Tensor.h>

#include <optional>
#include <vector>

namespace stealth_ns {

// (render_colors [C,H,W,D], render_alphas [C,H,W,1], last_ids [C,H,W] int32, T_final [C,H,W]);
// last_ids is -1 for pixels without contributor.
std::vector<at::Tensor> rasterize_fwd(
    const at::Tensor &means2d, const at::Tensor &conics, const at::Tensor &colors,
    const at::Tensor &opacities, const std::optional<at::Tensor> &backgrounds, int64_t image_width,
    int64_t image_height, int64_t tile_size, const at::Tensor &isect_offsets,
    const at::Tensor &flatten_ids, bool cull, int64_t n_threads
);

// (render_colors [C,H,W,D], render_alphas [C,H,W,1], weights [C,N]): the forward, and each Gaussian's
// blending weight, T * alpha summed over the pixels it is blended into (what the backward gives as the
// gradient of the colour sum with respect to the Gaussian's colour), without a backward pass.
std::vector<at::Tensor> rasterize_weights(
    const at::Tensor &means2d, const at::Tensor &conics, const at::Tensor &colors,
    const at::Tensor &opacities, const std::optional<at::Tensor> &backgrounds, int64_t image_width,
    int64_t image_height, int64_t tile_size, const at::Tensor &isect_offsets,
    const at::Tensor &flatten_ids, bool cull, int64_t n_threads
);

// (v_means2d [C,N,2], v_conics [C,N,3], v_colors [C,N,D], v_opacities [C,N]).
std::vector<at::Tensor> rasterize_bwd(
    const at::Tensor &means2d, const at::Tensor &conics, const at::Tensor &colors,
    const at::Tensor &opacities, const std::optional<at::Tensor> &backgrounds, int64_t image_width,
    int64_t image_height, int64_t tile_size, const at::Tensor &isect_offsets,
    const at::Tensor &flatten_ids, const at::Tensor &T_final, const at::Tensor &last_ids,
    const at::Tensor &v_render_colors, const at::Tensor &v_render_alphas, bool cull, int64_t mode,
    int64_t n_threads
);

// (isect_offsets [C, tiles_y, tiles_x] int32, flatten_ids [n_isects] int32, tiles_per_gauss [C, N] int32).
// With conics [C, N, 3] and opacities [C, N] (empty tensors: not used) only the pairs whose tile the
// Gaussian's alpha >= 1/255 footprint reaches (image_width x image_height pixels) are listed.
std::vector<at::Tensor> isect_tiles(
    const at::Tensor &means2d, const at::Tensor &radii, const at::Tensor &depths, int64_t tile_size,
    int64_t tile_width, int64_t tile_height, int64_t n_threads, const at::Tensor &conics,
    const at::Tensor &opacities, int64_t image_width, int64_t image_height
);

}  // namespace stealth_ns
