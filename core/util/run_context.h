#pragma once
// RunContext: what a long operation needs from its caller: a cancel flag that any
// thread may set, and a progress sink. The core calls ThrowIfCancelled() between
// stages and every few steps inside loops; Report() forwards progress to the sink.

#include <atomic>
#include <functional>
#include <mutex>
#include <string>

namespace avatar {

struct Progress {
  std::string stage;      // Short stage name, e.g. "detect faces".
  double fraction = 0.0;  // Overall completion in [0,1].
  std::string message;    // Optional detail for the user.
};

using ProgressSink = std::function<void(const Progress&)>;

class RunContext {
 public:
  RunContext() = default;
  explicit RunContext(ProgressSink sink) : sink_(std::move(sink)) {}
  RunContext(const RunContext&) = delete;
  RunContext& operator=(const RunContext&) = delete;

  // Thread-safe; may be called from a signal handler (only touches an atomic).
  void RequestCancel() noexcept { cancelled_.store(true, std::memory_order_relaxed); }
  bool IsCancelled() const noexcept { return cancelled_.load(std::memory_order_relaxed); }
  // Throws avatar::Cancelled if cancellation was requested.
  void ThrowIfCancelled() const;

  // Reports progress; `fraction` is clamped to [0,1] and mapped through the current
  // sub-range (see ProgressRange). Also checks for cancellation afterwards.
  void Report(const std::string& stage, double fraction, const std::string& message = {});

  // The most recent progress (for polling UIs and tests).
  Progress Last() const;

  // Maps local fractions [0,1] of a sub-task into [begin,end] of the parent's range.
  class ProgressRange {
   public:
    ProgressRange(RunContext& ctx, double begin, double end);
    ~ProgressRange();
    ProgressRange(const ProgressRange&) = delete;
    ProgressRange& operator=(const ProgressRange&) = delete;

   private:
    RunContext& ctx_;
    double saved_begin_;
    double saved_end_;
  };

 private:
  std::atomic<bool> cancelled_{false};
  ProgressSink sink_;
  mutable std::mutex mutex_;
  Progress last_;
  double range_begin_ = 0.0;
  double range_end_ = 1.0;
};

}  // namespace avatar
