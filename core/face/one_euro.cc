#include "core/face/one_euro.h"

#include <cmath>

namespace avatar::face {
namespace {

double Alpha(double cutoff, double dt) {
  const double tau = 1.0 / (2.0 * M_PI * cutoff);
  return 1.0 / (1.0 + tau / dt);
}

}  // namespace

double OneEuroFilter::Filter(double x, double t) {
  if (!initialised_) {
    initialised_ = true;
    x_prev_ = x;
    dx_prev_ = 0.0;
    t_prev_ = t;
    return x;
  }
  if (!(t > t_prev_)) return x_prev_;  // repeated or out-of-order time: keep the last estimate
  const double dt = t - t_prev_;
  const double dx = (x - x_prev_) / dt;
  const double a_d = Alpha(params_.d_cutoff, dt);
  const double dx_hat = a_d * dx + (1.0 - a_d) * dx_prev_;
  const double cutoff = params_.min_cutoff + params_.beta * std::abs(dx_hat);
  const double a = Alpha(cutoff, dt);
  const double x_hat = a * x + (1.0 - a) * x_prev_;
  x_prev_ = x_hat;
  dx_prev_ = dx_hat;
  t_prev_ = t;
  return x_hat;
}

}  // namespace avatar::face
