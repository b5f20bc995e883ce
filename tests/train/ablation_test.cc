// The trainer's ablation switches (issue 14, the paper's Table 4): w/o neutral loss
// (neutral_weight 0), w/o appearance branch (ModelConfig::appearance_branch false) and the
// linear expression bases (ModelConfig::expression_model "bases"), each trained a few steps on
// the tiny config; initialisation across the switches; a tiny overfit test of the bases path.

#include <cmath>
#include <filesystem>
#include <iostream>
#include <map>
#include <vector>

#include <gtest/gtest.h>

#include "core/model/goha_model.h"
#include "core/train/losses.h"
#include "core/train/trainer.h"
#include "core/util/error.h"
#include "train/trainer_test_util.h"

namespace avatar::train {
namespace {

ModelConfig TinyVariant(bool appearance, bool bases, int k = 8) {
  ModelConfig c = ModelConfig::Tiny();
  c.appearance_branch = appearance;
  if (bases) {
    c.expression_model = "bases";
    c.expression_coefficients = k;
  }
  c.Validate();
  return c;
}

// A copy of every parameter, by name.
std::map<std::string, torch::Tensor> Snapshot(GohaModel& m) {
  std::map<std::string, torch::Tensor> out;
  for (const auto& item : m->named_parameters(true)) out[item.key()] = item.value().detach().clone();
  return out;
}

// One batch of the synthetic pair with the given target expression coefficients [B,K].
TrainBatch WithCoefficients(const ModelConfig& c, const torch::Tensor& beta) {
  std::vector<TrainSample> samples;
  for (int64_t i = 0; i < beta.size(0); ++i) {
    TrainSample s = MakeSample(c, 0);
    s.target_expression = beta[i].clone();
    samples.push_back(s);
  }
  return Collate(samples);
}

TEST(Ablation, ZeroNeutralWeightDropsTheTermAndItsRender) {
  const ModelConfig c = ModelConfig::Tiny();
  std::map<double, StepResult> results;
  std::map<double, int64_t> renders;
  for (const double weight : {3.0, 0.0}) {
    torch::manual_seed(31);
    TrainerOptions o = TestOptions();
    o.expression_start = 0;
    o.appearance_start = 0;
    o.neutral_weight = weight;
    StageOneTrainer trainer(GohaModel(c), o, kStandIn);
    SyntheticSource source(c, 1, false);
    trainer.model()->counters().Reset();
    results[weight] = trainer.Step(source.Next());
    ASSERT_FALSE(results[weight].skipped) << results[weight].skip_reason;
    renders[weight] = trainer.model()->counters().renders.load();
  }
  EXPECT_EQ(results[3.0].terms.count("neutral"), 1u);
  EXPECT_GT(results[3.0].terms.at("neutral"), 0.0);
  EXPECT_EQ(results[0.0].terms.count("neutral"), 0u) << "a zero-weight neutral term is still reported";
  // Not computed at all: exactly one render (R(T_c, C_s)) fewer per step.
  EXPECT_EQ(renders[3.0] - renders[0.0], 1) << renders[3.0] << " vs " << renders[0.0] << " renders";
  // The other terms are the same step's (same initialisation, same random draws before it).
  for (const char* k : {"canonical", "expression", "appearance"})
    EXPECT_DOUBLE_EQ(results[0.0].terms.at(k), results[3.0].terms.at(k)) << k;
  double sum = 0.0;
  for (const auto& [k, v] : results[0.0].terms) sum += v;
  EXPECT_NEAR(results[0.0].loss, sum, 1e-6 * std::abs(sum));
}

TEST(Ablation, WithoutAppearanceNothingReachesTheAppearanceBranch) {
  torch::manual_seed(32);
  const ModelConfig c = TinyVariant(/*appearance=*/false, /*bases=*/false);
  const TrainerOptions o = TestOptions();  // expression from step 3, appearance (would be) from 6
  StageOneTrainer trainer(GohaModel(c), o, kStandIn);
  const auto before = Snapshot(trainer.model());
  int64_t frozen = 0;
  for (const auto& [name, t] : before) frozen += FrozenByConfig(c, name) ? 1 : 0;
  EXPECT_GT(frozen, 0) << "the appearance modules should still be in the network";
  SyntheticSource source(c, 1, true);
  trainer.model()->counters().Reset();
  for (int i = 0; i < 9; ++i) {
    const StepResult r = trainer.Step(source.Next());
    ASSERT_FALSE(r.skipped) << r.skip_reason;
    EXPECT_EQ(r.terms.count("appearance"), 0u) << "step " << i;
    EXPECT_EQ(r.terms.count("expression"), i >= 3 ? 1u : 0u) << "step " << i;
    EXPECT_EQ(r.phase, i >= 3 ? "expression" : "canonical") << "step " << i;
  }
  EXPECT_EQ(trainer.model()->counters().appearance_encoder.load(), 0);
  EXPECT_EQ(trainer.model()->counters().rasterizations.load(), 0);

  // No gradient reaches E_p or the upsamplers in a step of the appearance phase; the rest learns.
  const TrainBatch b = source.Next().To(trainer.device());
  torch::Tensor total;
  for (const auto& [k, t] : trainer.LossTerms(b, 8)) total = total.defined() ? total + t : t;
  total.backward();
  for (const auto& item : trainer.model()->named_parameters(true)) {
    if (FrozenByConfig(c, item.key())) {
      EXPECT_FALSE(item.value().grad().defined()) << item.key() << " got a gradient";
    }
  }
  EXPECT_TRUE(trainer.model()->expression_encoder->parameters()[0].grad().defined());
  for (auto& p : trainer.model()->parameters()) p.mutable_grad() = torch::Tensor();

  // After the steps the appearance weights are the initial ones; the other modules moved.
  const auto after = Snapshot(trainer.model());
  double frozen_change = 0.0, other_change = 0.0;
  for (const auto& [name, t] : after) {
    const double d = (t - before.at(name)).abs().max().item<double>();
    (FrozenByConfig(c, name) ? frozen_change : other_change) += d;
  }
  EXPECT_EQ(frozen_change, 0.0);
  EXPECT_GT(other_change, 0.0);

  // The output is I_c+e.
  const auto e = trainer.Evaluate(source.Next());
  EXPECT_TRUE(torch::equal(e.full, e.expression));

  // The switch is in the exported weights and in the state; a full-design trainer refuses the state.
  const fs::path dir = TempDir("ablation_noapp");
  trainer.ExportWeights(dir / "model.ckpt", "test");
  const LoadedModel file = LoadModelCheckpoint(dir / "model.ckpt");
  EXPECT_FALSE(file.model->config().appearance_branch);
  trainer.SaveState(dir / "state.ckpt", &source);
  EXPECT_FALSE(ReadStateModelConfig(dir / "state.ckpt").appearance_branch);
  StageOneTrainer resumed(GohaModel(c), o, kStandIn);
  resumed.LoadState(dir / "state.ckpt");
  EXPECT_EQ(resumed.step(), 9);
  StageOneTrainer full(GohaModel(ModelConfig::Tiny()), o, kStandIn);
  try {
    full.LoadState(dir / "state.ckpt");
    ADD_FAILURE() << "a full-design trainer resumed a w/o-appearance state";
  } catch (const ModelLoad& err) {
    EXPECT_NE(std::string(err.what()).find("appearance_branch"), std::string::npos) << err.what();
  }
  fs::remove_all(dir);
}

TEST(Ablation, ExpressionBasesLearnFromTheCoefficientsAndEeDoesNot) {
  torch::manual_seed(33);
  const ModelConfig c = TinyVariant(/*appearance=*/true, /*bases=*/true, 8);
  TrainerOptions o = TestOptions();
  o.expression_start = 0;
  o.appearance_start = 0;
  StageOneTrainer trainer(GohaModel(c), o, kStandIn);
  const auto before = Snapshot(trainer.model());
  const torch::Tensor beta = torch::randn({2, 8});
  const TrainBatch batch = WithCoefficients(c, beta);

  // One step's gradients: the bases get one, E_e and its head none.
  {
    const TrainBatch b = batch.To(trainer.device());
    torch::Tensor total;
    for (const auto& [k, t] : trainer.LossTerms(b, 0)) total = total.defined() ? total + t : t;
    total.backward();
    const torch::Tensor g = trainer.model()->expression_bases.grad();
    ASSERT_TRUE(g.defined()) << "no gradient reached the expression bases";
    EXPECT_GT(g.abs().sum().item<double>(), 0.0);
    for (const auto& item : trainer.model()->named_parameters(true)) {
      if (item.key().rfind("expression_encoder.", 0) == 0 || item.key().rfind("expression_head.", 0) == 0) {
        EXPECT_FALSE(item.value().grad().defined()) << item.key() << " got a gradient";
      }
    }
    for (auto& p : trainer.model()->parameters()) p.mutable_grad() = torch::Tensor();
  }
  trainer.model()->counters().Reset();
  for (int i = 0; i < 4; ++i) ASSERT_FALSE(trainer.Step(batch).skipped);
  const auto after = Snapshot(trainer.model());
  EXPECT_GT(after.at("expression_bases").abs().max().item<double>(), 0.0) << "the bases did not move from zero";
  for (const auto& [name, t] : after) {
    if (FrozenByConfig(c, name)) {
      EXPECT_TRUE(torch::equal(t, before.at(name))) << name << " changed";
    }
  }

  // The output changes with the coefficients; with beta = 0, T_e = 0 (I_c+e = I_c).
  const auto e1 = trainer.Evaluate(WithCoefficients(c, beta));
  const auto e2 = trainer.Evaluate(WithCoefficients(c, -beta));
  EXPECT_GT((e1.expression - e2.expression).abs().max().item<double>(), 0.0);
  EXPECT_GT((e1.full - e2.full).abs().max().item<double>(), 0.0);
  const auto e0 = trainer.Evaluate(WithCoefficients(c, torch::zeros({1, 8})));
  EXPECT_TRUE(torch::equal(e0.expression, e0.canonical));
  // A batch whose coefficients do not fit the bases is refused.
  EXPECT_THROW(trainer.Step(WithCoefficients(c, torch::zeros({1, 5}))), InvalidInput);
}

TEST(Ablation, InitialisationFromAFullModelAcrossTheSwitches) {
  torch::manual_seed(34);
  const ModelConfig c = ModelConfig::Tiny();
  const fs::path dir = TempDir("ablation_init");
  {
    StageOneTrainer trainer(GohaModel(c), TestOptions(), kStandIn);
    SyntheticSource source(c, 1, false);
    for (int i = 0; i < 3; ++i) ASSERT_FALSE(trainer.Step(source.Next()).skipped);
    trainer.ExportWeights(dir / "full.ckpt", "test");
    trainer.ExportWeights(dir / "full-fp16.ckpt", "test", /*half_precision=*/true);
  }
  GohaModel file_model = LoadModelCheckpoint(dir / "full.ckpt").model;
  const auto file = Snapshot(file_model);

  // Expression bases from encoder weights: every shared tensor, the bases stay zero, std as set.
  const ModelConfig bc = TinyVariant(true, true, 8);
  GohaModel bases_model(bc);
  bases_model->SetExpressionStd({1, 2, 3, 4, 5, 6, 7, 8});
  StageOneTrainer bases(bases_model, TestOptions(), kStandIn);
  bases.InitFromCheckpoint(dir / "full.ckpt");
  EXPECT_EQ(bases.step(), 3);
  for (const auto& [name, t] : Snapshot(bases.model())) {
    if (name == "expression_bases")
      EXPECT_EQ(t.abs().max().item<double>(), 0.0);
    else
      EXPECT_TRUE(torch::equal(t, file.at(name))) << name;
  }
  EXPECT_TRUE(torch::equal(bases.model()->expression_std, torch::arange(1, 9).to(torch::kFloat32)));
  StageOneTrainer bases_half(GohaModel(bc), TestOptions(), kStandIn);
  bases_half.InitFromCheckpoint(dir / "full-fp16.ckpt");
  EXPECT_EQ(bases_half.step(), 3);

  // Without the appearance branch: every tensor (the appearance modules keep the file's values).
  StageOneTrainer no_app(GohaModel(TinyVariant(false, false)), TestOptions(), kStandIn);
  no_app.InitFromCheckpoint(dir / "full.ckpt");
  for (const auto& [name, t] : Snapshot(no_app.model())) EXPECT_TRUE(torch::equal(t, file.at(name))) << name;

  // A bases run continued from its own export keeps its bases and std.
  ASSERT_FALSE(bases.Step(WithCoefficients(bc, torch::randn({1, 8}))).skipped);
  bases.ExportWeights(dir / "bases.ckpt", "test");
  const LoadedModel bases_file = LoadModelCheckpoint(dir / "bases.ckpt");
  EXPECT_EQ(bases_file.model->config(), bc);
  StageOneTrainer again(GohaModel(bc), TestOptions(), kStandIn);
  again.InitFromCheckpoint(dir / "bases.ckpt");
  EXPECT_TRUE(torch::equal(again.model()->expression_bases, bases.model()->expression_bases));
  EXPECT_TRUE(torch::equal(again.model()->expression_std, bases.model()->expression_std));

  // Other sizes are still refused.
  ModelConfig other = bc;
  other.plane_channels = 4;
  other.name = "tiny-c4";
  StageOneTrainer wrong(GohaModel(other), TestOptions(), kStandIn);
  EXPECT_THROW(wrong.InitFromCheckpoint(dir / "full.ckpt"), InvalidOptions);
  fs::remove_all(dir);
}

// What the ablation runs start from (docs/training/README.md "Ablations"): the shipped weights
// (config cpu, a file written before the ablation fields existed) initialise every variant.
TEST(Ablation, ShippedWeightsInitialiseEveryVariant) {
  const fs::path shipped = fs::path(AVATAR_SOURCE_DIR) / "resources" / "models" / "goha-default.ckpt";
  ASSERT_TRUE(fs::exists(shipped)) << shipped;
  const LoadedModel file = LoadModelCheckpoint(shipped);
  const ModelConfig& stored = file.model->config();
  ASSERT_EQ(stored.name, "cpu");
  EXPECT_TRUE(stored.appearance_branch);
  EXPECT_EQ(stored.expression_model, "encoder");
  GohaModel file_model = file.model;
  const auto weights = Snapshot(file_model);
  GohaModelOptions no_download;
  no_download.pretrained = false;
  for (const bool bases : {false, true}) {
    ModelConfig c = stored;
    if (bases) {
      c.expression_model = "bases";
      c.expression_coefficients = 26;
    } else {
      c.appearance_branch = false;
    }
    StageOneTrainer trainer(GohaModel(c, no_download), TestOptions(), kStandIn);
    trainer.InitFromCheckpoint(shipped);
    EXPECT_EQ(trainer.step(), file.info.step);
    for (const auto& [name, t] : Snapshot(trainer.model())) {
      if (name == "expression_bases") {
        EXPECT_EQ(t.abs().max().item<double>(), 0.0);
      } else {
        ASSERT_TRUE(torch::equal(t, weights.at(name))) << name;
      }
    }
  }
}

// The bases path can fit expression-dependent targets: one source, two targets told apart only
// by their coefficients. T_c (and T_p) are shared by the pair, so only T_e can fit both; the best
// any single image can do is their mean, whose PSNR (22.12 dB) bounds what a network without a
// working expression path reaches. Judged by the worse pair's PSNR, as the mean of the
// evaluations over the last 100 steps: jittered training renders at lr 3e-3 make the curve noisy
// (+-4 dB from one evaluation to the next), and the best of 12 evaluations at 300 steps, the test
// before, failed on another CPU (27.79 dB against a bar of 28.12). Measured 2026-12-04 (AMD EPYC,
// AVX-512) over AVATAR_THREADS 1 and 2 and the OpenBLAS core types Haswell (this CPU's default),
// Zen, SkylakeX, Sandybridge, Prescott, and Haswell with oneDNN and ATen limited to AVX2 (a machine
// without AVX-512): mean of the evaluations at steps 310-400 29.93 (Prescott) to 30.44 dB (AVX2),
// 7.8-8.3 dB above the bound (a spread of 0.52 dB; at 300 steps the curve was still rising and the
// same mean spread over 2.3 dB). The bar asks for 5 dB above the bound: 2.8 dB below the lowest
// measurement, 5 times the spread.
TEST(Ablation, TinyExpressionBasesOverfitTwoExpressions) {
  torch::manual_seed(35);
  const ModelConfig c = TinyVariant(/*appearance=*/false, /*bases=*/true, 4);
  TrainerOptions o = TestOptions();
  o.lr = 3e-3;  // as Trainer.TinyOverfitsOnePair (tuned for the tiny config only)
  o.expression_start = 0;
  o.appearance_start = 0;
  o.neutral_weight = 0.0;
  o.tv_weight = 0.0;
  StageOneTrainer trainer(GohaModel(c), o, kStandIn);
  TrainBatch batch = WithCoefficients(c, torch::tensor({{1.0f, 0.0f, 0.0f, 0.0f}, {0.0f, -1.0f, 0.0f, 0.0f}}));
  // The second target: the first's colours negated inside the person (another "expression").
  batch.target[1] = batch.target_matte[1] * (-batch.target[1]) + (batch.target_matte[1] - 1.0);
  const torch::Tensor targets = ResizeTo(Matte(batch.target, batch.target_matte), c.render_size);
  const torch::Tensor mean = targets.mean(0, true).expand_as(targets);
  const double bound = std::max(Psnr(mean[0].unsqueeze(0), targets[0].unsqueeze(0)),
                                Psnr(mean[1].unsqueeze(0), targets[1].unsqueeze(0)));
  const auto worse_pair_psnr = [&] {
    const auto e = trainer.Evaluate(batch);  // deterministic renders; draws no random numbers
    return std::min(Psnr(e.expression[0].unsqueeze(0), e.target[0].unsqueeze(0)),
                    Psnr(e.expression[1].unsqueeze(0), e.target[1].unsqueeze(0)));
  };
  const double start = worse_pair_psnr();
  const int steps = 400, every = 10, judged = 10;
  std::vector<double> curve;
  for (int i = 0; i < steps; ++i) {
    ASSERT_FALSE(trainer.Step(batch).skipped);
    if ((i + 1) % every == 0) curve.push_back(worse_pair_psnr());
  }
  double end = 0.0;
  for (int k = 0; k < judged; ++k) end += curve[curve.size() - 1 - k] / judged;
  std::cout << "bases overfit: worse pair's PSNR of I_c+e every " << every << " steps:";
  for (const double p : curve) std::cout << " " << p;
  std::cout << "\nbases overfit: start " << start << " dB, one image for both at most " << bound
            << " dB, mean of the last " << judged << " evaluations " << end << " dB (" << end - bound
            << " dB above that bound)\n";
  EXPECT_GT(end, bound + 5.0) << "the bases did not tell the two expressions apart";
}

}  // namespace
}  // namespace avatar::train
