// Inference-only skips of the renderer (issue 13, "render only what the frame needs"): early
// ray termination, rays that miss the tri-plane box, empty-space skipping through the occupancy
// grid (occupancy_grid.h), depth and alpha only when asked. Each skip
// is checked against the full render of the same field (mean abs change of the features <= 1e-3),
// on a small random field and on the bundled model; the speed-up is measured as a ratio in the
// same run and printed (never asserted). The work saved is asserted through the point count.

#include <gtest/gtest.h>
#include <torch/torch.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/io/data_paths.h"
#include "core/model/goha_model.h"
#include "core/model/model_config.h"
#include "core/render/camera.h"
#include "core/util/error.h"
#include "core/util/timer.h"
#include "render/render_test_util.h"

namespace avatar::render {
namespace {

using testing::ExpectValidOutputs;

// A random tri-plane field with an opaque core: random planes and a randomly initialised
// decoder; inside |p| < 0.3 the raw density is raised by 20 (rays through the core become opaque),
// (radius `core_radius`), elsewhere in the box lowered by 4 (light fog), and outside the box the field is empty (the
// assumption behind skipping missed rays).
struct RandomScene {
  torch::Tensor planes;
  TriplaneDecoder decoder;
  Field field;
  std::shared_ptr<RenderProfile> counter = std::make_shared<RenderProfile>();  // field evaluations
};

RandomScene MakeRandomScene(int64_t batch = 1, torch::ScalarType dtype = torch::kFloat32, double core_radius = 0.3) {
  torch::manual_seed(5);
  RandomScene s;
  s.planes = torch::randn({batch, 3, kDecoderInputChannels, 32, 32}, dtype) * 0.5;
  s.decoder = TriplaneDecoder();
  s.decoder->to(dtype);
  TriplaneDecoder decoder = s.decoder;
  const Field base = MakeTriplaneField(
      s.planes, [decoder](const torch::Tensor& f) mutable { return decoder->forward(f); }, 1.0, s.counter.get());
  s.field = [base, core_radius](const torch::Tensor& points) {
    FieldSamples out = base(points);
    const torch::Tensor inside_box = (points.abs() <= 0.5).all(2);
    const torch::Tensor core = points.norm(2, 2) < core_radius;
    const torch::Tensor raw = out.raw_density + core.to(out.raw_density.scalar_type()) * 24.0 - 4.0;
    out.raw_density = torch::where(inside_box, raw, torch::full_like(raw, -30.0));
    return out;
  };
  return s;
}

// Frontal cameras with the focal length scaled by `zoom` (< 1 widens the view).
Cameras WideCameras(double zoom) {
  Cameras cams = FrontalCameras(1);
  cams.intrinsics = cams.intrinsics.clone();
  cams.intrinsics.select(1, 0).select(1, 0).mul_(zoom);
  cams.intrinsics.select(1, 1).select(1, 1).mul_(zoom);
  return cams;
}

struct Timed {
  RenderOutput out;
  double seconds = 0.0;
  int64_t points = 0;
};

// Best of `repeats` renders (wall clock) and the field evaluations of one, counted in the
// profile passed to the render or, for a field with its own counter, in `counter`.
template <typename F>
Timed TimeRender(F&& render, RenderProfile* counter = nullptr, int repeats = 2) {
  Timed t;
  t.seconds = 1e30;
  for (int i = 0; i < repeats; ++i) {
    RenderProfile profile;
    if (counter != nullptr) counter->points = 0;
    Timer timer;
    t.out = render(&profile);
    t.seconds = std::min(t.seconds, timer.Seconds());
    t.points = counter != nullptr ? counter->points.load() : profile.points.load();
  }
  return t;
}

double MeanAbs(const torch::Tensor& a, const torch::Tensor& b) { return (a - b).abs().mean().item<double>(); }

void Report(const std::string& what, const Timed& full, const Timed& skipped) {
  const double change = MeanAbs(full.out.features, skipped.out.features);
  std::cout << "[skip] " << what << ": mean abs change " << change << ", max "
            << (full.out.features - skipped.out.features).abs().max().item<double>() << ", points " << skipped.points
            << " / " << full.points << " ("
            << static_cast<double>(skipped.points) / static_cast<double>(std::max<int64_t>(full.points, 1))
            << "), time " << skipped.seconds << " s / " << full.seconds << " s, speed-up "
            << full.seconds / std::max(skipped.seconds, 1e-9) << "x" << std::endl;
}

RenderOptions Options(int resolution) {
  RenderOptions o;
  o.resolution = resolution;
  return o;
}

TEST(RenderSkips, OffByDefault) {
  const RenderOptions o;
  EXPECT_FALSE(o.early_termination);
  EXPECT_FALSE(o.skip_missed_rays);
  EXPECT_FALSE(o.skip_empty_space);
  EXPECT_EQ(o.occupancy, nullptr);
  EXPECT_TRUE(o.return_depth);
  EXPECT_TRUE(o.return_opacity);
  RenderOptions bad;
  bad.termination_transmittance = 1.0;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  bad = RenderOptions();
  bad.termination_block = 0;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  bad = RenderOptions();
  bad.miss_margin = -0.1;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  GohaModel model(ModelConfig::Tiny());
  EXPECT_FALSE(model->inference_skips);
}

// With grad mode on (training) the skips do nothing: bit-identical outputs and gradients.
TEST(RenderSkips, GradModeRendersAreUnchanged) {
  torch::manual_seed(3);
  TriplaneDecoder decoder;
  const PointDecoder decode = [decoder](const torch::Tensor& f) mutable { return decoder->forward(f); };
  const torch::Tensor init = torch::randn({1, 3, kDecoderInputChannels, 16, 16}) * 2.0;
  RenderOptions plain = Options(8);
  plain.num_coarse = 12;
  plain.num_importance = 12;
  RenderOptions skipping = plain;
  skipping.EnableInferenceSkips();
  skipping.occupancy = BuildOccupancyGrid(init, DecoderDensityMlp(decoder), plain.box_warp);
  const Cameras cams = WideCameras(0.3);
  torch::Tensor grads[2];
  torch::Tensor rgb[2];
  for (int i = 0; i < 2; ++i) {
    torch::Tensor planes = init.clone().requires_grad_(true);
    const RenderOutput out = RenderTriplanes(planes, decode, cams, i == 0 ? plain : skipping);
    out.rgb.sum().backward();
    grads[i] = planes.grad();
    rgb[i] = out.rgb.detach();
  }
  EXPECT_TRUE(torch::equal(rgb[0], rgb[1]));
  EXPECT_TRUE(torch::equal(grads[0], grads[1]));
  // The model flag leaves training renders alone too.
  GohaModel model(ModelConfig::Tiny());
  torch::manual_seed(4);
  const torch::Tensor planes = torch::randn({1, 3, model->config().plane_channels, 32, 32});
  const torch::Tensor before = model->Render(planes, FrontalCameras(1)).rgb.detach();
  model->inference_skips = true;
  EXPECT_TRUE(torch::equal(before, model->Render(planes, FrontalCameras(1)).rgb.detach()));
}

TEST(RenderSkips, EarlyTerminationRandomField) {
  torch::NoGradGuard no_grad;
  const RandomScene scene = MakeRandomScene();
  const RenderOptions full = Options(48);
  RenderOptions ert = full;
  ert.early_termination = true;
  const Cameras cams = FrontalCameras(1);
  const Timed a = TimeRender([&](RenderProfile* p) { return RenderField(scene.field, cams, full, c10::nullopt, p); },
                             scene.counter.get());
  const Timed b = TimeRender([&](RenderProfile* p) { return RenderField(scene.field, cams, ert, c10::nullopt, p); },
                             scene.counter.get());
  Report("early termination, random field 48^2", a, b);
  ExpectValidOutputs(b.out, ert, "early termination");
  // The core makes rays opaque, so samples are saved.
  ASSERT_GT(a.out.opacity.max().item<double>(), 0.999);
  EXPECT_LT(b.points, a.points * 9 / 10);
  EXPECT_LE(MeanAbs(a.out.features, b.out.features), 1e-3);
  EXPECT_LE(MeanAbs(a.out.opacity, b.out.opacity), 1e-3);
  // Per ray the colour lost is bounded by the transmittance left (x2 for the [-1,1] mapping,
  // with slack for the importance samples moving once the skipped coarse samples read empty).
  EXPECT_LE((a.out.features - b.out.features).abs().max().item<double>(), 0.05);
  // A head-sized core that fills the view: rays turn opaque within the first coarse block.
  const RandomScene head = MakeRandomScene(1, torch::kFloat32, 0.45);
  const Timed c = TimeRender([&](RenderProfile* p) { return RenderField(head.field, cams, full, c10::nullopt, p); },
                             head.counter.get());
  const Timed d = TimeRender([&](RenderProfile* p) { return RenderField(head.field, cams, ert, c10::nullopt, p); },
                             head.counter.get());
  Report("early termination, random field with a view-filling core 48^2", c, d);
  EXPECT_LT(d.points, c.points * 4 / 5);
  EXPECT_LE(MeanAbs(c.out.features, d.out.features), 1e-3);
}

TEST(RenderSkips, MissedRaysRandomField) {
  torch::NoGradGuard no_grad;
  const RandomScene scene = MakeRandomScene();
  const RenderOptions full = Options(48);
  RenderOptions miss = full;
  miss.skip_missed_rays = true;
  const Cameras cams = WideCameras(0.25);  // the box covers the middle of the image only
  const Timed a = TimeRender([&](RenderProfile* p) { return RenderField(scene.field, cams, full, c10::nullopt, p); },
                             scene.counter.get());
  const Timed b = TimeRender([&](RenderProfile* p) { return RenderField(scene.field, cams, miss, c10::nullopt, p); },
                             scene.counter.get());
  Report("missed rays, random field 48^2, focal x0.25", a, b);
  ExpectValidOutputs(b.out, miss, "missed rays");
  EXPECT_LT(b.points, a.points * 3 / 4);
  EXPECT_LE(MeanAbs(a.out.features, b.out.features), 1e-3);
  EXPECT_LE(MeanAbs(a.out.depth, b.out.depth), 1e-3);
  // The corner pixel misses the box: exact background.
  EXPECT_EQ(b.out.opacity[0][0][0][0].item<double>(), 0.0);
  EXPECT_NEAR(b.out.depth[0][0][0][0].item<double>(), full.far, 1e-6);
  EXPECT_EQ(b.out.features[0][0][0][0].item<double>(), -1.0);
  // Both skips together, and a camera whose every ray misses.
  RenderOptions both = miss;
  both.early_termination = true;
  const Timed c = TimeRender([&](RenderProfile* p) { return RenderField(scene.field, cams, both, c10::nullopt, p); },
                             scene.counter.get());
  Report("both skips, random field 48^2, focal x0.25", a, c);
  EXPECT_LE(MeanAbs(a.out.features, c.out.features), 1e-3);
  Cameras away = FrontalCameras(1);
  away.cam2world =
      LookAtCam2World(torch::tensor({{0.0f, 0.0f, 2.7f}}), torch::tensor({{0.0f, 0.0f, 5.0f}}), torch::zeros({1}));
  const RenderOutput none = RenderField(scene.field, away, both);
  EXPECT_EQ(none.opacity.max().item<double>(), 0.0);
  EXPECT_EQ(none.features.max().item<double>(), -1.0);
}

// A batch of two cameras (one wide, one frontal) with both skips, uneven chunks, float64 and
// the random field: each image matches its full render; missed rays of one camera are
// background even where the other camera's rays of the same index are marched.
TEST(RenderSkips, BatchedCamerasBothSkips) {
  torch::NoGradGuard no_grad;
  const RandomScene scene = MakeRandomScene(2, torch::kFloat64);
  Cameras cams = WideCameras(0.25);
  cams.cam2world = torch::cat({cams.cam2world, FrontalCameras(1).cam2world}, 0).to(torch::kFloat64);
  cams.intrinsics = torch::cat({cams.intrinsics, FrontalCameras(1).intrinsics}, 0).to(torch::kFloat64);
  RenderOptions full = Options(20);
  full.chunk_rays = 37;
  RenderOptions both = full;
  both.EnableInferenceSkips();
  scene.counter->points = 0;
  const RenderOutput a = RenderField(scene.field, cams, full);
  const int64_t points_full = scene.counter->points.exchange(0);
  const RenderOutput b = RenderField(scene.field, cams, both);
  const int64_t points_skipped = scene.counter->points.load();
  ExpectValidOutputs(b, both, "batched");
  std::cout << "[skip] batched cameras: points " << points_skipped << " / " << points_full << std::endl;
  EXPECT_LT(points_skipped, points_full);
  for (int64_t i = 0; i < 2; ++i) {
    SCOPED_TRACE(i);
    // Opaque or missed rays dominate; the change stays within the bound.
    EXPECT_LE(MeanAbs(a.features[i], b.features[i]), 1e-3);
    EXPECT_LE(MeanAbs(a.opacity[i], b.opacity[i]), 1e-3);
  }
  // The wide camera's corner ray misses the box; the frontal camera's centre ray meets the core.
  EXPECT_EQ(b.opacity[0][0][0][0].item<double>(), 0.0);
  EXPECT_GT(b.opacity[1][0][10][10].item<double>(), 0.999);
}

TEST(RenderSkips, DepthAndAlphaOnlyWhenAsked) {
  torch::NoGradGuard no_grad;
  const RandomScene scene = MakeRandomScene();
  const RenderOptions full = Options(48);
  RenderOptions lean = full;
  lean.return_depth = false;
  lean.return_opacity = false;
  const Cameras cams = FrontalCameras(1);
  const Timed a = TimeRender([&](RenderProfile* p) { return RenderField(scene.field, cams, full, c10::nullopt, p); },
                             scene.counter.get());
  const Timed b = TimeRender([&](RenderProfile* p) { return RenderField(scene.field, cams, lean, c10::nullopt, p); },
                             scene.counter.get());
  Report("no depth/alpha, random field 48^2", a, b);
  EXPECT_FALSE(b.out.depth.defined());
  EXPECT_FALSE(b.out.opacity.defined());
  ASSERT_TRUE(a.out.depth.defined() && a.out.opacity.defined());
  EXPECT_TRUE(torch::equal(a.out.features, b.out.features));
  // In grad mode too (the dense path).
  torch::AutoGradMode grad(true);
  const RenderOutput g = RenderField(scene.field, cams, lean);
  EXPECT_FALSE(g.depth.defined());
  EXPECT_TRUE(g.rgb.defined());
}

// A head-like tri-plane field for the occupancy grid: a decoder whose density rises with plane
// channel 0 (positive first-layer weights on it, a positive density row) shifted by
// `density_offset` (-20: empty where the planes hold only their noise), and planes of noise with
// a Gaussian bump of channel 0 in the middle of each plane (an ellipsoidal opaque core). `grid` is
// the occupancy grid of the planes under the decoder (default options).
struct BlobScene {
  torch::Tensor planes;
  TriplaneDecoder decoder;
  std::shared_ptr<RenderProfile> counter = std::make_shared<RenderProfile>();  // field evaluations
  Field field;
  std::shared_ptr<const OccupancyGrid> grid;
};

BlobScene MakeBlobScene(double density_offset = -20.0, int64_t batch = 1, int64_t size = 64) {
  torch::manual_seed(11);
  BlobScene s;
  const int64_t c = kDecoderInputChannels, h = kDecoderHiddenChannels, f = kDecoderFeatureChannels;
  torch::Tensor w1 = torch::randn({h, c}) / std::sqrt(static_cast<double>(c));
  w1.select(1, 0).copy_(w1.select(1, 0).abs() * 2.0 + 0.5);
  torch::Tensor w2 = torch::randn({1 + f, h}) / std::sqrt(static_cast<double>(h));
  w2[0].abs_();
  torch::Tensor b2 = torch::zeros({1 + f});
  b2[0] = density_offset;
  s.decoder = TriplaneDecoder();
  s.decoder->SetEffectiveWeights(w1, torch::zeros({h}), w2, b2);
  const torch::Tensor centres = (torch::arange(size).to(torch::kFloat32) + 0.5) * (2.0 / static_cast<double>(size)) - 1.0;
  const torch::Tensor r2 = centres.view({-1, 1}).pow(2) + centres.view({1, -1}).pow(2);
  s.planes = torch::randn({batch, 3, c, size, size}) * 0.3;
  s.planes.select(2, 0).add_(10.0 * torch::exp(-r2 / (2.0 * 0.2 * 0.2)));
  TriplaneDecoder decoder = s.decoder;
  s.field = MakeTriplaneField(
      s.planes, [decoder](const torch::Tensor& x) mutable { return decoder->forward(x); }, 1.0, s.counter.get());
  s.grid = BuildOccupancyGrid(s.planes, DecoderDensityMlp(s.decoder), 1.0);
  return s;
}

// Flat cell index [P] of points [1,P,3] inside the grid's cube.
torch::Tensor CellOf(const OccupancyGrid& grid, const torch::Tensor& points) {
  const int64_t g = grid.resolution();
  const torch::Tensor idx = ((points[0] + grid.half()) / grid.cell()).floor().clamp(0, g - 1).to(torch::kLong);
  return (idx.select(1, 0) * g + idx.select(1, 1)) * g + idx.select(1, 2);
}

TEST(OccupancyGrid, OptionsAndThreshold) {
  OccupancyGridOptions bad;
  bad.resolution = 1;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  bad = OccupancyGridOptions();
  bad.extent = 0.0;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  bad = OccupancyGridOptions();
  bad.sigma_threshold = 0.0;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  const OccupancyGrid grid(torch::full({1, 4, 4, 4}, -30.0), 0.5, 1e-3);
  // The threshold in raw units is the renderer's density of 1e-3.
  EXPECT_NEAR(torch::softplus(torch::tensor(grid.raw_threshold() - 1.0)).item<double>(), 1e-3, 1e-9);
  EXPECT_EQ(grid.EmptyFraction(), 1.0);
  // Planes that do not match the MLP are refused.
  DensityMlp mlp = DecoderDensityMlp(TriplaneDecoder());
  EXPECT_THROW(BuildOccupancyGrid(torch::zeros({1, 3, 16, 8, 8}), mlp, 1.0), InvalidInput);
  EXPECT_THROW(BuildOccupancyGrid(torch::zeros({1, 2, 32, 8, 8}), mlp, 1.0), InvalidInput);
}

// Growing the occupied cells and the lookup of points: one occupied cell in an 8^3 grid.
TEST(OccupancyGrid, DilationAndLookup) {
  torch::Tensor max_raw = torch::full({1, 8, 8, 8}, -30.0);
  max_raw[0][4][4][2] = 5.0;
  const OccupancyGrid grid(max_raw, 0.5, 1e-3);
  EXPECT_NEAR(grid.EmptyFraction(), 511.0 / 512.0, 1e-12);
  EXPECT_EQ(grid.Dilated(0).sum().item<int64_t>(), 1);
  const torch::Tensor d1 = grid.Dilated(1).view({8, 8, 8});
  const torch::Tensor i = torch::arange(8);
  const auto near = [&](int64_t centre) { return (i - centre).abs() <= 1; };
  const auto face = (i == 0) | (i == 7);
  const torch::Tensor block = near(4).view({8, 1, 1}) & near(4).view({1, 8, 1}) & near(2).view({1, 1, 8});
  const torch::Tensor faces = face.view({8, 1, 1}) | face.view({1, 8, 1}) | face.view({1, 1, 8});
  EXPECT_TRUE(torch::equal(d1, block | faces));
  // Computed once and kept: a later call hands out the same mask (same storage), not a new one.
  EXPECT_EQ(grid.Dilated(1).data_ptr(), d1.data_ptr());
  EXPECT_FALSE(grid.AllOccupied(1));
  EXPECT_TRUE(grid.AllOccupied(4));  // the faces' layer alone covers an 8^3 grid at dilation 4
  // Cell centres: -0.5 + (i + 0.5) / 8.
  const auto centre = [](int64_t x, int64_t y, int64_t z) {
    return std::vector<float>{static_cast<float>(-0.5 + (x + 0.5) / 8.0), static_cast<float>(-0.5 + (y + 0.5) / 8.0),
                              static_cast<float>(-0.5 + (z + 0.5) / 8.0)};
  };
  std::vector<float> flat;
  for (const auto& p : {centre(4, 4, 2), centre(5, 5, 3), centre(2, 2, 5), centre(6, 6, 4)}) {
    flat.insert(flat.end(), p.begin(), p.end());
  }
  flat.insert(flat.end(), {0.7f, 0.0f, 0.0f});  // outside the cube
  const torch::Tensor points = torch::tensor(flat).view({1, 5, 3});
  const torch::Tensor at0 = grid.MayBeOccupied(points, 0)[0];
  const torch::Tensor at1 = grid.MayBeOccupied(points, 1)[0];
  const torch::Tensor at2 = grid.MayBeOccupied(points, 2)[0];
  EXPECT_TRUE(torch::equal(at0, torch::tensor({true, false, false, false, true})));
  EXPECT_TRUE(torch::equal(at1, torch::tensor({true, true, false, false, true})));
  // At dilation 2, (6,6,4) is two cells from the occupied cell and in the faces' layer.
  EXPECT_TRUE(torch::equal(at2, torch::tensor({true, true, false, true, true})));
  EXPECT_THROW(grid.MayBeOccupied(torch::zeros({2, 1, 3}), 0), InvalidInput);
}

// The property behind the skip: wherever a point lies in the cube, the field's raw density is at
// most its cell's bound, so points in cells marked empty have a density below the threshold.
TEST(OccupancyGrid, EmptyCellsHaveNoDensityAtSampledPoints) {
  torch::NoGradGuard no_grad;
  const BlobScene scene = MakeBlobScene();
  const OccupancyGrid& grid = *scene.grid;
  const int64_t g = grid.resolution();
  const double empty = grid.EmptyFraction();
  std::cout << "[skip] blob field occupancy grid " << g << "^3: empty fraction " << empty << std::endl;
  ASSERT_GT(empty, 0.3);
  ASSERT_LT(empty, 0.99);
  const torch::Tensor bounds = grid.max_raw().view({-1});
  const torch::Tensor occupied = grid.occupied().view({-1});
  torch::manual_seed(12);
  // (1) Uniform points over the whole cube.
  const torch::Tensor uniform = (torch::rand({1, 200000, 3}) * 2.0 - 1.0) * grid.half();
  // (2) Points in cells marked empty: 4 uniform points in each of up to 20000 random empty cells.
  const torch::Tensor empty_cells = torch::logical_not(occupied).nonzero().view({-1});
  const torch::Tensor pick =
      empty_cells.index_select(0, torch::randperm(empty_cells.numel()).narrow(0, 0, std::min<int64_t>(20000, empty_cells.numel())));
  const torch::Tensor cell_xyz =
      torch::stack({torch::div(pick, g * g, "floor"), torch::div(pick, g, "floor").remainder(g), pick.remainder(g)}, 1)
          .to(torch::kFloat32);  // [K,3]
  const torch::Tensor in_cells =
      ((cell_xyz.unsqueeze(1) + torch::rand({pick.numel(), 4, 3})) * grid.cell() - grid.half()).reshape({1, -1, 3});
  for (const auto& [what, points] : {std::make_pair("uniform", uniform), std::make_pair("in empty cells", in_cells)}) {
    SCOPED_TRACE(what);
    const torch::Tensor raw = scene.field(points).raw_density[0];
    const torch::Tensor cell = CellOf(grid, points);
    const torch::Tensor bound = bounds.index_select(0, cell);
    const double worst = (raw - bound).max().item<double>();
    const torch::Tensor in_empty = torch::logical_not(occupied.index_select(0, cell));
    ASSERT_GT(in_empty.sum().item<int64_t>(), 1000);
    const double sigma_max = torch::softplus(raw.masked_select(in_empty) - 1.0).max().item<double>();
    std::cout << "[skip]   " << what << ": " << points.size(1) << " points, max (raw - bound) " << worst
              << ", max density in empty cells " << sigma_max << " (threshold " << grid.sigma_threshold()
              << "), mean bound slack where computed "
              << (bound - raw).masked_select(torch::isfinite(bound)).mean().item<double>() << std::endl;
    EXPECT_LE(worst, 0.0);
    EXPECT_LT(sigma_max, grid.sigma_threshold());
  }
}

TEST(RenderSkips, EmptySpaceBlobField) {
  torch::NoGradGuard no_grad;
  const BlobScene scene = MakeBlobScene();
  const RenderOptions full = Options(48);
  RenderOptions empty = full;
  empty.skip_empty_space = true;
  empty.occupancy = scene.grid;
  const Cameras cams = FrontalCameras(1);
  const Timed a = TimeRender([&](RenderProfile* p) { return RenderField(scene.field, cams, full, c10::nullopt, p); },
                             scene.counter.get());
  const Timed b = TimeRender([&](RenderProfile* p) { return RenderField(scene.field, cams, empty, c10::nullopt, p); },
                             scene.counter.get());
  Report("empty space, blob field 48^2", a, b);
  ExpectValidOutputs(b.out, empty, "empty space");
  ASSERT_GT(a.out.opacity.max().item<double>(), 0.99);  // an opaque core
  ASSERT_LT(a.out.opacity.min().item<double>(), 1e-3);  // and empty corners
  EXPECT_LT(b.points, a.points * 3 / 4);
  EXPECT_LE(MeanAbs(a.out.features, b.out.features), 1e-3);
  EXPECT_LE(MeanAbs(a.out.opacity, b.out.opacity), 1e-3);
  // Per ray at most sigma_threshold x (far - near) of optical depth is lost.
  EXPECT_LE((a.out.opacity - b.out.opacity).abs().max().item<double>(), 1.1e-3);
  EXPECT_LE((a.out.features - b.out.features).abs().max().item<double>(), 1e-2);
  const torch::Tensor solid = a.out.opacity > 0.5;
  EXPECT_LE((a.out.depth - b.out.depth).abs().masked_select(solid).max().item<double>(), 1e-3);
  // Every skip together.
  RenderOptions all = empty;
  all.EnableInferenceSkips();
  const Timed c = TimeRender([&](RenderProfile* p) { return RenderField(scene.field, cams, all, c10::nullopt, p); },
                             scene.counter.get());
  Report("all skips, blob field 48^2", a, c);
  ExpectValidOutputs(c.out, all, "all skips");
  EXPECT_LE(c.points, b.points);
  EXPECT_LE(MeanAbs(a.out.features, c.out.features), 1e-3);
}

TEST(RenderSkips, EmptySpaceEdgeCases) {
  torch::NoGradGuard no_grad;
  const RenderOptions full = Options(24);
  const Cameras front = FrontalCameras(1);
  const auto with_grid = [&](const BlobScene& scene) {
    RenderOptions o = full;
    o.skip_empty_space = true;
    o.occupancy = scene.grid;
    return o;
  };
  {
    SCOPED_TRACE("dense everywhere: nothing empty, nothing skipped");
    const BlobScene dense = MakeBlobScene(5.0);
    EXPECT_EQ(dense.grid->EmptyFraction(), 0.0);
    dense.counter->points = 0;
    const RenderOutput a = RenderField(dense.field, front, full);
    const int64_t points_full = dense.counter->points.exchange(0);
    const RenderOutput b = RenderField(dense.field, front, with_grid(dense));
    EXPECT_EQ(dense.counter->points.load(), points_full);
    EXPECT_LE((a.features - b.features).abs().max().item<double>(), 1e-5);
  }
  {
    SCOPED_TRACE("empty everywhere: every sample skipped");
    const BlobScene vacuum = MakeBlobScene(-100.0);
    EXPECT_EQ(vacuum.grid->EmptyFraction(), 1.0);
    vacuum.counter->points = 0;
    const RenderOutput a = RenderField(vacuum.field, front, full);
    const int64_t points_full = vacuum.counter->points.exchange(0);
    const RenderOptions o = with_grid(vacuum);
    const RenderOutput b = RenderField(vacuum.field, front, o);
    ExpectValidOutputs(b, o, "vacuum");
    EXPECT_LT(vacuum.counter->points.load(), points_full / 100);
    // Skipped samples read as raw density -30 (softplus(-31) ~ 3e-14 per world unit).
    EXPECT_LT(b.opacity.max().item<double>(), 1e-12);
    EXPECT_NEAR(b.features.max().item<double>(), -1.0, 1e-12);
    EXPECT_LE(MeanAbs(a.features, b.features), 1e-3);
  }
  {
    // The grid alone: the blob field is not empty outside the box (the planes' projections reach
    // far along the axes), so skipping missed rays would drop it at the far camera.
    SCOPED_TRACE("extreme poses");
    const BlobScene scene = MakeBlobScene();
    const RenderOptions o = with_grid(scene);
    struct Pose {
      const char* name;
      double yaw, pitch, roll, radius;
    };
    for (const Pose& p : {Pose{"behind", 180, 0, 0, 2.7}, Pose{"above", 0, 89, 0, 2.7}, Pose{"below", 0, -89, 0, 2.7},
                          Pose{"turned and rolled", 135, 40, 170, 2.7}, Pose{"close, inside the range", 30, 10, 0, 2.3},
                          Pose{"far away", 0, 0, 0, 20.0}}) {
      SCOPED_TRACE(p.name);
      const Cameras cams{testing::LookAtOrbit(p.yaw, p.pitch, p.roll, p.radius).unsqueeze(0),
                         DefaultIntrinsics().unsqueeze(0)};
      const RenderOutput a = RenderField(scene.field, cams, full);
      const RenderOutput b = RenderField(scene.field, cams, o);
      ExpectValidOutputs(b, o, p.name);
      EXPECT_LE(MeanAbs(a.features, b.features), 1e-3);
      EXPECT_LE(MeanAbs(a.opacity, b.opacity), 1e-3);
    }
  }
  {
    SCOPED_TRACE("a batch of two plane sets; a grid of the wrong batch is refused");
    const BlobScene pair = MakeBlobScene(-20.0, 2);
    EXPECT_EQ(pair.grid->batch(), 2);
    const Cameras cams = FrontalCameras(2);
    const RenderOutput a = RenderField(pair.field, cams, full);
    const RenderOutput b = RenderField(pair.field, cams, with_grid(pair));
    for (int64_t i = 0; i < 2; ++i) EXPECT_LE(MeanAbs(a.features[i], b.features[i]), 1e-3);
    const BlobScene single = MakeBlobScene();
    EXPECT_THROW(RenderField(pair.field, cams, with_grid(single)), InvalidInput);
  }
}

// The bundled model: planes predicted from a synthetic portrait-like image, frontal and orbit views.
TEST(RenderSkips, BundledModel) {
  const std::filesystem::path path = std::filesystem::path(AVATAR_SOURCE_DIR) / "resources/models/goha-default.ckpt";
  if (!std::filesystem::exists(path)) FAIL() << "bundled model not found (it is part of the repository): " << path;
  torch::InferenceMode inference;
  Timer load_timer;
  LoadedModel loaded = LoadModelCheckpoint(path);
  GohaModel model = loaded.model;
  model->eval();
  const ModelConfig& c = model->config();
  // The bundled default portrait (centre square, resized), else a smooth synthetic image.
  torch::Tensor image;
  std::string input = "synthetic ellipse";
  const std::filesystem::path photo = DataPaths::Resolve().Path(DataPaths::kDefaultPortrait);
  if (std::filesystem::exists(photo)) {
    cv::Mat bgr = cv::imread(photo.string(), cv::IMREAD_COLOR);
    ASSERT_FALSE(bgr.empty()) << photo;
    const int side = std::min(bgr.rows, bgr.cols);
    cv::Mat square = bgr(cv::Rect((bgr.cols - side) / 2, (bgr.rows - side) / 2, side, side)).clone();
    cv::Mat resized, rgb;
    cv::resize(square, resized, cv::Size(c.image_size, c.image_size), 0, 0, cv::INTER_AREA);
    cv::cvtColor(resized, rgb, cv::COLOR_BGR2RGB);
    image = torch::from_blob(rgb.data, {1, c.image_size, c.image_size, 3}, torch::kUInt8)
                .permute({0, 3, 1, 2})
                .to(torch::kFloat32)
                .div(127.5)
                .sub(1.0)
                .contiguous();
    input = photo.filename().string();
  } else {
    const torch::Tensor ys = torch::linspace(-1.0, 1.0, c.image_size).view({-1, 1});
    const torch::Tensor xs = torch::linspace(-1.0, 1.0, c.image_size).view({1, -1});
    const torch::Tensor blob = (1.0 - (xs * xs / 0.36 + ys * ys / 0.5)).clamp(0.0, 1.0);
    image = torch::stack({blob * 0.9 - 0.3 + xs * 0.1, blob * 0.6 - 0.5 + ys * 0.1, blob * 0.4 - 0.6}, 0)
                .unsqueeze(0)
                .clamp(-1.0, 1.0);
  }
  const torch::Tensor planes = model->CanonicalPlanes(image);
  std::cout << "[skip] bundled model " << c.name << " on " << input << ": load + planes " << load_timer.Seconds()
            << " s, render " << c.render_size << "^2, " << c.num_coarse << " + " << c.num_importance << " samples"
            << std::endl;
  // The grid is built once per planes (as the session does) and passed in.
  Timer grid_timer;
  const auto grid = model->OccupancyGridFor(planes);
  std::cout << "[skip] bundled model occupancy grid " << grid->resolution() << "^3: built in " << grid_timer.Seconds()
            << " s, empty fraction " << grid->EmptyFraction() << ", raw bound min "
            << grid->max_raw().min().item<double>() << " (threshold " << grid->raw_threshold() << ")" << std::endl;
  // The model flag builds a grid itself when none is given: the same image.
  model->inference_skips = true;
  const RenderOutput flagged = model->Render(planes, FrontalCameras(1));
  model->inference_skips = false;
  EXPECT_LE(MeanAbs(flagged.features, model->Render(planes, FrontalCameras(1)).features), 1e-3);
  for (double yaw : {0.0, 30.0}) {
    ViewPose pose;
    pose.yaw = yaw;
    const Cameras cams{OrbitCam2World(pose).unsqueeze(0), DefaultIntrinsics().unsqueeze(0)};
    const auto render_with = [&](bool skips) {
      return TimeRender([&](RenderProfile* p) {
        RenderOptions o = model->RenderOptionsFor();
        if (skips) {
          o.EnableInferenceSkips();
          o.occupancy = grid;
        }
        return model->RenderWith(planes, cams, o, p);
      });
    };
    const Timed a = render_with(false);
    const Timed b = render_with(true);
    Report("bundled model, all skips, yaw " + std::to_string(static_cast<int>(yaw)), a, b);
    std::cout << "[skip]   full render opacity max " << a.out.opacity.max().item<double>() << ", mean "
              << a.out.opacity.mean().item<double>() << std::endl;
    ExpectValidOutputs(b.out, model->RenderOptionsFor(), "bundled");
    EXPECT_LE(b.points, a.points);
    EXPECT_LE(MeanAbs(a.out.features, b.out.features), 1e-3);
    EXPECT_LE(MeanAbs(a.out.rgb, b.out.rgb), 1e-3);
  }
  // Missed rays on the bundled model need a wider view than the app's (the box fills the app's
  // image, so there the skip changes nothing and saves nothing, as measured above). This model
  // is not empty outside the box: a wide view shows its fog there, which the skip drops (the
  // documented exception, printed). Rays that meet the box render as before.
  RenderOptions full = model->RenderOptionsFor();
  RenderOptions miss = full;
  miss.skip_missed_rays = true;
  const Cameras wide = WideCameras(0.3);
  const PointDecoder decode = [&](const torch::Tensor& f) { return model->decoder->forward(f); };
  const Timed a =
      TimeRender([&](RenderProfile* p) { return RenderTriplanes(planes, decode, wide, full, c10::nullopt, p); });
  const Timed b =
      TimeRender([&](RenderProfile* p) { return RenderTriplanes(planes, decode, wide, miss, c10::nullopt, p); });
  Report("bundled model, missed rays, focal x0.3", a, b);
  // Brute-force hit test: 512 points along each segment [near, far] against the grown box.
  const Rays rays = GenerateRays(wide, full.resolution);
  const torch::Tensor t = torch::linspace(full.near, full.far, 512).view({1, 1, -1, 1});
  const torch::Tensor pts = rays.origins.unsqueeze(2) + t * rays.directions.unsqueeze(2);  // [1,N,512,3]
  const torch::Tensor hit = (pts.abs() <= full.box_warp * (0.5 + miss.miss_margin))
                                .all(3)
                                .any(2)
                                .view({1, 1, full.resolution, full.resolution});
  const double hit_fraction = hit.to(torch::kFloat32).mean().item<double>();
  ASSERT_GT(hit_fraction, 0.1);
  ASSERT_LT(hit_fraction, 0.9);
  EXPECT_LT(b.points, a.points);
  const torch::Tensor diff = (a.out.features - b.out.features).abs();
  const double hit_change = (diff * hit).sum().item<double>() / (hit.sum().item<double>() * diff.size(1));
  const double missed_opacity =
      (a.out.opacity * hit.logical_not()).sum().item<double>() / std::max(1.0, hit.logical_not().sum().item<double>());
  std::cout << "[skip]   rays meeting the box " << hit_fraction << ", their mean abs change " << hit_change
            << "; full render opacity on the missed rays (fog outside the box) " << missed_opacity << std::endl;
  EXPECT_LE(hit_change, 1e-5);
  EXPECT_EQ((b.out.opacity * hit.logical_not()).abs().max().item<double>(), 0.0);
}

}  // namespace
}  // namespace avatar::render
