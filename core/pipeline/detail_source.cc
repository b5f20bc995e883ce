#include "core/pipeline/detail_source.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>

#include <opencv2/imgproc.hpp>

#include "core/model/fusion_net.h"
#include "core/pipeline/fusion_input.h"
#include "core/pipeline/head_mesh.h"
#include "core/pipeline/morphable_expression_source.h"
#include "core/pipeline/morphable_preview.h"
#include "core/util/error.h"
#include "core/util/logging.h"

namespace avatar {
namespace {

// The photo and matte the warps read: the portrait's, with the person's edge cleaned unless
// the options say not to.
compose::EdgeMatte PhotoOf(const SourceAnalysis& analysis, const DetailOptions& options) {
  options.Validate();
  if (!options.clean_edges || analysis.portrait.matte.empty())
    return {analysis.portrait.image_unmatted, analysis.portrait.matte};
  return compose::RefineEdgeMatte(analysis.portrait.image_unmatted, analysis.portrait.matte, options.edges);
}

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

  // The finished frame of a geometric composite's layers (BGR8 of the frame's size), at a view
  // turned `turn_degrees` from the photo's (FusionTurnDegrees).
  // Frames larger than kFusionNetSide on their longer side: the net runs on the layers scaled
  // down to it (the scale it was trained at) and its change to the composite, scaled up, is added
  // to the full-size composite, so the photo's own detail stays at full resolution.
  cv::Mat Finish(const DetailLayers& layers, double turn_degrees) {
    namespace F = torch::nn::functional;
    torch::NoGradGuard no_grad;
    const cv::Size size = layers.frame.bgr.size();
    const double scale = static_cast<double>(kFusionNetSide) / static_cast<double>(std::max(size.width, size.height));
    // The layers are scaled as bytes (cheaper than the 11 float planes at full size, and the same
    // kind of input as the stored fusion sets).
    DetailLayers small;
    if (scale < 1.0) {
      small = ScaledFusionLayers(layers, cv::Size(std::max(1, static_cast<int>(std::lround(size.width * scale))),
                                                  std::max(1, static_cast<int>(std::lround(size.height * scale)))));
    }
    const torch::Tensor x = FusionInputFromBytes(FusionInputBytes(scale < 1.0 ? small : layers).unsqueeze(0));
    const int64_t xh = x.size(2), xw = x.size(3);
    const int64_t factor = int64_t{1} << (static_cast<int64_t>(info.options.widths.size()) - 1);
    const int64_t ph = (factor - xh % factor) % factor, pw = (factor - xw % factor) % factor;
    torch::Tensor y;
    {
      std::lock_guard<std::mutex> lock(mutex);
      y = net->forward(ph > 0 || pw > 0 ? F::pad(x, F::PadFuncOptions({0, pw, 0, ph}).mode(torch::kReplicate)) : x,
                       torch::tensor({turn_degrees}, torch::kFloat32));
    }
    y = y.slice(2, 0, xh).slice(3, 0, xw);
    if (scale >= 1.0) return BgrFromRgb(y[0].clamp(-1.0, 1.0));
    // The net's change in grey levels, scaled up and added to the full-size composite.
    const torch::Tensor change = ((y[0] - x[0].slice(0, 0, 3)) * 127.5)
                                     .nan_to_num(0.0)
                                     .to(torch::kCPU, torch::kFloat32)
                                     .permute({1, 2, 0})
                                     .contiguous();
    const cv::Mat change_rgb(static_cast<int>(xh), static_cast<int>(xw), CV_32FC3, change.data_ptr());
    cv::Mat change_bgr, change_full, out;
    cv::cvtColor(change_rgb, change_bgr, cv::COLOR_RGB2BGR);
    cv::resize(change_bgr, change_full, size, 0, 0, cv::INTER_LINEAR);
    layers.frame.bgr.convertTo(out, CV_32FC3);
    out += change_full;
    out.convertTo(out, CV_8UC3);  // rounds and saturates to 0..255
    return out;
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
  edges.Validate();
  AVATAR_CHECK_OPTION(source_depth_size >= 16 && source_depth_size <= 1024)
      << "the source depth size must be within 16..1024, got " << source_depth_size;
  AVATAR_CHECK_OPTION(base_expression_every >= 1 && base_expression_every <= 100)
      << "--network-expression-every must be within 1..100, got " << base_expression_every;
  AVATAR_CHECK_OPTION(std::isfinite(align_depth_reach) && align_depth_reach <= 10.0)
      << "the depth alignment's reach must be finite and at most 10 image heights, got " << align_depth_reach;
}

std::string DetailLabel(const std::string& mode) {
  return std::string(kDetailLabel) + (mode == "head" ? " on the head" : " on the face");
}

DetailFrameSource::DetailFrameSource(std::shared_ptr<const FrameSource> base, const SourceAnalysis& analysis,
                                     const DetailOptions& options)
    : base_(std::move(base)),
      analysis_(std::make_shared<const SourceAnalysis>(analysis)),
      model_(analysis.model),
      photo_(PhotoOf(analysis, options)),
      detail_(ModelOf(analysis), analysis.morphable_fit, photo_.bgr, photo_.matte,
              analysis.portrait.eye_mouth_mask, options.face, analysis.portrait.landmarks.points),
      options_(options),
      kept_(std::make_shared<Kept>()) {
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
      if (options_.align_depth_to_face) {
        // The network's surface moved along the rays onto the fitted face mesh (FaceDepthOffset),
        // here and at every target view (DepthWarp): hair and temples then turn with the face.
        const cv::Mat mesh = compose::MeshRayDepth(depth.camera, morphable::WorldVertices(*model_, detail_.fit()),
                                                   model_->topology().triangles, frame.depth.size());
        depth_offset_ = compose::FaceDepthOffset(frame.depth, frame.alpha, mesh);
        if (depth_offset_ != 0.0) {
          const cv::Mat field = compose::FaceOffsetField(mesh < std::numeric_limits<float>::infinity(), depth_offset_,
                                                         options_.align_depth_reach);
          depth.depth = frame.depth + field;
        }
        AVATAR_LOG(kDebug) << "detail: the network's depth moves by " << depth_offset_ << " onto the face mesh";
      }
      depth_ = std::make_unique<compose::DepthDetail>(photo_.bgr, photo_.matte, std::move(depth), options_.depth);
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
    // The fit's texture sampled again from the cleaned photo, only from the person, when the edge
    // was cleaned (the analysis's texture, which the morphable preview shows, reads the photo
    // as it is).
    const bool cleaned = options_.clean_edges && !analysis.portrait.matte.empty();  // as PhotoOf decides
    detail_.SetFillTexture(cleaned ? morphable::SampleTexture(*model_, analysis.morphable_fit, photo_.bgr, {}, photo_.matte)
                                   : analysis.texture);
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

std::shared_ptr<const HeadMesh> DetailFrameSource::ViewportMesh(RunContext& ctx) const {
  HeadMeshOptions options;
  options.extend_to_matte = options_.depth.extend_to_matte;
  options.align_depth_to_face = options_.align_depth_to_face;
  options.align_depth_reach = options_.align_depth_reach;
  // A picture, not a file: the height field continues under the face and stays closed across
  // depth steps up to 0.1 of the camera distance (stretched, not torn, where a turn opens them).
  options.under_face = true;
  options.max_depth_step = 0.1;
  HeadMesh mesh = BuildHeadMesh(*analysis_, *base_, options, ctx);
  // Behind the photo's parts, the network's own frames at the source view and turned 30 degrees
  // each way: what the photo did not see shows the network's colour, as in the rendered frame.
  for (const double yaw : {0.0, -30.0, 30.0}) {
    ViewPose view = base_->SourcePose();
    view.yaw += yaw;
    TexturedMesh backdrop = NetworkViewMesh(*base_, view, detail_.fit().camera, 128, 0.1, ctx);
    if (!backdrop.triangles.empty()) mesh.parts.push_back(std::move(backdrop));
  }
  return std::make_shared<const HeadMesh>(std::move(mesh));
}

std::shared_ptr<const DetailFrameSource> DetailFrameSource::ForLive(int every, bool keep_fusion) const {
  DetailOptions options = options_;
  options.base_expression_every = every;
  if (!keep_fusion) options.fusion.clear();
  return std::make_shared<const DetailFrameSource>(base_, *analysis_, options);
}

std::shared_ptr<const DetailFrameSource> DetailFrameSource::WithFusion(const std::string& weights) const {
  DetailOptions options = options_;
  options.fusion = weights;
  return std::make_shared<const DetailFrameSource>(base_, *analysis_, options);
}

const DetailFrameSource* DetailFrameSource::Find(const FrameSource* source) {
  std::shared_ptr<const FrameSource> keep;  // the chain below `source` is owned by it
  while (source != nullptr) {
    if (const auto* detail = dynamic_cast<const DetailFrameSource*>(source)) return detail;
    keep = source->Wrapped();
    source = keep.get();
  }
  return nullptr;
}

DetailFrameSource::MeshView DetailFrameSource::ViewportView(const FrameRequest& request) const {
  MeshView view;
  view.camera = CameraForView(request.view, detail_.fit().camera);
  const morphable::Beta beta = ExpressionBeta(*model_, detail_.fit().beta, request.expression);
  view.face = morphable::WorldVertices(*model_, detail_.fit(), &beta);
  return view;
}

compose::FaceWarp DetailFrameSource::DepthWarp(const FrameRequest& request, const RenderedFrame& base_frame,
                                              const cv::Mat& face) const {
  const cv::Size size(request.width, request.height);
  if (depth_ == nullptr || base_frame.depth.empty() || base_frame.alpha.empty()) {
    compose::FaceWarp none;
    none.bgr = cv::Mat::zeros(size, CV_8UC3);
    none.valid = cv::Mat::zeros(size, CV_8UC1);
    none.face = cv::Mat::zeros(size, CV_8UC1);
    none.weight = cv::Mat::zeros(size, CV_32FC1);
    return none;
  }
  compose::ViewDepth target{CameraForView(request.view, detail_.fit().camera), base_frame.depth};
  if (depth_offset_ != 0.0) {
    cv::Mat coverage = face;
    if (options_.align_depth_reach > 0.0 && coverage.empty()) coverage = Warp(request).face;
    if (coverage.empty()) coverage = cv::Mat::zeros(base_frame.depth.size(), CV_8UC1);
    if (coverage.size() != base_frame.depth.size())
      cv::resize(coverage, coverage, base_frame.depth.size(), 0, 0, cv::INTER_NEAREST);
    target.depth = base_frame.depth + compose::FaceOffsetField(coverage, depth_offset_, options_.align_depth_reach);
  }
  return depth_->Warp(target, base_frame.alpha);
}

RenderedFrame DetailFrameSource::Render(const FrameRequest& request, RunContext& ctx) const {
  DetailLayers layers = RenderLayers(request, ctx);
  if (fusion_ != nullptr) {
    ctx.ThrowIfCancelled();
    const ViewPose source = base_->SourcePose();
    layers.frame.bgr =
        fusion_->Finish(layers, FusionTurnDegrees(request.view.yaw - source.yaw, request.view.pitch - source.pitch));
  }
  return std::move(layers.frame);
}

struct DetailFrameSource::Kept {
  std::mutex mutex;
  bool valid = false;
  ViewPose view;
  int width = 0, height = 0;
  RenderedFrame base;  // never modified once kept (Compose works on copies)
  std::atomic<int64_t> base_renders{0}, quick{0};
  // The expression the base source was last asked for, and the frames rendered with it since
  // (DetailOptions::base_expression_every).
  std::optional<FrameExpression> base_expression;
  int frames_with_it = 0;
};

DetailFrameSource::Counts DetailFrameSource::counts() const {
  return {kept_->base_renders.load(), kept_->quick.load()};
}

std::optional<RenderedFrame> DetailFrameSource::RenderQuick(const FrameRequest& request, RunContext& ctx) const {
  RenderedFrame base;
  {
    std::lock_guard<std::mutex> lock(kept_->mutex);
    if (!kept_->valid || kept_->view != request.view || kept_->width != request.width ||
        kept_->height != request.height) {
      return std::nullopt;
    }
    base = kept_->base;
    base.bgr = kept_->base.bgr.clone();
    base.alpha = kept_->base.alpha.clone();
    base.depth = kept_->base.depth.clone();
  }
  ++kept_->quick;
  // Larger frames are composed at kQuickSide and upscaled: the quick frame is shown for the
  // moment the full frame takes, and its cost then stays that of a 256 px frame.
  const double scale = std::min(1.0, static_cast<double>(kQuickSide) / std::max(request.width, request.height));
  if (scale >= 1.0) {
    RenderedFrame frame = Compose(request, std::move(base), ctx).frame;
    frame.stages = "face update";
    return frame;
  }
  FrameRequest small = request;
  small.width = std::max(16, static_cast<int>(std::lround(request.width * scale)));
  small.height = std::max(16, static_cast<int>(std::lround(request.height * scale)));
  const cv::Size small_size(small.width, small.height), full_size(request.width, request.height);
  cv::resize(base.bgr, base.bgr, small_size, 0, 0, cv::INTER_AREA);
  if (!base.alpha.empty()) cv::resize(base.alpha, base.alpha, small_size, 0, 0, cv::INTER_AREA);
  if (!base.depth.empty()) cv::resize(base.depth, base.depth, small_size, 0, 0, cv::INTER_NEAREST);
  RenderedFrame frame = Compose(small, std::move(base), ctx).frame;
  cv::resize(frame.bgr, frame.bgr, full_size, 0, 0, cv::INTER_LINEAR);
  if (!frame.alpha.empty()) cv::resize(frame.alpha, frame.alpha, full_size, 0, 0, cv::INTER_LINEAR);
  if (!frame.depth.empty()) cv::resize(frame.depth, frame.depth, full_size, 0, 0, cv::INTER_NEAREST);
  const float sx = static_cast<float>(request.width) / small.width, sy = static_cast<float>(request.height) / small.height;
  for (auto* points : {&frame.landmarks, &frame.vertices}) {
    for (cv::Point2f& p : *points) p = {p.x * sx, p.y * sy};
  }
  frame.stages = "face update";
  return frame;
}

DetailLayers DetailFrameSource::RenderLayers(const FrameRequest& request, RunContext& ctx) const {
  FrameRequest base_request = request;
  if (options_.base_expression_every > 1) {
    std::lock_guard<std::mutex> lock(kept_->mutex);
    if (kept_->base_expression.has_value() && kept_->frames_with_it < options_.base_expression_every) {
      base_request.expression = *kept_->base_expression;
    } else {
      kept_->base_expression = request.expression;
      kept_->frames_with_it = 0;
    }
    ++kept_->frames_with_it;
  }
  RenderedFrame base = base_->Render(base_request, ctx);
  ++kept_->base_renders;
  ctx.ThrowIfCancelled();
  {
    std::lock_guard<std::mutex> lock(kept_->mutex);
    kept_->valid = true;
    kept_->view = request.view;
    kept_->width = request.width;
    kept_->height = request.height;
    kept_->base = base;
    kept_->base.bgr = base.bgr.clone();
    kept_->base.alpha = base.alpha.clone();
    kept_->base.depth = base.depth.clone();
  }
  return Compose(request, std::move(base), ctx);
}

DetailLayers DetailFrameSource::Compose(const FrameRequest& request, RenderedFrame base_frame, RunContext& ctx) const {
  DetailLayers layers;
  RenderedFrame& frame = layers.frame;
  frame = std::move(base_frame);
  ctx.ThrowIfCancelled();
  layers.network = frame.bgr.clone();
  const cv::Size size(request.width, request.height);
  // The face warp first: its changed eyes and mouth are left to the base frame by every layer.
  const compose::FaceWarp warp = Warp(request);
  if (depth_ != nullptr) {
    compose::FaceWarp depth = DepthWarp(request, frame, warp.face);
    compose::ExcludeRegion(&depth, warp.changed, options_.face.feather);
    compose::ClearCarved(depth, &frame.bgr, &frame.alpha, &frame.depth);
    frame.bgr = compose::Composite(frame.bgr, depth, &frame.alpha);
    layers.depth_weight = depth.weight;
  } else {
    layers.depth_weight = cv::Mat::zeros(size, CV_32FC1);
  }
  if (!warp.fill_bgr.empty()) {
    // Under the photo's warp, the textured face mesh over the whole face: what the photo did not
    // see of the face shows the fit's texture, not the network's blur (looked up through the face
    // warp's own rasterisation of the mesh).
    compose::FaceWarp fill;
    fill.bgr = warp.fill_bgr;
    fill.valid = warp.face.clone();  // ExcludeRegion edits it; the warp's own mask stays whole
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
