#pragma once
// Fitting the morphable model to facemesh landmarks: pose, alpha and beta by Levenberg-Marquardt
// on the 2D reprojection of all 468 landmarks plus their relative depth, with Gaussian priors on
// the coefficients. For video, one identity is shared over the frames and beta/pose are per
// frame with a temporal smoothness prior.

#include <vector>

#include <opencv2/core.hpp>

#include "core/face/face_types.h"
#include "core/morphable/camera_label.h"
#include "core/morphable/morphable_model.h"
#include "core/util/run_context.h"

namespace avatar::morphable {

struct FitOptions {
  // Landmark noise, as a fraction of the inter-ocular distance (weights data vs priors).
  double landmark_sigma = 0.01;
  // Weight of the relative-depth residuals (facemesh z) relative to the 2D ones.
  double depth_weight = 0.3;
  // Multiplier on the identity prior (sum (alpha_k / std_k)^2).
  double identity_prior = 1.0;
  // Multiplier on the expression prior.
  double expression_prior = 1.0;
  // Levenberg-Marquardt iterations.
  int iterations = 30;
  // Estimate identity (false: keep alpha at zero or at the given shared identity).
  bool fit_identity = true;
  // Estimate expression (false: beta = 0).
  bool fit_expression = true;
  // Video: weight of (beta_t - beta_{t-1}) in units of the expression std.
  double temporal_smoothness = 4.0;
  // Video: identity/expression alternation rounds.
  int sequence_rounds = 2;

  template <typename V>
  void Visit(V&& v) {
    v("landmark_sigma", landmark_sigma, "Landmark noise as a fraction of the inter-ocular distance");
    v("depth_weight", depth_weight, "Weight of the facemesh relative-depth residuals");
    v("identity_prior", identity_prior, "Multiplier on the identity prior");
    v("expression_prior", expression_prior, "Multiplier on the expression prior");
    v("iterations", iterations, "Levenberg-Marquardt iterations");
    v("fit_identity", fit_identity, "Estimate identity coefficients");
    v("fit_expression", fit_expression, "Estimate expression coefficients");
    v("temporal_smoothness", temporal_smoothness, "Video: weight tying beta to the previous frame");
    v("sequence_rounds", sequence_rounds, "Video: identity/expression alternation rounds");
  }
  // Throws InvalidOptions.
  void Validate() const;
};

struct FitResult {
  Alpha alpha;                        // identity, [Kid]
  Beta beta;                          // expression, [Kexp]
  float scale = 1.0f;                 // world = scale * model vertices
  cv::Matx33d rotation;               // world -> camera rotation (OpenCV camera axes)
  cv::Vec3d translation;              // camera = rotation * world + translation; |translation| = 2.7
  CameraLabel camera{};               // the same camera as an EG3D label (cam2world at radius 2.7 + K)
  cv::Size image_size;                // size of the image the landmarks refer to
  std::vector<float> landmark_error;  // per landmark 2D reprojection error, pixels, [468]
  double mean_error_px = 0.0;         // mean of landmark_error
  double inter_ocular_px = 0.0;       // eye-centre distance of the input landmarks, pixels
  double mean_error_iod = 0.0;        // mean_error_px / inter_ocular_px
  int iterations = 0;                 // LM iterations used
};

// World-space vertices of a fit with a replaced expression (empty beta: the fit's).
std::vector<cv::Point3f> WorldVertices(const MorphableModel& model, const FitResult& fit, const Beta* beta = nullptr);

// Fits one face. `landmarks` are in the pixels of an image of `image_size`; the camera has the
// published normalised intrinsics for that image (meant for the 512 aligned crop). Throws
// InvalidInput for a wrong number of points, non-finite or degenerate (collapsed) landmarks.
// A fit stored as its coefficients, scale and camera label (dataset records, .avatar files):
// rotation and translation are read back from the label; no landmark errors.
FitResult FitFromLabel(const Alpha& alpha, const Beta& beta, float scale, const CameraLabel& label,
                       cv::Size image_size);

FitResult Fit(const MorphableModel& model, const face::Landmarks& landmarks, cv::Size image_size,
              const FitOptions& options = {});

// Fits a clip: one alpha for all frames, beta and pose per frame. Reports progress and honours
// cancel through `ctx`. Throws as Fit, and Cancelled.
std::vector<FitResult> FitSequence(const MorphableModel& model, const std::vector<face::Landmarks>& frames,
                                   cv::Size image_size, const FitOptions& options, RunContext& ctx);

// Inter-ocular distance (eye centres) of facemesh landmarks, in their units (x, y only).
double InterOcularDistance(const std::vector<cv::Point3f>& points);

}  // namespace avatar::morphable
