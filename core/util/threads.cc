#include "core/util/threads.h"

#include <ATen/Parallel.h>
#include <opencv2/core.hpp>

#include <atomic>
#include <cstdlib>
#include <string>
#include <thread>

#include <unistd.h>

#include "core/util/error.h"
#include "core/util/logging.h"

namespace avatar {
namespace {
std::atomic<int> g_threads{0};
}  // namespace

int ConfigureThreads(int requested) {
  AVATAR_CHECK_OPTION(requested >= 0) << "thread count must be >= 0 (0 = all cores), got " << requested;
  int threads = requested;
  if (threads == 0) {
    if (const char* env = std::getenv("AVATAR_THREADS"); env != nullptr && *env != '\0') {
      char* end = nullptr;
      const long value = std::strtol(env, &end, 10);
      AVATAR_CHECK_OPTION(end != nullptr && *end == '\0' && value >= 0 && value <= 1024)
          << "AVATAR_THREADS='" << env << "' is not a thread count; use a number such as 2, or unset it";
      threads = static_cast<int>(value);
    }
  }
  if (threads == 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  at::set_num_threads(threads);
  cv::setNumThreads(threads);
  g_threads.store(threads);
  AVATAR_LOG(kDebug) << "LibTorch intra-op threads: " << threads;
  return threads;
}

int ConfiguredThreads() { return g_threads.load(); }

void ReexecWithPassiveOpenMpWait(char** argv) {
  if (std::getenv("OMP_WAIT_POLICY") != nullptr) return;
  if (::setenv("OMP_WAIT_POLICY", "PASSIVE", /*overwrite=*/0) != 0) return;
  ::execv("/proc/self/exe", argv);
  // Only reached if execv failed: go on with the policy libgomp already chose.
  AVATAR_LOG(kDebug) << "could not re-execute with OMP_WAIT_POLICY=PASSIVE; OpenMP threads spin-wait";
}

}  // namespace avatar
