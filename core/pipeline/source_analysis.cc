#include "core/pipeline/source_analysis.h"

#include "core/util/error.h"

namespace avatar {

SourceAnalysis AnalyseSource(const cv::Mat& bgr, const std::string& /*data_dir*/, RunContext& ctx) {
  AVATAR_CHECK_INPUT(!bgr.empty()) << "the portrait image is empty";
  ctx.ThrowIfCancelled();
  throw MissingData(
      "face analysis and the morphable model are not part of this build yet: reconstruct needs them to align the "
      "portrait and fit the source camera");
}

}  // namespace avatar
