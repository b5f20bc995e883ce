// The network's ablation variants (issue 14, the paper's Table 4): the model-config fields and
// their round trips, the linear expression bases (T_e = sum_k (beta_k / std_k) B_k, checked in
// double precision) and the network without an appearance branch.

#include <cmath>
#include <filesystem>
#include <iostream>

#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "common/gradient_check.h"
#include "core/model/goha_model.h"
#include "core/render/camera.h"
#include "core/util/error.h"
#include "model_test_util.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;

const auto kF64 = torch::TensorOptions().dtype(torch::kFloat64);

ModelConfig TinyBases(int k) {
  ModelConfig c = ModelConfig::Tiny();
  c.expression_model = "bases";
  c.expression_coefficients = k;
  c.Validate();
  return c;
}

// Largest |central difference - autograd| over every element of x0, for a scalar f (double).
double WorstGradError(const std::function<torch::Tensor(const torch::Tensor&)>& f, const torch::Tensor& x0,
                      double* grad_sum) {
  const test::GradientCheck check = test::CheckGradient(f, x0);
  *grad_sum = check.analytic_abs_sum;
  return check.worst_error;
}

TEST(AblationConfig, FilesWithoutTheFieldsReadAsTheFullDesign) {
  nlohmann::json j = nlohmann::json::parse(ModelConfigToJson(ModelConfig::Tiny()));
  ASSERT_TRUE(j.contains("appearance_branch") && j.contains("expression_model") &&
              j.contains("expression_coefficients"));
  for (const char* k : {"appearance_branch", "expression_model", "expression_coefficients"}) j.erase(k);
  const ModelConfig old = ModelConfigFromJson(j.dump());
  EXPECT_TRUE(old.appearance_branch);
  EXPECT_EQ(old.expression_model, "encoder");
  EXPECT_FALSE(old.expression_bases());
  EXPECT_EQ(old, ModelConfig::Tiny());
  for (const ModelConfig& config :
       {ModelConfig::Paper(), ModelConfig::Lite(), ModelConfig::Cpu(), ModelConfig::Tiny()}) {
    EXPECT_TRUE(config.appearance_branch) << config.name;
    EXPECT_EQ(config.expression_model, "encoder") << config.name;
  }
}

TEST(AblationConfig, JsonRoundTripAndValidation) {
  ModelConfig c = TinyBases(8);
  c.appearance_branch = false;
  const ModelConfig back = ModelConfigFromJson(ModelConfigToJson(c));
  EXPECT_EQ(back, c);
  EXPECT_FALSE(back.appearance_branch);
  EXPECT_TRUE(back.expression_bases());
  EXPECT_EQ(back.expression_coefficients, 8);
  EXPECT_NE(back, ModelConfig::Tiny());
  ModelConfig bad = c;
  bad.expression_model = "linear";
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  bad = c;
  bad.expression_coefficients = 0;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
}

TEST(ExpressionBases, ParametersAndShapes) {
  const ModelConfig c = TinyBases(8);
  GohaModel model(c);
  ASSERT_TRUE(model->expression_bases.defined() && model->expression_std.defined());
  const int64_t p = c.plane_size();
  EXPECT_EQ(model->expression_bases.sizes(), (std::vector<int64_t>{8, 3, c.plane_channels, p, p}));
  EXPECT_EQ(model->expression_bases.abs().sum().item<double>(), 0.0) << "bases start at zero";
  EXPECT_TRUE(torch::equal(model->expression_std, torch::ones({8})));
  EXPECT_EQ(model->named_parameters(true).find("expression_bases")->numel(), model->expression_bases.numel());
  EXPECT_NE(model->named_buffers(true).find("expression_std"), nullptr);
  // An encoder model has neither.
  GohaModel encoder(ModelConfig::Tiny());
  EXPECT_FALSE(encoder->expression_bases.defined());
  EXPECT_EQ(encoder->named_parameters(true).find("expression_bases"), nullptr);

  // The size at the cpu config (planes 3x32x64x64), K = our morphable model's 26 coefficients.
  ModelConfig cpu = ModelConfig::Cpu();
  cpu.expression_model = "bases";
  GohaModelOptions no_download;
  no_download.pretrained = false;
  GohaModel big(cpu, no_download);
  const int64_t bp = cpu.plane_size();
  EXPECT_EQ(big->expression_bases.numel(), int64_t{cpu.expression_coefficients} * 3 * cpu.plane_channels * bp * bp);
  const int64_t encoder_params = CountParameters(*big->expression_encoder) + CountParameters(*big->expression_head);
  std::cout << "cpu config: expression bases " << cpu.expression_coefficients << " x [3," << cpu.plane_channels << ","
            << bp << "," << bp << "] = " << big->expression_bases.numel() << " parameters; E_e + head "
            << encoder_params << "; whole network with bases " << CountParameters(*big) << "\n";
}

TEST(ExpressionBases, GradientCheckInDoublePrecision) {
  torch::manual_seed(41);
  const torch::Tensor bases = torch::randn({4, 3, 2, 5, 5}, kF64);
  const torch::Tensor weights = torch::randn({2, 4}, kF64);
  const torch::Tensor probe = torch::randn({2, 3, 2, 5, 5}, kF64);
  // A non-linear read-out so that the check sees more than a constant gradient.
  const auto readout = [&](const torch::Tensor& planes) { return (planes.sin() * probe).sum(); };
  double sum = 0.0;
  EXPECT_LT(
      WorstGradError([&](const torch::Tensor& b) { return readout(MixExpressionBases(weights, b)); }, bases, &sum),
      1e-7);
  EXPECT_GT(sum, 0.0);
  EXPECT_LT(
      WorstGradError([&](const torch::Tensor& w) { return readout(MixExpressionBases(w, bases)); }, weights, &sum),
      1e-7);
  EXPECT_GT(sum, 0.0);
  // The mix is sum_k w[b,k] B_k.
  const torch::Tensor mixed = MixExpressionBases(weights, bases);
  for (int64_t b = 0; b < 2; ++b) {
    torch::Tensor by_hand = torch::zeros({3, 2, 5, 5}, kF64);
    for (int64_t k = 0; k < 4; ++k) by_hand += weights[b][k] * bases[k];
    EXPECT_LT((mixed[b] - by_hand).abs().max().item<double>(), 1e-12);
  }

  // Through the network (double): T_e = Mix(beta / std, B), and the gradient reaches B.
  const ModelConfig c = TinyBases(4);
  GohaModel model(c);
  model->to(torch::kFloat64);
  {
    torch::NoGradGuard g;
    model->expression_bases.copy_(torch::randn(model->expression_bases.sizes(), kF64));
  }
  model->SetExpressionStd({0.5f, 1.0f, 2.0f, 4.0f});
  const torch::Tensor beta = torch::randn({2, 4}, kF64);
  const torch::Tensor te = model->ExpressionPlanesFromCoefficients(beta);
  const torch::Tensor expected =
      MixExpressionBases(beta / torch::tensor({0.5, 1.0, 2.0, 4.0}, kF64), model->expression_bases);
  EXPECT_LT((te - expected).abs().max().item<double>(), 1e-12);
  te.pow(2).sum().backward();
  ASSERT_TRUE(model->expression_bases.grad().defined());
  EXPECT_GT(model->expression_bases.grad().abs().sum().item<double>(), 0.0);
}

TEST(ExpressionBases, PlanesFollowTheCoefficientsAndTheRenderChanges) {
  torch::manual_seed(42);
  const ModelConfig c = TinyBases(6);
  GohaModel model(c);
  model->eval();
  torch::NoGradGuard g;
  model->expression_bases.copy_(torch::randn(model->expression_bases.sizes()) * 0.5);
  const torch::Tensor a = torch::randn({1, 6}), b = torch::randn({1, 6});
  const torch::Tensor ta = model->ExpressionPlanesFromCoefficients(a), tb = model->ExpressionPlanesFromCoefficients(b);
  EXPECT_EQ(ta.sizes(), (std::vector<int64_t>{1, 3, c.plane_channels, c.plane_size(), c.plane_size()}));
  // Linear in beta, zero at beta = 0.
  EXPECT_LT((model->ExpressionPlanesFromCoefficients(a + b) - ta - tb).abs().max().item<double>(), 1e-4);
  EXPECT_EQ(model->ExpressionPlanesFromCoefficients(torch::zeros({1, 6})).abs().max().item<double>(), 0.0);
  // The render at a camera changes with the coefficients.
  const torch::Tensor image = torch::zeros({1, 3, c.image_size, c.image_size});
  const torch::Tensor tc = model->CanonicalPlanes(image);
  const auto cams = render::FrontalCameras(1);
  const torch::Tensor ra = model->Render(tc + ta, cams).rgb, rb = model->Render(tc + tb, cams).rgb;
  EXPECT_GT((ra - rb).abs().mean().item<double>(), 1e-3);
  // ExpressionPlanesFor picks the coefficients; I_exp is refused; a wrong K is refused.
  EXPECT_TRUE(torch::equal(model->ExpressionPlanesFor(torch::Tensor(), a), ta));
  EXPECT_THROW(model->ExpressionPlanes(image), InvalidInput);
  EXPECT_THROW(model->ExpressionPlanesFromCoefficients(torch::zeros({1, 5})), InvalidInput);
  EXPECT_THROW(model->SetExpressionStd({1, 1, 1, 1, 1, 0}), InvalidInput);
  // An encoder model refuses coefficients and keeps taking I_exp.
  GohaModel encoder(ModelConfig::Tiny());
  EXPECT_THROW(encoder->ExpressionPlanesFromCoefficients(a), InvalidInput);
  EXPECT_EQ(encoder->ExpressionPlanesFor(image, torch::Tensor()).sizes(), ta.sizes());
}

TEST(NoAppearance, AppearancePlanesAreZeroAndNothingRuns) {
  torch::manual_seed(43);
  ModelConfig c = ModelConfig::Tiny();
  c.appearance_branch = false;
  GohaModel model(c);
  const int64_t s = c.image_size;
  const torch::Tensor image = torch::rand({2, 3, s, s}) * 2 - 1;
  const torch::Tensor tc = model->CanonicalPlanes(image);
  model->counters().Reset();
  const AppearanceOutput app = model->AppearancePlanes(image, torch::zeros({2, 1, s, s}), torch::ones({2, 1, s, s}), tc,
                                                       render::FrontalCameras(2));
  EXPECT_EQ(app.planes.sizes(), tc.sizes());
  EXPECT_EQ(app.planes.abs().max().item<double>(), 0.0);
  EXPECT_FALSE(app.planes.requires_grad());
  EXPECT_EQ(model->counters().appearance_encoder.load(), 0);
  EXPECT_EQ(model->counters().rasterizations.load(), 0);
  EXPECT_EQ(model->counters().renders.load(), 0);
  // The modules are still there (same tensors as the full design: --init-weights and every
  // reader of the files keep working), and the FLOP list leaves them out.
  GohaModel full(ModelConfig::Tiny());
  EXPECT_EQ(CountParameters(*model), CountParameters(*full));
  for (const auto& e : model->Flops()) EXPECT_EQ(e.module.rfind("E_p", 0), std::string::npos) << e.module;
}

TEST(AblationCheckpoint, BasesAndNoAppearanceSurviveARoundTrip) {
  torch::manual_seed(44);
  ModelConfig c = TinyBases(5);
  c.appearance_branch = false;
  GohaModel model(c);
  {
    torch::NoGradGuard g;
    model->expression_bases.copy_(torch::randn(model->expression_bases.sizes()));
  }
  model->SetExpressionStd({0.1f, 0.2f, 0.3f, 0.4f, 0.5f});
  const fs::path path = fs::temp_directory_path() / ("avatar_ablation_ckpt_" + std::to_string(::getpid()) + ".ckpt");
  CheckpointInfo info;
  info.step = 7;
  info.data_provenance = "test";
  SaveModelCheckpoint(path, model, info);
  const LoadedModel loaded = LoadModelCheckpoint(path);
  EXPECT_EQ(loaded.model->config(), c);
  EXPECT_FALSE(loaded.model->config().appearance_branch);
  EXPECT_EQ(loaded.model->config().expression_model, "bases");
  EXPECT_EQ(loaded.model->config().expression_coefficients, 5);
  avatar::testing::ExpectBitIdenticalWeights(model, loaded.model);
  // A full-design file still loads into the full design (no bases tensors expected).
  GohaModel full(ModelConfig::Tiny());
  SaveModelCheckpoint(path, full, info);
  EXPECT_EQ(LoadModelCheckpoint(path).model->config(), ModelConfig::Tiny());
  fs::remove(path);
}

}  // namespace
}  // namespace avatar
