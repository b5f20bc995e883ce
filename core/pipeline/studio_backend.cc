#include "core/pipeline/studio_backend.h"

#include "core/util/error.h"

namespace avatar {

void BackendOptions::Validate() const {
  AVATAR_CHECK_OPTION(preset == "lite" || preset == "paper") << "--preset must be lite or paper, got '" << preset << "'";
}

std::shared_ptr<const FrameSource> CreateFrameSource(const cv::Mat& portrait, const BackendOptions& options,
                                                     RunContext& ctx) {
  options.Validate();
  AVATAR_CHECK_INPUT(!portrait.empty() && portrait.type() == CV_8UC3) << "the portrait must be a BGR8 image";
  if (options.random_weights) {
    throw InvalidOptions("--random-weights: the neural network session is not part of this build yet");
  }
  ctx.Report("prepare", 1.0);
  return std::make_shared<PortraitFrameSource>(portrait);
}

FrameAnalyzerFactory DrivingAnalyzers(const BackendOptions& /*options*/) {
  return [](RunContext&) -> std::unique_ptr<FrameAnalyzer> { return nullptr; };
}

std::string BackendStatement(const BackendOptions& options) {
  if (options.random_weights) return "The neural network runs with RANDOM weights: the frames are not a result.";
  return "The neural model is not trained yet; this build shows the portrait only.";
}

}  // namespace avatar
