#include "core/pipeline/source_analysis.h"

#include <opencv2/imgproc.hpp>

#include "core/face/face_analyzer.h"
#include "core/io/data_paths.h"
#include "core/pipeline/morphable_expression_source.h"
#include "core/util/error.h"
#include "core/util/logging.h"

namespace avatar {
namespace {

cv::Point2f ToImage(const cv::Matx23d& crop_from_image, const cv::Point2f& p) {
  cv::Mat inverse;
  cv::invertAffineTransform(cv::Mat(crop_from_image), inverse);
  const cv::Matx23d m(inverse);
  return {static_cast<float>(m(0, 0) * p.x + m(0, 1) * p.y + m(0, 2)),
          static_cast<float>(m(1, 0) * p.x + m(1, 1) * p.y + m(1, 2))};
}

SourceOverlay OverlayOf(const face::PortraitReport& report, const face::AlignedPortrait& aligned) {
  SourceOverlay overlay;
  for (const auto& d : report.faces) overlay.faces.push_back(d.box);
  for (const auto& p : report.image_landmarks.points) overlay.landmarks.emplace_back(p.x, p.y);
  if (overlay.landmarks.empty()) {
    for (const auto& p : aligned.landmarks.points) {
      overlay.landmarks.push_back(ToImage(aligned.crop_from_image, cv::Point2f(p.x, p.y)));
    }
  }
  return overlay;
}

// What every analysis derives from its fit: the model, the face texture and the network inputs.
void Complete(const morphable::MorphableModel& model, morphable::FitResult fit, SourceAnalysis* out) {
  out->model = &model;
  out->morphable_fit = std::move(fit);
  out->texture = morphable::SampleTexture(model, out->morphable_fit, out->portrait.image_unmatted);
  out->fit.camera = out->morphable_fit.camera;
  out->fit.expressions = std::make_shared<MorphableExpressionSource>(model, out->morphable_fit, out->texture);
}

}  // namespace

SourceAnalysis AnalyseSource(const cv::Mat& bgr, const std::string& data_dir, RunContext& ctx) {
  face::FaceAnalyzerOptions options;
  options.data_dir = data_dir;
  options.embedding = false;  // reconstruction does not use the identity embedding
  return AnalyseSource(bgr, options, ctx);
}

SourceAnalysis AnalyseSource(const cv::Mat& bgr, const face::FaceAnalyzerOptions& analyzer, RunContext& ctx) {
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3) << "the portrait must be a non-empty 8-bit BGR image";
  const std::string& data_dir = analyzer.data_dir;
  SourceAnalysis out;
  {
    RunContext::ProgressRange range(ctx, 0.0, 0.8);
    ctx.Report("analyse face", 0.0, "loading face models");
    face::PortraitReport report;
    out.portrait = face::SharedFaceAnalyzer(analyzer).AnalyzePortrait(bgr, ctx, &report);
    out.overlay = OverlayOf(report, out.portrait);
  }
  for (const auto& w : out.portrait.warnings) {
    out.warnings.push_back(w);
    AVATAR_LOG(kWarning) << w;
  }
  ctx.Report("fit morphable model", 0.8);
  const morphable::MorphableModel& model = morphable::LoadDefaultModel(DataPaths::Resolve(data_dir));
  morphable::FitResult fit = morphable::Fit(model, out.portrait.landmarks, out.portrait.image.size());
  ctx.ThrowIfCancelled();
  ctx.Report("fit morphable model", 0.9, "sampling the face texture");
  Complete(model, std::move(fit), &out);
  ctx.Report("fit morphable model", 1.0);
  return out;
}

SourceAnalysis AnalysisFromFit(face::AlignedPortrait portrait, morphable::FitResult fit, const std::string& data_dir) {
  const cv::Mat& crop = portrait.image_unmatted;
  AVATAR_CHECK_INPUT(!crop.empty() && crop.type() == CV_8UC3) << "the stored portrait has no BGR8 crop";
  AVATAR_CHECK_INPUT(fit.image_size == crop.size())
      << "the stored fit refers to a " << fit.image_size.width << "x" << fit.image_size.height << " image, the crop is "
      << crop.cols << "x" << crop.rows;
  AVATAR_CHECK_INPUT(portrait.matte.size() == crop.size() && portrait.matte.type() == CV_32FC1)
      << "the stored matte must be CV_32FC1 of the crop's size";
  AVATAR_CHECK_INPUT(portrait.eye_mouth_mask.empty() ||
                     (portrait.eye_mouth_mask.size() == crop.size() && portrait.eye_mouth_mask.type() == CV_8UC1))
      << "the stored eye/mouth mask must be CV_8UC1 of the crop's size";
  if (portrait.eye_mouth_mask.empty()) portrait.eye_mouth_mask = cv::Mat::zeros(crop.size(), CV_8UC1);
  if (portrait.image.empty()) {
    // The matted crop: the person over black, as the analyser makes it.
    cv::Mat matte3, f;
    cv::cvtColor(portrait.matte, matte3, cv::COLOR_GRAY2BGR);
    crop.convertTo(f, CV_32FC3);
    f = f.mul(matte3);
    f.convertTo(portrait.image, CV_8UC3);
  }
  const morphable::MorphableModel& model = morphable::LoadDefaultModel(DataPaths::Resolve(data_dir));
  AVATAR_CHECK_INPUT(static_cast<int>(fit.alpha.size()) == model.num_identity() &&
                     static_cast<int>(fit.beta.size()) == model.num_expression())
      << "the stored fit does not belong to the default morphable model";
  SourceAnalysis out;
  out.portrait = std::move(portrait);
  Complete(model, std::move(fit), &out);
  return out;
}

}  // namespace avatar
