// The training render's last step: the image composited onto the background and clamped,
//   rgb = clamp(render + (1 - alpha) * background, 0, 1),
// forward and backward in one pass each, instead of torch's chain of full-image operations (rsub, mul,
// add, clamp; in the backward the clamp's two comparisons, `and` and `where`, the product with the
// background, its sum over channels and a negation): each reads and writes the whole image (what that
// memory traffic costs: docs/cpu_rasterizer.md).
//
// The readable reference with the same contract is the torch expression in
// stealth_ns/raster/composite.py, and every value is rounded as torch rounds it (tests compare bitwise):
//   forward  t = 1 - alpha; x = render + t * background; rgb = min(max(x, 0), 1) (NaN stays NaN);
//   backward v_x = v_rgb where 0 <= x <= 1, else +0 (torch's clamp backward); v_render = v_x;
//            v_alpha = -((v_x[0] bg[0] + v_x[1] bg[1]) + v_x[2] bg[2] ...), the products summed left to
//            right as torch sums a product's gradient over its broadcast channel dimension.
// Compiled with -ffp-contract=off: no fused multiply-add.

#include "composite_cpu.h"
#include "tensor_checks.h"

#include <ATen/Parallel.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/empty_like.h>

#include <algorithm>

namespace stealth_ns {
namespace {

constexpr int64_t kGrain = 1 << 14;  // pixels per task

void check_args(const at::Tensor &render, const at::Tensor &alpha, const at::Tensor &background) {
    check_cpu_f32(render, "render");
    check_cpu_f32(alpha, "alpha");
    check_cpu_f32(background, "background");
    TORCH_CHECK(render.dim() >= 1 && background.dim() == 1 && background.size(0) == render.size(-1),
                "background must be [D] for a render [..., D]");
    const int64_t lead = render.dim() - 1;  // the pixel dimensions, shared by render and alpha
    TORCH_CHECK(alpha.dim() == render.dim() && alpha.size(-1) == 1 &&
                    alpha.sizes().slice(0, lead) == render.sizes().slice(0, lead),
                "alpha must be [..., 1] for a render [..., D]");
}

inline float clamp01(float x) { return std::min(std::max(x, 0.f), 1.f); }  // torch's: NaN stays NaN

// Pixels [p0, p1) of the forward; DT > 0: D known at compile time (with D only known at run time GCC
// keeps the loop scalar).
template <int DT>
void fwd_pixels(const float *__restrict__ r, const float *__restrict__ a, const float *__restrict__ bg,
                float *__restrict__ out, int64_t D_rt, int64_t p0, int64_t p1) {
    const int64_t D = DT > 0 ? DT : D_rt;
    for (int64_t p = p0; p < p1; ++p) {
        const float t = 1.f - a[p];
        for (int64_t c = 0; c < D; ++c) out[p * D + c] = clamp01(r[p * D + c] + t * bg[c]);
    }
}

// Pixels [p0, p1) of the backward; DT > 0: D known at compile time. No branch on the data (the clamp's
// test is a select): a render partly outside [0, 1] makes branches mispredict.
template <int DT>
void bwd_pixels(const float *__restrict__ r, const float *__restrict__ a, const float *__restrict__ bg,
                const float *__restrict__ v, float *__restrict__ vr, float *__restrict__ va, int64_t D_rt,
                int64_t p0, int64_t p1) {
    const int64_t D = DT > 0 ? DT : D_rt;
    for (int64_t p = p0; p < p1; ++p) {
        const float t = 1.f - a[p];
        float sum = 0.f;
        for (int64_t c = 0; c < D; ++c) {
            const float x = r[p * D + c] + t * bg[c];
            const bool inside = (x >= 0.f) & (x <= 1.f);
            const float up = v[p * D + c];  // loaded whatever the test: a conditional load makes it a branch
            const float vx = inside ? up : 0.f;
            vr[p * D + c] = vx;
            const float prod = vx * bg[c];
            sum = c == 0 ? prod : sum + prod;
        }
        va[p] = -sum;
    }
}

}  // namespace

at::Tensor composite_fwd(const at::Tensor &render, const at::Tensor &alpha, const at::Tensor &background) {
    check_args(render, alpha, background);
    const int64_t D = render.size(-1), P = alpha.numel();
    at::Tensor rgb = at::empty_like(render);
    const float *r = render.data_ptr<float>(), *a = alpha.data_ptr<float>(), *bg = background.data_ptr<float>();
    float *out = rgb.data_ptr<float>();
    at::parallel_for(0, P, kGrain, [&](int64_t p0, int64_t p1) {
        if (D == 3)
            fwd_pixels<3>(r, a, bg, out, D, p0, p1);
        else
            fwd_pixels<0>(r, a, bg, out, D, p0, p1);
    });
    return rgb;
}

std::vector<at::Tensor> composite_bwd(const at::Tensor &render, const at::Tensor &alpha,
                                      const at::Tensor &background, const at::Tensor &v_rgb) {
    check_args(render, alpha, background);
    check_cpu_f32(v_rgb, "v_rgb");
    TORCH_CHECK(v_rgb.sizes() == render.sizes(), "v_rgb must have the render's shape");
    const int64_t D = render.size(-1), P = alpha.numel();
    at::Tensor v_render = at::empty_like(render), v_alpha = at::empty_like(alpha);
    const float *r = render.data_ptr<float>(), *a = alpha.data_ptr<float>(), *bg = background.data_ptr<float>();
    const float *v = v_rgb.data_ptr<float>();
    float *vr = v_render.data_ptr<float>(), *va = v_alpha.data_ptr<float>();
    at::parallel_for(0, P, kGrain, [&](int64_t p0, int64_t p1) {
        if (D == 3)
            bwd_pixels<3>(r, a, bg, v, vr, va, D, p0, p1);
        else
            bwd_pixels<0>(r, a, bg, v, vr, va, D, p0, p1);
    });
    return {v_render, v_alpha};
}

}  // namespace stealth_ns
