#include "core/pipeline/detail_source.h"

#include "core/pipeline/morphable_expression_source.h"
#include "core/util/error.h"

namespace avatar {
namespace {

const morphable::MorphableModel& ModelOf(const SourceAnalysis& analysis) {
  AVATAR_CHECK_INPUT(analysis.model != nullptr) << "detail: the analysis has no morphable model";
  return *analysis.model;
}

}  // namespace

const std::vector<std::string>& DetailModes() {
  static const std::vector<std::string> modes = {"face", "off"};
  return modes;
}

void ValidateDetailMode(const std::string& mode) {
  for (const auto& m : DetailModes()) {
    if (m == mode) return;
  }
  throw InvalidOptions("--detail must be face or off, got '" + mode + "'");
}

DetailFrameSource::DetailFrameSource(std::shared_ptr<const FrameSource> base, const SourceAnalysis& analysis,
                                     const compose::FaceDetailOptions& options)
    : base_(std::move(base)),
      model_(analysis.model),
      detail_(ModelOf(analysis), analysis.morphable_fit, analysis.portrait.image_unmatted, analysis.portrait.matte,
              analysis.portrait.eye_mouth_mask, options) {
  AVATAR_CHECK_INPUT(base_ != nullptr) << "detail: no base frame source";
  SetWarnings(base_->Warnings());
}

std::string DetailFrameSource::Label() const { return base_->Label() + kDetailLabel; }

compose::FaceWarp DetailFrameSource::Warp(const FrameRequest& request) const {
  const CameraLabel25 camera = CameraForView(request.view, detail_.fit().camera);
  const morphable::Beta beta = ExpressionBeta(*model_, detail_.fit().beta, request.expression);
  return detail_.Warp(camera, beta, cv::Size(request.width, request.height));
}

RenderedFrame DetailFrameSource::Render(const FrameRequest& request, RunContext& ctx) const {
  RenderedFrame frame = base_->Render(request, ctx);
  ctx.ThrowIfCancelled();
  const compose::FaceWarp warp = Warp(request);
  frame.bgr = compose::Composite(frame.bgr, warp, &frame.alpha);
  return frame;
}

}  // namespace avatar
