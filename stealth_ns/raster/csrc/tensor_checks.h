// Argument checks shared by the compiled CPU kernels: one message per failed property.
#pragma once

#include <ATen/core/Tensor.h>

namespace stealth_ns {

inline void check_cpu_f32(const at::Tensor &t, const char *name) {
    TORCH_CHECK(t.device().is_cpu(), name, " must be a CPU tensor");
    TORCH_CHECK(t.scalar_type() == at::kFloat, name, " must be float32");
    TORCH_CHECK(t.is_contiguous(), name, " must be contiguous");
}

inline void check_cpu_f64(const at::Tensor &t, const char *name) {
    TORCH_CHECK(t.device().is_cpu(), name, " must be a CPU tensor");
    TORCH_CHECK(t.scalar_type() == at::kDouble, name, " must be float64");
    TORCH_CHECK(t.is_contiguous(), name, " must be contiguous");
}

inline void check_cpu_i32(const at::Tensor &t, const char *name) {
    TORCH_CHECK(t.device().is_cpu(), name, " must be a CPU tensor");
    TORCH_CHECK(t.scalar_type() == at::kInt, name, " must be int32");
    TORCH_CHECK(t.is_contiguous(), name, " must be contiguous");
}

}  // namespace stealth_ns
