#pragma once
// R_M: renders the morphable face (geometry + texture) through an EG3D camera label on the CPU.

#include <vector>

#include <opencv2/core.hpp>

#include "core/morphable/camera_label.h"
#include "core/morphable/fitter.h"
#include "core/morphable/morphable_model.h"
#include "core/morphable/texture.h"

namespace avatar::morphable {

struct RenderOptions {
  // Supersampling factor per axis (1 = none; 2 or 3 antialias edges and the mask).
  int supersample = 1;
  // Multiply colours by simple Lambert shading (light from the camera).
  bool shading = false;
  // Background colour (BGR in [0,1]).
  cv::Vec3f background{0.0f, 0.0f, 0.0f};

  template <typename V>
  void Visit(V&& v) {
    v("supersample", supersample, "Supersampling factor per axis (1 = off)");
    v("shading", shading, "Apply Lambert shading");
  }
  void Validate() const;
};

struct RenderResult {
  cv::Mat image;  // [H,W] CV_32FC3 BGR in [0,1]
  cv::Mat mask;   // [H,W] CV_32FC1 face coverage in [0,1] (binary without supersampling)
  cv::Mat depth;  // [H,W] CV_32FC1 camera depth of the nearest surface, 0 where empty (at full resolution)
};

// Renders world-space vertices (topology order). Throws InvalidInput on bad sizes.
RenderResult RenderMesh(const std::vector<cv::Point3f>& world_vertices, const Topology& topology,
                        const Texture& texture, const CameraLabel& camera, cv::Size size,
                        const RenderOptions& options = {});

// Renders scale * S(alpha, beta) through `camera`.
RenderResult Render(const MorphableModel& model, const Alpha& alpha, const Beta& beta, float scale,
                    const Texture& texture, const CameraLabel& camera, cv::Size size,
                    const RenderOptions& options = {});

// I_exp: the fit's identity with expression `beta_target` at the fixed frontal camera C_front.
RenderResult RenderExpressionImage(const MorphableModel& model, const FitResult& fit, const Texture& texture,
                                   const Beta& beta_target, cv::Size size, const RenderOptions& options = {});
// I_neu / M_neu: the fit's identity with beta = 0 at the fit's own camera.
RenderResult RenderNeutral(const MorphableModel& model, const FitResult& fit, const Texture& texture, cv::Size size,
                           const RenderOptions& options = {});

// Batched variants for training (loops over the batch).
std::vector<RenderResult> RenderExpressionImages(const MorphableModel& model, const std::vector<FitResult>& fits,
                                                 const std::vector<Texture>& textures,
                                                 const std::vector<Beta>& beta_targets, cv::Size size,
                                                 const RenderOptions& options = {});
std::vector<RenderResult> RenderNeutrals(const MorphableModel& model, const std::vector<FitResult>& fits,
                                         const std::vector<Texture>& textures, cv::Size size,
                                         const RenderOptions& options = {});

// Landmarks drawn over an image (the fit's reprojected vertices in green, input in red).
cv::Mat DrawFitOverlay(const cv::Mat& bgr, const MorphableModel& model, const FitResult& fit,
                       const face::Landmarks& landmarks);

}  // namespace avatar::morphable
