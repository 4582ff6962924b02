// The cameras of the visibility counts as the kernels read them, and the count of one block of points
// against one camera: shared by count_seeing (visibility_cpu.cpp) and the injection's fused ray search
// (ray_search_cpu.cpp), so that both count exactly as stealth_ns/attack/visibility.py's reference.
#pragma once

#include "tensor_checks.h"

#include <ATen/core/Tensor.h>

#include <cstdint>
#include <vector>

namespace stealth_ns {

struct CameraView {
    float V[12];  // the first three rows of the world-to-camera matrix
    float fx, cx, fy, cy;
    int32_t w;  // int32 pixel indices: GCC vectorises the lookup as a gather
    float fw, fh, fw1, fh1;  // w, h, w - 1 and h - 1 as floats (the reference's bounds and clamp)
    const float *bound;  // per pixel: the depth bound (CameraDepths.depth_bounds: one read per lookup)
};

// viewmats [J, 4, 4], Ks [J, 3, 3] and J depth-bound maps [H_j, W_j], checked (J may be 0)
inline std::vector<CameraView> camera_views(
    const at::Tensor &viewmats, const at::Tensor &Ks, const std::vector<at::Tensor> &bounds
) {
    check_cpu_f32(viewmats, "viewmats");
    check_cpu_f32(Ks, "Ks");
    const int64_t J = viewmats.size(0);
    TORCH_CHECK(viewmats.dim() == 3 && viewmats.size(1) == 4 && viewmats.size(2) == 4, "viewmats must be [J, 4, 4]");
    TORCH_CHECK(Ks.dim() == 3 && Ks.size(0) == J && Ks.size(1) == 3 && Ks.size(2) == 3, "Ks must be [J, 3, 3]");
    TORCH_CHECK((int64_t)bounds.size() == J, "need one depth-bound map per camera");
    std::vector<CameraView> cams(J);
    const float *vm = viewmats.data_ptr<float>(), *k = Ks.data_ptr<float>();
    for (int64_t j = 0; j < J; ++j) {
        check_cpu_f32(bounds[j], "bounds");
        TORCH_CHECK(bounds[j].dim() == 2, "each camera's depth-bound map must be [H, W]");
        CameraView &c = cams[j];
        for (int i = 0; i < 12; ++i) c.V[i] = vm[16 * j + i];
        c.fx = k[9 * j + 0], c.cx = k[9 * j + 2], c.fy = k[9 * j + 4], c.cy = k[9 * j + 5];
        const int64_t h = bounds[j].size(0), w = bounds[j].size(1);
        TORCH_CHECK(h * w < (int64_t)1 << 31, "depth-bound maps must have fewer than 2^31 pixels");
        c.w = (int32_t)w;
        c.fw = (float)w, c.fh = (float)h, c.fw1 = (float)(w - 1), c.fh1 = (float)(h - 1);
        c.bound = bounds[j].data_ptr<float>();
    }
    return cams;
}

// out[p] += 1 for each point p in [lo, hi) of pts [P, 3] that camera c sees.  Branch free, as the
// reference computes it for every point: the lookups of points outside the image read a clamped pixel
// and count for nothing.
inline void add_seen(const CameraView &c, const float *pts, int64_t lo, int64_t hi, float fnear, int32_t *out) {
    for (int64_t p = lo; p < hi; ++p) {
        const float x = pts[3 * p], y = pts[3 * p + 1], zw = pts[3 * p + 2];
        const float xc = c.V[0] * x + c.V[1] * y + c.V[2] * zw + c.V[3];
        const float yc = c.V[4] * x + c.V[5] * y + c.V[6] * zw + c.V[7];
        const float z = c.V[8] * x + c.V[9] * y + c.V[10] * zw + c.V[11];
        const bool front = z > fnear;
        const float zs = front ? z : 1.0f;
        const float u = c.fx * xc / zs + c.cx, v = c.fy * yc / zs + c.cy;
        const bool inside = front & (u >= 0.0f) & (u < c.fw) & (v >= 0.0f) & (v < c.fh);
        // clamped to [0, w - 1] (NaN to 0: never an index outside the map)
        const int32_t col = (int32_t)(u >= 0.0f ? (u <= c.fw1 ? u : c.fw1) : 0.0f);
        const int32_t row = (int32_t)(v >= 0.0f ? (v <= c.fh1 ? v : c.fh1) : 0.0f);
        const int32_t at = row * c.w + col;
        const bool unoccluded = z <= c.bound[at];
        out[p] += (int32_t)(inside & unoccluded);
    }
}

}  // namespace stealth_ns
