#pragma once
// Novel views without ground truth, the back end of `avatar-studio eval orbit PHOTO...`: each
// photo is reconstructed once (one analysis) and rendered at a row of camera yaws around its
// own pose by every path that can show it, and each render is scored against the photo:
//   network  the neural avatar alone (bicubic-upsampled volume render)
//   preview  the morphable preview (the fitted face mask, textured from the photo)
//   paste    the preview's face pasted over the network render by the preview's alpha (the
//            naive combination of the two)
//   face     the source-guided detail path on the face only (the face mesh's warp)
//   detail   the detail path on the head (the default: the face mesh's warp over the network
//            depth's warp of hair, ears and neck; core/compose, core/pipeline/detail_source.h)
// Scores per path and yaw:
//   identity  cosine of the identity embeddings (fr_feature, face_metrics.h) of render and photo
//   detail outside the face  mean |Laplacian| of the grey render over its opaque pixels outside
//            the convex hull of its face landmarks (eroded 3 px from both borders), as a fraction
//            of the same measure on the photo's aligned crop at the same size within its matte:
//            how much of the photo's hair, ear and neck texture survives (1 = as sharp as the
//            photo, 0 = flat)
//   mouth opening at the source view with the control `jaw_control` at `jaw_value` minus the
//            neutral render's, from the landmarks of each render (MouthOpening).
// A render without a detected face counts in `found`, never in the means. Writes OUT/orbit.md,
// OUT/orbit.json and OUT/orbit.png (photo | one row per path at each yaw, first photos).

#include <string>
#include <vector>

#include "core/tools/face_metrics.h"
#include "core/util/run_context.h"

namespace avatar {

struct OrbitEvalOptions {
  // Portrait photos to reconstruct and orbit.
  std::vector<std::string> photos;
  // Output folder (created).
  std::string out = "eval-orbit";
  // Camera yaw offsets from the photo's own pose, degrees, comma-separated.
  std::string yaws = "-30,-15,0,15,30";
  // Output size of every render (square).
  int size = 256;
  // The expression control opened for the mouth measure, and its value.
  std::string jaw_control = "jawOpen";
  double jaw_value = 0.9;
  // Photos shown in orbit.png.
  int contact_photos = 2;
  // Neural model checkpoint ("" = the installed or bundled model).
  std::string checkpoint;
  // Fusion net weights of the learned path's row ("" = the bundled net, FusionWeightsOf).
  std::string fusion;
  // BackendOptions::align_depth of the detail paths (< 0 = off, the default).
  double align_depth = -1.0;
  // Folder with the installed models and samples (set from the command's --data-dir).
  std::string data_dir;
  face::FaceMetricsOptions face;

  template <typename V>
  void Visit(V&& v) {
    v("out", out, "Output folder (orbit.md, orbit.json, orbit.png)", 'o');
    v("yaws", yaws, "Camera yaw offsets from the photo's pose, degrees, comma-separated");
    v("size", size, "Output size of every render in pixels (square)");
    v("jaw_control", jaw_control, "Expression control of the mouth-opening measure");
    v("jaw_value", jaw_value, "Value of that control");
    v("contact_photos", contact_photos, "Photos shown in orbit.png");
    v("checkpoint", checkpoint, "Neural model checkpoint (default: the installed or bundled model)");
    v("fusion", fusion, "Fusion net weights of the learned path's row (default: the bundled net)");
    v("align_depth", align_depth,
      "Detail paths: move the network's depth onto the fitted face mesh, reaching this fraction of the image height "
      "(0 = the whole head; < 0 = off)");
    // The face analysis of the metrics (AED is not measured here).
    v("face_analysis_size", face.analysis_size, "Long side small images are upsampled to before face analysis");
    v("face_min_score", face.min_score, "Face detection score threshold of the face metrics");
    v("face_min_mesh_confidence", face.min_mesh_confidence, "Landmark confidence below which a face counts as not found");
  }
  // Throws InvalidOptions (no photos, a bad yaw list, size outside 64..1024, ...).
  void Validate() const;
  std::vector<double> YawList() const;
};

struct OrbitPathResult {
  std::string key;   // network, preview, paste, face, detail, learned (when a fusion net finishes the detail)
  std::string name;  // the frame source's label (or the paste's description)
  // Per yaw (OrbitEvalReport::yaws): means over the photos whose render has a face, and counts.
  std::vector<double> identity;
  std::vector<double> outside_detail;
  std::vector<int> found;
  // Mouth opening (jaw_control at jaw_value minus neutral, source view), mean over photos where
  // both renders have a face, and their count.
  double mouth_opening = 0.0;
  int mouth_found = 0;
  // Source view (yaw 0, the photo's expression): PSNR in dB of the render on black against the
  // photo's matted crop at the output size, mean over photos.
  double source_psnr = 0.0;
};

struct OrbitEvalReport {
  std::vector<double> yaws;
  std::vector<std::string> photos;  // those evaluated (a photo without a face fails the run)
  std::vector<OrbitPathResult> paths;
  double seconds = 0.0;
  std::string markdown;
  std::string markdown_path, json_path, contact_path;
};

// Throws InvalidOptions, InvalidInput naming a photo without a usable face, MissingData /
// ModelLoad for missing models, Cancelled (nothing written then).
OrbitEvalReport RunOrbitEvaluation(const OrbitEvalOptions& options, RunContext& ctx);

}  // namespace avatar
