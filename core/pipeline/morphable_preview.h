#pragma once
// The morphable preview: the morphable face model fitted to the portrait, textured from the
// portrait, and rendered by the CPU rasterizer at any head pose and expression. The studio and
// `animate` show it when the user chooses it (--renderer morphable) or when no neural model
// loads, always labelled "Preview: morphable model (...why...)".
//
// Pose: every frame is rendered at CameraForView(request.view, the fit's camera C_s)
// (frame_source.h), the same camera the neural source uses; at SourcePose() that is C_s itself,
// so the preview lines up with the photo. Expression: ExpressionBeta (one function with the
// neural session's I_exp).

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/morphable/morphable.h"
#include "core/pipeline/driving.h"
#include "core/pipeline/frame_source.h"
#include "core/pipeline/morphable_expression_source.h"

namespace avatar {

// The head pose of a fit: its world->camera rotation relative to the frontal camera's.
ViewPose PoseOfFit(const morphable::FitResult& fit);

// The label every morphable preview frame starts with (CreateFrameSource adds why it is shown:
// chosen by the user, or the neural model could not be loaded and the reason).
inline constexpr const char* kMorphablePreviewLabel = "Preview: morphable model";

class MorphablePreviewSource : public FrameSource {
 public:
  // `model` must outlive the source (LoadDefaultModel's models live for the process).
  // `fit` and `texture` describe the portrait; `overlay` is drawn over the source thumbnail.
  // `label` is what Label() says (kMorphablePreviewLabel plus why the preview is shown).
  MorphablePreviewSource(const morphable::MorphableModel& model, morphable::FitResult fit, morphable::Texture texture,
                         SourceOverlay overlay = {}, std::string label = kMorphablePreviewLabel);

  std::string Label() const override;
  bool SupportsPose() const override { return true; }
  std::vector<std::string> ExpressionControls() const override;
  int CoefficientCount() const override;
  ViewPose SourcePose() const override { return source_pose_; }
  SourceOverlay Overlay() const override { return overlay_; }
  // The mesh with ExpressionBeta(model, fit, request.expression) seen by
  // CameraForView(request.view, fit camera). Throws InvalidInput (unknown control, wrong
  // coefficient count), InvalidOptions (size, pose), Cancelled.
  RenderedFrame Render(const FrameRequest& request, RunContext& ctx) const override;
  // The expression coefficients Render uses for `expression` (ExpressionBeta on this fit).
  morphable::Beta Coefficients(const FrameExpression& expression) const;

  const morphable::FitResult& Fit() const { return fit_; }

 private:
  const morphable::MorphableModel& model_;
  morphable::FitResult fit_;
  morphable::Texture texture_;
  SourceOverlay overlay_;
  ViewPose source_pose_;
  std::string label_;
};

// Measures driving frames: tracks the face through the video and fits the morphable model
// per frame (expression coefficients + head pose). `landmarks_of` returns the frame's
// landmarks (or found = false); separated so the tracker can be swapped and tested.
class MorphableFrameAnalyzer : public FrameAnalyzer {
 public:
  using LandmarkFn = std::function<bool(const cv::Mat& bgr, face::Landmarks* landmarks)>;
  MorphableFrameAnalyzer(const morphable::MorphableModel& model, LandmarkFn landmarks_of,
                         std::function<void()> reset = {});
  FrameMeasurement Measure(const cv::Mat& bgr, RunContext& ctx) override;
  void Reset() override {
    if (reset_) reset_();
  }

 private:
  const morphable::MorphableModel& model_;
  LandmarkFn landmarks_of_;
  std::function<void()> reset_;
};

}  // namespace avatar
