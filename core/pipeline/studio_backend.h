#pragma once
// The one place that decides what renders the head for a portrait, shared by the studio
// and the command line. The choice is honest:
//  - the neural session only when trained weights exist, or when the user explicitly asks
//    for random weights (labelled "random weights, not a result");
//  - otherwise the textured morphable-model preview, labelled as a preview;
//  - without face analysis / the morphable model in this build: the portrait itself.

#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "core/pipeline/driving.h"
#include "core/pipeline/frame_source.h"
#include "core/util/run_context.h"

namespace avatar {

struct BackendOptions {
  // Network configuration: "lite" (fast, CPU-sized) or "paper".
  std::string preset = "lite";
  // Use the neural network with random weights (a plumbing check, never a result).
  bool random_weights = false;
  // Folder with the installed models ("" = AVATAR_DATA_DIR or ~/.cache/avatar-studio).
  std::string data_dir;

  template <typename V>
  void Visit(V&& v) {
    v("preset", preset, "Network configuration: lite or paper");
    v("random_weights", random_weights,
      "Render with the untrained network's random weights (plumbing check; not a result)");
  }
  // Throws InvalidOptions for an unknown preset.
  void Validate() const;
};

// Builds the frame source for `portrait` (BGR8). Reports stages through ctx and honours
// cancel. Throws InvalidInput (no face), MissingData (models not installed), Cancelled.
std::shared_ptr<const FrameSource> CreateFrameSource(const cv::Mat& portrait, const BackendOptions& options,
                                                     RunContext& ctx);

// The analyser for driving videos (face tracking + morphable fit), or a factory returning
// null when this build cannot measure driving frames.
FrameAnalyzerFactory DrivingAnalyzers(const BackendOptions& options);

// A short sentence for the user about what renders the frames today.
std::string BackendStatement(const BackendOptions& options);

}  // namespace avatar
