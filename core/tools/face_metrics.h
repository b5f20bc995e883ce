#pragma once
// Face metrics of evaluation (GOHA, Li et al. 2023, section 4: CSIM, AED, APD), computed on
// pairs of images (a rendered image and its reference, both BGR):
//   CSIM  cosine similarity of the two identity embeddings (fr_feature.onnx, ArcFace-style
//         five-point alignment from our facemesh landmarks; identity_net.h). Higher is better.
//   APD   mean absolute difference of yaw, pitch and roll in degrees from fr_pose.onnx
//         (head_pose_net.h), on the detector's face box. Lower is better.
//   AED   mean absolute difference of the morphable expression coefficients (beta) that our
//         fitter (core/morphable/fitter.h) finds on the two images' landmarks. The paper uses
//         the coefficients of Deng et al.'s 3DMM; ours are the coefficients of our morphable
//         model, so values are comparable between our rows only. Lower is better.
// Renders are small (16 to 128 px), so every image whose long side is below analysis_size is
// upsampled (bicubic) to it before detection. An image where no face is found (or whose
// landmarks are unreliable) is reported as such, never as an exception; a pair counts for the
// averages only when both images have a face.

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/face/face_types.h"
#include "core/util/run_context.h"

namespace avatar::face {

struct FaceMetricsOptions {
  // Folder with models/ ("" = AVATAR_DATA_DIR, then ~/.cache/avatar-studio).
  std::string data_dir;
  // Images whose long side is smaller are upsampled (bicubic) to this long side before analysis.
  int analysis_size = 256;
  // Face detection score threshold in [0,1].
  float min_score = 0.5f;
  // Landmarks below this face-presence confidence count as no face.
  float min_mesh_confidence = 0.5f;
  // Compute AED (fits the morphable model; needs the morphable model data).
  bool expression = true;
  // Levenberg-Marquardt iterations of the expression fit.
  int fit_iterations = 30;

  template <typename V>
  void Visit(V&& v) {
    v("face_analysis_size", analysis_size, "Long side small images are upsampled to before face analysis");
    v("face_min_score", min_score, "Face detection score threshold of the face metrics");
    v("face_min_mesh_confidence", min_mesh_confidence, "Landmark confidence below which a face counts as not found");
    v("aed", expression, "Compute AED (morphable expression fit)");
    v("face_fit_iterations", fit_iterations, "Iterations of the expression fit of AED");
  }
  // Throws InvalidOptions.
  void Validate() const;
};

// What was measured on one image.
struct FaceMeasurement {
  bool found = false;              // a face with reliable landmarks
  std::string reason;              // why not (when !found)
  std::vector<float> embedding;    // 512-d unit identity embedding
  HeadPose pose;                   // fr_pose angles, degrees
  std::vector<float> expression;   // morphable beta (empty when expression metrics are off)
  std::vector<cv::Point2f> landmarks;  // facemesh points in the given image's pixels
  float detection_score = 0.0f;
};

// The metrics of one (render, reference) pair.
struct PairFaceMetrics {
  bool render_face = false;     // a face was found in the render
  bool reference_face = false;  // ... and in the reference
  bool valid() const { return render_face && reference_face; }
  double csim = 0.0;            // cosine similarity in [-1,1]
  double apd = 0.0;             // mean |d yaw|, |d pitch|, |d roll|, degrees
  double yaw_diff = 0.0, pitch_diff = 0.0, roll_diff = 0.0;  // absolute, degrees
  double aed = 0.0;             // mean |d beta| (0 when expression metrics are off)
  bool has_aed = false;
};

// Averages over the valid pairs, with how many pairs lacked a face.
struct FaceMetricsSummary {
  int pairs = 0;               // pairs given
  int valid = 0;               // pairs with a face in both images (those averaged)
  int no_face_render = 0;      // pairs whose render has no face
  int no_face_reference = 0;   // pairs whose reference has no face
  double csim = 0.0, apd = 0.0, aed = 0.0;  // means over valid pairs (0 when valid == 0)
  bool has_aed = false;
};

// Mouth opening of facemesh landmarks: the gap between the inner lips' centres over the face's
// height (forehead to chin); 0 for a closed mouth, about 0.1-0.25 wide open. Throws InvalidInput
// for fewer than kMeshPoints points or a degenerate face height.
double MouthOpening(const std::vector<cv::Point2f>& landmarks);

class FaceMetrics {
 public:
  // Loads the face detector, landmark, identity and head-pose networks (and the morphable model
  // when options.expression). Throws MissingData / ModelLoad naming the missing file,
  // InvalidOptions.
  explicit FaceMetrics(const FaceMetricsOptions& options = {});
  ~FaceMetrics();
  FaceMetrics(const FaceMetrics&) = delete;
  FaceMetrics& operator=(const FaceMetrics&) = delete;

  const FaceMetricsOptions& options() const { return options_; }

  // Measures one image: CV_8UC3 BGR, CV_8UC1 grey or CV_32FC3 BGR in [0,1]. An empty image, an
  // unsupported type or an image without a face gives found = false with the reason.
  FaceMeasurement Measure(const cv::Mat& image) const;

  // Metrics of a pair from its two measurements.
  PairFaceMetrics Compare(const FaceMeasurement& render, const FaceMeasurement& reference) const;

  // Per-pair metrics of renders[i] against references[i] (equal counts, else InvalidInput).
  // Honours cancel through ctx.
  std::vector<PairFaceMetrics> Evaluate(const std::vector<cv::Mat>& renders, const std::vector<cv::Mat>& references,
                                        RunContext& ctx) const;

  static FaceMetricsSummary Summarise(const std::vector<PairFaceMetrics>& pairs);

 private:
  struct Impl;
  FaceMetricsOptions options_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace avatar::face
