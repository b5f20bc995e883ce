#pragma once
// The neural network behind the studio's FrameSource interface: one reconstruction per
// portrait, Session::Animate per frame. Labelled "Neural avatar: <DescribeModel>", or as random
// weights when the user asked for those.

#include <memory>
#include <string>

#include "core/morphable/morphable_model.h"
#include "core/pipeline/frame_source.h"
#include "core/pipeline/session.h"

namespace avatar {

class SessionFrameSource : public FrameSource {
 public:
  // `session` renders `avatar`; `random_weights` only changes the label. With `model`, raw
  // driver coefficients are turned into named controls (ControlsFromCoefficients). `overlay`
  // is the source analysis's, for the source panel.
  SessionFrameSource(std::shared_ptr<const Session> session, Avatar avatar, bool random_weights,
                     const morphable::MorphableModel* model = nullptr, SourceOverlay overlay = {});

  std::string Label() const override;
  bool SupportsPose() const override { return true; }
  std::vector<std::string> ExpressionControls() const override { return avatar_.ControlNames(); }
  ViewPose SourcePose() const override { return source_pose_; }
  SourceOverlay Overlay() const override { return overlay_; }
  // Named controls and the camera drive the network; raw driver coefficients become named
  // controls through the morphable model (without one they are ignored).
  RenderedFrame Render(const FrameRequest& request, RunContext& ctx) const override;

  // Our head-pose convention -> the session's orbit camera (exposed for tests).
  static View ToView(const ViewPose& pose);

 private:
  std::shared_ptr<const Session> session_;
  Avatar avatar_;
  bool random_weights_;
  const morphable::MorphableModel* model_;
  ViewPose source_pose_;
  SourceOverlay overlay_;
  std::string label_;
  bool sr_trained_ = false;
};

// The label of random-weight frames.
inline constexpr const char* kRandomWeightsLabel = "Neural network with RANDOM weights (untrained): not a result";

}  // namespace avatar
