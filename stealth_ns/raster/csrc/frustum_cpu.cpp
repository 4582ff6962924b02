// camera-proximity's depth ratios: for each Gaussian centre, its smallest depth in a training camera
// that has it in view, over that camera's scene depth.
//
// The readable reference with the same contract is stealth_ns/defences/scores.py's
// `frustum_depth_ratios` (numpy, a dozen full-size array operations per camera). Here each block of
// points visits every camera once, in float64 like the reference, with its expressions in its order:
// the camera-space point R x + t, u = fx * x_c / z + cx, the in-image test 0 <= u < w, 0 <= v < h,
// the ratio z / depth. The reference's matrix product may sum in another order (BLAS), so the two agree
// to float64 rounding, not bit for bit (tests/defences/test_frustum_kernel.py).

#include "frustum_cpu.h"
#include "tensor_checks.h"

#include <ATen/Parallel.h>
#include <ATen/ops/empty.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace stealth_ns {

namespace {

constexpr int64_t BLOCK = 256;  // points per task block

struct FrustumCamera {
    double R[9], t[3];
    double fx, cx, fy, cy, w, h, depth;
};

}  // namespace

at::Tensor frustum_depth_ratios(const at::Tensor &points, const at::Tensor &viewmats, const at::Tensor &Ks,
                                const at::Tensor &sizes, const at::Tensor &depths) {
    check_cpu_f64(points, "points");
    check_cpu_f64(viewmats, "viewmats");
    check_cpu_f64(Ks, "Ks");
    check_cpu_f64(sizes, "sizes");
    check_cpu_f64(depths, "depths");
    TORCH_CHECK(points.dim() == 2 && points.size(1) == 3, "points must be [P, 3]");
    const int64_t V = viewmats.size(0), P = points.size(0);
    TORCH_CHECK(viewmats.dim() == 3 && viewmats.size(1) == 4 && viewmats.size(2) == 4, "viewmats must be [V, 4, 4]");
    TORCH_CHECK(Ks.dim() == 3 && Ks.size(0) == V && Ks.size(1) == 3 && Ks.size(2) == 3, "Ks must be [V, 3, 3]");
    TORCH_CHECK(sizes.dim() == 2 && sizes.size(0) == V && sizes.size(1) == 2, "sizes must be [V, 2]");
    TORCH_CHECK(depths.dim() == 1 && depths.size(0) == V, "depths must be [V]");
    std::vector<FrustumCamera> cams(V);
    const double *vm = viewmats.data_ptr<double>(), *k = Ks.data_ptr<double>();
    const double *sz = sizes.data_ptr<double>(), *dp = depths.data_ptr<double>();
    for (int64_t v = 0; v < V; ++v) {
        FrustumCamera &c = cams[v];
        for (int r = 0; r < 3; ++r) {
            for (int col = 0; col < 3; ++col) c.R[3 * r + col] = vm[16 * v + 4 * r + col];
            c.t[r] = vm[16 * v + 4 * r + 3];
        }
        c.fx = k[9 * v + 0], c.cx = k[9 * v + 2], c.fy = k[9 * v + 4], c.cy = k[9 * v + 5];
        c.w = sz[2 * v], c.h = sz[2 * v + 1], c.depth = dp[v];
    }
    at::Tensor ratios = at::empty({P}, points.options());
    const double *pts = points.data_ptr<double>();
    double *out = ratios.data_ptr<double>();
    const double inf = std::numeric_limits<double>::infinity();
    at::parallel_for(0, (P + BLOCK - 1) / BLOCK, 1, [&](int64_t b0, int64_t b1) {
        for (int64_t b = b0; b < b1; ++b) {
            const int64_t lo = b * BLOCK, hi = std::min(P, lo + BLOCK);
            for (int64_t p = lo; p < hi; ++p) out[p] = inf;
            for (const FrustumCamera &c : cams) {
                for (int64_t p = lo; p < hi; ++p) {
                    const double x = pts[3 * p], y = pts[3 * p + 1], zw = pts[3 * p + 2];
                    const double xc = c.R[0] * x + c.R[1] * y + c.R[2] * zw + c.t[0];
                    const double yc = c.R[3] * x + c.R[4] * y + c.R[5] * zw + c.t[1];
                    const double z = c.R[6] * x + c.R[7] * y + c.R[8] * zw + c.t[2];
                    const bool front = z > 0.0;
                    const double zs = front ? z : 1.0;
                    const double u = c.fx * xc / zs + c.cx, v = c.fy * yc / zs + c.cy;
                    const bool inside = front & (u >= 0.0) & (u < c.w) & (v >= 0.0) & (v < c.h);
                    const double r = z / c.depth;
                    out[p] = (inside && r < out[p]) ? r : out[p];
                }
            }
            for (int64_t p = lo; p < hi; ++p) {
                const bool finite = std::isfinite(pts[3 * p]) && std::isfinite(pts[3 * p + 1]) &&
                                    std::isfinite(pts[3 * p + 2]);
                if (!finite) out[p] = 0.0;
            }
        }
    });
    return ratios;
}

}  // namespace stealth_ns
