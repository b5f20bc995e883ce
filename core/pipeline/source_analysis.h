#pragma once
// Source analysis for Session::Reconstruct: face analysis (aligned 512 crop, matte, eye/mouth
// mask, landmarks) and the morphable fit (source camera, expression renderer).

#include <string>

#include <opencv2/core.hpp>

#include "core/face/face_types.h"
#include "core/pipeline/session.h"
#include "core/util/run_context.h"

namespace avatar {

struct SourceAnalysis {
  face::AlignedPortrait portrait;
  SourceFit fit;
};

// Analyses a BGR photo. `data_dir` as in SessionOptions. Throws InvalidInput (no face),
// MissingData (face models not installed or not part of this build), Cancelled.
SourceAnalysis AnalyseSource(const cv::Mat& bgr, const std::string& data_dir, RunContext& ctx);

}  // namespace avatar
