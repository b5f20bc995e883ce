// `avatar-studio bench accuracy` on a tiny random checkpoint and a tiny dataset built by the data
// factory from three packaged photos (as eval_test.cc builds one): one table row per quality
// level, its detail-path twin and per swept step count, each with finite metrics and positive
// times, refined rows costing their refinement on top of the one-shot time, detail rows costing
// their bake on top and showing the photo at its own view, a plot that decodes, and clear errors
// for a missing dataset, an unknown quality level or detail path.

#include <cmath>
#include <filesystem>
#include <iostream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/temp_dir.h"
#include "common/tiny_checkpoint.h"
#include "common/tiny_evaluation.h"
#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/model/goha_model.h"
#include "core/tools/dataset_build.h"
#include "core/pipeline/quality.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::TempDir;

class BenchAccuracy : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    CheckpointInfo info;
    info.data_provenance = "random init (bench accuracy test)";
    inputs_ = testing::MakeTinyEvaluationInputs(7, {{"tiny.ckpt", info}});
  }
  static void TearDownTestSuite() { inputs_.reset(); }
  static testing::ProcessResult Studio(const std::string& args) { return testing::RunStudio(AVATAR_STUDIO_EXE, args); }
  static std::string Common() {
    return "--checkpoint '" + inputs_->Checkpoint("tiny.ckpt").string() + "' --data '" + inputs_->Data().string() +
           "' --threads 2";
  }
  static std::unique_ptr<testing::TinyEvaluationInputs> inputs_;
};
std::unique_ptr<testing::TinyEvaluationInputs> BenchAccuracy::inputs_;

TEST_F(BenchAccuracy, OneRowPerLevelAndSweptStepWithFiniteMetricsAndAPlot) {
  ASSERT_GE(inputs_->report.val_pairs, 2) << "the tiny dataset needs two validation portraits";
  TempDir out;
  const auto r = Studio("bench accuracy " + Common() + " --portraits 2 --refine-steps 0,3 --out '" +
                        out.path().string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;

  const json j = json::parse(ReadFileBytes(out / "accuracy.json"));
  EXPECT_EQ(j["portraits"].get<int>(), 2);
  ASSERT_EQ(j["per_portrait"].size(), 2u);
  const std::string md = ReadFileBytes(out / "accuracy.md");
  std::vector<std::string> expected;
  for (const auto& p : QualityLadder()) {
    expected.push_back(p.name);
    expected.push_back(p.name + " + detail");
  }
  expected.push_back("refine 0");
  expected.push_back("refine 3");
  ASSERT_EQ(j["rows"].size(), expected.size());
  std::map<std::string, json> by_name;
  for (size_t i = 0; i < expected.size(); ++i) {
    const json& row = j["rows"][i];
    const std::string name = row["name"];
    EXPECT_EQ(name, expected[i]);
    by_name[name] = row;
    EXPECT_NE(md.find("| " + name + " |"), std::string::npos) << name << " not in\n" << md;
    for (const char* k : {"reconstruct_seconds", "frame_seconds"}) {
      ASSERT_TRUE(row[k].is_number()) << name << " " << k;
      EXPECT_GT(row[k].get<double>(), 0.0) << name << " " << k;
    }
    for (const char* k : {"psnr", "psnr_matte", "ssim", "perceptual"}) {
      ASSERT_TRUE(row[k].is_number()) << name << " " << k;
      EXPECT_TRUE(std::isfinite(row[k].get<double>())) << name << " " << k;
    }
    EXPECT_GE(row["ssim"].get<double>(), -1.0);
    EXPECT_LE(row["ssim"].get<double>(), 1.0);
    EXPECT_GE(row["perceptual"].get<double>(), 0.0);
    EXPECT_EQ(row["csim_plus"]["pairs"].get<int>(), 2) << name;
    EXPECT_EQ(row["csim_minus"]["pairs"].get<int>(), 2) << name;
  }
  // Settings follow the ladder: paper renders the model's size with SR, instant half of it.
  EXPECT_EQ(by_name["paper"]["render_size"].get<int>(), 16);
  EXPECT_TRUE(by_name["paper"]["super_resolution"].get<bool>());
  EXPECT_EQ(by_name["instant"]["render_size"].get<int>(), 8);
  EXPECT_EQ(by_name["best"]["refine_steps"].get<int>(), 100);
  // Refined rows pay their refinement on top of the same one-shot time (per portrait).
  for (const auto& p : j["per_portrait"]) {
    const json& rows = p["rows"];
    const double one_shot = p["one_shot_seconds"].get<double>();
    EXPECT_DOUBLE_EQ(rows["standard"]["reconstruct_seconds"].get<double>(), one_shot);
    EXPECT_DOUBLE_EQ(rows["refine 0"]["reconstruct_seconds"].get<double>(), one_shot);
    for (const char* refined : {"fine", "best", "refine 3"})
      EXPECT_GT(rows[refined]["reconstruct_seconds"].get<double>(), one_shot) << refined;
    // Same planes and settings: the same source-view PSNR.
    EXPECT_EQ(rows["standard"]["psnr"], rows["refine 0"]["psnr"]);
    // The detail twin: the same avatar plus the bake; at the source view it shows the photo
    // itself, which the random network does not (measured +14..+19 dB over the random net).
    for (const auto& level : QualityLadder()) {
      const json& plain = rows[level.name];
      const json& detail = rows[level.name + " + detail"];
      EXPECT_GT(detail["reconstruct_seconds"].get<double>(), plain["reconstruct_seconds"].get<double>()) << level.name;
      std::cout << level.name << ": PSNR (matte) " << plain["psnr_matte"] << " -> " << detail["psnr_matte"]
                << " with detail\n";
      EXPECT_GT(detail["psnr_matte"].get<double>(), plain["psnr_matte"].get<double>() + 10.0) << level.name;
    }
  }
  for (const json& row : j["rows"]) {
    const std::string name = row["name"];
    const bool twin = name.find(" + detail") != std::string::npos;
    EXPECT_EQ(row["detail"].get<std::string>(), twin ? "head" : "off") << name;
  }
  const cv::Mat plot = cv::imread((out / "accuracy.png").string());
  ASSERT_FALSE(plot.empty()) << "accuracy.png does not decode";
  EXPECT_EQ(plot.cols, 1200);
  EXPECT_EQ(plot.rows, 520);
  // The plot is drawn (not a blank canvas).
  cv::Mat grey;
  cv::cvtColor(plot, grey, cv::COLOR_BGR2GRAY);
  EXPECT_GT(cv::countNonZero(grey < 128), 1000);
  for (const auto& name : out.List()) EXPECT_EQ(name.find(".tmp"), std::string::npos) << "temporary left: " << name;
}

TEST_F(BenchAccuracy, ExpressionBasesCheckpointIsMeasuredWithTheDatasetsCoefficients) {
  // A network whose T_e comes from morphable coefficients: each portrait gives its shard's beta.
  TempDir out;
  testing::SaveTinyCheckpoint(out / "bases.ckpt", 9, {}, /*expression_bases=*/true);
  const auto r = Studio("bench accuracy --checkpoint '" + (out / "bases.ckpt").string() + "' --data '" +
                        inputs_->Data().string() + "' --threads 2 --portraits 1 --quality standard --refine-steps 0 " +
                        "--no-face-metrics --out '" + (out / "report").string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  const json j = json::parse(ReadFileBytes(out / "report" / "accuracy.json"));
  ASSERT_EQ(j["rows"].size(), 3u);  // standard, standard + detail, refine 0
  for (const json& row : j["rows"]) {
    for (const char* k : {"psnr", "ssim", "frame_seconds"}) {
      ASSERT_TRUE(row[k].is_number()) << row["name"] << " " << k;
      EXPECT_TRUE(std::isfinite(row[k].get<double>())) << row["name"] << " " << k;
    }
  }
}

TEST_F(BenchAccuracy, BadInputsNameTheProblem) {
  TempDir out;
  const auto missing = Studio("bench accuracy --data '" + (out / "nope").string() + "' --out '" +
                              out.path().string() + "' --threads 2");
  EXPECT_EQ(missing.exit_code, 1) << missing.err;
  EXPECT_NE(missing.err.find("nope"), std::string::npos) << missing.err;
  EXPECT_NE(missing.err.find("dataset build"), std::string::npos) << missing.err;
  const auto level = Studio("bench accuracy " + Common() + " --quality fine,ultra --out '" + out.path().string() + "'");
  EXPECT_EQ(level.exit_code, 2) << level.err;
  EXPECT_NE(level.err.find("ultra"), std::string::npos) << level.err;
  const auto steps = Studio("bench accuracy " + Common() + " --refine-steps 5,x --out '" + out.path().string() + "'");
  EXPECT_EQ(steps.exit_code, 2) << steps.err;
  EXPECT_NE(steps.err.find("'x'"), std::string::npos) << steps.err;
  const auto detail = Studio("bench accuracy " + Common() + " --detail sideways --out '" + out.path().string() + "'");
  EXPECT_EQ(detail.exit_code, 2) << detail.err;
  EXPECT_NE(detail.err.find("sideways"), std::string::npos) << detail.err;
}

}  // namespace
}  // namespace avatar
