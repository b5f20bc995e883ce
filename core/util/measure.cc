#include "core/util/measure.h"

#include <cmath>

#include <sys/resource.h>

#include <algorithm>

#include <torch/torch.h>

#include "core/util/error.h"
#include "core/util/timer.h"

namespace avatar {

double Median(std::vector<double> values) {
  AVATAR_CHECK_INPUT(!values.empty()) << "the median of no values is undefined";
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  return n % 2 == 1 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

double MeanOrNan(const std::vector<double>& values) {
  if (values.empty()) return std::nan("");
  double sum = 0.0;
  for (double x : values) sum += x;
  return sum / static_cast<double>(values.size());
}

double MedianSeconds(int repeats, RunContext& ctx, const std::function<void()>& fn) {
  AVATAR_CHECK_INPUT(repeats >= 1) << "a median of " << repeats << " timed runs is undefined";
  fn();
  std::vector<double> t;
  for (int i = 0; i < repeats; ++i) {
    ctx.ThrowIfCancelled();
    Timer timer;
    fn();
    t.push_back(timer.Seconds());
  }
  return Median(t);
}

double PeakRssMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // Linux reports kilobytes.
}

double MeasureGemmGflops(int64_t n, int repeats) {
  torch::NoGradGuard no_grad;
  const torch::Tensor a = torch::randn({n, n});
  const torch::Tensor b = torch::randn({n, n});
  torch::Tensor c = torch::mm(a, b);  // warm-up (allocations, BLAS threads)
  double best = 0.0;
  for (int i = 0; i < repeats; ++i) {
    Timer timer;
    torch::mm_out(c, a, b);
    const double seconds = timer.Seconds();
    best = std::max(best, 2.0 * static_cast<double>(n) * n * n / seconds / 1e9);
  }
  return best;
}

}  // namespace avatar
