// The injection's ray search (stealth_ns/attack/ray_search.py, min_density_points) in one compiled
// pass: for every ray, its samples, their density (the KDE grid's nearest voxel), their penalty (the
// innocent cameras that see them, plus the support cameras that do not) and the tie-break, each ray
// on one thread.  The torch version runs ~35 multi-threaded operations per chunk of 256 rays; each
// ends with all threads waiting for the slowest, so one core busy elsewhere stalls every step
// (docs/cpu_rasterizer.md).  Here the search is one parallel loop.
//
// The result is the torch version's exactly (tests/test_placement.py): every float expression is
// its, in its order, rounded to float32 (-ffp-contract=off):
//   t      = t_min + (t_max - t_min) * frac[k]          (frac: torch.linspace, passed in)
//   point  = origin + t * dir
//   u      = (point - grid_origin) / float(voxel_size)   inside when 0 <= u <= shape on every axis
//   f      = values[min(floor(u), shape - 1)] inside, float(outside) elsewhere
//   pen    = seen(innocent) + (S - seen(support))        (camera_views.h, the counts' own code)
//   cost   = 2 * float(pen) + f, NaN -> +inf, +-inf -> +-FLT_MAX (torch.nan_to_num)
// and the candidates cost <= min + float(tie_tol), chosen by the tie-break rule.

#include "ray_search_cpu.h"
#include "camera_views.h"
#include "tensor_checks.h"

#include <ATen/Parallel.h>
#include <ATen/ops/empty.h>

#include <cfloat>
#include <cmath>
#include <vector>

namespace stealth_ns {

namespace {

enum TieBreak : int64_t { kNearestSurface = 0, kFirst = 1, kMiddle = 2 };

struct Grid {
    const float *values;
    int64_t X, Y, Z;
    float ox, oy, oz, size, fX, fY, fZ, outside;

    float at(float x, float y, float z) const {
        const float u = (x - ox) / size, v = (y - oy) / size, w = (z - oz) / size;
        if (!(u >= 0.f && u <= fX && v >= 0.f && v <= fY && w >= 0.f && w <= fZ)) return outside;
        const int64_t i = std::min((int64_t)std::floor(u), X - 1), j = std::min((int64_t)std::floor(v), Y - 1),
                      k = std::min((int64_t)std::floor(w), Z - 1);
        return values[(i * Y + j) * Z + k];
    }
};

// torch.nan_to_num(x, nan=inf)
inline float finite_or_inf(float x) {
    if (std::isnan(x)) return INFINITY;
    if (std::isinf(x)) return x > 0 ? FLT_MAX : -FLT_MAX;
    return x;
}

// The chosen sample among costs c[0, n) (ray_search.py's _pick_index)
int64_t pick(const float *c, int64_t n, int64_t rule, float tol) {
    float lo = c[0];
    for (int64_t k = 1; k < n; ++k) lo = c[k] < lo ? c[k] : lo;
    const float limit = lo + tol;
    int64_t first = -1, last = -1;
    for (int64_t k = 0; k < n; ++k) {
        if (c[k] <= limit) {
            if (first < 0) first = k;
            last = k;
        }
    }
    if (first < 0) return rule == kNearestSurface ? n - 1 : 0;  // argmax of all-zero rows
    if (rule == kFirst) return first;
    if (rule == kNearestSurface) return last;
    int64_t end = n - 1;  // the first run of candidates ends before the first non-candidate after it
    for (int64_t k = first + 1; k < n; ++k) {
        if (!(c[k] <= limit)) {
            end = k - 1;
            break;
        }
    }
    return (first + end) / 2;
}

}  // namespace

std::vector<at::Tensor> ray_search(
    const at::Tensor &origins, const at::Tensor &dirs, const at::Tensor &t_min, const at::Tensor &t_max,
    const at::Tensor &frac, const at::Tensor &values, const at::Tensor &grid_origin, double voxel_size,
    double outside, const at::Tensor &viewmats, const at::Tensor &Ks, const std::vector<at::Tensor> &bounds,
    const at::Tensor &support_viewmats, const at::Tensor &support_Ks,
    const std::vector<at::Tensor> &support_bounds, double near_plane, int64_t tie_break, double tie_tol
) {
    for (const at::Tensor *t : {&origins, &dirs, &t_min, &t_max, &frac, &values, &grid_origin})
        check_cpu_f32(*t, "ray search input");
    TORCH_CHECK(origins.dim() == 2 && origins.size(1) == 3 && dirs.sizes() == origins.sizes(), "rays must be [M, 3]");
    const int64_t M = origins.size(0), n = frac.numel();
    TORCH_CHECK(t_min.numel() == M && t_max.numel() == M, "t_min and t_max must be [M]");
    TORCH_CHECK(n >= 1 && values.dim() == 3 && grid_origin.numel() == 3, "bad samples or grid");
    TORCH_CHECK(tie_break >= kNearestSurface && tie_break <= kMiddle, "bad tie-break");
    const std::vector<CameraView> innocent = camera_views(viewmats, Ks, bounds);
    const std::vector<CameraView> support = camera_views(support_viewmats, support_Ks, support_bounds);
    const float *go = grid_origin.data_ptr<float>();
    const Grid grid{values.data_ptr<float>(), values.size(0), values.size(1), values.size(2),
                    go[0], go[1], go[2], (float)voxel_size, (float)values.size(0), (float)values.size(1),
                    (float)values.size(2), (float)outside};  // fmt: skip
    const float fnear = (float)near_plane, tol = (float)tie_tol;
    const int32_t n_support = (int32_t)support.size();
    const float *o = origins.data_ptr<float>(), *d = dirs.data_ptr<float>(), *tn = t_min.data_ptr<float>(),
                *tf = t_max.data_ptr<float>(), *fr = frac.data_ptr<float>();
    at::Tensor index = at::empty({M}, origins.options().dtype(at::kLong));
    at::Tensor density = at::empty({M}, origins.options()), penalty = at::empty({M}, origins.options());
    int64_t *out_k = index.data_ptr<int64_t>();
    float *out_f = density.data_ptr<float>(), *out_pen = penalty.data_ptr<float>();
    at::parallel_for(0, M, 4, [&](int64_t r0, int64_t r1) {
        std::vector<float> pts(3 * n), f(n), cost(n);
        std::vector<int32_t> seen(n), seen_support(n);
        for (int64_t r = r0; r < r1; ++r) {
            const float span = tf[r] - tn[r];
            for (int64_t k = 0; k < n; ++k) {
                const float t = tn[r] + span * fr[k];
                float *p = pts.data() + 3 * k;
                for (int a = 0; a < 3; ++a) p[a] = o[3 * r + a] + t * d[3 * r + a];
                f[k] = grid.at(p[0], p[1], p[2]);
            }
            std::fill(seen.begin(), seen.end(), 0);
            std::fill(seen_support.begin(), seen_support.end(), 0);
            for (const CameraView &c : innocent) add_seen(c, pts.data(), 0, n, fnear, seen.data());
            for (const CameraView &c : support) add_seen(c, pts.data(), 0, n, fnear, seen_support.data());
            for (int64_t k = 0; k < n; ++k) {
                seen[k] += n_support - seen_support[k];
                cost[k] = finite_or_inf(2.0f * (float)seen[k] + f[k]);
            }
            const int64_t k = pick(cost.data(), n, tie_break, tol);
            out_k[r] = k;
            out_f[r] = f[k];
            out_pen[r] = (float)seen[k];
        }
    });
    return {index, density, penalty};
}

}  // namespace stealth_ns
