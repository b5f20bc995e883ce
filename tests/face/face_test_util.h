#pragma once
// Shared helpers of the face tests: the installed sample data and one analyzer per process.

#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "core/face/face_analyzer.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"

namespace avatar::face::testing {

// A sample file from the installed data; a missing file fails the test (run scripts/setup).
inline std::filesystem::path Sample(const std::string& name) {
  return DataPaths::Resolve().Require("samples/" + name, "face test sample (run scripts/setup)");
}

inline cv::Mat LoadSample(const std::string& name) { return LoadImageBgr(Sample(name)); }

// The process-wide analyzer (models load once; FaceAnalyzer is thread-safe).
inline const FaceAnalyzer& Analyzer() {
  static const FaceAnalyzer analyzer;
  return analyzer;
}

}  // namespace avatar::face::testing
