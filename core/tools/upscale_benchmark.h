#pragma once
// `avatar-studio bench upscale`: the 256 -> 512 step of exports (issue 33). On a built dataset's
// validation split it measures every upscaler (compose/upscaler.h) two ways:
//   real frames    the val clip targets at the dataset size (matted onto black), reduced to half
//                  (area) and brought back by each upscaler: PSNR / SSIM / perceptual against
//                  the frame itself, over the whole frame and (PSNR) inside the person matte;
//   detail frames  for val clip pairs, the detail path's frame of the target camera and
//                  expression rendered at half size and upscaled, against the same frame rendered
//                  directly at full size (the alternative: run the detail path at 512), both
//                  compared with the real target frame.
// Seconds per frame (median) and, for learned upscalers, GFLOP/s against the GEMM peak of the
// same run. Writes upscale.md, upscale.json and upscale.png (crops: target and each way) into
// --out, atomically.

#include <functional>
#include <string>

#include "core/util/run_context.h"

namespace avatar {

struct UpscaleBenchmarkOptions {
  std::string data;                       // dataset folder (dataset build)
  std::string out = "bench-upscale";      // output folder
  std::string upscalers = "bicubic,esrgan-slim";
  int frames = 48;                        // real val frames (clip targets, spread over the split)
  int detail_pairs = 8;                   // val clip pairs rendered through the detail path (0 = none)
  std::string checkpoint;                 // neural model of the detail frames ("" = installed or bundled)
  bool perceptual = true;
  std::string data_dir;
  int threads = 0;

  template <typename V>
  void Visit(V&& v) {
    v("data", data, "Dataset folder from 'avatar-studio dataset build' (its val split is read)", 'd');
    v("out", out, "Output folder (upscale.md, upscale.json, upscale.png)", 'o');
    v("upscalers", upscalers, "Comma-separated upscalers: bicubic, esrgan-slim");
    v("frames", frames, "Real validation frames (clip targets)");
    v("detail_pairs", detail_pairs, "Validation clip pairs rendered through the detail path (0 = none)");
    v("checkpoint", checkpoint, "Neural model of the detail frames (default: the installed or bundled model)");
    v("perceptual", perceptual, "Compute the perceptual distance (MobileNetV2 features)");
  }
  // Throws InvalidOptions.
  void Validate() const;
};

struct UpscaleBenchmarkReport {
  std::string markdown;
  std::string markdown_path, json_path, image_path;
};

// Throws InvalidOptions, Io (no dataset), InvalidInput (no val clip frames), MissingData,
// ModelLoad, Cancelled. `notes` gets progress lines.
UpscaleBenchmarkReport RunUpscaleBenchmark(const UpscaleBenchmarkOptions& options, RunContext& ctx,
                                           const std::function<void(const std::string&)>& notes = {});

}  // namespace avatar
