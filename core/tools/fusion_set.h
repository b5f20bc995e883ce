#pragma once
// The fusion net's training and validation data (issue 33): for pairs of a built dataset (two
// frames of one clip, or a photo with itself), the detail path of the source rendered at the
// target's camera and expression, with the 3D core frozen - computed once and stored, so that a
// training step costs only the 2D net.
//
// Layout of DIR:
//   fusion.json              options, the 3D core's fingerprint, counts per split (written last)
//   train/SOURCE.pt, val/SOURCE.pt
//                            one file per source frame (torch::save of a tensor list, see
//                            core/train/fusion_training.h): input uint8 [N,11,S,S]
//                            (fusion_input.h), target uint8 [N,3,S,S] (the target frame
//                            matted onto black, RGB), target matte uint8 [N,1,S,S], the
//                            morphable preview uint8 [N,3,S,S], meta float [N,4] (target minus
//                            source yaw and pitch in degrees, expression distance, pair kind
//                            0 photo / 1 clip / 2 synthetic)
//   train/SOURCE.json ...    the targets of each file, in order
// A file is written through a temporary name, so a cancelled build keeps whole sources and a
// rerun skips them.

#include <cstdint>
#include <string>

#include "core/util/run_context.h"

namespace avatar {

struct FusionSetOptions {
  // Dataset folder (`dataset build`; stored crops of 512 px give the detail path its inference input).
  std::string dataset;
  // Output folder.
  std::string out_dir;
  // Side of the stored frames (the fusion net's working size).
  int size = 256;
  // Source frames per clip (the clip frames with the most pairs first) and targets per source.
  int sources_per_clip = 24;
  int targets_per_source = 32;
  // Photo pairs (the source view of a photo) per split, at most (0 = none).
  int photos = 200;
  // Synthetic source views (training split only; dataset build --synthetic N), at most, each with
  // up to targets_per_source other views of its head (0 = none). Keep them a minority.
  int synthetic_sources = 0;
  // The 3D core ("" = the installed or bundled default model).
  std::string checkpoint;
  // Folder with the installed data ("" = AVATAR_DATA_DIR, then the default cache).
  std::string data_dir;
  // Print progress with ETA on stderr.
  bool print_progress = true;

  template <typename V>
  void Visit(V&& v) {
    v("data", dataset, "Dataset folder (dataset build --size 512)");
    v("out", out_dir, "Output folder of the fusion set");
    v("size", size, "Side of the stored frames");
    v("sources_per_clip", sources_per_clip, "Source frames per clip");
    v("targets_per_source", targets_per_source, "Target frames per source frame");
    v("photos", photos, "Photo pairs (source view) per split, at most");
    v("synthetic_sources", synthetic_sources, "Synthetic source views (training only), at most");
    v("checkpoint", checkpoint, "3D core checkpoint (default: the installed or bundled model)");
  }
  // Throws InvalidOptions.
  void Validate() const;
};

struct FusionSetReport {
  int64_t train_samples = 0, val_samples = 0;
  int64_t train_sources = 0, val_sources = 0;
  int64_t skipped = 0;        // sources or targets that failed (reasons on stderr and in build.log)
  double seconds = 0.0;       // wall time of this run
  double render_seconds = 0.0;  // time in the detail path's renders of this run
  std::string model;          // the 3D core's description
};

// Builds (or resumes) the fusion set. Throws InvalidOptions, Io, InvalidInput (a dataset without
// records or pairs), MissingData / ModelLoad (models), Cancelled (whole sources stay).
FusionSetReport BuildFusionSet(const FusionSetOptions& options, RunContext& ctx);

}  // namespace avatar
