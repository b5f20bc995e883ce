// The ablation checkpoints (issue 14) on a real dataset built by the data factory from three
// packaged photos: a bases model takes the dataset's morphable coefficients in a training step,
// and `eval` (core/pipeline/evaluate) reports both variants: without an appearance branch the
// I_c+e+p row says it is I_c+e and repeats its numbers; with expression bases T_e comes from the
// coefficients. The `train` command: --no-appearance and --expression-model bases reach the
// weights, and --resume / --init-weights keep them without the flag.

#include <cmath>
#include <filesystem>
#include <iostream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "common/run_process.h"
#include "common/temp_dir.h"
#include "common/tiny_dataset.h"
#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/model/goha_model.h"
#include "core/morphable/morphable_model.h"
#include "core/tools/dataset_build.h"
#include "core/tools/evaluate.h"
#include "core/train/dataset.h"
#include "core/train/trainer.h"
#include "train/trainer_test_util.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

class AblationEval : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new avatar::testing::TempDir();
    RunContext ctx;
    BuildDataset(avatar::testing::TinyDatasetOptions(*dir_ / "ds", 2), avatar::testing::TinyDatasetPhotos(), {}, ctx);
    const train::TrainDataset val = train::TrainDataset::Open((*dir_ / "ds").string(), "val");
    coefficients_ = val.Get(0).target_expression.size(0);

    torch::manual_seed(51);
    CheckpointInfo info;
    info.data_provenance = "random init (ablation eval test)";
    ModelConfig no_app = ModelConfig::Tiny();
    no_app.appearance_branch = false;
    GohaModel a(no_app);
    SaveModelCheckpoint(*dir_ / "no_app.ckpt", a, info);
    GohaModel b(BasesConfig());
    {
      torch::NoGradGuard g;
      b->expression_bases.copy_(torch::randn(b->expression_bases.sizes()));
    }
    SaveModelCheckpoint(*dir_ / "bases.ckpt", b, info);
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static ModelConfig BasesConfig() {
    ModelConfig c = ModelConfig::Tiny();
    c.expression_model = "bases";
    c.expression_coefficients = static_cast<int>(coefficients_);
    c.Validate();
    return c;
  }
  static EvaluateReport Evaluate(const std::string& checkpoint, const std::string& out) {
    EvaluateOptions o;
    o.checkpoint = (*dir_ / checkpoint).string();
    o.data = (*dir_ / "ds").string();
    o.out = (*dir_ / out).string();
    o.face_metrics = false;
    o.perceptual = false;
    o.baseline = false;
    o.print_progress = false;
    RunContext ctx;
    return RunEvaluation(o, ctx);
  }
  static const EvalRow& Row(const EvaluateReport& r, const std::string& key) {
    for (const auto& row : r.rows)
      if (row.key == key) return row;
    throw std::runtime_error("no row " + key);
  }

  static avatar::testing::TempDir* dir_;
  static int64_t coefficients_;
};
avatar::testing::TempDir* AblationEval::dir_ = nullptr;
int64_t AblationEval::coefficients_ = 0;

TEST_F(AblationEval, BasesTrainOnTheDatasetsCoefficients) {
  // The dataset carries our morphable model's coefficients (24 PCA + 2 eye components).
  EXPECT_GT(coefficients_, 0);
  const morphable::MorphableModel& mm = morphable::LoadDefaultModel(DataPaths::Resolve());
  const torch::Tensor std_k = torch::tensor(mm.expression_std());
  std::cout << "dataset expression coefficients per frame: " << coefficients_ << "; morphable std "
            << std_k.min().item<double>() << " .. " << std_k.max().item<double>() << "\n";
  const train::TrainDataset train_split = train::TrainDataset::Open((*dir_ / "ds").string(), "train");
  ASSERT_GT(train_split.size(), 0);
  const train::TrainBatch batch = train::Collate({train_split.Get(0)});
  ASSERT_EQ(batch.target_expression.size(1), coefficients_);
  std::cout << "|beta| of the first pair's target: max " << batch.target_expression.abs().max().item<double>()
            << ", in std units max " << (batch.target_expression[0] / std_k).abs().max().item<double>() << "\n";
  train::TrainerOptions o = train::TestOptions();
  o.expression_start = 0;
  o.appearance_start = 0;
  ModelConfig c = BasesConfig();
  c.image_size = 128;  // the dataset's size
  train::StageOneTrainer trainer(GohaModel(c), o, train::kStandIn);
  const train::StepResult r = trainer.Step(batch);
  ASSERT_FALSE(r.skipped) << r.skip_reason;
  EXPECT_EQ(r.terms.count("expression"), 1u);
  EXPECT_GT(trainer.model()->expression_bases.abs().max().item<double>(), 0.0);
}

TEST_F(AblationEval, WithoutAppearanceTheOutputRowIsIce) {
  const EvaluateReport r = Evaluate("no_app.ckpt", "eval_no_app");
  ASSERT_GT(r.pairs, 0);
  const EvalRow& full = Row(r, "full");
  const EvalRow& expression = Row(r, "expression");
  ASSERT_TRUE(full.available);
  EXPECT_NE(full.name.find("no appearance branch"), std::string::npos) << full.name;
  EXPECT_FALSE(full.note.empty());
  for (const char* k : {"psnr", "ssim", "l1"}) {
    EXPECT_EQ(full.full.at(k), expression.full.at(k)) << k;
    EXPECT_EQ(full.masked.at(k), expression.masked.at(k)) << k;
  }
  EXPECT_NE(r.markdown.find("ablation: no appearance branch"), std::string::npos) << r.markdown;
  const json j = json::parse(ReadFileBytes(r.json_path));
  EXPECT_FALSE(j["checkpoint"]["appearance_branch"].get<bool>());
  EXPECT_EQ(j["checkpoint"]["expression_model"], "encoder");
}

TEST_F(AblationEval, BasesModelIsEvaluatedFromTheCoefficients) {
  const EvaluateReport r = Evaluate("bases.ckpt", "eval_bases");
  ASSERT_GT(r.pairs, 0);
  const EvalRow& canonical = Row(r, "canonical");
  const EvalRow& expression = Row(r, "expression");
  ASSERT_TRUE(expression.available);
  EXPECT_TRUE(std::isfinite(expression.full.at("psnr")));
  // Random bases and non-zero coefficients: T_e changes the render.
  EXPECT_NE(expression.full.at("psnr"), canonical.full.at("psnr"));
  EXPECT_EQ(Row(r, "full").name, "I_c+e+p");
  EXPECT_NE(r.markdown.find("linear expression bases"), std::string::npos) << r.markdown;
  const json j = json::parse(ReadFileBytes(r.json_path));
  EXPECT_EQ(j["checkpoint"]["expression_model"], "bases");
  EXPECT_EQ(j["checkpoint"]["expression_coefficients"].get<int64_t>(), coefficients_);
  EXPECT_TRUE(j["checkpoint"]["appearance_branch"].get<bool>());
}

// `avatar-studio train` on the tiny network at the dataset's 128 px, a couple of steps each.
TEST_F(AblationEval, TrainCommandStoresTheSwitchesAndResumeAndInitKeepThem) {
  ModelConfig tiny = ModelConfig::Tiny();
  tiny.name = "tiny128";
  tiny.image_size = 128;
  const fs::path config = *dir_ / "tiny128.json";
  WriteBytesAtomically(config, ModelConfigToJson(tiny));
  const auto train = [&](const std::string& out, const std::string& args) {
    const avatar::testing::ProcessResult r = avatar::testing::RunProcess(
        std::string("'") + AVATAR_STUDIO_EXE + "' train --config '" + config.string() + "' --data '" +
            (*dir_ / "ds").string() + "' --out '" + (*dir_ / out).string() +
            "' --batch-size 1 --perceptual none --no-progress --sample-every 0 --threads 2 " + args,
        "env -u DISPLAY AVATAR_THREADS=2");
    EXPECT_EQ(r.exit_code, 0) << args << "\n" << r.err;
    return r;
  };
  const auto weights = [&](const std::string& run) { return LoadModelCheckpoint(*dir_ / run / "model.ckpt"); };

  // w/o appearance: in the weights and the state; --resume and --init-weights keep it.
  const auto first = train("run_noapp", "--steps 2 --no-appearance");
  EXPECT_NE(first.err.find("ablation: no appearance branch"), std::string::npos) << first.err;
  EXPECT_FALSE(weights("run_noapp").model->config().appearance_branch);
  train("run_noapp", "--steps 3 --resume");
  EXPECT_FALSE(weights("run_noapp").model->config().appearance_branch);
  EXPECT_EQ(weights("run_noapp").info.step, 3);
  train("run_noapp2", "--steps 4 --init-weights '" + (*dir_ / "run_noapp" / "model.ckpt").string() + "'");
  EXPECT_FALSE(weights("run_noapp2").model->config().appearance_branch);
  EXPECT_EQ(weights("run_noapp2").info.step, 4);

  // Expression bases from full-design weights: K from the dataset, std from the morphable model,
  // every other tensor from the file (then trained), kept by --resume.
  train("run_full", "--steps 1");
  const auto bases_run = train("run_bases", "--steps 2 --expression-model bases --init-weights '" +
                                                (*dir_ / "run_full" / "model.ckpt").string() + "'");
  EXPECT_NE(bases_run.err.find("linear expression bases"), std::string::npos) << bases_run.err;
  LoadedModel bases = weights("run_bases");
  const ModelConfig& bc = bases.model->config();
  EXPECT_TRUE(bc.expression_bases());
  EXPECT_TRUE(bc.appearance_branch);
  EXPECT_EQ(bc.expression_coefficients, coefficients_);
  const morphable::MorphableModel& mm = morphable::LoadDefaultModel(DataPaths::Resolve());
  EXPECT_TRUE(torch::allclose(bases.model->expression_std, torch::tensor(mm.expression_std())));
  EXPECT_GT(bases.model->expression_bases.abs().max().item<double>(), 0.0);
  train("run_bases", "--steps 3 --resume");
  EXPECT_TRUE(weights("run_bases").model->config().expression_bases());
  // A flag that contradicts the state being resumed is refused, naming the field.
  const avatar::testing::ProcessResult bad = avatar::testing::RunProcess(
      std::string("'") + AVATAR_STUDIO_EXE + "' train --config '" + config.string() + "' --data '" +
          (*dir_ / "ds").string() + "' --out '" + (*dir_ / "run_bases").string() +
          "' --batch-size 1 --perceptual none --no-progress --threads 2 --steps 4 --resume --expression-model encoder",
      "env -u DISPLAY AVATAR_THREADS=2");
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.err.find("expression_model"), std::string::npos) << bad.err;
}

}  // namespace
}  // namespace avatar
