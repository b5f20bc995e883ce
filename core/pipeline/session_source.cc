#include "core/pipeline/session_source.h"

#include <cstdio>

#include <nlohmann/json.hpp>
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
  if (const std::string refined = avatar_.RefinementInfo(); !refined.empty()) {
    // Refined planes (refine.h) say so, with what the refinement measured on the photo.
    try {
      const nlohmann::json j = nlohmann::json::parse(refined);
      char buf[160];
      std::snprintf(buf, sizeof(buf), "; refined on the photo: %d steps, source-view PSNR %.2f -> %.2f dB",
                    j.value("steps", 0), j.value("psnr_before", 0.0), j.value("psnr_after", 0.0));
      label_ += buf;
    } catch (const nlohmann::json::exception&) {
      label_ += "; refined on the photo";
    }
  }
  sr_trained_ = info.sr_trained;
  source_pose_ = render::PoseOfCamera(avatar_.SourceCamera());
}

std::string SessionFrameSource::Label() const { return label_; }

void SessionFrameSource::SetRenderSettings(const RenderSettings& settings) {
  settings.Validate();
  settings_ = settings;
}

CameraLabel25 SessionFrameSource::Camera(const ViewPose& pose) const {
  return CameraForView(pose, avatar_.SourceCamera());
}

RenderedFrame SessionFrameSource::Render(const FrameRequest& request, RunContext& ctx) const {
  ValidateFrameSize(request.width, request.height);
  const CameraLabel25 camera = Camera(request.view);  // Throws InvalidOptions for a bad pose.
  // A trained super-resolution serves every frame larger than the render; otherwise the render
  // is scaled to the request here.
  const RenderMode mode = sr_trained_ ? RenderMode::kFinal : RenderMode::kStandard;
  const Frame frame = settings_ ? session_->Animate(avatar_, request.expression, camera, *settings_, &ctx)
                                : session_->Animate(avatar_, request.expression, camera, mode, &ctx);
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
