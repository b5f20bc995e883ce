#pragma once
// The One-Euro filter (Casiez, Roussel, Vogel, CHI 2012): an adaptive low-pass filter whose
// cutoff rises with the signal's speed, so slow jitter is smoothed and fast motion lags little.
//   cutoff = min_cutoff + beta * |dx/dt| (dx/dt itself low-passed at d_cutoff), alpha from cutoff.

namespace avatar::face {

struct OneEuroParams {
  double min_cutoff = 1.0;  // Hz: cutoff at rest (lower = smoother, more lag when slow).
  double beta = 0.05;       // Cutoff increase per unit/s of speed (higher = less lag when fast).
  double d_cutoff = 1.0;    // Hz: cutoff of the speed estimate.
};

class OneEuroFilter {
 public:
  explicit OneEuroFilter(const OneEuroParams& params = {}) : params_(params) {}
  // Filters `x` observed at time `t` seconds (t must increase; the first call passes x through).
  double Filter(double x, double t);
  void Reset() { initialised_ = false; }

 private:
  OneEuroParams params_;
  bool initialised_ = false;
  double x_prev_ = 0.0;
  double dx_prev_ = 0.0;
  double t_prev_ = 0.0;
};

}  // namespace avatar::face
