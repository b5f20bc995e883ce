#include "core/util/run_context.h"

#include <algorithm>

#include "core/util/error.h"

namespace avatar {

void RunContext::ThrowIfCancelled() const {
  if (IsCancelled()) throw Cancelled("cancelled by the user");
}

void RunContext::Report(const std::string& stage, double fraction, const std::string& message) {
  Progress progress;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const double local = std::clamp(fraction, 0.0, 1.0);
    progress.stage = stage;
    progress.fraction = range_begin_ + local * (range_end_ - range_begin_);
    progress.message = message;
    last_ = progress;
  }
  if (sink_) sink_(progress);
  ThrowIfCancelled();
}

Progress RunContext::Last() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return last_;
}

RunContext::ProgressRange::ProgressRange(RunContext& ctx, double begin, double end) : ctx_(ctx) {
  std::lock_guard<std::mutex> lock(ctx_.mutex_);
  saved_begin_ = ctx_.range_begin_;
  saved_end_ = ctx_.range_end_;
  const double span = saved_end_ - saved_begin_;
  ctx_.range_begin_ = saved_begin_ + std::clamp(begin, 0.0, 1.0) * span;
  ctx_.range_end_ = saved_begin_ + std::clamp(end, 0.0, 1.0) * span;
}

RunContext::ProgressRange::~ProgressRange() {
  std::lock_guard<std::mutex> lock(ctx_.mutex_);
  ctx_.range_begin_ = saved_begin_;
  ctx_.range_end_ = saved_end_;
}

}  // namespace avatar
