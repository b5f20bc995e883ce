#pragma once
// The neural network behind the studio's FrameSource interface: one reconstruction per
// portrait, Session::Animate per frame. Labelled "Neural avatar: <DescribeModel>", or as random
// weights when the user asked for those.

#include <memory>
#include <optional>
#include <string>

#include "core/pipeline/frame_source.h"
#include "core/pipeline/session.h"

namespace avatar {

class SessionFrameSource : public FrameSource {
 public:
  // `session` renders `avatar`; `random_weights` only changes the label. `overlay` is the
  // source analysis's, for the source panel.
  SessionFrameSource(std::shared_ptr<const Session> session, Avatar avatar, bool random_weights,
                     SourceOverlay overlay = {});

  std::string Label() const override;
  bool SupportsPose() const override { return true; }
  std::vector<std::string> ExpressionControls() const override { return avatar_.ControlNames(); }
  int CoefficientCount() const override { return avatar_.CoefficientCount(); }
  // The head pose of the source camera C_s (PoseOfCamera).
  ViewPose SourcePose() const override { return source_pose_; }
  SourceOverlay Overlay() const override { return overlay_; }
  // Session::Animate at Camera(request.view), with request.expression passed on unchanged (the
  // avatar's expression source turns it into I_exp, ExpressionBeta for the morphable one).
  RenderedFrame Render(const FrameRequest& request, RunContext& ctx) const override;
  // The camera a view pose is rendered from: CameraForView(pose, avatar.SourceCamera()).
  CameraLabel25 Camera(const ViewPose& pose) const;
  // Frames render with these settings (a quality level, quality.h) instead of the default
  // (super-resolution when the model's SR is trained). Call before sharing the source.
  void SetRenderSettings(const RenderSettings& settings);
  // The rendered avatar (e.g. to read its RefinementInfo).
  const Avatar& avatar() const { return avatar_; }

 private:
  std::shared_ptr<const Session> session_;
  Avatar avatar_;
  bool random_weights_;
  ViewPose source_pose_;
  SourceOverlay overlay_;
  std::string label_;
  bool sr_trained_ = false;
  std::optional<RenderSettings> settings_;
};

// The label of random-weight frames.
inline constexpr const char* kRandomWeightsLabel = "Neural network with RANDOM weights (untrained): not a result";

}  // namespace avatar
