// Hard cases (every output finite and in range) and gradient checks.

#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "core/render/depth_sampling.h"
#include "core/render/ray_marcher.h"
#include "core/render/triplane_sampling.h"
#include "render/render_test_util.h"

namespace avatar::render {
namespace {

using testing::Decode;
using testing::ExpectValidOutputs;

const auto kF64 = torch::TensorOptions().dtype(torch::kFloat64);

RenderOptions Small(int resolution = 6) {
  RenderOptions o;
  o.resolution = resolution;
  o.num_coarse = 12;
  o.num_importance = 12;
  o.return_weights = true;
  return o;
}

torch::Tensor RandomPlanes(int64_t batch, int64_t size = 16) {
  torch::manual_seed(11);
  return torch::randn({batch, 3, kDecoderInputChannels, size, size});
}

// A decoder whose raw density is the constant `raw` (all weights zero).
TriplaneDecoder ConstantDensityDecoder(double raw) {
  TriplaneDecoder d;
  torch::NoGradGuard no_grad;
  d->fc1_weight.zero_();
  d->fc2_weight.zero_();
  d->fc2_bias.fill_(0.3);
  d->fc2_bias[0].fill_(raw);
  return d;
}

TEST(HardCases, RaysThatMissTheVolume) {
  torch::NoGradGuard no_grad;
  // Camera beside the box looking away from it: every sample is outside [-0.5,0.5]^3, where
  // the planes read zero; a decoder mapping zero features to empty space gives empty rays.
  Cameras cams = FrontalCameras(1);
  cams.cam2world =
      LookAtCam2World(torch::tensor({{0.0f, 0.0f, 2.7f}}), torch::tensor({{0.0f, 0.0f, 5.0f}}), torch::zeros({1}))
          .to(torch::kFloat32);
  TriplaneDecoder d = ConstantDensityDecoder(-40.0);  // zero features -> empty
  const RenderOptions o = Small();
  const RenderOutput out = RenderTriplanes(RandomPlanes(1), Decode(d), cams, o);
  ExpectValidOutputs(out, o, "miss");
  EXPECT_LE(out.opacity.max().item<double>(), 1e-12);
  EXPECT_NEAR(out.depth.min().item<double>(), o.far, 1e-5);
  EXPECT_NEAR(out.features.max().item<double>(), -1.0, 1e-6);
}

TEST(HardCases, ExtremeRawDensities) {
  torch::NoGradGuard no_grad;
  const RenderOptions o = Small();
  for (double raw : {1e4, -1e4}) {
    TriplaneDecoder d = ConstantDensityDecoder(raw);
    const RenderOutput out = RenderTriplanes(RandomPlanes(1), Decode(d), FrontalCameras(1), o);
    ExpectValidOutputs(out, o, "raw " + std::to_string(raw));
    if (raw > 0) {
      EXPECT_EQ(out.opacity.min().item<double>(), 1.0);
      // Opaque at the first interval: depth = its midpoint.
      EXPECT_LE(out.depth.max().item<double>(), o.near + 1.05 / 12);
    } else {
      EXPECT_EQ(out.opacity.max().item<double>(), 0.0);
      EXPECT_EQ(out.depth.min().item<double>(), static_cast<float>(o.far));
    }
  }
  // Gradients stay finite at both extremes too (log-space transmittance).
  torch::AutoGradMode grad_mode(true);
  for (double raw : {1e4, -1e4}) {
    const torch::Tensor r = torch::full({1, 2, 8}, raw, kF64).requires_grad_(true);
    const torch::Tensor z = torch::linspace(2.3, 3.2, 8, kF64).view({1, 1, 8}).expand({1, 2, 8});
    const MarchWeights w = ComputeMarchWeights(r, z, 3.3);
    (w.opacity.sum() + w.depth.sum() + w.interval_weights.sum()).backward();
    EXPECT_TRUE(torch::isfinite(r.grad()).all().item<bool>()) << raw;
  }
}

TEST(HardCases, ZeroDensityEverywhere) {
  torch::NoGradGuard no_grad;
  const RenderOptions o = Small();
  // Softplus underflows to exactly 0 for raw = -1e4: no density anywhere.
  TriplaneDecoder d = ConstantDensityDecoder(-1e4);
  const RenderOutput out = RenderTriplanes(RandomPlanes(2), Decode(d), FrontalCameras(2), o);
  ExpectValidOutputs(out, o, "zero density");
  EXPECT_EQ(out.weights.abs().max().item<double>(), 0.0);
  EXPECT_EQ(out.features.max().item<double>(), -1.0);
  // Also a field that returns zero density directly (sigma = softplus(-inf) = 0).
  const Field empty = [](const torch::Tensor& p) {
    FieldSamples s;
    s.raw_density = torch::full({p.size(0), p.size(1)}, -std::numeric_limits<double>::infinity(), p.options());
    s.features = torch::zeros({p.size(0), p.size(1), 4}, p.options());
    return s;
  };
  const RenderOutput e = RenderField(empty, FrontalCameras(1), o);
  ExpectValidOutputs(e, o, "zero-density field");
  EXPECT_EQ(e.opacity.max().item<double>(), 0.0);
}

TEST(HardCases, CameraInsideTheVolume) {
  torch::NoGradGuard no_grad;
  RenderOptions o = Small();
  o.near = 0.0;
  o.far = 1.2;
  Cameras cams = FrontalCameras(2);
  cams.cam2world[0].copy_(testing::LookAtOrbit(0.0, 0.0, 0.0, 0.1));
  cams.cam2world[1].copy_(testing::LookAtOrbit(130.0, 20.0, 10.0, 0.2, {0.1, 0.0, 0.0}));
  TriplaneDecoder d;
  {
    torch::NoGradGuard g;
    d->fc2_bias[0].fill_(4.0);
  }
  const RenderOutput out = RenderTriplanes(RandomPlanes(2), Decode(d), cams, o);
  ExpectValidOutputs(out, o, "inside");
  EXPECT_GT(out.opacity.min().item<double>(), 0.1) << "the camera sees the density around it";
}

TEST(HardCases, GrazingRays) {
  torch::NoGradGuard no_grad;
  // Rays tangent to an opaque sphere and rays running along the box faces.
  const torch::Tensor planes = testing::CoordinatePlanes(64);
  TriplaneDecoder d = testing::ShapeDecoder(testing::Shape::kSphere, 0.3, 50.0);
  const Field field = MakeTriplaneField(planes, Decode(d), 1.0);
  const torch::Tensor o =
      torch::tensor(
          {{0.3, -0.4, 2.7}, {-0.3, 0.0, 2.7}, {0.5, 0.2, 2.7}, {0.2, -0.5, 2.7}, {-0.5, -0.5, 2.7}, {0.0, 0.3, 2.7}},
          kF64)
          .unsqueeze(0);
  const torch::Tensor dir = torch::tensor({0.0, 0.0, -1.0}, kF64).view({1, 1, 3}).expand({1, 6, 3}).contiguous();
  RenderOptions opts = Small();
  for (bool det : {true, false}) {
    opts.deterministic = det;
    const RayRenderOutput out = RenderRays(field, o, dir, opts);
    RenderOutput as_image;
    as_image.features = out.features;
    as_image.opacity = out.opacity;
    as_image.depth = out.depth;
    as_image.weights = out.weights;
    ExpectValidOutputs(as_image, opts, det ? "grazing, deterministic" : "grazing, random");
  }
}

TEST(HardCases, ResolutionsOneAndFiveTwelve) {
  torch::NoGradGuard no_grad;
  TriplaneDecoder d;
  for (int res : {1, 512}) {
    RenderOptions o;
    o.resolution = res;
    o.num_coarse = 4;
    o.num_importance = res == 1 ? 8 : 4;
    const RenderOutput out = RenderTriplanes(RandomPlanes(1, 8), Decode(d), FrontalCameras(1), o);
    ASSERT_EQ(out.features.sizes(), (std::vector<int64_t>{1, 32, res, res}));
    ExpectValidOutputs(out, o, "resolution " + std::to_string(res));
  }
}

TEST(HardCases, BatchOneAndEightAreIndependent) {
  torch::NoGradGuard no_grad;
  TriplaneDecoder d;
  const torch::Tensor planes = RandomPlanes(8);
  Cameras cams = FrontalCameras(8);
  for (int i = 0; i < 8; ++i) cams.cam2world[i].copy_(OrbitCam2World({-35.0 + 10.0 * i, 5.0 - 5.0 * (i % 3)}));
  const RenderOptions o = Small();
  const RenderOutput all = RenderTriplanes(planes, Decode(d), cams, o);
  ExpectValidOutputs(all, o, "batch 8");
  for (int i : {0, 5}) {
    const RenderOutput one = RenderTriplanes(
        planes.narrow(0, i, 1), Decode(d), Cameras{cams.cam2world.narrow(0, i, 1), cams.intrinsics.narrow(0, i, 1)}, o);
    ExpectValidOutputs(one, o, "batch 1");
    EXPECT_LE((one.features[0] - all.features[i]).abs().max().item<double>(), 1e-5) << i;
    EXPECT_LE((one.depth[0] - all.depth[i]).abs().max().item<double>(), 1e-5) << i;
  }
}

TEST(HardCases, Float32AndFloat64Agree) {
  torch::NoGradGuard no_grad;
  TriplaneDecoder d32;
  TriplaneDecoder d64 = TriplaneDecoder();
  {
    torch::NoGradGuard g;
    d32->fc2_bias[0].fill_(2.0);
    for (size_t i = 0; i < d32->parameters().size(); ++i) d64->parameters()[i].copy_(d32->parameters()[i]);
  }
  d64->to(torch::kFloat64);
  const RenderOptions o = Small();
  const RenderOutput a = RenderTriplanes(RandomPlanes(1), Decode(d32), FrontalCameras(1), o);
  const RenderOutput b = RenderTriplanes(RandomPlanes(1).to(torch::kFloat64), Decode(d64), FrontalCameras(1, kF64), o);
  ExpectValidOutputs(a, o, "float32");
  ExpectValidOutputs(b, o, "float64");
  EXPECT_EQ(a.features.scalar_type(), torch::kFloat32);
  EXPECT_EQ(b.features.scalar_type(), torch::kFloat64);
  EXPECT_LE((a.features.to(torch::kFloat64) - b.features).abs().max().item<double>(), 1e-4);
  EXPECT_LE((a.depth.to(torch::kFloat64) - b.depth).abs().max().item<double>(), 1e-4);
}

// --- Gradients: central differences of a random projection of all outputs, float64. ---

// Compares autograd's gradient of `loss` for each tensor in `inputs` with central differences
// at `probes` random elements per tensor.
void CheckGradients(const std::function<torch::Tensor()>& loss, std::vector<torch::Tensor> inputs, int probes,
                    const std::string& what) {
  SCOPED_TRACE(what);
  for (auto& t : inputs) {
    if (t.grad().defined()) t.grad().zero_();
  }
  loss().backward();
  torch::manual_seed(21);
  for (size_t k = 0; k < inputs.size(); ++k) {
    torch::Tensor& t = inputs[k];
    ASSERT_TRUE(t.grad().defined()) << "input " << k << " got no gradient";
    const torch::Tensor grad = t.grad().clone().reshape(-1);
    const int64_t n = t.numel();
    const torch::Tensor picks = torch::randint(n, {probes}, torch::kLong);
    double worst = 0.0;
    for (int i = 0; i < probes; ++i) {
      const int64_t j = picks[i].item<int64_t>();
      const double eps = 1e-6;
      torch::NoGradGuard no_grad;
      torch::Tensor flat = t.view(-1);
      const double saved = flat[j].item<double>();
      flat[j] = saved + eps;
      const double up = loss().item<double>();
      flat[j] = saved - eps;
      const double down = loss().item<double>();
      flat[j] = saved;
      const double numeric = (up - down) / (2 * eps);
      const double analytic = grad[j].item<double>();
      worst = std::max(worst, std::abs(numeric - analytic) / (1e-3 + std::abs(numeric)));
      EXPECT_NEAR(analytic, numeric, 1e-5 + 1e-4 * std::abs(numeric)) << "input " << k << " element " << j;
    }
    std::cout << what << ": input " << k << " worst relative gradient error " << worst << "\n";
  }
}

TEST(Gradients, ThroughPlaneSamplingDecoderAndMarcher) {
  torch::manual_seed(13);
  torch::Tensor planes = (torch::randn({1, 3, 32, 4, 4}, kF64) * 0.5).requires_grad_(true);
  TriplaneDecoder d(32, 8, 3);
  d->to(torch::kFloat64);
  {
    torch::NoGradGuard g;
    d->fc2_bias[0].fill_(2.0);
  }
  RenderOptions o;
  o.resolution = 2;
  o.num_coarse = 10;
  o.num_importance = 0;  // importance positions are not differentiated (as published)
  Cameras cams = FrontalCameras(1, kF64);
  cams.cam2world[0].copy_(OrbitCam2World({15.0, -10.0}, kF64));
  const torch::Tensor proj_f = torch::randn({1, 3, 2, 2}, kF64);
  const torch::Tensor proj_d = torch::randn({1, 1, 2, 2}, kF64);
  const auto loss = [&] {
    const RenderOutput out = RenderTriplanes(planes, Decode(d), cams, o);
    return (out.features * proj_f).sum() + (out.depth * proj_d).sum() + out.opacity.sum();
  };
  CheckGradients(loss, {planes, d->fc1_weight, d->fc1_bias, d->fc2_weight, d->fc2_bias}, 12, "render");
}

TEST(Gradients, ReferenceSamplerPointsAndMarcherInputs) {
  torch::manual_seed(17);
  torch::Tensor planes = torch::randn({1, 3, 2, 5, 5}, kF64).requires_grad_(true);
  torch::Tensor points = ((torch::rand({1, 6, 3}, kF64) - 0.5) * 0.9).requires_grad_(true);
  const torch::Tensor proj = torch::randn({1, 6, 2}, kF64);
  CheckGradients([&] { return (SampleTriplanes(planes, points, 1.0) * proj).sum(); }, {planes, points}, 10,
                 "plane sampling");
  torch::Tensor raw = (torch::randn({2, 3, 7}, kF64) * 2).requires_grad_(true);
  torch::Tensor feats = torch::rand({2, 3, 7, 4}, kF64).requires_grad_(true);
  const torch::Tensor depths = std::get<0>(torch::sort(torch::rand({2, 3, 7}, kF64) + 2.5, 2));
  const torch::Tensor proj_f = torch::randn({2, 3, 4}, kF64);
  CheckGradients(
      [&] {
        const MarchResult r = MarchRays(raw, feats, depths, 3.6);
        return (r.features * proj_f).sum() + r.weights.depth.sum() + 0.5 * r.weights.opacity.sum();
      },
      {raw, feats}, 10, "marcher");
}

}  // namespace
}  // namespace avatar::render
