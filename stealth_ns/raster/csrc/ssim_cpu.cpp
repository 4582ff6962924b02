// SSIM (Gaussian window, valid convolution) and its gradient with respect to the second image, on the CPU.
//
// The readable reference with the same contract is pytorch_msssim's `ssim` (what splatfacto's loss calls):
//   mu = G * I, sigma_xx = G * (X X) - mu_x^2, ..., with G the separable 1-D window applied along H, then W,
//   no padding; S = (2 mu_x mu_y + C1)(2 sigma_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(sigma_xx + sigma_yy + C2));
//   one value per (image, channel) plane: the mean of S over the valid H' x W' window positions.
// The forward keeps dS/d(mu_y), dS/d(E[YY]), dS/d(E[XY]) per window position; the backward scales them by
// the upstream gradient of each plane and takes them back through the transposed window:
//   dL/dY = G^T g_mu + 2 Y G^T g_yy + X G^T g_xy.
// Both passes are fused row by row (each output row's five maps are filtered down the window's rows and
// then along the row, in L1; the backward likewise), one task per block of ROWS output rows of a plane,
// and every sum keeps the order of the unfused filters (down the rows, then along them; the transposed
// filters in reverse), so the values are bitwise those of filtering whole maps. Each plane's SSIM is
// summed in window order by one task: deterministic whatever the thread count.

#include "simd_width.h"
#include "ssim_cpu.h"
#include "tensor_checks.h"

#include <ATen/Parallel.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/empty_like.h>

#include <algorithm>
#include <vector>

namespace stealth_ns {
namespace {

void check_image(const at::Tensor &t, const char *name) {
    check_cpu_f32(t, name);
    TORCH_CHECK(t.dim() == 4, name, " must be [B, C, H, W]");
}

// The filters below keep each output's sum in registers, VL outputs at a time, over the window's taps
// in order (the sum starts at 0): the same additions in the same order as accumulating whole rows in
// memory tap by tap, which takes 5 loads and stores per tap and output.  VL is one register
// (simd_width.h; wider vectors are compiled lane by lane: docs/cpu_rasterizer.md).
constexpr int64_t VL = STEALTH_NS_FLOAT_LANES;
typedef float vec __attribute__((vector_size(4 * VL)));
typedef float vec_u __attribute__((vector_size(4 * VL), aligned(4), __may_alias__));
inline vec ld(const float *p) { return *reinterpret_cast<const vec_u *>(p); }
inline void st(float *p, vec v) { *reinterpret_cast<vec_u *>(p) = v; }

// Outputs [x, x + VL U) of a K-tap filter, out[x] = sum_k w[k] in[x + s k] (s = +1 or -1), k in order from
// 0. U independent sums: one alone waits on the latency of each addition.
template <int U, int S>
inline void filter_chunk(const float *__restrict__ in, const float *__restrict__ w, int64_t K,
                         float *__restrict__ out, int64_t x) {
    vec acc[U] = {};
    for (int64_t k = 0; k < K; ++k) {
        const float wk = w[k];
        for (int u = 0; u < U; ++u) acc[u] += wk * ld(in + x + VL * u + S * k);
    }
    for (int u = 0; u < U; ++u) st(out + x + VL * u, acc[u]);
}

template <int S>
void filter_line(const float *__restrict__ in, int64_t n, const float *__restrict__ w, int64_t K,
                 float *__restrict__ out) {
    int64_t x = 0;
    for (; x + 4 * VL <= n; x += 4 * VL) filter_chunk<4, S>(in, w, K, out, x);
    for (; x + VL <= n; x += VL) filter_chunk<1, S>(in, w, K, out, x);
    for (; x < n; ++x) {
        float acc = 0.0f;
        for (int64_t k = 0; k < K; ++k) acc += w[k] * in[x + S * k];
        out[x] = acc;
    }
}

// out[x] = sum_k w[k] in[x + k]: one row of W -> W - K + 1 (the sum starts at 0, k in order)
void filter_row(const float *in, int64_t W, const float *w, int64_t K, float *out) {
    filter_line<1>(in, W - K + 1, w, K, out);
}

// Transpose of filter_row, from a row of Wo values with K - 1 zeros on each side (in[-(K-1)] ..
// in[Wo + K - 2]): out[j] = sum_k w[k] in[j - k], j < Wo + K - 1.  The zeros stand for the terms the
// transposed filter does not have at the borders: each adds +0, which leaves the sum as it was.
void filter_row_t(const float *in, int64_t Wo, const float *w, int64_t K, float *out) {
    filter_line<-1>(in, Wo + K - 1, w, K, out);
}

// The five maps of one output row filtered down the window's rows (image rows r .. r + K - 1 at x, y):
// col[q * W + i] = sum_k w_k (mu_x, mu_y, E[XX], E[YY], E[XY]) terms, k in order.
void window_col(const float *__restrict__ x, const float *__restrict__ y, int64_t W, const float *__restrict__ w,
                int64_t K, float *__restrict__ col) {
    int64_t i = 0;
    for (; i + VL <= W; i += VL) {
        vec c0 = {}, c1 = {}, c2 = {}, c3 = {}, c4 = {};
        for (int64_t k = 0; k < K; ++k) {
            const vec a = ld(x + k * W + i), b = ld(y + k * W + i);
            const float wk = w[k];
            c0 += wk * a;
            c1 += wk * b;
            c2 += wk * (a * a);
            c3 += wk * (b * b);
            c4 += wk * (a * b);
        }
        st(col + i, c0);
        st(col + W + i, c1);
        st(col + 2 * W + i, c2);
        st(col + 3 * W + i, c3);
        st(col + 4 * W + i, c4);
    }
    for (; i < W; ++i) {
        float c0 = 0.0f, c1 = 0.0f, c2 = 0.0f, c3 = 0.0f, c4 = 0.0f;
        for (int64_t k = 0; k < K; ++k) {
            const float a = x[k * W + i], b = y[k * W + i], wk = w[k];
            c0 += wk * a;
            c1 += wk * b;
            c2 += wk * (a * a);
            c3 += wk * (b * b);
            c4 += wk * (a * b);
        }
        col[i] = c0;
        col[W + i] = c1;
        col[2 * W + i] = c2;
        col[3 * W + i] = c3;
        col[4 * W + i] = c4;
    }
}

// Output row Yr, columns [i, i + VL U), of the backward: the three maps taken back down the rows (the
// n filtered rows lo..lo + n - 1 of t0, t1, t2, in increasing order, row lo + j at offset off[j]) and
// combined, dL/dY = b0 + 2 Y b1 + X b2.
template <int U>
inline void back_chunk(const float *__restrict__ t0, const float *__restrict__ t1, const float *__restrict__ t2,
                       const float *__restrict__ w, int64_t Yr, int64_t lo, int64_t n, const int64_t *__restrict__ off,
                       const float *__restrict__ xr, const float *__restrict__ yr, float *__restrict__ o, int64_t i) {
    vec b0[U] = {}, b1[U] = {}, b2[U] = {};
    for (int64_t j = 0; j < n; ++j) {
        const float wk = w[Yr - lo - j];
        for (int u = 0; u < U; ++u) {
            const int64_t at = off[j] + i + VL * u;
            b0[u] += wk * ld(t0 + at);
            b1[u] += wk * ld(t1 + at);
            b2[u] += wk * ld(t2 + at);
        }
    }
    for (int u = 0; u < U; ++u) {
        const int64_t c = i + VL * u;
        st(o + c, b0[u] + 2.0f * ld(yr + c) * b1[u] + ld(xr + c) * b2[u]);
    }
}

// One row of dL/dY into out[i * step]: the SSIM term o plus, when the training loss fuses it here, its L1
// term's gradient -(l1 sgn(x - y)) (l1 = its weight over the pixel count), rounded as torch's autograd of
// w * |x - y|.mean() rounds it: sgn as torch.sgn (0 for 0 and NaN), the exact product with l1, the
// negation, then the sum of the two gradients (which autograd adds in either order: the same bits).
// l1 = 0 adds -0, which changes no value.  step = C gives the [B, H, W, C] layout.
inline void write_row(const float *__restrict__ o, const float *__restrict__ x, const float *__restrict__ y,
                      int64_t W, float l1, float *__restrict__ out, int64_t step) {
    for (int64_t i = 0; i < W; ++i) {
        const float d = x[i] - y[i];
        const float sgn = (float)((0.0f < d) - (d < 0.0f));
        out[i * step] = o[i] + -(l1 * sgn);
    }
}

// The SSIM map S of one row of window positions from its five filtered maps m [5, Wo] into s [Wo], and
// with G the derivatives dS/dmu_y, dS/dE[YY], dS/dE[XY] (divided by n) into g, g + HWo, g + 2 HWo.
template <bool G>
void ssim_row(const float *__restrict__ m, int64_t Wo, float c1, float c2, float inv_n, float *__restrict__ s,
              float *__restrict__ g, int64_t HWo) {
    float *__restrict__ g1 = G ? g + HWo : nullptr, *__restrict__ g2 = G ? g + 2 * HWo : nullptr;
    for (int64_t i = 0; i < Wo; ++i) {
        const float mx = m[i], my = m[Wo + i];
        const float sxx = m[2 * Wo + i] - mx * mx, syy = m[3 * Wo + i] - my * my;
        const float sxy = m[4 * Wo + i] - mx * my;
        const float A = 2.0f * mx * my + c1, B = mx * mx + my * my + c1;
        const float Cn = 2.0f * sxy + c2, D = sxx + syy + c2;
        const float S = (A * Cn) / (B * D);
        s[i] = S;
        if (G) {
            g[i] = (2.0f * mx * (Cn - A) / (B * D) - 2.0f * my * S / B + 2.0f * my * S / D) * inv_n;
            g1[i] = (-S / D) * inv_n;
            g2[i] = (2.0f * A / (B * D)) * inv_n;
        }
    }
}

// The sums of Q planes of n values each (plane q at s + q n) into out[q], each in index order from 0,
// in double: the same value for any thread count.  Each sum is one chain of dependent additions; the Q
// chains side by side let the processor overlap them (with one plane per task a thread sums planes one
// after the other, one chain at a time: docs/cpu_rasterizer.md).
template <int Q> void sum_planes(const float *__restrict__ s, int64_t n, double *out) {
    double t[Q] = {};
    for (int64_t i = 0; i < n; ++i)
        for (int q = 0; q < Q; ++q) t[q] += s[q * n + i];
    for (int q = 0; q < Q; ++q) out[q] = t[q];
}
constexpr int64_t kSumPlanes = 4;  // planes per task of sum_planes

// Output rows per task.  The backward filters its first K - 1 rows along W again at each task's start
// (they are the last rows of the task above): taller tasks repeat that work less often (64 against 32
// rows: docs/cpu_rasterizer.md).
constexpr int64_t ROWS = 64;

struct Dims {
    int64_t planes, H, W, K, Ho, Wo, B, C;
};

Dims check(const at::Tensor &X, const at::Tensor &Y, const at::Tensor &win) {
    check_image(X, "X");
    check_image(Y, "Y");
    TORCH_CHECK(X.sizes() == Y.sizes(), "X and Y must have the same shape");
    check_cpu_f32(win, "win");
    TORCH_CHECK(win.dim() == 1, "win must be a vector");
    const int64_t K = win.size(0), H = X.size(2), W = X.size(3);
    TORCH_CHECK(H >= K && W >= K, "the image (", H, " x ", W, ") is smaller than the window (", K, ")");
    return {X.size(0) * X.size(1), H, W, K, H - K + 1, W - K + 1, X.size(0), X.size(1)};
}

}  // namespace

std::vector<at::Tensor> ssim_fwd(const at::Tensor &X, const at::Tensor &Y, const at::Tensor &win,
                                 double C1, double C2, bool need_grad) {
    const Dims d = check(X, Y, win);
    const int64_t HW = d.H * d.W, HWo = d.Ho * d.Wo, W = d.W, K = d.K;
    auto planes = at::empty({X.size(0), X.size(1)}, X.options());
    // per plane: dS/dmu_y, dS/dE[YY], dS/dE[XY], already divided by the number of window positions
    auto dmaps = need_grad ? at::empty({d.planes, 3, d.Ho, d.Wo}, X.options()) : at::empty({0}, X.options());
    auto smap = at::empty({d.planes, HWo}, X.options());  // S per window position, summed in order below
    const float *xp = X.data_ptr<float>(), *yp = Y.data_ptr<float>(), *w = win.data_ptr<float>();
    float *pp = planes.data_ptr<float>(), *sp = smap.data_ptr<float>();
    float *dp = need_grad ? dmaps.data_ptr<float>() : nullptr;
    const float c1 = (float)C1, c2 = (float)C2, inv_n = 1.0f / (float)HWo;
    const int64_t blocks = (d.Ho + ROWS - 1) / ROWS;
    at::parallel_for(0, d.planes * blocks, 1, [&](int64_t begin, int64_t end) {
        // the five maps of one output row, filtered down the rows (W) and then along them (Wo)
        std::vector<float> col((size_t)5 * W), m((size_t)5 * d.Wo);
        for (int64_t task = begin; task < end; ++task) {
            const int64_t p = task / blocks, y0 = (task % blocks) * ROWS, y1 = std::min(d.Ho, y0 + ROWS);
            const float *x = xp + p * HW, *yy = yp + p * HW;
            for (int64_t r = y0; r < y1; ++r) {
                window_col(x + r * W, yy + r * W, W, w, K, col.data());
                for (int q = 0; q < 5; ++q) filter_row(col.data() + q * W, W, w, K, m.data() + q * d.Wo);
                const int64_t o = r * d.Wo;
                if (dp)
                    ssim_row<true>(m.data(), d.Wo, c1, c2, inv_n, sp + p * HWo + o, dp + p * 3 * HWo + o, HWo);
                else
                    ssim_row<false>(m.data(), d.Wo, c1, c2, inv_n, sp + p * HWo + o, nullptr, HWo);
            }
        }
    });
    const int64_t groups = (d.planes + kSumPlanes - 1) / kSumPlanes;
    at::parallel_for(0, groups, 1, [&](int64_t begin, int64_t end) {
        for (int64_t group = begin; group < end; ++group) {
            const int64_t p0 = group * kSumPlanes, n = std::min(kSumPlanes, d.planes - p0);
            double totals[kSumPlanes];
            const float *s = sp + p0 * HWo;
            if (n == 4) sum_planes<4>(s, HWo, totals);
            else if (n == 3) sum_planes<3>(s, HWo, totals);
            else if (n == 2) sum_planes<2>(s, HWo, totals);
            else sum_planes<1>(s, HWo, totals);
            for (int64_t q = 0; q < n; ++q) pp[p0 + q] = (float)(totals[q] / (double)HWo);
        }
    });
    return {planes, dmaps};
}

at::Tensor ssim_bwd(const at::Tensor &X, const at::Tensor &Y, const at::Tensor &win,
                    const at::Tensor &dmaps, const at::Tensor &v_planes, double l1_coef, bool channels_last) {
    const Dims d = check(X, Y, win);
    const int64_t HW = d.H * d.W, HWo = d.Ho * d.Wo, W = d.W, K = d.K;
    check_cpu_f32(dmaps, "dmaps");
    check_cpu_f32(v_planes, "v_planes");
    TORCH_CHECK(dmaps.numel() == d.planes * 3 * HWo, "dmaps must be [planes, 3, H', W']");
    TORCH_CHECK(v_planes.numel() == d.planes, "v_planes must be [B, C]");
    at::Tensor v_Y = channels_last ? at::empty({d.B, d.H, d.W, d.C}, Y.options()) : at::empty_like(Y);
    const float l1 = (float)l1_coef;
    const float *xp = X.data_ptr<float>(), *yp = Y.data_ptr<float>(), *w = win.data_ptr<float>();
    const float *dp = dmaps.data_ptr<float>(), *vp = v_planes.data_ptr<float>();
    float *out = v_Y.data_ptr<float>();
    const int64_t blocks = (d.H + ROWS - 1) / ROWS;
    at::parallel_for(0, d.planes * blocks, 1, [&](int64_t begin, int64_t end) {
        // G^T (v dS/dmu_y), G^T (v dS/dE[YY]), G^T (v dS/dE[XY]): each map's rows taken back along W as the
        // output rows need them, into a ring of the last K rows per map (row r in slot r mod K: the rows
        // an output row gathers), then down the rows, row by row
        std::vector<float> gpad((size_t)d.Wo + 2 * (K - 1), 0.0f), t((size_t)3 * K * W), row(W);
        std::vector<int64_t> off(K);
        float *g = gpad.data() + K - 1;  // zeros on both sides stay zeros
        const float *t0 = t.data(), *t1 = t0 + K * W, *t2 = t1 + K * W;
        for (int64_t task = begin; task < end; ++task) {
            const int64_t p = task / blocks, Y0 = (task % blocks) * ROWS, Y1 = std::min(d.H, Y0 + ROWS);
            const float *x = xp + p * HW, *yy = yp + p * HW;
            int64_t next = std::max<int64_t>(0, Y0 - K + 1);  // the next row to filter along W
            for (int64_t Yr = Y0; Yr < Y1; ++Yr) {
                // rows r with r <= Yr < r + K, in increasing r (the order the transposed filter adds them)
                const int64_t lo = std::max<int64_t>(0, Yr - K + 1), hi = std::min(d.Ho - 1, Yr);
                for (; next <= hi; ++next)
                    for (int q = 0; q < 3; ++q) {
                        const float *src = dp + (p * 3 + q) * HWo + next * d.Wo;
                        for (int64_t i = 0; i < d.Wo; ++i) g[i] = vp[p] * src[i];
                        filter_row_t(g, d.Wo, w, K, t.data() + (q * K + next % K) * W);
                    }
                const int64_t n = hi - lo + 1;
                for (int64_t j = 0; j < n; ++j) off[j] = ((lo + j) % K) * W;
                const float *xr = x + Yr * W, *yr = yy + Yr * W;
                float *o = row.data();
                int64_t i = 0;
                for (; i + 2 * VL <= W; i += 2 * VL) back_chunk<2>(t0, t1, t2, w, Yr, lo, n, off.data(), xr, yr, o, i);
                for (; i + VL <= W; i += VL) back_chunk<1>(t0, t1, t2, w, Yr, lo, n, off.data(), xr, yr, o, i);
                for (; i < W; ++i) {
                    float b0 = 0.0f, b1 = 0.0f, b2 = 0.0f;
                    for (int64_t j = 0; j < n; ++j) {
                        const float wk = w[Yr - lo - j];
                        const int64_t at = off[j] + i;
                        b0 += wk * t0[at];
                        b1 += wk * t1[at];
                        b2 += wk * t2[at];
                    }
                    o[i] = b0 + 2.0f * yr[i] * b1 + xr[i] * b2;
                }
                write_row(o, xr, yr, W, l1, channels_last ? out + (p / d.C * HW + Yr * W) * d.C + p % d.C
                                                          : out + p * HW + Yr * W, channels_last ? d.C : 1);
            }
        }
    });
    return v_Y;
}

}  // namespace stealth_ns
