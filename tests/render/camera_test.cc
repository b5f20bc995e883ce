// Cameras, rays, depth sampling, tri-plane lookup and the decoder.

#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "core/render/depth_sampling.h"
#include "core/render/ray_marcher.h"
#include "core/render/triplane_sampling.h"
#include "core/util/error.h"
#include "render/render_test_util.h"

namespace avatar::render {
namespace {

const auto kF64 = torch::TensorOptions().dtype(torch::kFloat64);

Cameras SomeCameras() {
  Cameras c;
  c.cam2world = torch::stack({testing::LookAtOrbit(25.0, 10.0, 7.0, 2.5, {0.0, 0.05, 0.2}, kF64),
                              OrbitCam2World({-40.0, 15.0, 3.0, kCameraRadius / 3.0}, kF64), FrontalCam2World(kF64)});
  c.intrinsics = DefaultIntrinsics(kF64).unsqueeze(0).repeat({3, 1, 1});
  c.intrinsics[1][0][0] = 3.9;   // fx != fy
  c.intrinsics[1][0][1] = 0.02;  // skew
  c.intrinsics[2][0][2] = 0.47;  // off-centre principal point
  return c;
}

TEST(Camera, LabelRoundTrip) {
  const Cameras c = SomeCameras();
  const torch::Tensor labels = LabelsFromCameras(c);
  ASSERT_EQ(labels.sizes(), (std::vector<int64_t>{3, kCameraLabelSize}));
  const Cameras back = CamerasFromLabels(labels);
  EXPECT_TRUE(torch::equal(back.cam2world, c.cam2world));
  EXPECT_TRUE(torch::equal(back.intrinsics, c.intrinsics));
  EXPECT_TRUE(torch::equal(LabelsFromCameras(back), labels));
  // A single [25] label is a batch of one.
  EXPECT_EQ(CamerasFromLabels(labels[0]).cam2world.sizes(), (std::vector<int64_t>{1, 4, 4}));
  // Label layout: row-major cam2world, then row-major K.
  EXPECT_EQ(labels[2][11].item<double>(), kCameraRadius);
  EXPECT_EQ(labels[2][16].item<double>(), kFocal);
  EXPECT_EQ(labels[2][24].item<double>(), 1.0);
  EXPECT_THROW(CamerasFromLabels(torch::zeros({2, 24}, kF64)), InvalidInput);
  EXPECT_THROW(CamerasFromLabels(torch::zeros({1, 25}, kF64)), InvalidInput);  // last row not (0,0,0,1)
}

TEST(Camera, OrbitZeroIsTheFrontalConstant) {
  EXPECT_TRUE(torch::equal(OrbitCam2World({}, kF64), FrontalCam2World(kF64)));
  EXPECT_TRUE(torch::equal(OrbitCam2World({}), FrontalCam2World()));
  const Cameras f = FrontalCameras(2);
  EXPECT_TRUE(torch::equal(f.cam2world[1], FrontalCam2World()));
  EXPECT_NEAR(f.intrinsics[0][0][0].item<double>(), 4.2647, 1e-6);
  EXPECT_NEAR(f.intrinsics[0][1][2].item<double>(), 0.5, 0.0);
  // The field of view the frontal camera sees is EG3D's published 13.37 degrees (FFHQ's focal of
  // 4.2647 image widths): points on the head's depth at half that angle off the axis, left, right,
  // up and down, project to the image's edges (1e-3 of the width: 13.37 has two decimals).
  const double half = 13.37 / 2.0 * M_PI / 180.0;
  const double off = kCameraRadius * std::tan(half);
  const torch::Tensor edges = torch::tensor({off, 0.0, 0.0, -off, 0.0, 0.0, 0.0, off, 0.0, 0.0, -off, 0.0}, kF64);
  const torch::Tensor uv = ProjectPoints(edges.view({1, 4, 3}), FrontalCameras(1, kF64))[0];
  EXPECT_NEAR(uv[0][0].item<double>(), 1.0, 1e-3);  // world +x: the right edge
  EXPECT_NEAR(uv[1][0].item<double>(), 0.0, 1e-3);
  EXPECT_NEAR(uv[2][1].item<double>(), 0.0, 1e-3);  // world +y: the top edge
  EXPECT_NEAR(uv[3][1].item<double>(), 1.0, 1e-3);
}

TEST(Camera, AxesFollowOpenCvInAYUpWorld) {
  const Cameras f = FrontalCameras(1, kF64);
  // World +x is image right, world +y is image up, the origin is the image centre at depth 2.7.
  const torch::Tensor pts = torch::tensor({0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 0.1, 0.0}, kF64).view({1, 3, 3});
  const torch::Tensor uvz = ProjectPoints(pts, f)[0];
  EXPECT_NEAR(uvz[0][0].item<double>(), 0.5, 1e-12);
  EXPECT_NEAR(uvz[0][1].item<double>(), 0.5, 1e-12);
  EXPECT_NEAR(uvz[0][2].item<double>(), kCameraRadius, 1e-12);
  EXPECT_GT(uvz[1][0].item<double>(), 0.5);
  EXPECT_LT(uvz[2][1].item<double>(), 0.5);
  // Pose: yaw 90 puts the camera on +x; the head tilted down 30 puts it above; the look-at target
  // projects to the centre.
  const torch::Tensor side = OrbitCam2World({90.0, 0.0, 0.0, kCameraRadius / 2.0}, kF64);
  EXPECT_NEAR(side[0][3].item<double>(), 2.0, 1e-12);
  const torch::Tensor above = OrbitCam2World({0.0, -30.0}, kF64);
  EXPECT_NEAR(above[1][3].item<double>(), kCameraRadius * 0.5, 1e-12);
  Cameras c = SomeCameras();
  const torch::Tensor target = torch::tensor({0.0, 0.05, 0.2}, kF64).view({1, 1, 3});
  const torch::Tensor t = ProjectPoints(target, {c.cam2world.narrow(0, 0, 1), c.intrinsics.narrow(0, 0, 1)});
  EXPECT_NEAR(t[0][0][0].item<double>(), 0.5, 1e-12);
  EXPECT_NEAR(t[0][0][1].item<double>(), 0.5, 1e-12);
  // Rotation part is orthonormal with det +1.
  const torch::Tensor r = c.cam2world.narrow(1, 0, 3).narrow(2, 0, 3);
  EXPECT_LE((torch::bmm(r.transpose(1, 2), r) - torch::eye(3, kF64)).abs().max().item<double>(), 1e-12);
  EXPECT_NEAR(torch::det(r).min().item<double>(), 1.0, 1e-12);
  EXPECT_THROW(OrbitCam2World({0.0, 0.0, 0.0, 0.0}), InvalidOptions);
  EXPECT_THROW(OrbitCam2World({std::nan(""), 0.0}), InvalidOptions);
  EXPECT_THROW(LookAtCam2World(torch::zeros({1, 3}), torch::zeros({1, 3}), torch::zeros({1})), InvalidInput);
}

TEST(Camera, ProjectedPointLandsOnThePixelWhoseRayHitsIt) {
  const Cameras c = SomeCameras();
  const int64_t res = 37;
  const Rays rays = GenerateRays(c, res);
  ASSERT_EQ(rays.origins.sizes(), (std::vector<int64_t>{3, res * res, 3}));
  EXPECT_LE((rays.directions.norm(2, -1) - 1.0).abs().max().item<double>(), 1e-12);
  // Points at several depths along every pixel's ray project back onto that pixel's centre.
  for (double t : {2.0, 2.7, 3.4}) {
    const torch::Tensor pts = rays.origins + t * rays.directions;
    const torch::Tensor uvz = ProjectPoints(pts, c);
    const torch::Tensor idx = torch::arange(res * res, torch::kLong);
    const torch::Tensor u = ((idx % res).to(torch::kFloat64) + 0.5) / res;
    const torch::Tensor v = (torch::div(idx, res, "floor").to(torch::kFloat64) + 0.5) / res;
    const double du = (uvz.select(2, 0) - u).abs().max().item<double>() * res;  // in pixels
    const double dv = (uvz.select(2, 1) - v).abs().max().item<double>() * res;
    EXPECT_LE(du, 1e-6) << "pixels";
    EXPECT_LE(dv, 1e-6) << "pixels";
    // z is the depth along the optical axis: t * cos(angle to the axis) <= t.
    EXPECT_LE(uvz.select(2, 2).max().item<double>(), t + 1e-12);
  }
  // A random point lands inside the pixel (floor(u R), floor(v R)) whose ray passes closest.
  torch::manual_seed(3);
  const torch::Tensor pts = (torch::rand({3, 50, 3}, kF64) - 0.5) * 0.3;
  const torch::Tensor uvz = ProjectPoints(pts, c);
  ASSERT_GT(uvz.narrow(2, 0, 2).min().item<double>(), 0.0) << "test points must be in view";
  ASSERT_LT(uvz.narrow(2, 0, 2).max().item<double>(), 1.0) << "test points must be in view";
  const torch::Tensor col = (uvz.select(2, 0) * res).floor().to(torch::kLong).clamp(0, res - 1);
  const torch::Tensor row = (uvz.select(2, 1) * res).floor().to(torch::kLong).clamp(0, res - 1);
  const torch::Tensor ray = row * res + col;  // [3,50]
  const torch::Tensor d = rays.directions.gather(1, ray.unsqueeze(2).expand({3, 50, 3}));
  const torch::Tensor o = rays.origins.gather(1, ray.unsqueeze(2).expand({3, 50, 3}));
  const torch::Tensor rel = pts - o;
  const torch::Tensor dist = (rel - (rel * d).sum(2, true) * d).norm(2, -1);
  // Half a pixel diagonal at depth <= 3.6 for focal 3.9..4.3: 3.6 * 0.71 / (37 * 3.9) < 0.018.
  EXPECT_LE(dist.max().item<double>(), 3.6 * 0.71 / (res * 3.9));
}

TEST(DepthSampling, StratifiedAndImportanceSamples) {
  const auto f64 = kF64;
  const torch::Tensor det = StratifiedDepths(2, 3, 8, 2.25, 3.3, true, f64);
  EXPECT_NEAR(det[0][0][0].item<double>(), 2.25 + 0.5 * 1.05 / 8, 1e-12);
  EXPECT_TRUE(torch::equal(det, StratifiedDepths(2, 3, 8, 2.25, 3.3, true, f64)));
  torch::manual_seed(1);
  const torch::Tensor rnd = StratifiedDepths(2, 3, 8, 2.25, 3.3, false, f64);
  EXPECT_LE((rnd - det).abs().max().item<double>(), 0.5 * 1.05 / 8 + 1e-12) << "jitter stays in its stratum";
  EXPECT_GT((rnd - det).abs().max().item<double>(), 0.0);
  // Importance samples follow a peaked weight distribution and stay sorted inside the bins.
  const int64_t s = 32;
  const torch::Tensor z = StratifiedDepths(1, 2, s, 2.25, 3.3, true, f64);
  torch::Tensor w = torch::zeros({1, 2, s - 1}, f64);
  w[0][0][10] = 1.0;
  w[0][1].fill_(0.0);  // empty ray: samples spread over the range
  const torch::Tensor fine = ImportanceDepths(z, w, 64, true);
  const torch::Tensor mids = 0.5 * (z.narrow(2, 0, s - 1) + z.narrow(2, 1, s - 1));
  EXPECT_TRUE((fine.narrow(2, 1, 63) >= fine.narrow(2, 0, 63)).all().item<bool>());
  EXPECT_GE(fine.min().item<double>(), mids[0][0][0].item<double>() - 1e-12);
  EXPECT_LE(fine.max().item<double>(), mids[0][0][s - 3].item<double>() + 1e-12);
  // Most samples of the peaked ray fall within a few bins of the peak.
  const double peak = mids[0][0][10].item<double>(), bin = 1.05 / s;
  const double near_peak = ((fine[0][0] - peak).abs() < 3 * bin).to(torch::kFloat64).mean().item<double>();
  EXPECT_GT(near_peak, 0.6);
  const double spread = (fine[0][1].max() - fine[0][1].min()).item<double>();
  EXPECT_GT(spread, 0.8 * (mids[0][1][s - 3] - mids[0][1][0]).item<double>());
  EXPECT_TRUE(torch::equal(fine, ImportanceDepths(z, w, 64, true)));
  torch::manual_seed(2);
  const torch::Tensor fine_rnd = ImportanceDepths(z, w, 64, false);
  EXPECT_TRUE((fine_rnd.narrow(2, 1, 63) >= fine_rnd.narrow(2, 0, 63)).all().item<bool>());
}

TEST(TriplaneSampling, FastKernelMatchesGridSampleReference) {
  torch::manual_seed(4);
  for (auto dtype : {torch::kFloat32, torch::kFloat64}) {
    const auto opts = torch::TensorOptions().dtype(dtype);
    const torch::Tensor planes = torch::randn({2, 3, 5, 7, 6}, opts);
    // Points inside, on the border band and far outside the box (zero padding).
    const torch::Tensor pts = (torch::rand({2, 400, 3}, opts) - 0.5) * 1.6;
    for (double box_warp : {1.0, 0.8}) {
      const torch::Tensor ref = SampleTriplanesReference(planes, pts, box_warp);
      const torch::Tensor fast = SampleTriplanesFast(PlanesChannelsLast(planes), pts, box_warp);
      ASSERT_EQ(fast.sizes(), (std::vector<int64_t>{2, 400, 5}));
      const double tol = dtype == torch::kFloat32 ? 1e-5 : 1e-12;
      EXPECT_LE((ref - fast).abs().max().item<double>(), tol);
    }
  }
  // Plane conventions: a texel centre of plane p returns (its value) / 3 for the mean.
  torch::Tensor planes = torch::zeros({1, 3, 1, 4, 4}, kF64);
  planes[0][0][0][1][3] = 3.0;                                               // XY plane: row (y) 1, column (x) 3
  planes[0][1][0][2][0] = 6.0;                                               // XZ plane: row (z) 2, column (x) 0
  planes[0][2][0][0][2] = 9.0;                                               // ZY plane: row (y) 0, column (z) 2
  const auto centre = [](int i) { return (-1.0 + (i + 0.5) * 0.5) / 2.0; };  // world, box_warp 1
  const torch::Tensor p = torch::tensor({centre(3), centre(1), 5.0,          //
                                         centre(0), 5.0, centre(2),          //
                                         5.0, centre(0), centre(2)},
                                        kF64)
                              .view({1, 3, 3});
  const torch::Tensor f = SampleTriplanes(planes, p, 1.0);
  EXPECT_NEAR(f[0][0][0].item<double>(), 1.0, 1e-12);
  EXPECT_NEAR(f[0][1][0].item<double>(), 2.0, 1e-12);
  EXPECT_NEAR(f[0][2][0].item<double>(), 3.0, 1e-12);
}

TEST(TriplaneDecoder, ShapesRangeAndEffectiveWeights) {
  TriplaneDecoder decoder;
  EXPECT_EQ(decoder->fc1_weight.sizes(), (std::vector<int64_t>{64, 32}));
  EXPECT_EQ(decoder->fc2_weight.sizes(), (std::vector<int64_t>{33, 64}));
  torch::manual_seed(5);
  const torch::Tensor x = torch::randn({2, 10, 32}) * 10;
  const torch::Tensor y = decoder->forward(x);
  ASSERT_EQ(y.sizes(), (std::vector<int64_t>{2, 10, 33}));
  EXPECT_GE(y.narrow(2, 1, 32).min().item<double>(), -0.001 - 1e-6);
  EXPECT_LE(y.narrow(2, 1, 32).max().item<double>(), 1.001 + 1e-6);
  // Equalised learning rate: effective weight = stored / sqrt(fan_in).
  const torch::Tensor h = torch::softplus(torch::matmul(x, decoder->fc1_weight.t() / std::sqrt(32.0)));
  const torch::Tensor raw = torch::matmul(h, decoder->fc2_weight.t() / 8.0).select(2, 0);
  EXPECT_LE((y.select(2, 0) - raw).abs().max().item<double>(), 1e-4);
  // The no-grad (in-place) path gives the same values.
  torch::NoGradGuard no_grad;
  EXPECT_LE((decoder->forward(x) - y).abs().max().item<double>(), 1e-6);
  EXPECT_THROW(decoder->forward(torch::zeros({3, 31})), InvalidInput);
}

TEST(Renderer, PaperSizeShapes) {
  torch::NoGradGuard no_grad;
  TriplaneDecoder decoder;
  const torch::Tensor planes = torch::randn({1, 3, 32, 256, 256}) * 0.5;
  RenderOptions o;  // the defaults are the paper's sizes
  EXPECT_EQ(o.resolution, 128);
  EXPECT_EQ(o.num_coarse + o.num_importance, 96);
  o.return_weights = true;
  const RenderOutput out = RenderTriplanes(planes, testing::Decode(decoder), LabelsFromCameras(FrontalCameras(1)), o);
  EXPECT_EQ(out.features.sizes(), (std::vector<int64_t>{1, 32, 128, 128}));
  EXPECT_EQ(out.rgb.sizes(), (std::vector<int64_t>{1, 3, 128, 128}));
  EXPECT_EQ(out.opacity.sizes(), (std::vector<int64_t>{1, 1, 128, 128}));
  EXPECT_EQ(out.depth.sizes(), (std::vector<int64_t>{1, 1, 128, 128}));
  EXPECT_EQ(out.weights.sizes(), (std::vector<int64_t>{1, 128 * 128, 95}));
  testing::ExpectValidOutputs(out, o, "paper size");
}

TEST(Renderer, OptionsValidate) {
  RenderOptions o;
  EXPECT_NO_THROW(o.Validate());
  o.num_coarse = 3;
  EXPECT_THROW(o.Validate(), InvalidOptions);
  o = RenderOptions();
  o.far = o.near;
  EXPECT_THROW(o.Validate(), InvalidOptions);
  o = RenderOptions();
  o.resolution = 0;
  EXPECT_THROW(o.Validate(), InvalidOptions);
}

}  // namespace
}  // namespace avatar::render
