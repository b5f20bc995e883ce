#pragma once
// `avatar-studio bench train`: the stage-I training step (StageOneTrainer::Step, every loss term
// active: I_c, I_c+e, I_c+e+p, neutral, density TV) for model configs x batch sizes on synthetic
// batches. Per case: the median step time after warm-up steps, a forward-only pass of the same
// losses on the same batch (backward + update = step - forward), peak memory, and the GEMM rate
// measured right before the case. The tiny batch-1 case always runs first (the reference of
// every ratio), marked reference_only when it was not asked for.

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "core/util/run_context.h"

namespace avatar {

struct TrainBenchmarkOptions {
  // Model configs: tiny, cpu, lite, paper.
  std::vector<std::string> configs = {"tiny", "cpu", "lite"};
  // Batch sizes (1..64).
  std::vector<int64_t> batches = {1, 4};
  // Timed steps per case (median reported), after `warmup` untimed ones.
  int steps = 3;
  int warmup = 1;
  // Perceptual term of the image losses: mobilenet (as `train`), pyramid (stand-in), none.
  std::string perceptual = "mobilenet";
  // Results as JSON (written atomically); "" = none.
  std::string json;
  // Folder with the installed data ("" = AVATAR_DATA_DIR, then the default cache).
  std::string data_dir;

  // Throws InvalidOptions.
  void Validate() const;
};

inline constexpr int64_t kTrainBenchmarkGemmSize = 1024;

struct TrainBenchmarkCase {
  std::string config;
  int64_t batch = 0;
  std::vector<double> step_s, forward_s;  // every timed step
  double step = 0, forward = 0, backward = 0;  // medians; backward = step - forward
  double peak_rss_mb = 0, rss_growth_mb = 0;
  double gemm_gflops = 0;    // measured right before the case
  double last_loss = 0;
  double loss_rel_diff = 0;  // largest |forward loss - step loss| / |step loss|
  int64_t skipped = 0;       // non-finite steps
  bool reference_only = false;  // the tiny batch-1 reference, not asked for
  // Step time over one fp32 GEMM of kTrainBenchmarkGemmSize^3 at gemm_gflops.
  double StepOverGemm() const;
};

struct TrainBenchmarkReport {
  int threads = 0;
  double gemm_before = 0, gemm_after = 0;
  // true: peak RSS is the per-case high-water mark (VmHWM reset before each case); false: the
  // process's lifetime peak (getrusage).
  bool peak_resettable = false;
  double reference_step = 0;  // the tiny batch-1 step (s)
  std::vector<TrainBenchmarkCase> cases;
  double worst_loss_rel_diff = 0;
  std::string json_path;  // written, or ""
};

// What the caller hears while the benchmark runs (each may be empty).
struct TrainBenchmarkListener {
  std::function<void(const TrainBenchmarkReport&)> started;  // GEMM baseline measured
  // One case measured; `reference` is the tiny batch-1 step time.
  std::function<void(const TrainBenchmarkCase&, double reference)> measured;
};

// Runs the benchmark and writes options.json (when set). `threads` as the command line gives it
// (0 = the configured default). Throws InvalidOptions, MissingData (perceptual network), Io,
// InternalError (a non-finite forward loss), Cancelled.
TrainBenchmarkReport RunTrainBenchmark(const TrainBenchmarkOptions& options, int threads, RunContext& ctx,
                                       const TrainBenchmarkListener& listener = {});

}  // namespace avatar
