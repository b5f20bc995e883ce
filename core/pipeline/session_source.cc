#include "core/pipeline/session_source.h"

#include <opencv2/imgproc.hpp>

#include "core/util/error.h"

namespace avatar {

SessionFrameSource::SessionFrameSource(std::shared_ptr<const Session> session, Avatar avatar, bool random_weights,
                                       SourceOverlay overlay)
    : session_(std::move(session)),
      avatar_(std::move(avatar)),
      random_weights_(random_weights),
      overlay_(std::move(overlay)) {
  AVATAR_CHECK_INPUT(session_ != nullptr && avatar_.valid()) << "the neural source needs a session and an avatar";
  const ModelInfo info = session_->Info();
  label_ = random_weights_ ? std::string(kRandomWeightsLabel) : "Neural avatar: " + DescribeModel(info);
  sr_trained_ = info.sr_trained;
  source_pose_ = PoseOfCamera(avatar_.SourceCamera());
}

std::string SessionFrameSource::Label() const { return label_; }

CameraLabel25 SessionFrameSource::Camera(const ViewPose& pose) const {
  return CameraForView(pose, avatar_.SourceCamera());
}

RenderedFrame SessionFrameSource::Render(const FrameRequest& request, RunContext& ctx) const {
  ValidateFrameSize(request.width, request.height);
  const CameraLabel25 camera = Camera(request.view);  // Throws InvalidOptions for a bad pose.
  // A trained super-resolution serves every frame larger than the render; otherwise the render
  // is scaled to the request here.
  const Preset preset = sr_trained_ ? Preset::kFinal : Preset::kStandard;
  const Frame frame = session_->Animate(avatar_, request.expression, camera, preset, &ctx);
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
