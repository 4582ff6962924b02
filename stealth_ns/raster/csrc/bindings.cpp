// The Python module of the compiled CPU kernels: one binding per kernel (declared in the headers).
// Only this file includes torch's pybind11 glue; the kernels include ATen alone, which keeps the
// first build short (torch/extension.h is slow to parse: docs/cpu_rasterizer.md, "Compilation and cache").

#include "composite_cpu.h"
#include "densify_cpu.h"
#include "frustum_cpu.h"
#include "noise_cpu.h"
#include "project_cpu.h"
#include "rasterize_cpu.h"
#include "ray_search_cpu.h"
#include "ssim_cpu.h"
#include "visibility_cpu.h"
#include <ATen/ops/empty.h>

#include <torch/csrc/utils/pybind.h>

namespace py = pybind11;

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
    m.doc() = "stealth-ns compiled CPU kernels: rasterizer, projection + SH, SSIM, background composite, densification statistics, camera visibility, camera-proximity's depth ratios, the injection's ray search, view noise";
    m.def("rasterize_fwd", &stealth_ns::rasterize_fwd,
          py::arg("means2d"), py::arg("conics"), py::arg("colors"),
          py::arg("opacities"), py::arg("backgrounds"), py::arg("image_width"), py::arg("image_height"),
          py::arg("tile_size"), py::arg("isect_offsets"), py::arg("flatten_ids"), py::arg("cull") = true,
          py::arg("n_threads") = 0);
    m.def("rasterize_weights", &stealth_ns::rasterize_weights,
          py::arg("means2d"), py::arg("conics"), py::arg("colors"),
          py::arg("opacities"), py::arg("backgrounds"), py::arg("image_width"), py::arg("image_height"),
          py::arg("tile_size"), py::arg("isect_offsets"), py::arg("flatten_ids"), py::arg("cull") = true,
          py::arg("n_threads") = 0);
    m.def("rasterize_bwd", &stealth_ns::rasterize_bwd,
          py::arg("means2d"), py::arg("conics"), py::arg("colors"),
          py::arg("opacities"), py::arg("backgrounds"), py::arg("image_width"), py::arg("image_height"),
          py::arg("tile_size"), py::arg("isect_offsets"), py::arg("flatten_ids"), py::arg("T_final"),
          py::arg("last_ids"), py::arg("v_render_colors"), py::arg("v_render_alphas"), py::arg("cull") = true,
          py::arg("mode") = 0, py::arg("n_threads") = 0);
    m.def("isect_tiles", &stealth_ns::isect_tiles, py::arg("means2d"), py::arg("radii"), py::arg("depths"),
          py::arg("tile_size"), py::arg("tile_width"), py::arg("tile_height"), py::arg("n_threads") = 0,
          py::arg("conics") = at::empty({0}), py::arg("opacities") = at::empty({0}), py::arg("image_width") = 0,
          py::arg("image_height") = 0);
    m.def("project_fwd", &stealth_ns::project_fwd, py::arg("means"), py::arg("quats"), py::arg("scales"),
          py::arg("viewmats"), py::arg("Ks"), py::arg("width"), py::arg("height"), py::arg("eps2d"),
          py::arg("near_plane"), py::arg("far_plane"), py::arg("radius_clip"));
    m.def("project_bwd", &stealth_ns::project_bwd, py::arg("means"), py::arg("quats"), py::arg("scales"),
          py::arg("viewmats"), py::arg("Ks"), py::arg("width"), py::arg("height"), py::arg("eps2d"),
          py::arg("radii"), py::arg("v_means2d"), py::arg("v_depths"), py::arg("v_conics"));
    m.def("sh_fwd", &stealth_ns::sh_fwd, py::arg("means"), py::arg("viewmats"), py::arg("sh_dc"),
          py::arg("sh_rest"), py::arg("degree"), py::arg("radii"));
    m.def("sh_bwd", &stealth_ns::sh_bwd, py::arg("means"), py::arg("viewmats"), py::arg("sh_dc"),
          py::arg("sh_rest"), py::arg("degree"), py::arg("radii"), py::arg("v_colors"));
    m.def("ssim_fwd", &stealth_ns::ssim_fwd, py::arg("X"), py::arg("Y"), py::arg("win"), py::arg("C1"),
          py::arg("C2"), py::arg("need_grad"));
    m.def("ssim_bwd", &stealth_ns::ssim_bwd, py::arg("X"), py::arg("Y"), py::arg("win"), py::arg("dmaps"),
          py::arg("v_planes"), py::arg("l1_coef") = 0.0, py::arg("channels_last") = false);
    m.def("composite_fwd", &stealth_ns::composite_fwd, py::arg("render"), py::arg("alpha"), py::arg("background"));
    m.def("composite_bwd", &stealth_ns::composite_bwd, py::arg("render"), py::arg("alpha"), py::arg("background"),
          py::arg("v_rgb"));
    m.def("densify_stats", &stealth_ns::densify_stats,
          py::arg("grad2d"), py::arg("count"), py::arg("max_radii"),
          py::arg("grads"), py::arg("radii"), py::arg("scale_x"), py::arg("scale_y"), py::arg("size"));
    m.def("count_seeing", &stealth_ns::count_seeing, py::arg("points"), py::arg("viewmats"), py::arg("Ks"),
          py::arg("bounds"), py::arg("near_plane"));
    m.def("frustum_depth_ratios", &stealth_ns::frustum_depth_ratios, py::arg("points"), py::arg("viewmats"),
          py::arg("Ks"), py::arg("sizes"), py::arg("depths"));
    m.def("ray_search", &stealth_ns::ray_search, py::arg("origins"), py::arg("dirs"), py::arg("t_min"),
          py::arg("t_max"), py::arg("frac"), py::arg("values"), py::arg("grid_origin"), py::arg("voxel_size"),
          py::arg("outside"), py::arg("viewmats"), py::arg("Ks"), py::arg("bounds"), py::arg("support_viewmats"),
          py::arg("support_Ks"), py::arg("support_bounds"), py::arg("near_plane"), py::arg("tie_break"),
          py::arg("tie_tol"));
    m.def("normal_draw", &stealth_ns::normal_draw, py::arg("count"), py::arg("key"));
    m.def("noisy_u8", &stealth_ns::noisy_u8, py::arg("image"), py::arg("sigma"), py::arg("key"));
}
