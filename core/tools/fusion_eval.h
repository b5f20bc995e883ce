#pragma once
// Evaluation of the detail path's rows on a fusion set's split (core/tools/fusion_set.h): the
// bicubic network render, the morphable preview, the geometric composite and (with weights) the
// fusion net's output, each against the target frame, per pair kind (clip / photo) and per bucket
// of the target's yaw relative to the source (0-10, 10-20, 20-35, 35+ degrees), over the whole
// frame and inside / outside the valid-warp mask (where either warp's weight is above 0.5).

#include <string>
#include <vector>

#include "core/util/run_context.h"

namespace avatar {

struct FusionEvalOptions {
  std::string data;         // fusion set folder
  std::string split = "val";
  std::string weights;      // fusion net weights ("" = no learned row)
  std::string sheet;        // contact sheet PNG ("" = none): network | preview | composite | learned | target
  int sheet_rows = 8;
  // CSIM and AED (core/tools/face_metrics.h) of every path against the target on whole frames (a
  // face analysis and expression fit per image: slow).
  bool face_metrics = false;
  std::string data_dir;     // MobileNetV2 weights for the perceptual distance, the face models

  template <typename V>
  void Visit(V&& v) {
    v("data", data, "Fusion set folder");
    v("split", split, "Split: val or train");
    v("weights", weights, "Fusion net weights for the learned row");
    v("sheet", sheet, "Contact sheet PNG of validation frames");
    v("sheet_rows", sheet_rows, "Frames on the contact sheet");
    v("face_metrics", face_metrics, "Also CSIM and AED of every path on whole frames (slow)");
  }
  void Validate() const;
};

struct FusionEvalRow {
  std::string kind;    // clip, photo
  std::string bucket;  // 0-10, 10-20, 20-35, 35+, all
  std::string region;  // frame, valid warp, outside warp
  std::string path;    // network (bicubic), morphable preview, geometric composite, learned fusion
  int64_t pairs = 0;
  double psnr = 0, ssim = 0, l1 = 0, perceptual = 0;
  // With face_metrics (whole frames): pairs with a face in the output and the target,
  // and their mean identity cosine and expression distance.
  int64_t face_pairs = 0;
  double csim = 0, aed = 0;
};

struct FusionEvalReport {
  std::vector<FusionEvalRow> rows;
  std::string weights_info;  // step and fingerprint of the fusion weights
  int64_t samples = 0;
};

// Throws InvalidOptions, Io, InvalidInput (empty split), ModelLoad.
FusionEvalReport EvaluateFusionSet(const FusionEvalOptions& options, RunContext& ctx);
// The report as Markdown tables (one per kind and region).
std::string FusionEvalMarkdown(const FusionEvalReport& report);

}  // namespace avatar
