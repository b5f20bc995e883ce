#pragma once
// The packaged sample portrait's source analysis (real face analysis and morphable fit), made
// once per test process and shared by the suites that start from a real portrait.

#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/pipeline/source_analysis.h"

namespace avatar::testing {

inline const SourceAnalysis& SampleAnalysis() {
  static const SourceAnalysis analysis = [] {
    const cv::Mat photo = LoadImageBgr(
        DataPaths::Resolve().Require(DataPaths::kDefaultPortrait, "the sample portrait (run scripts/setup)"));
    RunContext ctx;
    return AnalyseSource(photo, "", ctx);
  }();
  return analysis;
}

}  // namespace avatar::testing
