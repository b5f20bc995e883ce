#pragma once
// `avatar-studio bench accuracy`: what waiting buys. On validation portraits of a dataset built
// by `avatar-studio dataset build` (the photo pairs of the val split: one portrait per identity),
// for every quality level (core/pipeline/quality.h) and for a sweep of refinement steps at the
// model's own render settings, it measures
//   reconstruct seconds  the one-shot forward (T_c, T_p) + the refinement, wall clock;
//   frame seconds        the median of the three renders below (expression planes cached);
//   PSNR, SSIM, perceptual at the source view: the render at the source camera C_s against the
//                        matted source, both at the model's SR size (renders resized bicubically),
//                        as `eval` computes them (EvaluationImageMetrics); PSNR (matte) weights by
//                        the person matte;
//   CSIM at yaw +-30     fr_feature cosine similarity of the renders turned 30 degrees either way
//                        (CameraForView about C_s) against the source portrait (FaceMetrics).
// With --detail head (the default) or face, every quality level gets a twin row "LEVEL + detail":
// the same avatar and render settings finished by the photo's detail path (DetailFrameSource
// over the network frames, built from the dataset record's crop and morphable fit), frames at the
// comparison size; its reconstruct seconds add the detail path's bake (the source-view depth).
// Refinement depends only on the steps, so each distinct step count is run once per portrait and
// shared by every row that asks for it. Outputs in OUT (atomically): accuracy.md (table),
// accuracy.json (means and per-portrait values) and accuracy.png (accuracy against seconds).

#include <functional>
#include <string>
#include <vector>

#include "core/pipeline/quality.h"
#include "core/util/run_context.h"

namespace avatar {

struct AccuracyBenchmarkOptions {
  // Model checkpoint ("" = the installed or bundled model).
  std::string checkpoint;
  // Dataset folder written by `avatar-studio dataset build` (its val split is read, never written).
  std::string data;
  // Validation portraits (photo pairs, one per identity).
  int portraits = 4;
  // Output folder.
  std::string out = "bench-accuracy";
  // Comma-separated quality levels, or "all".
  std::string quality = "all";
  // Comma-separated refinement steps of the sweep at the model's render settings ("" = no sweep).
  std::string refine_steps = "0,10,30,100";
  // Head turn of the identity renders, degrees (renders at +yaw and -yaw).
  double yaw = 30.0;
  // Compute the perceptual distance (MobileNetV2 features).
  bool perceptual = true;
  // Compute CSIM (face detection, landmarks and fr_feature on every turned render).
  bool face_metrics = true;
  // Detail path of the "+ detail" rows: head, face, or off (no such rows).
  std::string detail = "head";
  // Folder with the installed data ("" = AVATAR_DATA_DIR, then the default cache).
  std::string data_dir;
  // LibTorch threads as the command line gives them (0 = the configured default).
  int threads = 0;

  template <typename V>
  void Visit(V&& v) {
    v("checkpoint", checkpoint, "Model checkpoint (default: the installed or bundled model)");
    v("data", data, "Dataset folder from 'avatar-studio dataset build' (its val split is read)", 'd');
    v("portraits", portraits, "Validation portraits to use (photo pairs, one per identity)");
    v("out", out, "Output folder (accuracy.md, accuracy.json, accuracy.png)", 'o');
    v("quality", quality, "Comma-separated quality levels, or all");
    v("refine_steps", refine_steps, "Comma-separated refinement steps of the sweep at the model's render settings");
    v("yaw", yaw, "Head turn of the CSIM renders in degrees (+yaw and -yaw)");
    v("perceptual", perceptual, "Compute the perceptual distance (MobileNetV2 features)");
    v("face_metrics", face_metrics, "Compute CSIM at the turned views");
    v("detail", detail, "Detail path of the '+ detail' twin of every quality level: head, face, or off (no twins)");
  }

  // The refinement steps of the sweep. Throws InvalidOptions.
  std::vector<int> Steps() const;
  // The quality levels asked for, in ladder order for "all". Throws InvalidOptions.
  std::vector<const QualityLevel*> Levels() const;
  // Throws InvalidOptions.
  void Validate() const;
};

struct AccuracyBenchmarkReport {
  std::string markdown;  // the table file's text
  std::string markdown_path, json_path, plot_path;
};

// Runs the benchmark and writes the outputs. `notes` (may be empty) gets a line at the start and
// one per portrait (progress for the user). Throws InvalidOptions; Io (no dataset folder, output
// folder); ModelLoad; InvalidInput (a val split without portraits, a corrupt dataset);
// MissingData (perceptual or face models); Cancelled.
AccuracyBenchmarkReport RunAccuracyBenchmark(const AccuracyBenchmarkOptions& options, RunContext& ctx,
                                             const std::function<void(const std::string&)>& notes = {});

}  // namespace avatar
