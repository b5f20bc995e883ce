// Analytic scenes encoded in tri-planes + a hand-set decoder, rendered by the full pipeline:
// opacity against 1 - exp(-sigma * chord), depth of an opaque sphere against the ray-sphere hit,
// plus determinism of the inference mode and the mean of the random mode.

#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <iostream>

#include "render/render_test_util.h"

namespace avatar::render {
namespace {

using testing::CoordinatePlanes;
using testing::Decode;
using testing::RaysThrough;
using testing::Shape;
using testing::ShapeDecoder;

const auto kF64 = torch::TensorOptions().dtype(torch::kFloat64);

torch::Tensor CameraOrigin() { return torch::tensor({0.0, 0.0, kCameraRadius}, kF64); }

// Targets on the z = 0 plane, spread across the shape (and beyond it for the sphere).
torch::Tensor Targets() {
  return torch::tensor({0.0, 0.0,   0.0,  0.1, 0.0, 0.0, 0.0, -0.17, 0.0,  0.21, 0.13,
                        0.0, -0.26, 0.05, 0.0, 0.3, 0.3, 0.0, -0.05, 0.33, 0.0},
                       kF64)
      .view({-1, 3});
}

RenderOptions Samples(int coarse, int importance) {
  RenderOptions o;
  o.num_coarse = coarse;
  o.num_importance = importance;
  return o;
}

struct Scene {
  torch::Tensor planes;
  TriplaneDecoder decoder;
};

class AnalyticTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { planes_ = new torch::Tensor(CoordinatePlanes(256)); }
  static void TearDownTestSuite() { delete planes_; }
  static torch::Tensor* planes_;
};
torch::Tensor* AnalyticTest::planes_ = nullptr;

TEST_F(AnalyticTest, SlabOpacityMatchesBeerLambert) {
  torch::NoGradGuard no_grad;
  const double half = 0.15, sigma = 0.5;
  const Field field = MakeTriplaneField(*planes_, Decode(ShapeDecoder(Shape::kSlab, half, sigma)), 1.0);
  auto [origins, dirs] = RaysThrough(CameraOrigin(), Targets());
  // Chord through |z| < half along a ray with direction d: 2 * half / |d_z|.
  const torch::Tensor expected = 1.0 - torch::exp(-sigma * 2.0 * half / dirs[0].select(1, 2).abs());
  double previous = 1.0;
  for (int n : {256, 2048, 16384}) {
    const RayRenderOutput out = RenderRays(field, origins, dirs, Samples(n, 0));
    const double err = (out.opacity[0] - expected).abs().max().item<double>();
    const double spacing = (3.3 - 2.25) / n;
    std::cout << "slab: " << n << " samples, max |opacity error| = " << err << "\n";
    // Each of the two boundaries can misplace at most one interval's optical depth.
    EXPECT_LE(err, 2.0 * sigma * spacing) << n;
    EXPECT_LE(err, previous) << "error must not grow with more samples";
    previous = err;
    if (n == 16384) {
      EXPECT_LE(err, 1e-4);
    }
    // Feature channel 0 is a constant colour c: composite = opacity * c, mapped to [-1,1].
    const double c = 0.8;
    EXPECT_LE((out.features[0].select(1, 0) - (2.0 * c * out.opacity[0] - 1.0)).abs().max().item<double>(), 1e-9);
  }
}

TEST_F(AnalyticTest, SphereOpacityMatchesBeerLambert) {
  torch::NoGradGuard no_grad;
  const double radius = 0.35, sigma = 0.5;
  const Field field = MakeTriplaneField(*planes_, Decode(ShapeDecoder(Shape::kSphere, radius, sigma)), 1.0);
  auto [origins, dirs] = RaysThrough(CameraOrigin(), Targets());
  // Distance of each ray from the centre, and the chord 2 sqrt(r^2 - b^2) (0 for misses).
  const torch::Tensor o = origins[0];
  const torch::Tensor along = -(o * dirs[0]).sum(1, true);
  const torch::Tensor b2 = ((o + along * dirs[0]).pow(2)).sum(1);
  const torch::Tensor chord = 2.0 * torch::sqrt(torch::clamp_min(radius * radius - b2, 0.0));
  const torch::Tensor expected = 1.0 - torch::exp(-sigma * chord);
  ASSERT_GT((chord > 0).sum().item<int64_t>(), 4) << "most rays must hit the sphere";
  ASSERT_GT((chord == 0).sum().item<int64_t>(), 0) << "one ray must miss it";
  double previous = 1.0;
  for (int n : {256, 2048, 16384}) {
    const RayRenderOutput out = RenderRays(field, origins, dirs, Samples(n, 0));
    const double err = (out.opacity[0] - expected).abs().max().item<double>();
    const double spacing = (3.3 - 2.25) / n;
    std::cout << "sphere: " << n << " samples, max |opacity error| = " << err << "\n";
    // Quadrature (one interval per boundary) + the quadratic channel's interpolation (< 2e-5).
    EXPECT_LE(err, 2.0 * sigma * spacing + 2e-5) << n;
    EXPECT_LE(err, previous);
    previous = err;
    if (n == 16384) {
      EXPECT_LE(err, 1e-4);
    }
  }
  // The published sampling (48 + 48) is within its coarse spacing bound.
  const RayRenderOutput paper = RenderRays(field, origins, dirs, Samples(48, 48));
  const double err = (paper.opacity[0] - expected).abs().max().item<double>();
  std::cout << "sphere: 48+48 samples, max |opacity error| = " << err << "\n";
  EXPECT_LE(err, 2.0 * sigma * (3.3 - 2.25) / 48);
}

TEST_F(AnalyticTest, OpaqueSphereDepthWithinOneSampleSpacing) {
  torch::NoGradGuard no_grad;
  const double radius = 0.3, sigma = 1e4;
  const Field field = MakeTriplaneField(*planes_, Decode(ShapeDecoder(Shape::kSphere, radius, sigma)), 1.0);
  const torch::Tensor targets = Targets().narrow(0, 0, 5);  // all inside the silhouette
  auto [origins, dirs] = RaysThrough(CameraOrigin(), targets);
  const torch::Tensor o = origins[0];
  const torch::Tensor along = -(o * dirs[0]).sum(1);  // depth of the closest approach
  const torch::Tensor b2 = (o + along.unsqueeze(1) * dirs[0]).pow(2).sum(1);
  const torch::Tensor hit = along - torch::sqrt(radius * radius - b2);
  double first_err = -1.0, last_err = -1.0;
  for (int n : {64, 256, 1024, 4096}) {
    const RayRenderOutput out = RenderRays(field, origins, dirs, Samples(n, 0));
    const double spacing = (3.3 - 2.25) / n;
    const double err = (out.depth[0] - hit).abs().max().item<double>();
    std::cout << "opaque sphere: " << n << " samples, max |depth error| = " << err << " (spacing " << spacing << ")\n";
    EXPECT_LE(err, spacing) << n;
    EXPECT_GE(out.opacity.min().item<double>(), 1.0 - 1e-9);
    if (first_err < 0) first_err = err;
    last_err = err;
  }
  EXPECT_LT(last_err, first_err / 8) << "depth must converge as samples grow";
  // With importance samples the surface is found far below the coarse spacing.
  const RayRenderOutput paper = RenderRays(field, origins, dirs, Samples(48, 48));
  const double err = (paper.depth[0] - hit).abs().max().item<double>();
  std::cout << "opaque sphere: 48+48 samples, max |depth error| = " << err << "\n";
  EXPECT_LE(err, (3.3 - 2.25) / 48);
}

// A smooth random scene for the determinism tests.
Scene SmoothScene(int64_t batch) {
  torch::manual_seed(7);
  Scene s;
  const torch::Tensor coarse = torch::randn({batch * 3, kDecoderInputChannels, 8, 8});
  s.planes = torch::upsample_bilinear2d(coarse, {32, 32}, false).view({batch, 3, kDecoderInputChannels, 32, 32});
  s.decoder = TriplaneDecoder();
  {
    torch::NoGradGuard no_grad;
    s.decoder->fc2_bias[0].fill_(3.0);  // visible density
  }
  return s;
}

TEST(RenderDeterminism, DeterministicRendersAreBitIdentical) {
  torch::NoGradGuard no_grad;
  Scene s = SmoothScene(2);
  RenderOptions o = Samples(16, 16);
  o.resolution = 12;
  o.chunk_rays = 7;  // uneven chunks, several per thread
  Cameras cams = FrontalCameras(2);
  cams.cam2world[1].copy_(OrbitCam2World({20.0, 5.0}));
  const RenderOutput a = RenderTriplanes(s.planes, Decode(s.decoder), cams, o);
  const RenderOutput b = RenderTriplanes(s.planes, Decode(s.decoder), cams, o);
  EXPECT_TRUE(torch::equal(a.features, b.features));
  EXPECT_TRUE(torch::equal(a.opacity, b.opacity));
  EXPECT_TRUE(torch::equal(a.depth, b.depth));
  // The autograd path (one graph, reference sampler) agrees to float rounding.
  torch::AutoGradMode grad(true);
  const RenderOutput g = RenderTriplanes(s.planes, Decode(s.decoder), cams, o);
  EXPECT_LE((g.features - a.features).abs().max().item<double>(), 1e-4);
  EXPECT_LE((g.depth - a.depth).abs().max().item<double>(), 1e-4);
}

TEST(RenderDeterminism, RandomModeMeanMatchesDeterministic) {
  torch::NoGradGuard no_grad;
  Scene s = SmoothScene(1);
  RenderOptions o = Samples(32, 32);
  o.resolution = 8;
  const Cameras cams = FrontalCameras(1);
  const RenderOutput det = RenderTriplanes(s.planes, Decode(s.decoder), cams, o);
  o.deterministic = false;
  const int renders = 64;
  torch::Tensor sum = torch::zeros_like(det.features), sum_opacity = torch::zeros_like(det.opacity);
  torch::Tensor first;
  for (int i = 0; i < renders; ++i) {
    const RenderOutput r = RenderTriplanes(s.planes, Decode(s.decoder), cams, o);
    if (i == 0) first = r.features;
    sum += r.features;
    sum_opacity += r.opacity;
  }
  const double feat_err = (sum / renders - det.features).abs().max().item<double>();
  const double opac_err = (sum_opacity / renders - det.opacity).abs().max().item<double>();
  const double single_err = (first - det.features).abs().max().item<double>();
  std::cout << "random-mode mean vs deterministic: features " << feat_err << ", opacity " << opac_err
            << "; one random render: " << single_err << "\n";
  // Both are quadratures of the same integral; the random mean's standard error and the
  // quadrature bias at 32 + 32 samples are both well below 0.01 in the [-1,1] range.
  EXPECT_LE(feat_err, 0.01);
  EXPECT_LE(opac_err, 0.01);
  EXPECT_GT(single_err, 0.0) << "the random mode must actually jitter";
}

}  // namespace
}  // namespace avatar::render
