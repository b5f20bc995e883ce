// The fusion net's data and evaluation (core/tools/fusion_set.h, fusion_eval.h) on a tiny dataset
// built here (three sample photos, one held out) with the bundled 3D core:
//  - the set holds each photo's source view and views of the training photos' synthetic heads
//    (training only), the layers in the fusion net's format, and at the
//    source view the geometric composite gives the photo back inside the valid warp;
//  - a rerun resumes (renders nothing);
//  - `fusion eval` reports every path, and an untrained fusion net scores as the composite does
//    (it starts as the identity on the composite);
//  - bad options and a folder without a dataset are refused.
#include <gtest/gtest.h>

#include <cmath>

#include <filesystem>
#include <iostream>

#include <nlohmann/json.hpp>

#include "common/temp_dir.h"
#include "common/tiny_dataset.h"
#include "core/io/atomic_file.h"
#include "core/model/fusion_net.h"
#include "core/tools/fusion_eval.h"
#include "core/tools/fusion_set.h"
#include "core/train/fusion_training.h"
#include "core/train/metrics.h"
#include "core/util/error.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using testing::TempDir;

class FusionSet : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir();
    RunContext ctx;
    DatasetBuildOptions ds = testing::TinyDatasetOptions(*dir_ / "ds", 1);
    ds.synthetic = 8;  // 2.5D heads of the two training photos
    BuildDataset(ds, testing::TinyDatasetPhotos(), {}, ctx);
    report_ = BuildFusionSet(Options(), ctx);
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static FusionSetOptions Options() {
    FusionSetOptions o;
    o.dataset = (*dir_ / "ds").string();
    o.out_dir = (*dir_ / "fusion").string();
    o.size = 64;
    o.synthetic_sources = 2;
    o.targets_per_source = 3;
    o.print_progress = false;
    return o;
  }
  static TempDir* dir_;
  static FusionSetReport report_;
};
TempDir* FusionSet::dir_ = nullptr;
FusionSetReport FusionSet::report_;

TEST_F(FusionSet, HoldsEachPhotosSourceViewAndTheCompositeGivesThePhotoBack) {
  EXPECT_EQ(report_.val_samples, 1);  // the held-out photo's source view; no synthetic pairs
  EXPECT_EQ(report_.skipped, 0);
  EXPECT_NE(report_.model.find("neural model"), std::string::npos) << report_.model;
  const auto meta = nlohmann::json::parse(ReadFileBytes(*dir_ / "fusion" / "fusion.json"));
  EXPECT_EQ(meta.at("counts").at("train").at("samples").get<int64_t>(), report_.train_samples);
  const train::FusionSamples s = train::LoadFusionSplit((*dir_ / "fusion").string(), "train");
  ASSERT_EQ(s.size(), report_.train_samples);
  EXPECT_EQ(s.input.size(1), kFusionInputChannels);
  EXPECT_EQ(s.input.size(2), 64);
  EXPECT_EQ(s.target.size(1), 3);
  std::vector<int64_t> photos, synthetic;
  for (int64_t i = 0; i < s.size(); ++i) {
    const float kind = s.meta[i][3].item<float>();
    if (kind == 0.0f) {
      photos.push_back(i);
      EXPECT_NEAR(s.meta[i][0].item<float>(), 0.0f, 1e-3);  // source view: no yaw change
    } else {
      EXPECT_EQ(kind, 2.0f);
      synthetic.push_back(i);
    }
  }
  EXPECT_EQ(photos.size(), 2u);
  EXPECT_GE(synthetic.size(), 2u);          // two synthetic sources, each with other views of its head
  EXPECT_LE(synthetic.size(), 2u * 3u);
  const train::FusionSamples v = train::LoadFusionSplit((*dir_ / "fusion").string(), "val");
  ASSERT_EQ(v.size(), 1);
  EXPECT_EQ(v.meta[0][3].item<float>(), 0.0f);  // never a synthetic pair in validation
  const torch::Tensor idx = torch::tensor(photos);
  const torch::Tensor x = FusionInputFromBytes(s.input.index_select(0, idx));
  const torch::Tensor y = FusionInputFromBytes(s.target.index_select(0, idx), 3);
  const torch::Tensor valid = (x.slice(1, 6, 7) > 0.9).to(torch::kFloat32);
  EXPECT_GT(valid.sum().item<double>(), 2 * 200.0);  // the face is seen
  const torch::Tensor psnr = train::PsnrPerImage(x.slice(1, 0, 3), y, valid);
  const torch::Tensor network = train::PsnrPerImage(x.slice(1, 3, 6), y, valid);
  for (int64_t i = 0; i < 2; ++i) {
    std::cout << "source view " << i << ": composite " << psnr[i].item<double>() << " dB, network "
              << network[i].item<double>() << " dB inside the valid warp\n";
    EXPECT_GT(psnr[i].item<double>(), 25.0) << i;
    EXPECT_GT(psnr[i].item<double>(), network[i].item<double>() + 3.0) << i;
  }
}

TEST_F(FusionSet, RerunResumes) {
  RunContext ctx;
  const FusionSetReport again = BuildFusionSet(Options(), ctx);
  EXPECT_EQ(again.render_seconds, 0.0);
  EXPECT_EQ(again.train_samples, report_.train_samples);
  EXPECT_EQ(again.val_samples, report_.val_samples);
}

TEST_F(FusionSet, EvalReportsEveryPathAndAnUntrainedNetScoresAsTheComposite) {
  FusionNet net;
  SaveFusionNet(*dir_ / "untrained.ckpt", net, FusionNetInfo{}, false);
  FusionEvalOptions o;
  o.data = (*dir_ / "fusion").string();
  o.split = "train";
  o.weights = (*dir_ / "untrained.ckpt").string();
  o.sheet = (*dir_ / "sheet.png").string();
  o.face_metrics = true;
  RunContext ctx;
  const FusionEvalReport r = EvaluateFusionSet(o, ctx);
  EXPECT_EQ(r.samples, report_.train_samples);
  EXPECT_TRUE(fs::exists(*dir_ / "sheet.png"));
  const FusionEvalRow* composite = nullptr;
  const FusionEvalRow* learned = nullptr;
  int paths = 0;
  for (const auto& row : r.rows) {
    if (row.kind != "photo" || row.bucket != "all" || row.region != "frame") continue;
    ++paths;
    EXPECT_EQ(row.pairs, 2);
    // Face metrics on whole frames: the preview is a face mask that the analyser may miss, the
    // others hold the photo's face.
    EXPECT_LE(row.face_pairs, row.pairs);
    if (row.path != "morphable preview") EXPECT_GT(row.face_pairs, 0) << row.path;
    EXPECT_GE(row.csim, -1.0);
    EXPECT_LE(row.csim, 1.0);
    EXPECT_GE(row.aed, 0.0);
    EXPECT_TRUE(std::isfinite(row.aed));
    if (row.path == "geometric composite") composite = &row;
    if (row.path == "learned fusion") learned = &row;
  }
  EXPECT_EQ(paths, 4);
  ASSERT_TRUE(composite != nullptr && learned != nullptr);
  EXPECT_NEAR(learned->psnr, composite->psnr, 0.5);
  EXPECT_NEAR(learned->l1, composite->l1, 0.01);
  EXPECT_NEAR(learned->csim, composite->csim, 0.05);
  const std::string md = FusionEvalMarkdown(r);
  EXPECT_NE(md.find("| all | learned fusion | 2 |"), std::string::npos) << md;
  EXPECT_NE(md.find("| faces | CSIM | AED |"), std::string::npos) << md;
}

TEST_F(FusionSet, BadOptionsAndAMissingDatasetAreRefused) {
  FusionSetOptions o = Options();
  o.size = 60;
  EXPECT_THROW(o.Validate(), InvalidOptions);
  o = Options();
  o.dataset = (*dir_ / "none").string();
  o.out_dir = (*dir_ / "out-none").string();
  RunContext ctx;
  try {
    BuildFusionSet(o, ctx);
    FAIL() << "a folder without a dataset was accepted";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("none"), std::string::npos) << e.what();
  }
  FusionEvalOptions e;
  e.data = (*dir_ / "fusion").string();
  e.split = "test";
  EXPECT_THROW(EvaluateFusionSet(e, ctx), InvalidOptions);
}

}  // namespace
}  // namespace avatar
