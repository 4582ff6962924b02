// The number of cameras that see each 3D point: the view-aware placement's per-sample cost.
//
// The readable reference with the same contract is stealth_ns/attack/visibility.py's
// `count_seeing_cameras_reference` (a dozen full-size torch operations per camera). The injection's
// ray search asks it for every sample of every illusion ray against every innocent camera (sizes and
// torch timings: docs/cpu_rasterizer.md). Here each point visits every camera once, and reads one
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
#include "camera_views.h"
#include "tensor_checks.h"

#include <ATen/Parallel.h>
#include <ATen/ops/zeros.h>

#include <algorithm>

namespace stealth_ns {

namespace {

constexpr int64_t BLOCK = 256;  // points per task block (larger blocks gain nothing: docs/cpu_rasterizer.md)

}  // namespace

at::Tensor count_seeing(const at::Tensor &points, const at::Tensor &viewmats, const at::Tensor &Ks,
                        const std::vector<at::Tensor> &bounds, double near_plane) {
    check_cpu_f32(points, "points");
    TORCH_CHECK(points.dim() == 2 && points.size(1) == 3, "points must be [P, 3]");
    const int64_t P = points.size(0);
    const std::vector<CameraView> cams = camera_views(viewmats, Ks, bounds);
    const float fnear = (float)near_plane;
    at::Tensor counts = at::zeros({P}, points.options().dtype(at::kInt));
    const float *pts = points.data_ptr<float>();
    int32_t *out = counts.data_ptr<int32_t>();
    at::parallel_for(0, (P + BLOCK - 1) / BLOCK, 1, [&](int64_t b0, int64_t b1) {
        for (int64_t b = b0; b < b1; ++b) {
            const int64_t lo = b * BLOCK, hi = std::min(P, lo + BLOCK);
            for (const CameraView &c : cams) add_seen(c, pts, lo, hi, fnear, out);
        }
    });
    return counts;
}

}  // namespace stealth_ns
