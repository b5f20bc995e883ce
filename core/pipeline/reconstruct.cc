#include "core/pipeline/reconstruct.h"

#include <utility>

#include "core/pipeline/quality.h"

namespace avatar {

void ReconstructionOptions::Validate() const {
  if (!quality.empty()) QualityLevelByName(quality);
  refine.Validate();
}

RefineOptions EffectiveRefinement(const ReconstructionOptions& options) {
  RefineOptions r = options.refine;
  if (!r.Enabled() && !options.quality.empty()) r = QualityLevelByName(options.quality).Refine(r);
  r.data_dir = options.data_dir;
  return r;
}

Reconstruction ReconstructAnalysed(const Session& session, SourceAnalysis analysis,
                                   const ReconstructionOptions& options, RunContext& ctx) {
  options.Validate();
  const RefineOptions refine = EffectiveRefinement(options);
  Reconstruction out;
  out.analysis = std::move(analysis);
  {
    RunContext::ProgressRange range(ctx, 0.0, refine.Enabled() ? 0.1 : 1.0);
    out.avatar = session.ReconstructFromAnalysis(out.analysis, ctx);
  }
  if (refine.Enabled()) {
    // Refinement of the planes on the photo (progress "refine", step k/N; cancellable).
    RunContext::ProgressRange range(ctx, 0.1, 1.0);
    out.refinement = RefineAvatar(session, out.avatar, out.analysis, refine, ctx);
    out.avatar = out.refinement->avatar;
  }
  if (!options.quality.empty()) out.render = QualityLevelByName(options.quality).Render(session.Info());
  return out;
}

Reconstruction ReconstructPortrait(const Session& session, const cv::Mat& bgr, const ReconstructionOptions& options,
                                   RunContext& ctx) {
  options.Validate();
  SourceAnalysis analysis;
  {
    RunContext::ProgressRange range(ctx, 0.0, 0.4);
    analysis = AnalyseSource(bgr, options.data_dir, ctx);
  }
  RunContext::ProgressRange range(ctx, 0.4, 1.0);
  return ReconstructAnalysed(session, std::move(analysis), options, ctx);
}

}  // namespace avatar
