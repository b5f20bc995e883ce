// `avatar-studio eval` and core/pipeline/evaluate on a tiny random checkpoint and a tiny dataset
// built by the data factory from three packaged photos: every row of eval.json has finite image
// metrics and appears in the table, a render's PSNR equals train::Psnr computed independently,
// SR is reported as not trained (or measured when the checkpoint says it was trained), and bad
// paths give errors naming the file.

#include <cmath>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <torch/serialize.h>

#include "common/dataset_shard.h"
#include "common/temp_dir.h"
#include "common/tiny_evaluation.h"
#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/model/goha_model.h"
#include "core/tools/dataset_build.h"
#include "core/tools/evaluate.h"
#include "core/render/camera.h"
#include "core/train/dataset.h"
#include "core/train/losses.h"
#include "core/util/error.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::TempDir;

// Shared inputs: one dataset and two tiny checkpoints (SR untrained / "trained") per process.
class EvalTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    CheckpointInfo info;
    info.data_provenance = "random init (eval test)";
    CheckpointInfo sr_info = info;
    sr_info.sr_trained = true;
    inputs_ = testing::MakeTinyEvaluationInputs(3, {{"tiny.ckpt", info}, {"tiny_sr.ckpt", sr_info}});
  }
  static void TearDownTestSuite() { inputs_.reset(); }

  static fs::path Data() { return inputs_->Data(); }
  static fs::path Checkpoint(bool sr = false) { return inputs_->Checkpoint(sr ? "tiny_sr.ckpt" : "tiny.ckpt"); }
  static json Load(const fs::path& p) { return json::parse(ReadFileBytes(p)); }

  static std::unique_ptr<testing::TinyEvaluationInputs> inputs_;
};
std::unique_ptr<testing::TinyEvaluationInputs> EvalTest::inputs_;

testing::ProcessResult Studio(const std::string& args) { return testing::RunStudio(AVATAR_STUDIO_EXE, args); }

TEST_F(EvalTest, CommandWritesEveryRowWithFiniteMetricsTableAndContactSheet) {
  ASSERT_GE(inputs_->report.val_pairs, 2) << "the tiny dataset needs two validation pairs";
  TempDir out;
  const auto r = Studio("eval --checkpoint '" + Checkpoint().string() + "' --data '" + Data().string() +
                        "' --split val --max-pairs 0 --out '" + out.path().string() + "' --threads 2");
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  EXPECT_NE(r.err.find("ETA"), std::string::npos) << "no progress line: " << r.err;

  const json j = Load(out / "eval.json");
  EXPECT_EQ(j["pairs"].get<int>(), inputs_->report.val_pairs);
  EXPECT_EQ(j["checkpoint"]["sr_trained"].get<bool>(), false);
  const std::string md = ReadFileBytes(out / "eval.md");
  ASSERT_EQ(j["rows"].size(), 6u);
  for (const auto& row : j["rows"]) {
    const std::string key = row["key"];
    EXPECT_NE(md.find("| " + row["name"].get<std::string>() + " |"), std::string::npos) << key << " not in\n" << md;
    if (key == "sr") {
      EXPECT_FALSE(row["available"].get<bool>());
      EXPECT_NE(row["note"].get<std::string>().find("not trained"), std::string::npos);
      EXPECT_FALSE(row.contains("full"));
      continue;
    }
    ASSERT_TRUE(row["available"].get<bool>()) << key << ": " << row.value("note", "");
    for (const char* part : {"full", "matte"}) {
      for (const char* m : {"psnr", "ssim", "l1", "perceptual"}) {
        ASSERT_TRUE(row[part].contains(m) && row[part][m].is_number()) << key << " " << part << " " << m;
        const double v = row[part][m].get<double>();
        EXPECT_TRUE(std::isfinite(v)) << key << " " << part << " " << m;
      }
      EXPECT_GE(row[part]["ssim"].get<double>(), -1.0);
      EXPECT_LE(row[part]["ssim"].get<double>(), 1.0);
      EXPECT_GE(row[part]["l1"].get<double>(), 0.0);
      EXPECT_GE(row[part]["perceptual"].get<double>(), 0.0);
    }
    // Face metrics: every pair is counted; the targets are real faces.
    const json& f = row["face"];
    EXPECT_EQ(f["pairs"].get<int>(), inputs_->report.val_pairs) << key;
    EXPECT_EQ(f["no_face_target"].get<int>(), 0) << key;
    EXPECT_EQ(f["valid"].get<int>() + f["no_face_render"].get<int>(), f["pairs"].get<int>()) << key;
    if (f["valid"].get<int>() > 0) {
      for (const char* m : {"csim", "aed", "apd"}) EXPECT_TRUE(std::isfinite(f[m].get<double>())) << key << " " << m;
    }
  }
  EXPECT_NE(md.find("not trained"), std::string::npos) << md;
  // The morphable baseline of real faces is a face: CSIM is measured for it.
  EXPECT_GT(j["rows"][0]["face"]["valid"].get<int>(), 0) << md;
  ASSERT_EQ(j["per_pair"].size(), static_cast<size_t>(inputs_->report.val_pairs));

  const cv::Mat contact = cv::imread((out / "contact.png").string());
  ASSERT_FALSE(contact.empty());
  EXPECT_EQ(contact.cols, 6 * 128);  // source, target, baseline, I_c, I_c+e, I_c+e+p
  EXPECT_GE(contact.rows, 2 * 128);
  for (const auto& name : out.List()) EXPECT_EQ(name.find(".tmp"), std::string::npos) << "temporary left: " << name;
}

TEST_F(EvalTest, RenderPsnrEqualsAnIndependentPsnr) {
  TempDir out;
  EvaluateOptions o;
  o.checkpoint = Checkpoint().string();
  o.data = Data().string();
  o.out = out.path().string();
  o.max_pairs = 0;
  o.face_metrics = false;
  o.perceptual = false;
  o.print_progress = false;
  RunContext ctx;
  const EvaluateReport report = RunEvaluation(o, ctx);
  const json j = Load(report.json_path);
  ASSERT_FALSE(j["per_pair"].empty());

  // The same renders through the model API, compared with train::Psnr (a whole-batch scalar).
  LoadedModel loaded = LoadModelCheckpoint(Checkpoint());
  GohaModel& model = loaded.model;
  model->eval();
  torch::NoGradGuard no_grad;
  const auto dataset = train::TrainDataset::Open(Data().string(), "val");
  const ModelConfig& c = model->config();
  double mean_full = 0.0;
  for (const auto& p : j["per_pair"]) {
    const train::TrainSample s = dataset.Get(p["index"].get<int64_t>());
    const train::TrainBatch b = train::Collate({s});
    const auto in = [&](const torch::Tensor& x) { return train::ResizeTo(x, c.image_size); };
    const torch::Tensor tc = model->CanonicalPlanes(in(b.source));
    const torch::Tensor tce = tc + model->ExpressionPlanes(in(b.expression_image));
    const torch::Tensor tp = model->AppearancePlanes(in(b.source), in(b.source_eye_mouth), in(b.source_matte), tc,
                                                     render::CamerasFromLabels(b.source_label))
                                 .planes;
    const render::Cameras cam = render::CamerasFromLabels(b.target_label);
    const torch::Tensor target = train::ResizeTo(train::Matte(b.target, b.target_matte), c.render_size);
    const double psnr_c = train::Psnr(model->Render(tc, cam, 0, true).rgb, target);
    const double psnr_full = train::Psnr(model->Render(tce + tp, cam, 0, true).rgb, target);
    EXPECT_NEAR(p["rows"]["canonical"]["psnr"].get<double>(), psnr_c, 1e-3);
    EXPECT_NEAR(p["rows"]["full"]["psnr"].get<double>(), psnr_full, 1e-3);
    EXPECT_TRUE(std::isfinite(psnr_full));
    mean_full += psnr_full / static_cast<double>(j["per_pair"].size());
  }
  EXPECT_NEAR(report.rows[3].full.at("psnr"), mean_full, 1e-3);
  // The tiny dataset has photo pairs only: the per-kind rows are the overall rows.
  ASSERT_EQ(report.rows_by_kind.size(), 1u);
  ASSERT_EQ(report.rows_by_kind.at("photo").size(), 6u);
  EXPECT_NEAR(report.rows_by_kind.at("photo")[3].full.at("psnr"), mean_full, 1e-3);
  EXPECT_EQ(j["rows_by_kind"]["photo"].size(), 6u);
  EXPECT_EQ(report.rows[3].key, "full");
  // Face metrics off: no face numbers, and no perceptual column.
  EXPECT_EQ(report.rows[3].face.pairs, 0);
  EXPECT_EQ(report.rows[3].full.count("perceptual"), 0u);
}

TEST_F(EvalTest, TrainedSrIsMeasuredAtItsResolution) {
  TempDir out;
  EvaluateOptions o;
  o.checkpoint = Checkpoint(true).string();
  o.data = Data().string();
  o.out = out.path().string();
  o.max_pairs = 1;
  o.face_metrics = false;
  o.print_progress = false;
  RunContext ctx;
  const EvaluateReport report = RunEvaluation(o, ctx);
  EXPECT_EQ(report.pairs, 1);
  ASSERT_EQ(report.rows.size(), 6u);
  const EvalRow& sr = report.rows[4];
  ASSERT_TRUE(sr.available);
  EXPECT_EQ(sr.resolution, ModelConfig::Tiny().sr_size);
  EXPECT_TRUE(std::isfinite(sr.full.at("psnr")));
  EXPECT_TRUE(std::isfinite(sr.masked.at("perceptual")));
  // The bicubic upsampling of I_c+e+p, at the SR's size: the yardstick the SR must beat.
  const EvalRow& up = report.rows[5];
  ASSERT_TRUE(up.available);
  EXPECT_EQ(up.resolution, ModelConfig::Tiny().sr_size);
  EXPECT_TRUE(std::isfinite(up.full.at("psnr")));
  const cv::Mat contact = cv::imread(report.contact_path);
  EXPECT_EQ(contact.cols, 7 * 128);
}

TEST_F(EvalTest, BadPathsGiveErrorsNamingTheFile) {
  TempDir out;
  const std::string data = " --data '" + Data().string() + "' --out '" + out.path().string() + "'";
  const fs::path missing = out / "no_such_model.ckpt";
  auto r = Studio("eval --checkpoint '" + missing.string() + "'" + data);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("no_such_model.ckpt"), std::string::npos) << r.err;

  const fs::path garbage = out / "garbage.ckpt";
  WriteBytesAtomically(garbage, "not a checkpoint at all");
  r = Studio("eval --checkpoint '" + garbage.string() + "'" + data);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("garbage.ckpt"), std::string::npos) << r.err;

  r = Studio("eval --checkpoint '" + Checkpoint().string() + "' --data '" + (out / "no_such_data").string() +
             "' --out '" + out.path().string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("no_such_data"), std::string::npos) << r.err;

  r = Studio("eval --data '" + Data().string() + "'");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--checkpoint"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out / "eval.json"));
}

TEST_F(EvalTest, CancelWritesNothing) {
  TempDir out;
  EvaluateOptions o;
  o.checkpoint = Checkpoint().string();
  o.data = Data().string();
  o.out = out.path().string();
  o.face_metrics = false;
  o.perceptual = false;
  o.print_progress = false;
  RunContext ctx;
  ctx.RequestCancel();
  EXPECT_THROW(RunEvaluation(o, ctx), Cancelled);
  EXPECT_FALSE(fs::exists(out / "eval.json"));
  EXPECT_FALSE(fs::exists(out / "eval.md"));

  o.split = "test";
  RunContext fresh;
  EXPECT_THROW(RunEvaluation(o, fresh), InvalidOptions);
}

// A val split of `photos` photo pairs and `clips` clip pairs (kinds interleaved as the builder
// writes them: photos first, then clips), 8 px frames, written as dataset_build writes shards.
fs::path ValSplitOf(const TempDir& dir, int64_t photos, int64_t clips) {
  const int64_t n = photos + clips, s = 8;
  const std::string bytes = testing::DatasetShardBytes(n, s, 4, torch::arange(n, torch::kInt64).remainder(3), [&] {
    const torch::Tensor frames = torch::arange(n, torch::kInt64);
    return std::make_pair(torch::stack({frames, frames}, 1),
                          torch::cat({torch::zeros({photos}, torch::kInt64), torch::ones({clips}, torch::kInt64)}));
  });
  const fs::path root = dir / ("val_" + std::to_string(photos) + "_" + std::to_string(clips));
  fs::create_directories(root / "shards");
  WriteBytesAtomically(root / "shards" / "val.pt", bytes);
  const nlohmann::json ds = {{"size", s},
                             {"labels", nlohmann::json::array()},
                             {"shards", {{"train", "shards/train.pt"}, {"val", "shards/val.pt"}}}};
  WriteBytesAtomically(root / "dataset.json", ds.dump());
  return root;
}

TEST(EvalPairs, EqualSharesPerKindEvenlySpaced) {
  // ChooseEvaluationPairs: at most half of the chosen pairs per kind while both kinds have enough
  // (all photos when there are fewer), increasing indices, every pair for max_pairs 0.
  TempDir dir;
  torch::manual_seed(3);
  for (const auto& [photos, clips] : std::vector<std::pair<int64_t, int64_t>>{{21, 43}, {4, 60}, {30, 5}}) {
    const auto ds = train::TrainDataset::Open(ValSplitOf(dir, photos, clips).string(), "val");
    ASSERT_EQ(ds.CountKind(train::PairKind::kPhoto), photos);
    const auto chosen = ChooseEvaluationPairs(ds, 20);
    ASSERT_EQ(chosen.size(), 20u) << photos << " photos, " << clips << " clips";
    int64_t photo_chosen = 0;
    for (size_t i = 0; i < chosen.size(); ++i) {
      if (i > 0) {
        EXPECT_LT(chosen[i - 1], chosen[i]);
      }
      if (ds.Get(chosen[i]).kind == train::PairKind::kPhoto) ++photo_chosen;
    }
    // Equal shares (10 + 10) when both kinds have 10; otherwise the scarce kind gives all it has.
    const int64_t expected = clips >= 10 ? std::min<int64_t>(photos, 10) : 20 - clips;
    EXPECT_EQ(photo_chosen, expected) << photos << " photos, " << clips << " clips";
    // Evenly spaced within a kind: the chosen photos reach into the second half of the photos.
    int64_t last_photo = -1;
    for (int64_t i : chosen)
      if (i < photos) last_photo = std::max(last_photo, i);
    EXPECT_GE(last_photo, photos / 2) << photos << " photos, " << clips << " clips";
    EXPECT_EQ(ChooseEvaluationPairs(ds, 0).size(), static_cast<size_t>(ds.size()));
  }
}

}  // namespace
}  // namespace avatar
