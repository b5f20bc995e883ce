// Shapes, rasterization exactness, super-resolution determinism for the GOHA network.

#include <gtest/gtest.h>

#include <iostream>
#include <map>
#include <random>

#include "core/model/goha_model.h"
#include "core/model/rasterize.h"
#include "core/render/camera.h"
#include "core/render/triplane_sampling.h"
#include "core/util/error.h"
#include "model_test_util.h"

namespace avatar {
namespace {

using testing::Shape;

TEST(SegFormer, TinyStageAndOutputShapes) {
  torch::manual_seed(0);
  const ModelConfig c = ModelConfig::Tiny();
  SegFormerEncoder enc(c, 3);
  const torch::Tensor x = torch::randn({2, 3, 64, 64});
  const auto stages = enc->Stages(x);
  ASSERT_EQ(stages.size(), 4u);
  for (int s = 0; s < 4; ++s) {
    EXPECT_EQ(Shape(stages[s]), (std::vector<int64_t>{2, c.encoder_widths[s], 64 >> (s + 2), 64 >> (s + 2)}));
  }
  const torch::Tensor y = enc->forward(x);
  EXPECT_EQ(Shape(y), (std::vector<int64_t>{2, c.decoder_dim, 16, 16}));
  EXPECT_TRUE(torch::isfinite(y).all().item<bool>());
}

TEST(SegFormer, RejectsSizesNotDivisibleBy32) {
  SegFormerEncoder enc(ModelConfig::Tiny(), 3);
  EXPECT_THROW(enc->forward(torch::randn({1, 3, 48, 40})), InvalidInput);
}

TEST(SegFormer, BatchItemsAreIndependent) {
  // Property: the encoder has no cross-batch interaction (no batch norm in inference).
  torch::manual_seed(1);
  SegFormerEncoder enc(ModelConfig::Tiny(), 6);
  torch::NoGradGuard no_grad;
  const torch::Tensor x = torch::randn({2, 6, 64, 64});
  const torch::Tensor both = enc->forward(x);
  const torch::Tensor one = enc->forward(x.narrow(0, 1, 1));
  EXPECT_TRUE(torch::allclose(both.narrow(0, 1, 1), one, 1e-4, 1e-5));
}

TEST(SegFormer, PaperEncoderParameterCountIsMitB0) {
  // MiT-b0 has 3.32M encoder parameters; the decode head up to the fuse conv (256 channels)
  // adds (32+64+160+256)*256 + 4*256 + 1024*256. Counted independently here.
  const ModelConfig c = ModelConfig::Paper();
  SegFormerEncoder enc(c, 3);
  const int64_t head = (32 + 64 + 160 + 256) * 256 + 4 * 256 + 1024 * 256;
  const int64_t total = CountParameters(*enc);
  EXPECT_NEAR(static_cast<double>(total - head), 3.32e6, 0.02e6);
}

TEST(GohaModel, TinyShapesOfEveryBranch) {
  torch::manual_seed(2);
  const ModelConfig c = avatar::testing::TinyForTest();
  GohaModel model(c);
  torch::InferenceMode inference;
  const int64_t s = c.image_size, p = c.plane_size();
  const torch::Tensor image = torch::rand({1, 3, s, s}) * 2 - 1;
  const torch::Tensor tc = model->CanonicalPlanes(image);
  EXPECT_EQ(Shape(tc), (std::vector<int64_t>{1, 3, c.plane_channels, p, p}));
  const torch::Tensor mask = torch::zeros({1, 1, s, s});
  const torch::Tensor matte = torch::ones({1, 1, s, s});
  const AppearanceOutput app = model->AppearancePlanes(image, mask, matte, tc, render::FrontalCameras(1));
  EXPECT_EQ(Shape(app.planes), Shape(tc));
  EXPECT_EQ(Shape(app.depth), (std::vector<int64_t>{1, 1, c.feature_size(), c.feature_size()}));
  EXPECT_EQ(app.foreground.sum().item<int64_t>(), c.feature_size() * c.feature_size());
  const torch::Tensor te = model->ExpressionPlanes(image);
  EXPECT_EQ(Shape(te), Shape(tc));
  const render::RenderOutput out = model->Render(tc + te + app.planes, render::FrontalCameras(1));
  EXPECT_EQ(Shape(out.rgb), (std::vector<int64_t>{1, 3, c.render_size, c.render_size}));
  const torch::Tensor hr = model->SuperResolve(out.rgb);
  EXPECT_EQ(Shape(hr), (std::vector<int64_t>{1, 3, c.sr_size, c.sr_size}));
  EXPECT_TRUE(torch::isfinite(hr).all().item<bool>());
  DualDiscriminator disc(c);
  EXPECT_EQ(Shape(disc->forward(torch::cat({hr, hr}), torch::cat({out.rgb, out.rgb}))), (std::vector<int64_t>{2, 1}));
}

TEST(GohaModel, EachAppearancePlaneHasItsOwnUpsampler) {
  GohaModel model(avatar::testing::TinyForTest());
  ASSERT_EQ(model->upsamplers.size(), 3u);
  const auto a = model->upsamplers[0]->parameters();
  const auto b = model->upsamplers[1]->parameters();
  ASSERT_EQ(a.size(), b.size());
  EXPECT_NE(a[0].data_ptr(), b[0].data_ptr());
  EXPECT_FALSE(torch::equal(a[0], b[0]));
}

TEST(GohaModel, EmptyMatteGivesZeroRasterAndFiniteOutput) {
  torch::manual_seed(3);
  const ModelConfig c = avatar::testing::TinyForTest();
  GohaModel model(c);
  torch::InferenceMode inference;
  const int64_t s = c.image_size;
  const torch::Tensor image = torch::rand({1, 3, s, s}) * 2 - 1;
  const torch::Tensor tc = model->CanonicalPlanes(image);
  const AppearanceOutput app = model->AppearancePlanes(image, torch::ones({1, 1, s, s}), torch::zeros({1, 1, s, s}), tc,
                                                       render::FrontalCameras(1));
  EXPECT_EQ(app.foreground.sum().item<int64_t>(), 0);
  EXPECT_TRUE(torch::isfinite(app.planes).all().item<bool>());
}

TEST(SuperResolution, DeterministicNoise) {
  torch::manual_seed(4);
  SuperResolution sr(ModelConfig::Tiny());
  torch::InferenceMode inference;
  const torch::Tensor x = torch::rand({1, 3, 16, 16}) * 2 - 1;
  EXPECT_TRUE(torch::equal(sr->forward(x), sr->forward(x)));
}

TEST(SuperResolution, PaperChannelTableMatchesGfpganMultiplier2) {
  const ModelConfig c = ModelConfig::Paper();
  EXPECT_EQ(c.SrChannels(4), 512);
  EXPECT_EQ(c.SrChannels(32), 512);
  EXPECT_EQ(c.SrChannels(64), 512);
  EXPECT_EQ(c.SrChannels(128), 256);
  EXPECT_EQ(c.SrChannels(256), 128);
  EXPECT_EQ(c.SrChannels(512), 64);
}

// GFPGANv1-clean at 512 with channel multiplier 2 (facts sheet, section 8): U-Net down 6.2 M,
// U-Net up 6.2 M, w+ linear 33.6 M, SFT 10.2 M, StyleGAN2 decoder 28.2 M (its unused style MLP,
// 2.1 M, is not built here). The published figures are rounded to 0.1 M.
TEST(SuperResolution, PaperParameterTableIsGfpganV1Clean) {
  SuperResolution sr(ModelConfig::Paper());
  std::map<std::string, double> groups;
  for (const auto& item : sr->named_parameters()) {
    const std::string& name = item.key();
    std::string group = "stylegan_decoder";
    if (name.rfind("unet_final_linear", 0) == 0) group = "wplus_linear";
    else if (name.rfind("unet_up", 0) == 0) group = "unet_up";
    else if (name.rfind("unet_", 0) == 0) group = "unet_down";
    else if (name.rfind("sft_", 0) == 0) group = "sft";
    groups[group] += static_cast<double>(item.value().numel()) / 1e6;
  }
  const std::map<std::string, double> published = {
      {"unet_down", 6.2}, {"unet_up", 6.2}, {"wplus_linear", 33.6}, {"sft", 10.2}, {"stylegan_decoder", 28.2}};
  double total = 0.0;
  for (const auto& [group, millions] : published) {
    EXPECT_NEAR(groups[group], millions, 0.06) << group;
    total += groups[group];
  }
  std::cout << "SR parameters (M): down " << groups["unet_down"] << ", up " << groups["unet_up"] << ", w+ "
            << groups["wplus_linear"] << ", SFT " << groups["sft"] << ", StyleGAN2 " << groups["stylegan_decoder"]
            << ", total " << total << "\n";
  EXPECT_EQ(groups.size(), published.size());
}

// ---------------------------------------------------------------- rasterization

TEST(Rasterize, KdTreeEqualsBruteForceOnRandomClouds) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 12; ++trial) {
    const int64_t n = std::vector<int64_t>{1, 2, 7, 100, 1000, 3000}[trial % 6];
    const int64_t grid = std::vector<int64_t>{1, 5, 33, 64}[trial % 4];
    torch::Tensor pts;
    if (trial % 3 == 0) {
      pts = torch::rand({n, 2}, torch::kFloat64) * 3 - 1.5;  // also outside [-1,1]
    } else if (trial % 3 == 1) {
      pts = torch::randn({n, 2}) * 0.3;  // clustered, float32
    } else {
      // Lattice points with duplicates: many exact distance ties.
      pts = (torch::randint(-4, 5, {n, 2}).to(torch::kFloat32) / 4.0);
    }
    const auto fast = NearestPointIndices(pts, grid);
    const auto brute = NearestPointIndicesBruteForce(pts, grid);
    ASSERT_EQ(fast, brute) << "trial " << trial << " n " << n << " grid " << grid;
  }
}

TEST(Rasterize, TiesGoToTheSmallestIndex) {
  // Two points symmetric about the grid centre (0,0) with grid 3: centre query ties.
  const torch::Tensor pts = torch::tensor({0.5, 0.0, -0.5, 0.0}, torch::kFloat64).view({2, 2});
  const auto idx = NearestPointIndices(pts, 3);
  EXPECT_EQ(idx[4], 0);  // row 1, col 1 = (0,0): equal distance 0.25, index 0 wins
  const auto swapped = NearestPointIndices(pts.flip(0), 3);
  EXPECT_EQ(swapped[4], 0);
  // Identical points: the first wins everywhere.
  const torch::Tensor dup = torch::zeros({5, 2});
  for (int64_t i : NearestPointIndices(dup, 4)) EXPECT_EQ(i, 0);
}

TEST(Rasterize, PlanesTakeFeaturesOfNearestForegroundPointsAndPassGradients) {
  torch::manual_seed(6);
  const int64_t n = 50, c = 4, grid = 8;
  const torch::Tensor points = torch::rand({1, n, 3}) - 0.5;  // inside the unit box
  torch::Tensor mask = torch::rand({1, n}) > 0.3;
  mask[0][0] = true;
  const torch::Tensor features = torch::randn({1, n, c}, torch::requires_grad());
  const torch::Tensor planes = RasterizePointFeatures(points, mask, features, grid, 1.0);
  ASSERT_EQ(Shape(planes), (std::vector<int64_t>{1, 3, c, grid, grid}));
  const torch::Tensor fg = torch::nonzero(mask[0]).flatten();
  for (int p = 0; p < 3; ++p) {
    const torch::Tensor xy = torch::stack({points[0].index_select(0, fg).select(1, render::kPlaneAxes[p][0]),
                                           points[0].index_select(0, fg).select(1, render::kPlaneAxes[p][1])},
                                          1) *
                             2.0;
    const auto idx = NearestPointIndicesBruteForce(xy, grid);
    for (int64_t cell = 0; cell < grid * grid; ++cell) {
      const int64_t point = fg[idx[cell]].item<int64_t>();
      EXPECT_TRUE(torch::equal(planes[0][p].select(1, cell / grid).select(1, cell % grid), features[0][point]));
    }
  }
  planes.sum().backward();
  const torch::Tensor g = features.grad();
  // Background points get no gradient; the gradient of a point = number of cells it won.
  EXPECT_EQ(g[0].index_select(0, torch::nonzero(~mask[0]).flatten()).abs().sum().item<float>(), 0.0f);
  EXPECT_NEAR(g.sum().item<float>(), 3.0 * grid * grid * c, 1e-3);
}

TEST(Rasterize, InferencePathEqualsAutogradPath) {
  torch::manual_seed(7);
  const torch::Tensor points = torch::rand({2, 300, 3}) - 0.5;
  const torch::Tensor mask = torch::rand({2, 300}) > 0.4;
  const torch::Tensor features = torch::randn({2, 300, 6});
  const torch::Tensor with_grad = RasterizePointFeatures(points, mask, features.clone().requires_grad_(), 16, 1.0);
  torch::Tensor fast;
  {
    torch::InferenceMode inference;
    fast = RasterizePointFeatures(points, mask, features, 16, 1.0);
  }
  EXPECT_TRUE(torch::equal(with_grad.detach(), fast));
}

TEST(Rasterize, RejectsBadShapes) {
  EXPECT_THROW(RasterizePointFeatures(torch::zeros({1, 4, 2}), torch::ones({1, 4}, torch::kBool),
                                      torch::zeros({1, 4, 3}), 8, 1.0),
               InvalidInput);
  EXPECT_THROW(NearestPointIndices(torch::zeros({0, 2}), 4), InvalidInput);
}

// ---------------------------------------------------------------- configs and FLOPs

TEST(ModelConfig, JsonRoundTripAndValidation) {
  for (const auto& c : {ModelConfig::Paper(), ModelConfig::Lite(), ModelConfig::Tiny()}) {
    EXPECT_EQ(ModelConfigFromJson(ModelConfigToJson(c)), c);
  }
  ModelConfig bad = ModelConfig::Tiny();
  bad.encoder_heads = {1, 1, 5, 2};  // 24 not divisible by 5
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  bad = ModelConfig::Tiny();
  bad.image_size = 100;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  EXPECT_THROW(ModelConfig::FromName("huge"), InvalidOptions);
  EXPECT_THROW(ModelConfigFromJson("{\"image_size\": \"x\"}"), InvalidOptions);
}

TEST(Flops, ConvFormulaAndEncoderStageZero) {
  EXPECT_DOUBLE_EQ(ConvFlops(3, 32, 7, 128, 128), 2.0 * 3 * 49 * 32 * 128 * 128);
  EXPECT_DOUBLE_EQ(ConvFlops(64, 64, 3, 10, 10, 64), 2.0 * 9 * 64 * 100);
  // Stage 0 of MiT-b0 at 512 by hand: patch conv + 2 blocks (q, kv on 16x16 reduced tokens,
  // sr conv k8, attention, proj, FFN with 128 hidden and a depthwise 3x3).
  const double n = 128.0 * 128, nr = 16.0 * 16, c = 32, h = 128;
  const double embed = 2.0 * 3 * 49 * 32 * n;
  const double attn = 2 * n * c * c + 2 * c * c * 64 * nr + 2 * nr * c * 2 * c + 4 * n * nr * c + 2 * n * c * c;
  const double ffn = 4 * n * c * h + 2 * 9 * h * n;
  SegFormerEncoder enc(ModelConfig::Paper(), 3);
  const auto f = enc->Flops(512);
  ASSERT_EQ(f[0].module, "stage0");
  EXPECT_NEAR(f[0].flops, embed + 2 * (attn + ffn), 1.0);
}

}  // namespace
}  // namespace avatar
