#pragma once
// The measurements behind `avatar-studio bench SUBJECT`: each subject is an option struct and a
// function that measures and returns the figures; app/ prints them. Every subject measures this
// machine's baseline (the fp32 GEMM rate) in the same run, because the machines are shared and
// noisy: the ratios stay comparable where the times do not.

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "core/util/measure.h"
#include "core/util/run_context.h"
#include "core/util/text.h"

namespace avatar {

// ---------------------------------------------------------------------------- bench render

// The render cases of `bench render`, in table order: paper, medium, small, tiny.
std::vector<std::string> RenderBenchmarkCases();

struct RenderBenchmarkOptions {
  // Comma-separated cases: paper, medium, small, tiny (or "all").
  std::string cases = "all";
  // Timed renders per case (after one warm-up); the median is reported.
  int repeats = 3;
  // Cameras rendered together.
  int batch = 1;
  // Rays per parallel work item.
  int chunk_rays = 256;

  template <typename V>
  void Visit(V&& v) {
    v("cases", cases, "Comma-separated cases: paper,medium,small,tiny or all");
    v("repeats", repeats, "Timed renders per case (median reported)");
    v("batch", batch, "Cameras rendered together");
    v("chunk_rays", chunk_rays, "Rays per parallel work item");
  }
  // Throws InvalidOptions.
  void Validate() const;
};

// One case's figures (random tri-planes and decoder, deterministic sampling, no gradients).
struct RenderBenchmarkRow {
  std::string name;  // the case (RenderBenchmarkCases())
  int64_t batch = 1;
  int resolution = 0;                  // rays per camera: resolution^2
  int num_coarse = 0, num_importance = 0;
  int plane_size = 0;                  // planes 3 x 32 x plane_size^2
  double median_seconds = 0.0;
  double rays_per_second = 0.0, samples_per_second = 0.0;
  // Shares of the thread-summed renderer time: plane sampling, decoder, the rest.
  double sample_share = 0.0, decoder_share = 0.0, other_share = 0.0;
  double decoder_gflops = 0.0;         // decoder FLOPs / (thread-summed decoder time / threads)
};

struct RenderBenchmarkReport {
  int threads = 0;
  double gemm_before = 0.0, gemm_after = 0.0;  // GFLOP/s
  std::vector<RenderBenchmarkRow> rows;
};

// Runs the render benchmark. `on_start` (may be empty) is called once the GEMM baseline is
// measured, with the report so far; `on_row` (may be empty) with each row as it is measured.
// `threads` as the command line gives it (0 = the configured default). Throws InvalidOptions,
// InternalError (non-finite render), Cancelled.
RenderBenchmarkReport RunRenderBenchmark(const RenderBenchmarkOptions& options, int threads, RunContext& ctx,
                                         const std::function<void(const RenderBenchmarkReport&)>& on_start = {},
                                         const std::function<void(const RenderBenchmarkRow&)>& on_row = {});

// ---------------------------------------------------------------------------- bench face

struct FaceBenchmarkOptions {
  // Timed repetitions per photo (after one warm-up); medians are reported.
  int repeats = 5;
  // Frames of the clip tracked for the video rate.
  int frames = 100;
  // Folder with the installed data ("" = AVATAR_DATA_DIR, then the default cache).
  std::string data_dir;

  template <typename V>
  void Visit(V&& v) {
    v("repeats", repeats, "Timed repetitions per photo (median reported)");
    v("frames", frames, "Frames of franck.mp4 tracked for the video rate");
  }
  // Throws InvalidOptions.
  void Validate() const;
};

struct FaceBenchmarkStage {
  std::string photo;   // file name under samples/
  std::string stage;   // an analyser stage, or "total"
  double median_ms = 0.0;
};

struct FaceBenchmarkReport {
  double gemm_gflops = 0.0;
  double model_load_ms = 0.0;
  std::vector<FaceBenchmarkStage> stages;  // per photo (grace_hopper.jpg, sample1.jpg), in stage order
  int tracked_frames = 0;                  // of franck.mp4
  double track_ms_per_frame = 0.0;         // decode included
};

// Per-stage times of the portrait analysis on two packaged photos and the tracking rate on the
// first frames of a clip. Throws InvalidOptions, MissingData, Cancelled.
FaceBenchmarkReport RunFaceBenchmark(const FaceBenchmarkOptions& options, RunContext& ctx);

// ---------------------------------------------------------------------------- bench morphable

struct MorphableBenchmarkOptions {
  // Timed repetitions (median reported).
  int repeats = 5;
  // Frames of the sequence fit.
  int frames = 50;
  // Folder with the installed data ("" = AVATAR_DATA_DIR, then the default cache).
  std::string data_dir;

  template <typename V>
  void Visit(V&& v) {
    v("repeats", repeats, "Timed repetitions (median reported)");
    v("frames", frames, "Frames of the sequence fit");
  }
  // Throws InvalidOptions.
  void Validate() const;
};

// Milliseconds (medians after a warm-up) of the morphable model's stages.
struct MorphableBenchmarkReport {
  int identity_components = 0, expression_components = 0;
  double gemm_gflops = 0.0;
  double gemm_ms = 0.0;                  // one fp32 1024^3 GEMM at that rate
  double fit_ms = 0.0;                   // Fit, one 512 crop, 468 landmarks
  double texture_ms = 0.0;               // SampleTexture, 256^2 UV
  double render_ms = 0.0;                // RenderNeutral 512^2
  double render_supersampled_ms = 0.0;   // the same with 2x2 supersampling
  double render_256_ms = 0.0;            // RenderExpressionImage 256^2
  double sequence_ms_per_frame = 0.0;    // FitSequence over options.frames frames
};

// Fitting, texture and rendering speed on synthetic landmarks of the installed morphable model
// (no face analysis). Throws InvalidOptions, MissingData, Cancelled.
MorphableBenchmarkReport RunMorphableBenchmark(const MorphableBenchmarkOptions& options, RunContext& ctx);

}  // namespace avatar
