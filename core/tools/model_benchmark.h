#pragma once
// `avatar-studio bench model`: the GOHA network's speed with random weights. Per config: the
// session (first reconstruct + final frame, full recompute, new expression, camera-only frames
// at the standard and preview render modes, a final frame with SR) and every network stage timed
// right after its own GEMM-peak measurement (achieved GFLOP/s against analytic FLOPs); once: the
// rasterizer's k-d tree search against brute force. Peak memory is taken after the first frame.

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "core/util/run_context.h"

namespace avatar {

struct ModelBenchmarkOptions {
  // Configs to measure (paper, lite, tiny, cpu), in order.
  std::vector<std::string> configs = {"paper", "lite"};
  // Timed runs per stage (after one warm-up); the median is reported.
  int repeats = 3;

  // Throws InvalidOptions (repeats, an unknown config).
  void Validate() const;
};

// Seconds per session step of one config.
struct SessionBenchmarkRow {
  std::string config;
  double first_seconds = 0.0;        // first reconstruct + final frame
  double full_seconds = 0.0;         // reconstruct + frame with a new expression
  double expression_seconds = 0.0;   // frame with a new expression
  double camera_only_seconds = 0.0;  // standard frame, new camera
  double preview_seconds = 0.0;      // preview frame, new camera
  double final_seconds = 0.0;        // final frame (SR), new camera
  double peak_rss_mb = 0.0;          // after the first frame
  int final_frame_size = 0;          // side of the final frame
};

// One network stage of one config.
struct StageBenchmarkRow {
  std::string config;
  std::string stage;
  double seconds = 0.0;      // median
  double flops = 0.0;        // analytic (0 = not counted)
  double gemm_gflops = 0.0;  // GEMM peak measured right before
};

struct RasterizerBenchmark {
  int64_t grid = 128;             // grid x grid points, three grid x grid planes, 256 features
  double rasterize_seconds = 0.0;
  double search_seconds = 0.0;    // one plane's k-d tree search
  double brute_force_seconds = 0.0;
  bool identical = false;         // the two searches give the same indices
};

struct ModelBenchmarkReport {
  int threads = 0;
  double gemm_before = 0.0, gemm_after = 0.0;
  std::vector<SessionBenchmarkRow> sessions;
  RasterizerBenchmark rasterizer;
  std::vector<StageBenchmarkRow> stages;
};

// What the caller hears while the benchmark runs (each may be empty).
struct ModelBenchmarkListener {
  std::function<void(const ModelBenchmarkReport&)> started;         // GEMM baseline measured
  std::function<void(const SessionBenchmarkRow&)> session;          // one config's session row
  std::function<void(const RasterizerBenchmark&)> rasterizer;       // after the session rows
  std::function<void(const std::vector<StageBenchmarkRow>&)> stages;  // one config's stage rows
};

// Runs the benchmark. `threads` as the command line gives it (0 = the configured default).
// Throws InvalidOptions, Cancelled.
ModelBenchmarkReport RunModelBenchmark(const ModelBenchmarkOptions& options, int threads, RunContext& ctx,
                                       const ModelBenchmarkListener& listener = {});

}  // namespace avatar
