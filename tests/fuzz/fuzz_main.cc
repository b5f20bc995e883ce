// libFuzzer entry points for the one target linked into a fuzz_<name> executable.
//
// AVATAR_FUZZ_MAKE_SEEDS=DIR: write the target's seed inputs into DIR and exit (scripts/fuzz
// makes the seed corpus this way before fuzzing).
#include <ATen/Parallel.h>
#include <opencv2/core.hpp>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>

#include "fuzz_common.h"

// The fuzz build links core/pipeline/avatar_file.cc without the session (core/pipeline/session.cc),
// which owns the avatar id counter.
namespace avatar {
uint64_t NextAvatarId() {
  static std::atomic<uint64_t> next{0};
  return ++next;
}
}  // namespace avatar

namespace {

const avatar::fuzz::Target& TheTarget() {
  const auto& targets = avatar::fuzz::Targets();
  if (targets.size() != 1) {
    std::fprintf(stderr, "fuzz executable must link exactly one target, has %zu\n", targets.size());
    std::abort();
  }
  return targets.front();
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int* /*argc*/, char*** /*argv*/) {
  // One thread: findings reproduce, and the fuzzer shares the machine.
  at::set_num_threads(1);
  cv::setNumThreads(0);
  const auto& target = TheTarget();
  if (const char* dir = std::getenv("AVATAR_FUZZ_MAKE_SEEDS"); dir != nullptr && *dir != '\0') {
    std::filesystem::create_directories(dir);
    const int n = target.make_seeds(dir);
    std::printf("%s: %d seeds written to %s\n", target.name.c_str(), n, dir);
    // Each seed goes through the parser once: valid seeds should say "accepted".
    for (const auto& entry : std::filesystem::directory_iterator(dir)) {
      const std::string error = target.run(avatar::fuzz::ReadFile(entry.path()));
      std::printf("  %s (%zu bytes): %s\n", entry.path().filename().c_str(),
                  static_cast<size_t>(std::filesystem::file_size(entry.path())),
                  error.empty() ? "accepted" : error.substr(0, 300).c_str());
    }
    std::exit(n > 0 ? 0 : 1);
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto& target = TheTarget();
  try {
    target.run(std::string_view(reinterpret_cast<const char*>(data), size));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: escaped exception (not avatar::Error): %s\n", target.name.c_str(), e.what());
    std::abort();
  } catch (...) {
    std::fprintf(stderr, "%s: escaped exception of unknown type\n", target.name.c_str());
    std::abort();
  }
  return 0;
}
