// Central differences of a scalar function against autograd, element by element (tests in
// double precision). One copy for every test folder that checks gradients.
#pragma once

#include <algorithm>
#include <cmath>
#include <functional>

#include <torch/torch.h>

namespace avatar::test {

struct GradientCheck {
  double worst_error = 0.0;       // max |finite difference - autograd| over the elements of x0
  double analytic_abs_sum = 0.0;  // sum |autograd gradient| (0 means nothing reached x0)
};

inline GradientCheck CheckGradient(const std::function<torch::Tensor(const torch::Tensor&)>& f,
                                   const torch::Tensor& x0, double h = 1e-6) {
  torch::Tensor x = x0.detach().clone().set_requires_grad(true);
  f(x).backward();
  const torch::Tensor analytic = x.grad().detach().flatten();
  GradientCheck check;
  check.analytic_abs_sum = analytic.abs().sum().item<double>();
  torch::Tensor flat = x0.detach().clone().flatten();
  for (int64_t i = 0; i < flat.numel(); ++i) {
    const double v = flat[i].item<double>();
    flat[i] = v + h;
    const double up = f(flat.view(x0.sizes())).item<double>();
    flat[i] = v - h;
    const double down = f(flat.view(x0.sizes())).item<double>();
    flat[i] = v;
    check.worst_error = std::max(check.worst_error, std::abs((up - down) / (2 * h) - analytic[i].item<double>()));
  }
  return check;
}

}  // namespace avatar::test
