#pragma once
// Cancels a job the way the studio's Cancel button does (another thread calls
// RunContext::RequestCancel while the job runs), at a chosen progress report, and records what the
// job reported before and after the request. Tests judge a cancel by events: the job threw
// Cancelled, how many reports came after the request, what it left behind. How many milliseconds
// the stop took is a benchmark's measure, not a test's.

#include <chrono>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "core/util/error.h"
#include "core/util/run_context.h"

namespace avatar::testing {

// A safety net against a cancel that is never honoured (the job would run on or hang): generous
// enough for a sanitizer build on a busy machine, so it measures no speed.
inline constexpr double kCancelHangLimitSeconds = 30.0;

struct CancelOutcome {
  bool requested = false;          // the trigger report came and the cancel was requested
  bool cancelled = false;          // the job threw avatar::Cancelled
  bool finished = false;           // the job returned normally
  std::string other_error;         // what() of any other exception ("" when none)
  std::string other_kind;          // its Error::Kind() ("model_load", ...; "exception" when not an Error)
  std::vector<Progress> reports;   // every report of the job, in order
  size_t reports_at_request = 0;   // how many of them came before RequestCancel
  double seconds_after_request = 0.0;  // from RequestCancel to the job's end (for the hang limit)

  size_t ReportsAfterRequest() const { return requested ? reports.size() - reports_at_request : 0; }
  std::string LastStage() const { return reports.empty() ? std::string() : reports.back().stage; }
  std::string Describe() const {
    std::string s = std::string("requested ") + (requested ? "yes" : "no") + ", cancelled " +
                    (cancelled ? "yes" : "no") + ", finished " + (finished ? "yes" : "no") +
                    (other_error.empty() ? "" : ", error: " + other_error) + "; reports:";
    for (size_t i = 0; i < reports.size(); ++i) {
      s += (i == reports_at_request && requested ? " [cancel requested]" : "");
      s += " " + reports[i].stage + " (" + reports[i].message + ")";
    }
    return s;
  }
};

// Runs job(ctx) on this thread. When report number `trigger` (0-based) arrives, a second thread
// requests the cancel, so that it lands while the job works on; should the job report again before
// that thread got to run, that report waits for the request (the cancel is never requested later
// than the report after the trigger, however busy the machine). With `max_reports_after` > 0 the
// sink throws once the job reported that many times after the request: a job that ignores the
// cancel ends with an error (outcome.other_error) instead of running on.
inline CancelOutcome RunAndCancelAtReport(const std::function<void(RunContext&)>& job, size_t trigger,
                                          size_t max_reports_after = 0) {
  using Clock = std::chrono::steady_clock;
  CancelOutcome out;
  std::mutex mutex;
  std::condition_variable requested_cv;
  std::thread canceller;
  Clock::time_point requested_at;
  RunContext ctx([&](const Progress& p) {
    std::unique_lock<std::mutex> lock(mutex);
    out.reports.push_back(p);
    const size_t n = out.reports.size();
    if (n == trigger + 1) {
      canceller = std::thread([&] {
        std::lock_guard<std::mutex> guard(mutex);
        out.reports_at_request = out.reports.size();
        requested_at = Clock::now();
        ctx.RequestCancel();
        out.requested = true;
        requested_cv.notify_all();
      });
    } else if (n > trigger + 1) {
      requested_cv.wait(lock, [&] { return out.requested; });
      if (max_reports_after > 0 && n - out.reports_at_request >= max_reports_after)
        throw std::runtime_error("the job reported " + std::to_string(n - out.reports_at_request) +
                                 " times after the cancel request and went on");
    }
  });
  try {
    job(ctx);
    out.finished = true;
  } catch (const Cancelled&) {
    out.cancelled = true;
  } catch (const Error& e) {
    out.other_error = e.what();
    out.other_kind = e.Kind();
  } catch (const std::exception& e) {
    out.other_error = e.what();
    out.other_kind = "exception";
  }
  const Clock::time_point end = Clock::now();
  if (canceller.joinable()) canceller.join();
  if (out.requested) out.seconds_after_request = std::chrono::duration<double>(end - requested_at).count();
  return out;
}

}  // namespace avatar::testing
