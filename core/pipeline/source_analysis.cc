#include "core/pipeline/source_analysis.h"

#include "core/face/face_analyzer.h"
#include "core/io/data_paths.h"
#include "core/morphable/morphable.h"
#include "core/pipeline/morphable_expression_source.h"
#include "core/util/error.h"

namespace avatar {

SourceAnalysis AnalyseSource(const cv::Mat& bgr, const std::string& data_dir, RunContext& ctx) {
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3) << "the portrait must be a non-empty 8-bit BGR image";
  SourceAnalysis out;
  {
    RunContext::ProgressRange range(ctx, 0.0, 0.8);
    ctx.Report("analyse face", 0.0, "loading face models");
    face::FaceAnalyzerOptions options;
    options.data_dir = data_dir;
    out.portrait = face::SharedFaceAnalyzer(options).AnalyzePortrait(bgr, ctx);
  }
  ctx.Report("fit morphable model", 0.8);
  const morphable::MorphableModel& model = morphable::LoadDefaultModel(DataPaths::Resolve(data_dir));
  morphable::FitResult fit = morphable::Fit(model, out.portrait.landmarks, out.portrait.image.size());
  ctx.ThrowIfCancelled();
  ctx.Report("fit morphable model", 0.9, "sampling the face texture");
  morphable::Texture texture = morphable::SampleTexture(model, fit, out.portrait.image_unmatted);
  out.fit.camera = fit.camera;
  out.fit.expressions = std::make_shared<MorphableExpressionSource>(model, std::move(fit), std::move(texture));
  ctx.Report("fit morphable model", 1.0);
  return out;
}

}  // namespace avatar
