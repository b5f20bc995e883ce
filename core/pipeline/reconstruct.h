#pragma once
// The one reconstruction entry of the studio, `reconstruct` and `animate`: the portrait's
// analysis (once), the network's one-shot planes, then the refinement the options ask for. Which
// refinement runs is decided here and nowhere else:
//   an explicit refinement (ReconstructionOptions::refine enabled) > the quality level's > none.

#include <optional>
#include <string>

#include <opencv2/core.hpp>

#include "core/pipeline/refine.h"
#include "core/pipeline/session.h"
#include "core/pipeline/source_analysis.h"
#include "core/util/run_context.h"

namespace avatar {

struct ReconstructionOptions {
  // Quality level (core/pipeline/quality.h: instant ... best, paper); "" = the one-shot planes
  // rendered at the model's own size (SR when trained).
  std::string quality;
  // Refinement asked for explicitly (the --refine-* flags); when enabled it wins over the
  // quality level's steps. Off by default.
  RefineOptions refine = NoRefinement();
  // Folder with the installed data ("" = AVATAR_DATA_DIR, then the default cache).
  std::string data_dir;

  static RefineOptions NoRefinement() {
    RefineOptions r;
    r.steps = 0;
    return r;
  }
  // Throws InvalidOptions (unknown quality level, bad refinement options).
  void Validate() const;
};

// The refinement that runs for `options` (steps 0 and seconds 0 = none), by the precedence above.
RefineOptions EffectiveRefinement(const ReconstructionOptions& options);

struct Reconstruction {
  SourceAnalysis analysis;                 // the portrait's one analysis
  Avatar avatar;                           // one-shot planes, refined when a refinement ran
  std::optional<RefineResult> refinement;  // what the refinement did (when one ran)
  std::optional<RenderSettings> render;    // the quality level's frame settings (when one is chosen)
};

// Analyses `bgr` (BGR8) and reconstructs it. Progress: analysis 0..0.4, one-shot 0.4..0.5 (to 1.0
// without refinement), refinement 0.5..1.0. Throws InvalidOptions, InvalidInput (no face),
// MissingData, Cancelled.
Reconstruction ReconstructPortrait(const Session& session, const cv::Mat& bgr, const ReconstructionOptions& options,
                                   RunContext& ctx);

// The same from an analysis already made (the studio analyses once for whichever renderer shows
// the portrait). Progress: one-shot 0..0.1 (to 1.0 without refinement), refinement 0.1..1.0.
Reconstruction ReconstructAnalysed(const Session& session, SourceAnalysis analysis,
                                   const ReconstructionOptions& options, RunContext& ctx);

}  // namespace avatar
