// Gradients reach every branch, and the tiny network can overfit one fixed batch.

#include <cmath>
#include <iostream>
#include <vector>

#include <gtest/gtest.h>

#include "core/model/goha_model.h"
#include "core/render/camera.h"
#include "model_test_util.h"

namespace avatar {
namespace {

struct Batch {
  torch::Tensor source, eye_mouth, matte, expression, target, target_hr;
  render::Cameras source_cam, target_cam;
};

// A fixed, smooth batch: a source image, masks, I_exp, and target images at another camera.
Batch MakeBatch(const ModelConfig& c) {
  const int64_t s = c.image_size;
  const torch::Tensor yy = torch::linspace(-1, 1, s).view({1, 1, s, 1}).expand({1, 1, s, s});
  const torch::Tensor xx = torch::linspace(-1, 1, s).view({1, 1, 1, s}).expand({1, 1, s, s});
  const torch::Tensor disk = ((xx * xx + yy * yy) < 0.5).to(torch::kFloat32);
  Batch b;
  b.source = torch::cat({xx * disk, yy * disk, (disk * 0.6 - 0.3)}, 1);  // [1,3,S,S]
  b.eye_mouth = ((yy.abs() < 0.1) * (xx.abs() < 0.3)).to(torch::kFloat32);
  b.matte = disk;
  b.expression = torch::cat({disk * 0.5, -disk * 0.2, xx * 0.3}, 1);
  const int64_t r = c.render_size;
  const torch::Tensor ry = torch::linspace(-1, 1, r).view({1, 1, r, 1}).expand({1, 1, r, r});
  const torch::Tensor rx = torch::linspace(-1, 1, r).view({1, 1, 1, r}).expand({1, 1, r, r});
  b.target = torch::cat({rx * 0.5, ry * 0.5, rx * ry * 0.5}, 1);
  b.target_hr = ResizeBilinear(b.target, c.sr_size, c.sr_size);
  b.source_cam = render::FrontalCameras(1);
  render::ViewPose pose;  // The camera 15 degrees to the side and 5 above.
  pose.yaw = 15;
  pose.pitch = -5;
  b.target_cam = {render::OrbitCam2World(pose).unsqueeze(0), render::DefaultIntrinsics().unsqueeze(0)};
  return b;
}

struct Losses {
  torch::Tensor reconstruction;  // L1 of the three plane sums and of the SR output
  torch::Tensor generator_adv;   // softplus(-D(fake))
};

Losses Forward(GohaModel& model, DualDiscriminator& disc, const Batch& b) {
  const torch::Tensor tc = model->CanonicalPlanes(b.source);
  const torch::Tensor tp = model->AppearancePlanes(b.source, b.eye_mouth, b.matte, tc, b.source_cam).planes;
  const torch::Tensor te = model->ExpressionPlanes(b.expression);
  const auto ic = model->Render(tc, b.target_cam, /*resolution=*/0, /*deterministic=*/false);
  const auto ice = model->Render(tc + te, b.target_cam, /*resolution=*/0, /*deterministic=*/false);
  const auto icep = model->Render(tc + te + tp, b.target_cam, /*resolution=*/0, /*deterministic=*/false);
  const torch::Tensor hr = model->SuperResolve(icep.rgb);
  Losses l;
  l.reconstruction = (ic.rgb - b.target).abs().mean() + (ice.rgb - b.target).abs().mean() +
                     (icep.rgb - b.target).abs().mean() + (hr - b.target_hr).abs().mean();
  l.generator_adv = torch::softplus(-disc->forward(hr, icep.rgb)).mean();
  return l;
}

TEST(Training, GradientsReachEveryModule) {
  torch::manual_seed(20);
  const ModelConfig c = avatar::testing::TinyForTest();
  GohaModel model(c);
  DualDiscriminator disc(c);
  const Batch b = MakeBatch(c);
  const Losses l = Forward(model, disc, b);
  (l.reconstruction + 0.1 * l.generator_adv).backward();
  std::vector<std::pair<std::string, std::shared_ptr<torch::nn::Module>>> modules = {
      {"canonical_encoder", model->canonical_encoder.ptr()},   {"canonical_head", model->canonical_head.ptr()},
      {"appearance_encoder", model->appearance_encoder.ptr()}, {"expression_encoder", model->expression_encoder.ptr()},
      {"expression_head", model->expression_head.ptr()},       {"decoder", model->decoder.ptr()},
      {"super_resolution", model->super_resolution.ptr()},     {"discriminator", disc.ptr()}};
  for (int p = 0; p < 3; ++p) modules.emplace_back("upsampler" + std::to_string(p), model->upsamplers[p].ptr());
  for (const auto& [name, module] : modules) {
    int64_t tensors = 0, nonzero = 0;
    for (const auto& item : module->named_parameters(true)) {
      ++tensors;
      const torch::Tensor g = item.value().grad();
      ASSERT_TRUE(g.defined()) << name << "." << item.key() << " has no gradient";
      ASSERT_TRUE(torch::isfinite(g).all().item<bool>()) << name << "." << item.key();
      if (g.abs().sum().item<double>() > 0)
        ++nonzero;
      else
        ADD_FAILURE() << name << "." << item.key() << " has an all-zero gradient";
    }
    EXPECT_GT(tensors, 0) << name;
    EXPECT_EQ(nonzero, tensors) << name;
  }
}

// Judged by the mean of the last 10 losses (not a lucky step) against the untrained network's
// loss (step 0). Measured 2026-12-04 (AMD EPYC, AVX-512) over AVATAR_THREADS 1 and 2 and the
// OpenBLAS core types Haswell (this CPU's default), Zen, SkylakeX, Sandybridge, Prescott, and
// Haswell with oneDNN and ATen limited to AVX2 (a machine without AVX-512), as the mean of the last
// 10 losses over the loss at step 0: mit_b0 0.0438-0.0489 (start 2.2206), mobilenet_v2 (this test
// again under AVATAR_TEST_ENCODER, see tests/model/CMakeLists.txt) 0.0269-0.0404 (start 3.1769;
// its loss climbs back between steps 80 and 130 before it falls, differently on each core type,
// which is why the run is not shorter: at step 200 the ratio was 0.056-0.105). The bar, a tenth,
// is 2x the highest measurement, and its distance to it is 4 times the spread.
TEST(Training, TinyModelOverfitsOneBatch) {
  torch::manual_seed(21);
  const ModelConfig c = avatar::testing::TinyForTest();
  GohaModel model(c);
  DualDiscriminator disc(c);
  const Batch b = MakeBatch(c);
  torch::optim::Adam opt = avatar::testing::OverfitOptimizer(model);  // backbones (mobilenet_v2) at 1e-4
  const int steps = 300, window = 10;
  std::vector<double> losses;
  for (int step = 0; step < steps; ++step) {
    opt.zero_grad();
    const torch::Tensor loss = Forward(model, disc, b).reconstruction;
    loss.backward();
    opt.step();
    losses.push_back(loss.item<double>());
  }
  const double first = losses.front();
  double last = 0.0;
  for (int k = 0; k < window; ++k) last += losses[steps - 1 - k] / window;
  std::cout << "overfit (" << c.encoder << "): mean loss of each " << window << " steps:";
  for (int w = 0; w < steps / window; ++w) {
    double m = 0.0;
    for (int k = 0; k < window; ++k) m += losses[w * window + k] / window;
    std::cout << " " << m;
  }
  std::cout << "\noverfit (" << c.encoder << "): loss " << first << " -> " << last << " (ratio " << last / first
            << ") in " << steps << " steps\n";
  EXPECT_TRUE(std::isfinite(last));
  EXPECT_LT(last, first / 10.0) << "loss (mean of the last " << window << " steps) did not fall 10x";
}

}  // namespace
}  // namespace avatar
