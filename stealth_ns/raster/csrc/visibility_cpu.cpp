// The number of cameras that see each 3D point: the view-aware placement's per-sample cost.
//
// The readable reference with the same contract is stealth_ns/attack/visibility.py's
// `count_seeing_cameras_reference` (a dozen full-size torch operations per camera). The injection's
// ray search asks it for every sample of every illusion ray against every innocent camera (1.5M
// samples x 100 cameras on the generated object scene: 2.25 s in torch; 52M samples x 20 cameras on
// the 1-MP facing scene: a 49.7 s injection). Here each point visits every camera once, and reads one
// map of depth bounds per camera (made once per injection by CameraDepths.depth_bounds: depth *
// (1 + margin) where the pixel shows a surface, +inf elsewhere; the maps of a 1-MP capture do not
// stay in cache, so one read per lookup instead of a depth and an opacity read).
//
// Float expressions are those of the reference, in its order, rounded to float32 (compiled with
// -ffp-contract=off): the camera-space point is V[i,0] x + V[i,1] y + V[i,2] z + V[i,3] summed left
// to right, u = K00 * x_c / z + K02, the pixel the clamped u truncated, and the depth bound
// surface * float(1 + margin) (made in torch, the same float32 product); the counts are the
// reference's exactly (tests/test_placement.py). A point is unoccluded when z <= bound: true for
// every finite z where the bound is +inf, false where it is NaN, as the reference's comparison.

#include "visibility_cpu.h"
#include "tensor_checks.h"

#include <ATen/Parallel.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/zeros.h>

#include <algorithm>


namespace stealth_ns {

namespace {

struct CameraView {
    float V[12];  // the first three rows of the world-to-camera matrix
    float fx, cx, fy, cy;
    int32_t w;  // int32 pixel indices: GCC vectorises the lookup as a gather (1-MP facing: 4.0 -> 1.4 s)
    float fw, fh, fw1, fh1;  // w, h, w - 1 and h - 1 as floats (the reference's bounds and clamp)
    const float *bound;  // per pixel: the depth bound (CameraDepths.depth_bounds: one read per lookup)
};

constexpr int64_t BLOCK = 256;  // points per task block (4096 and 65536 measured the same at 1 MP)

}  // namespace

at::Tensor count_seeing(const at::Tensor &points, const at::Tensor &viewmats, const at::Tensor &Ks,
                        const std::vector<at::Tensor> &bounds, double near_plane) {
    check_cpu_f32(points, "points");
    check_cpu_f32(viewmats, "viewmats");
    check_cpu_f32(Ks, "Ks");
    TORCH_CHECK(points.dim() == 2 && points.size(1) == 3, "points must be [P, 3]");
    const int64_t P = points.size(0), J = viewmats.size(0);
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
    const float fnear = (float)near_plane;
    at::Tensor counts = at::zeros({P}, points.options().dtype(at::kInt));
    const float *pts = points.data_ptr<float>();
    int32_t *out = counts.data_ptr<int32_t>();
    at::parallel_for(0, (P + BLOCK - 1) / BLOCK, 1, [&](int64_t b0, int64_t b1) {
        for (int64_t b = b0; b < b1; ++b) {
            const int64_t lo = b * BLOCK, hi = std::min(P, lo + BLOCK);
            for (const CameraView &c : cams) {
                // branch-free, as the reference computes it for every point: the lookups of points
                // outside the image read a clamped pixel and count for nothing
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
        }
    });
    return counts;
}

}  // namespace stealth_ns
