// `avatar-studio bench accuracy`: what waiting buys (core/tools/accuracy_benchmark.h). On
// validation portraits of a dataset, for every quality level and a sweep of refinement steps:
// reconstruct seconds, frame seconds, PSNR/SSIM/perceptual at the source view and CSIM at the
// turned views; writes accuracy.md, accuracy.json and accuracy.png into --out and prints the table.

#include <iostream>

#include "app/cmd_bench.h"
#include "core/tools/accuracy_benchmark.h"
#include "core/util/error.h"

namespace avatar::app {

namespace {

// Checkpoint, data, portraits, output folder, quality levels, sweep, yaw, metrics; threads, data folder, verbosity.
using BenchAccuracyOptions = BenchSubjectOptions<AccuracyBenchmarkOptions>;

int RunBenchAccuracyImpl(BenchAccuracyOptions options, RunContext& ctx) {
  options.Validate();
  options.bench.data_dir = options.common.data_dir;
  options.bench.threads = options.common.threads;
  const AccuracyBenchmarkReport r =
      RunAccuracyBenchmark(options.bench, ctx, [](const std::string& line) { std::cerr << line; });
  std::cout << r.markdown << "\nWrote " << r.markdown_path << ", " << r.json_path << " and " << r.plot_path << ".\n";
  return kExitOk;
}

int RunBenchAccuracy(const std::vector<std::string>& args) {
  return RunBenchSubject<BenchAccuracyOptions>(
      args, "accuracy",
      "On validation portraits of a dataset, for every quality level and a sweep of refinement steps:\n"
      "reconstruct seconds, frame seconds, PSNR/SSIM/perceptual at the source view and CSIM at yaw +-30;\n"
      "writes accuracy.md, accuracy.json and accuracy.png (accuracy against seconds) into --out.",
      RunBenchAccuracyImpl);
}

}  // namespace

AVATAR_REGISTER_BENCH_SUBJECT("accuracy",
                              "quality levels and refinement steps: seconds vs PSNR/SSIM/perceptual and CSIM",
                              RunBenchAccuracy);

}  // namespace avatar::app
