// `avatar-studio bench model`: per-stage time and achieved GFLOP/s of the GOHA network for the
// paper and lite configs, the session's cached-frame vs full-recompute ratio, the rasterizer
// against brute force, and peak memory; every ratio against baselines measured in this run.

#include <iostream>

#include "app/cli_util.h"
#include "app/cmd_bench.h"
#include "core/tools/model_benchmark.h"
#include "core/util/error.h"

namespace avatar::app {

namespace {

struct BenchModelOptions {
  // Comma-separated configs: paper, lite, tiny.
  std::string configs = "paper,lite";
  // Timed runs per stage (after one warm-up); the median is reported.
  int repeats = 3;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("configs", configs, "Comma-separated configs: paper,lite,tiny");
    v("repeats", repeats, "Timed runs per stage (median reported)");
    common.Visit(v);
  }
  // The benchmark these options ask for.
  ModelBenchmarkOptions Bench() const {
    ModelBenchmarkOptions b;
    b.configs = SplitList(configs);
    b.repeats = repeats;
    return b;
  }
  void Validate() const {
    Bench().Validate();
    common.Validate();
  }
};

int RunBenchModelImpl(const BenchModelOptions& options, RunContext& ctx) {
  options.Validate();
  ModelBenchmarkListener listener;
  listener.started = [&](const ModelBenchmarkReport& r) {
    std::cout << "Model benchmark: " << r.threads << " threads, random weights, float32, inference mode, median of "
              << options.repeats << " runs after a warm-up.\nGEMM peak (fp32 1024^3, best of 5): "
              << Fixed(r.gemm_before, 1) << " GFLOP/s\n\n"
              << std::flush;
    std::cout << "Session (synthetic I_exp; times in s): full = reconstruct + frame with a new expression; "
                 "camera-only and preview reuse every plane.\n\n"
              << "| config | first reconstruct + final frame | full recompute | new expression | camera-only frame | "
                 "camera-only preview | final frame (SR) | full / camera-only | full / preview | peak RSS so far |\n"
              << "|---|---|---|---|---|---|---|---|---|---|\n";
  };
  listener.session = [](const SessionBenchmarkRow& r) {
    std::cout << "| " << r.config << " | " << Fixed(r.first_seconds, 2) << " | " << Fixed(r.full_seconds, 3) << " | "
              << Fixed(r.expression_seconds, 3) << " | " << Fixed(r.camera_only_seconds, 3) << " | "
              << Fixed(r.preview_seconds, 3) << " | " << Fixed(r.final_seconds, 3) << " | "
              << Fixed(r.full_seconds / r.camera_only_seconds, 1) << "x | "
              << Fixed(r.full_seconds / r.preview_seconds, 1) << "x | " << Fixed(r.peak_rss_mb, 0) << " MB ("
              << r.final_frame_size << "^2 frame) |" << std::endl;
  };
  listener.rasterizer = [](const RasterizerBenchmark& r) {
    const int64_t grid = r.grid;
    std::cout << "\n";
    std::cout << "Rasterization of a " << grid << "x" << grid << "-point cloud (256 features) onto three " << grid
              << "x" << grid
              << " grids, features gathered into [3,256,128,128]: " << Fixed(r.rasterize_seconds * 1e3, 1)
              << " ms (target <= 50 ms); one plane's k-d tree search " << Fixed(r.search_seconds * 1e3, 1)
              << " ms vs brute force " << Fixed(r.brute_force_seconds * 1e3, 0) << " ms ("
              << Fixed(r.brute_force_seconds / r.search_seconds, 0)
              << "x faster, identical indices: " << (r.identical ? "yes" : "NO") << ").\n\n";
    std::cout << "Stages (GEMM peak measured right before each stage, best of 3):\n\n"
              << "| config | stage | time (ms) | GFLOPs | GFLOP/s | GEMM peak (GFLOP/s) | of GEMM peak |\n"
              << "|---|---|---|---|---|---|---|\n";
  };
  listener.stages = [](const std::vector<StageBenchmarkRow>& rows) {
    double total_t = 0, total_f = 0, gemm_sum = 0;
    for (const auto& row : rows) {
      const double f = row.flops;
      const double t = row.seconds;
      total_t += t;
      total_f += f;
      gemm_sum += row.gemm_gflops * t;
      std::cout << "| " << row.config << " | " << row.stage << " | " << Fixed(t * 1e3, 1) << " | " << Fixed(f / 1e9, 2)
                << " | " << (f > 0 ? Fixed(f / t / 1e9, 1) : std::string("-")) << " | " << Fixed(row.gemm_gflops, 0)
                << " | " << (f > 0 ? Fixed(100.0 * f / t / 1e9 / row.gemm_gflops, 0) + "%" : std::string("-"))
                << " |" << std::endl;
    }
    if (rows.empty()) return;
    const double gemm_mean = gemm_sum / total_t;  // time-weighted
    std::cout << "| " << rows.front().config << " | **all stages** | " << Fixed(total_t * 1e3, 1) << " | "
              << Fixed(total_f / 1e9, 2) << " | " << Fixed(total_f / total_t / 1e9, 1) << " | " << Fixed(gemm_mean, 0)
              << " | " << Fixed(100.0 * total_f / total_t / 1e9 / gemm_mean, 0) << "% |" << std::endl;
  };
  const ModelBenchmarkReport report = RunModelBenchmark(options.Bench(), options.common.threads, ctx, listener);
  std::cout << "\nGEMM peak after the run: " << Fixed(report.gemm_after, 1)
            << " GFLOP/s. FLOPs are analytic (see `avatar-studio inspect`); render FLOPs count only the decoder MLP.\n";
  return kExitOk;
}

int RunBenchModel(const std::vector<std::string>& args) {
  return RunBenchSubject<BenchModelOptions>(
      args, "model",
      "Times every stage of the GOHA network (random weights), the session's cached frames\n"
      "against a full recompute, the rasterizer against brute force, and peak memory.",
      RunBenchModelImpl);
}

}  // namespace

AVATAR_REGISTER_BENCH_SUBJECT("model",
                              "GOHA network: per-stage time and GFLOP/s vs GEMM peak, cached vs full frames, "
                              "rasterizer, peak memory",
                              RunBenchModel);

}  // namespace avatar::app
