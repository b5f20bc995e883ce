#include "core/pipeline/detail_source.h"

#include <mutex>

#include "core/model/fusion_net.h"
#include "core/pipeline/fusion_input.h"
#include "core/pipeline/morphable_expression_source.h"
#include "core/pipeline/morphable_preview.h"
#include "core/util/error.h"
#include "core/util/logging.h"

namespace avatar {
namespace {

const morphable::MorphableModel& ModelOf(const SourceAnalysis& analysis) {
  AVATAR_CHECK_INPUT(analysis.model != nullptr) << "detail: the analysis has no morphable model";
  return *analysis.model;
}

}  // namespace

// The fusion net, shared by copies of a source; one frame at a time through it.
struct DetailFrameSource::Fusion {
  FusionNet net{nullptr};
  FusionNetInfo info;
  std::mutex mutex;

  // The finished frame of a geometric composite's layers (BGR8 of the frame's size).
  cv::Mat Finish(const DetailLayers& layers) {
    torch::NoGradGuard no_grad;
    torch::Tensor x = FusionInputFromBytes(FusionInputBytes(layers).unsqueeze(0));
    const int64_t h = x.size(2), w = x.size(3);
    const int64_t factor = int64_t{1} << (static_cast<int64_t>(info.options.widths.size()) - 1);
    const int64_t ph = (factor - h % factor) % factor, pw = (factor - w % factor) % factor;
    if (ph > 0 || pw > 0) {
      x = torch::nn::functional::pad(
          x, torch::nn::functional::PadFuncOptions({0, pw, 0, ph}).mode(torch::kReplicate));
    }
    torch::Tensor y;
    {
      std::lock_guard<std::mutex> lock(mutex);
      y = net->forward(x);
    }
    return BgrFromRgb(y[0].slice(1, 0, h).slice(2, 0, w).clamp(-1.0, 1.0));
  }
};

const std::vector<std::string>& DetailModes() {
  static const std::vector<std::string> modes = {"head", "face", "off"};
  return modes;
}

void ValidateDetailMode(const std::string& mode) {
  for (const auto& m : DetailModes()) {
    if (m == mode) return;
  }
  throw InvalidOptions("--detail must be head, face or off, got '" + mode + "'");
}

void DetailOptions::Validate() const {
  AVATAR_CHECK_OPTION(mode == "head" || mode == "face") << "a detail source's mode must be head or face, got '" << mode
                                                        << "'";
  face.Validate();
  depth.Validate();
  AVATAR_CHECK_OPTION(source_depth_size >= 16 && source_depth_size <= 1024)
      << "the source depth size must be within 16..1024, got " << source_depth_size;
}

std::string DetailLabel(const std::string& mode) {
  return std::string(kDetailLabel) + (mode == "head" ? " on the head" : " on the face");
}

DetailFrameSource::DetailFrameSource(std::shared_ptr<const FrameSource> base, const SourceAnalysis& analysis,
                                     const DetailOptions& options)
    : base_(std::move(base)),
      model_(analysis.model),
      detail_(ModelOf(analysis), analysis.morphable_fit, analysis.portrait.image_unmatted, analysis.portrait.matte,
              analysis.portrait.eye_mouth_mask, options.face, analysis.portrait.landmarks.points),
      options_(options) {
  AVATAR_CHECK_INPUT(base_ != nullptr) << "detail: no base frame source";
  options_.Validate();
  std::vector<std::string> warnings = base_->Warnings();
  if (options_.mode == "head") {
    // The proxy of hair, ears and neck: the base's own depth at the photo's view.
    FrameRequest source_view;
    source_view.view = base_->SourcePose();
    source_view.width = source_view.height = options_.source_depth_size;
    RunContext ctx;
    const RenderedFrame frame = base_->Render(source_view, ctx);
    compose::ViewDepth depth{CameraForView(source_view.view, detail_.fit().camera), frame.depth};
    try {
      if (frame.depth.empty()) throw InvalidInput("the head renderer gives no depth");
      depth_ = std::make_unique<compose::DepthDetail>(analysis.portrait.image_unmatted, analysis.portrait.matte,
                                                      std::move(depth), options_.depth);
    } catch (const InvalidInput& e) {
      warnings.push_back(std::string("The photo's detail covers the face only: ") + e.what() + ".");
      AVATAR_LOG(kWarning) << warnings.back();
    }
  }
  if (!options_.fusion.empty()) {
    fusion_ = std::make_shared<Fusion>();
    fusion_->net = LoadFusionNet(options_.fusion, &fusion_->info);
  }
  if (options_.face_fill) {
    fill_ = std::make_unique<MorphablePreviewSource>(*analysis.model, analysis.morphable_fit, analysis.texture);
  }
  SetWarnings(std::move(warnings));
}

std::string DetailFrameSource::Label() const {
  std::string label = base_->Label() + DetailLabel(options_.mode);
  if (fusion_ != nullptr)
    label += ", finished by the fusion net (step " + std::to_string(fusion_->info.step) + ", fusion:" +
             fusion_->info.fingerprint + ")";
  return label;
}

compose::FaceWarp DetailFrameSource::Warp(const FrameRequest& request) const {
  const CameraLabel25 camera = CameraForView(request.view, detail_.fit().camera);
  const morphable::Beta beta = ExpressionBeta(*model_, detail_.fit().beta, request.expression);
  return detail_.Warp(camera, beta, cv::Size(request.width, request.height));
}

compose::FaceWarp DetailFrameSource::DepthWarp(const FrameRequest& request, const RenderedFrame& base_frame) const {
  const cv::Size size(request.width, request.height);
  if (depth_ == nullptr || base_frame.depth.empty() || base_frame.alpha.empty()) {
    compose::FaceWarp none;
    none.bgr = cv::Mat::zeros(size, CV_8UC3);
    none.valid = cv::Mat::zeros(size, CV_8UC1);
    none.face = cv::Mat::zeros(size, CV_8UC1);
    none.weight = cv::Mat::zeros(size, CV_32FC1);
    return none;
  }
  const compose::ViewDepth target{CameraForView(request.view, detail_.fit().camera), base_frame.depth};
  return depth_->Warp(target, base_frame.alpha);
}

RenderedFrame DetailFrameSource::Render(const FrameRequest& request, RunContext& ctx) const {
  DetailLayers layers = RenderLayers(request, ctx);
  if (fusion_ != nullptr) {
    ctx.ThrowIfCancelled();
    layers.frame.bgr = fusion_->Finish(layers);
  }
  return std::move(layers.frame);
}

DetailLayers DetailFrameSource::RenderLayers(const FrameRequest& request, RunContext& ctx) const {
  DetailLayers layers;
  RenderedFrame& frame = layers.frame;
  frame = base_->Render(request, ctx);
  ctx.ThrowIfCancelled();
  layers.network = frame.bgr.clone();
  const cv::Size size(request.width, request.height);
  // The face warp first: its changed eyes and mouth are left to the base frame by every layer.
  const compose::FaceWarp warp = Warp(request);
  if (depth_ != nullptr) {
    compose::FaceWarp depth = DepthWarp(request, frame);
    compose::ExcludeRegion(&depth, warp.changed, options_.face.feather);
    compose::ClearCarved(depth, &frame.bgr, &frame.alpha, &frame.depth);
    frame.bgr = compose::Composite(frame.bgr, depth, &frame.alpha);
    layers.depth_weight = depth.weight;
  } else {
    layers.depth_weight = cv::Mat::zeros(size, CV_32FC1);
  }
  if (fill_ != nullptr) {
    // Under the photo's warp, the textured face mesh over the whole face: what the photo did not
    // see of the face shows the fit's texture, not the network's blur.
    const RenderedFrame face = fill_->Render(request, ctx);
    compose::FaceWarp fill;
    fill.bgr = face.bgr;
    fill.valid = face.alpha >= 128;
    fill.face = fill.valid;
    fill.weight = compose::FeatheredWeight(fill.valid, options_.face.feather);
    compose::ExcludeRegion(&fill, warp.changed, options_.face.feather);
    frame.bgr = compose::Composite(frame.bgr, fill, &frame.alpha);
  }
  frame.bgr = compose::Composite(frame.bgr, warp, &frame.alpha);
  frame.bgr = compose::PaintCavity(frame.bgr, warp);
  layers.face_weight = warp.weight;
  layers.face = warp.face;
  layers.eye_mouth = warp.eye_mouth;
  return layers;
}

}  // namespace avatar
