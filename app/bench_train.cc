// `avatar-studio bench train`: the stage-I training step (StageOneTrainer::Step, every loss term
// active: I_c, I_c+e, I_c+e+p, neutral, density TV) for model configs x batch sizes on synthetic
// batches. Per case: the median step time after warm-up steps, a forward-only pass of the same
// losses on the same batch (backward + update = step - forward), samples/s, peak memory, and the
// step time as ratios to the tiny batch-1 step and to a GEMM measured right before the case.

#include <iostream>

#include "app/cli_util.h"
#include "app/cmd_bench.h"
#include "core/tools/train_benchmark.h"
#include "core/util/error.h"

namespace avatar::app {

namespace {

struct BenchTrainOptions {
  // Comma-separated model configs: tiny, cpu, lite, paper.
  std::string configs = "tiny,cpu,lite";
  // Comma-separated batch sizes.
  std::string batches = "1,4";
  // Timed steps per case (median reported), after `warmup` untimed ones.
  int steps = 3;
  int warmup = 1;
  // Perceptual term of the image losses: mobilenet (as `train`), pyramid (stand-in), none.
  std::string perceptual = "mobilenet";
  // Results as JSON (written atomically); "" = none.
  std::string json;
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("configs", configs, "Comma-separated model configs: tiny,cpu,lite,paper (paper: ~10 GB, ~30 s a step)");
    v("batches", batches, "Comma-separated batch sizes");
    v("steps", steps, "Timed training steps per case (median reported)");
    v("warmup", warmup, "Untimed warm-up steps per case");
    v("perceptual", perceptual, "Perceptual term: mobilenet (as train), pyramid (stand-in) or none");
    v("json", json, "Also write the results to this JSON file");
    common.Visit(v);
  }
  // The benchmark these options ask for. Throws InvalidOptions for a bad --batches list.
  TrainBenchmarkOptions Bench() const;
  void Validate() const;
};

std::vector<int64_t> ParseBatches(const std::string& text) {
  std::vector<int64_t> out;
  for (const auto& item : SplitList(text)) {
    size_t used = 0;
    long long value = 0;
    try {
      value = std::stoll(item, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    AVATAR_CHECK_OPTION(used == item.size() && value >= 1 && value <= 64)
        << "--batches takes comma-separated integers 1..64, got '" << item << "'";
    out.push_back(value);
  }
  AVATAR_CHECK_OPTION(!out.empty()) << "--batches is empty";
  return out;
}

TrainBenchmarkOptions BenchTrainOptions::Bench() const {
  TrainBenchmarkOptions b;
  b.configs = SplitList(configs);
  b.batches = ParseBatches(batches);
  b.steps = steps;
  b.warmup = warmup;
  b.perceptual = perceptual;
  b.json = json;
  b.data_dir = common.data_dir;
  return b;
}

void BenchTrainOptions::Validate() const {
  Bench().Validate();
  common.Validate();
}

int RunBenchTrainImpl(const BenchTrainOptions& options, RunContext& ctx) {
  options.Validate();
  const int64_t n = kTrainBenchmarkGemmSize;
  TrainBenchmarkListener listener;
  listener.started = [&](const TrainBenchmarkReport& r) {
    std::cout << "Training benchmark (stage I, StageOneTrainer::Step, every term: I_c, I_c+e, I_c+e+p, neutral, TV): "
              << r.threads << " threads, float32, random weights, synthetic batches, perceptual " << options.perceptual
              << ", median of " << options.steps << " steps after " << options.warmup << " warm-up.\n"
              << "GEMM peak (fp32 " << n << "^3, best of 5): " << Fixed(r.gemm_before, 1) << " GFLOP/s\n\n"
              << "| config | batch | step (s) | forward (s) | backward + update (s) | samples/s | peak RSS (MB) | "
                 "RSS growth (MB) | step / tiny b1 | GEMM (GFLOP/s) | step / GEMM |\n"
              << "|---|---|---|---|---|---|---|---|---|---|---|\n"
              << std::flush;
  };
  listener.measured = [](const TrainBenchmarkCase& r, double reference) {
    const double over_gemm = r.StepOverGemm();
    std::cout << "| " << r.config << (r.reference_only ? " (reference)" : "") << " | " << r.batch << " | "
              << Fixed(r.step, 3) << " | " << Fixed(r.forward, 3) << " | " << Fixed(r.backward, 3) << " | "
              << Fixed(static_cast<double>(r.batch) / r.step, 2) << " | " << Fixed(r.peak_rss_mb, 0) << " | "
              << Fixed(r.rss_growth_mb, 0) << " | " << Fixed(r.step / reference, 2) << "x | " << Fixed(r.gemm_gflops, 1)
              << " | " << Fixed(over_gemm, over_gemm < 100 ? 1 : 0) << "x |"
              << (r.skipped > 0 ? " (" + std::to_string(r.skipped) + " non-finite steps skipped)" : "") << std::endl;
  };
  const TrainBenchmarkReport report = RunTrainBenchmark(options.Bench(), options.common.threads, ctx, listener);
  std::cout
      << "\nGEMM peak after the run: " << Fixed(report.gemm_after, 1)
      << " GFLOP/s (a large change means the machine was busy).\n"
      << "forward = a forward-only pass of the same loss terms on the same batch (graph recorded, no backward; "
         "the trainer has no split; it drew the step's random numbers and its loss matched the step's to a relative "
         "difference of "
      << report.worst_loss_rel_diff << "); backward + update = step - forward (backward, gradient norm, clip, Adam).\n"
      << "step / GEMM = step time over the time of one fp32 " << n << "^3 GEMM at the rate measured "
      << "right before that case. "
      << (report.peak_resettable ? "peak RSS = the process's resident-set high-water mark during the case (VmHWM, "
                                   "reset before it); RSS growth = that peak minus the RSS at the case's start."
                                 : "peak RSS = the process's lifetime peak (getrusage ru_maxrss) after the case; "
                                   "RSS growth = its increase during the case (0 when an earlier case peaked higher).")
      << "\n";
  if (!report.json_path.empty()) std::cout << "Results written to " << report.json_path << "\n";
  return kExitOk;
}

int RunBenchTrain(const std::vector<std::string>& args) {
  return RunBenchSubject<BenchTrainOptions>(
      args, "train",
      "Times the stage-I training step (every loss term) on synthetic batches for model configs x\n"
      "batch sizes: step, forward and backward time, samples/s and peak memory, with every step\n"
      "time as a ratio to the tiny batch-1 step and to a GEMM measured in the same run.",
      RunBenchTrainImpl);
}

}  // namespace

AVATAR_REGISTER_BENCH_SUBJECT("train",
                              "stage-I training step per config x batch: step, forward/backward, samples/s, "
                              "peak RSS, ratios to tiny b1 and GEMM",
                              RunBenchTrain);

}  // namespace avatar::app
