#pragma once
// Building the morphable model from facemesh landmarks of real faces:
// - every shape is aligned to the canonical mesh (in model units) by a weighted similarity
//   transform on MediaPipe's rigid Procrustes points (generalised Procrustes, 2 rounds);
// - identity: one mean shape per distinct person (stills and clip means grouped by a key),
//   PCA over persons, plus documented smooth deformations where data is thin;
// - expression: per-clip mean removed from every frame, PCA; K by variance explained;
//   plus two one-sided eye-closing components (blinkLeft/blinkRight);
// - named controls: for each, the most probable expression change under the clips' PCA
//   statistics (minimum sum (beta_k/std_k)^2) that moves the named measured quantity (lip gap,
//   mouth corners, mouth width, brows, eyelids, lip protrusion; see measures.h) by its
//   median-to-98th-percentile step in the clips while holding the unrelated measures fixed.

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/face/face_types.h"
#include "core/morphable/morphable_model.h"
#include "core/util/run_context.h"

namespace avatar::morphable {

// Landmarks of one person.
struct BuildSource {
  std::string name;                     // e.g. "franck.mp4" or "sample1.jpg#2"
  std::string identity;                 // sources with the same key are one person
  bool is_clip = false;                 // clip frames feed the expression basis
  std::vector<face::Landmarks> shapes;  // facemesh landmarks (image pixels)
};

struct MorphableBuildOptions {
  // Expression components from PCA (0 = smallest K reaching expression_variance, within [24, 64]).
  int expression_components = 0;
  // Fraction of the expression variance the automatic K must explain.
  double expression_variance = 0.995;
  // Largest number of identity components taken from PCA over persons.
  int max_identity_components = 24;
  // Add the smooth identity deformations (face width, face length, jaw width, nose, eye spacing).
  bool smooth_deformations = true;

  template <typename V>
  void Visit(V&& v) {
    v("expression_components", expression_components, "Expression PCA components (0 = automatic)");
    v("expression_variance", expression_variance, "Variance fraction for the automatic expression K");
    v("max_identity_components", max_identity_components, "Largest number of identity PCA components");
    v("smooth_deformations", smooth_deformations, "Add smooth identity deformations (width, length, jaw, nose, eyes)");
  }
  void Validate() const;
};

struct MorphableBuildReport {
  int persons = 0;                                            // distinct identities
  int clip_frames = 0;                                        // frames in the expression PCA
  int identity_pca_components = 0;                            // identity components from data
  std::vector<double> expression_cumulative;                  // cumulative variance fraction for K = 1..64
  int expression_pca_components = 0;                          // chosen K
  std::vector<std::pair<std::string, double>> alignment_rms;  // per source: RMS residual after alignment (model units)
  nlohmann::json controls;                                    // per control: regressor, quantile step, R^2
  nlohmann::json ToJson() const;
};

// Builds the model. Throws InvalidInput when there are no clip frames (expression needs them)
// or no persons; Cancelled through ctx.
MorphableModel BuildMorphableModel(const Topology& topology, const std::vector<BuildSource>& sources,
                                   const MorphableBuildOptions& options, RunContext& ctx,
                                   MorphableBuildReport* report = nullptr);

// Similarity-aligns facemesh landmarks (image frame) to `reference` (model frame, 468 points) using
// the topology's Procrustes weights. Returns the aligned points in the model frame.
std::vector<cv::Point3f> AlignToReference(const face::Landmarks& landmarks, const std::vector<cv::Point3f>& reference,
                                          const Topology& topology, double* rms = nullptr);

}  // namespace avatar::morphable
