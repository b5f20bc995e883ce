#include "core/pipeline/session_source.h"

#include <opencv2/imgproc.hpp>

#include "core/morphable/camera_label.h"
#include "core/pipeline/morphable_preview.h"
#include "core/util/error.h"

namespace avatar {

SessionFrameSource::SessionFrameSource(std::shared_ptr<const Session> session, Avatar avatar, bool random_weights,
                                       const morphable::MorphableModel* model, SourceOverlay overlay)
    : session_(std::move(session)),
      avatar_(std::move(avatar)),
      random_weights_(random_weights),
      model_(model),
      overlay_(std::move(overlay)) {
  AVATAR_CHECK_INPUT(session_ != nullptr && avatar_.valid()) << "the neural source needs a session and an avatar";
  const ModelInfo info = session_->Info();
  label_ = random_weights_ ? std::string(kRandomWeightsLabel) : "Neural avatar: " + DescribeModel(info);
  sr_trained_ = info.sr_trained;
  const auto label = avatar_.SourceCamera();
  morphable::CameraLabel camera;
  std::copy(label.begin(), label.end(), camera.begin());
  const morphable::PinholeCamera source = morphable::PinholeCamera::FromLabel(camera);
  const morphable::PinholeCamera front = morphable::PinholeCamera::FromLabel(morphable::FrontalLabel());
  source_pose_ = PoseFromRotation(front.world_to_cam.t() * source.world_to_cam);
}

std::string SessionFrameSource::Label() const { return label_; }

View SessionFrameSource::ToView(const ViewPose& pose) {
  // Turning the head towards the image's left is the camera orbiting to the subject's left
  // (+x, the session's positive yaw); tilting the head up is the camera moving below it
  // (negative session pitch); rolling the head clockwise is rolling the camera the other way.
  View v;
  v.yaw = pose.yaw;
  v.pitch = -pose.pitch;
  v.roll = -pose.roll;
  v.radius = 2.7 / pose.zoom;
  return v;
}

RenderedFrame SessionFrameSource::Render(const FrameRequest& request, RunContext& ctx) const {
  ValidateFrameSize(request.width, request.height);
  AVATAR_CHECK_OPTION(std::isfinite(request.view.zoom) && request.view.zoom >= 0.1 && request.view.zoom <= 10.0)
      << "zoom must be within 0.1..10";
  Expression expression;
  if (model_ != nullptr && !request.expression.coefficients.empty()) {
    expression.controls = ControlsFromCoefficients(*model_, request.expression.coefficients);
  }
  for (const auto& [name, value] : request.expression.controls) {
    if (value != 0.0f) expression.controls[name] = std::clamp(expression.controls[name] + value, 0.0f, 1.0f);
  }
  // A trained super-resolution serves every frame larger than the render; otherwise the render
  // is scaled to the request here.
  const Preset preset = sr_trained_ ? Preset::kFinal : Preset::kStandard;
  const Frame frame = session_->Animate(avatar_, expression, ToView(request.view), preset, &ctx);
  RenderedFrame out;
  const cv::Size size(request.width, request.height);
  const bool enlarging = size.width > frame.bgr.cols || size.height > frame.bgr.rows;
  cv::resize(frame.bgr, out.bgr, size, 0, 0, enlarging ? cv::INTER_CUBIC : cv::INTER_AREA);
  cv::Mat alpha;
  cv::resize(frame.opacity, alpha, size, 0, 0, cv::INTER_LINEAR);
  alpha.convertTo(out.alpha, CV_8UC1, 255.0);
  cv::resize(frame.depth, out.depth, size, 0, 0, cv::INTER_NEAREST);
  return out;
}

}  // namespace avatar
