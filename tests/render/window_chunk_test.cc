// Training-render support (issue 12): renders of pixel windows (RenderOptions::window_size) equal
// the crop of the whole render, and ray-chunked renders with gradients
// (RenderOptions::grad_chunk_rays) give the unchunked gradients; with jittered samples the
// backward pass uses the samples of its forward pass.

#include <ATen/CPUGeneratorImpl.h>
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <array>
#include <atomic>
#include <chrono>
#include <functional>
#include <iostream>
#include <memory>
#include <thread>
#include <vector>

#include "core/render/camera.h"
#include "core/render/rays.h"
#include "core/render/renderer.h"
#include "core/render/view_pose.h"
#include "core/util/error.h"

namespace avatar::render {
namespace {

const auto kF64 = torch::TensorOptions().dtype(torch::kFloat64);

// A small random scene in double: planes = 1.5 * base (base is the leaf, so a gradient has to
// pass through the planes' producer) and a two-layer decoder whose weights are leaves too.
struct Scene {
  torch::Tensor base, w1, b1, w2;
  torch::Tensor planes() const { return base * 1.5; }
  std::vector<torch::Tensor> parameters() const { return {w1, b1, w2}; }
  std::vector<torch::Tensor> leaves() const { return {base, w1, b1, w2}; }
  PointDecoder decoder() const {
    return [w1 = w1, b1 = b1, w2 = w2](const torch::Tensor& f) {
      const torch::Tensor out = torch::softplus(f.matmul(w1) + b1).matmul(w2);  // [B,P,1+3]
      return torch::cat({out.narrow(2, 0, 1) * 4.0, torch::sigmoid(out.narrow(2, 1, 3))}, 2);
    };
  }
};

Scene MakeScene(int64_t batch, uint64_t seed) {
  torch::manual_seed(seed);
  Scene s;
  s.base = torch::randn({batch, 3, 6, 10, 10}, kF64).requires_grad_(true);
  s.w1 = (torch::randn({6, 12}, kF64) * 0.6).requires_grad_(true);
  s.b1 = (torch::randn({12}, kF64) * 0.1).requires_grad_(true);
  s.w2 = (torch::randn({12, 4}, kF64) * 0.5).requires_grad_(true);
  return s;
}

// Two cameras: frontal, and 20 degrees to the side, 6 above.
Cameras TwoCameras() {
  ViewPose pose;
  pose.yaw = 20;
  pose.pitch = -6;
  return {torch::stack({FrontalCam2World(kF64), OrbitCam2World(pose, kF64)}),
          DefaultIntrinsics(kF64).unsqueeze(0).expand({2, 3, 3}).contiguous()};
}

RenderOptions SmallOptions() {
  RenderOptions o;
  o.resolution = 12;
  o.num_coarse = 8;
  o.num_importance = 8;
  return o;
}

torch::Tensor Crop(const torch::Tensor& images, const std::vector<std::array<int64_t, 2>>& corners, int64_t size) {
  std::vector<torch::Tensor> crops;
  for (size_t i = 0; i < corners.size(); ++i)
    crops.push_back(images[static_cast<int64_t>(i)].narrow(1, corners[i][0], size).narrow(2, corners[i][1], size));
  return torch::stack(crops);
}

TEST(RenderWindow, RaysArePixelsOfTheWholeImage) {
  const Cameras cams = TwoCameras();
  const int64_t res = 12, size = 5;
  const Rays whole = GenerateRays(cams, res);
  const torch::Tensor corners = torch::tensor({3, 7, 0, 2}, torch::kLong).view({2, 2});
  const Rays window = GenerateWindowRays(cams, res, corners, size);
  ASSERT_EQ(window.directions.sizes(), (std::vector<int64_t>{2, size * size, 3}));
  double worst = 0.0;
  for (int64_t b = 0; b < 2; ++b)
    for (int64_t i = 0; i < size; ++i)
      for (int64_t j = 0; j < size; ++j) {
        const int64_t row = corners[b][0].item<int64_t>() + i, col = corners[b][1].item<int64_t>() + j;
        const torch::Tensor d = whole.directions[b][row * res + col] - window.directions[b][i * size + j];
        const torch::Tensor o = whole.origins[b][row * res + col] - window.origins[b][i * size + j];
        worst = std::max({worst, d.abs().max().item<double>(), o.abs().max().item<double>()});
      }
  EXPECT_LE(worst, 1e-12) << "a window ray differs from the whole image's ray of its pixel";
  // Windows that leave the image, bad shapes and sizes are refused.
  EXPECT_THROW(GenerateWindowRays(cams, res, torch::tensor({8, 0, 0, 0}, torch::kLong).view({2, 2}), size),
               InvalidInput);
  EXPECT_THROW(GenerateWindowRays(cams, res, torch::tensor({-1, 0, 0, 0}, torch::kLong).view({2, 2}), size),
               InvalidInput);
  EXPECT_THROW(GenerateWindowRays(cams, res, torch::zeros({2, 2}), size), InvalidInput);
  EXPECT_THROW(GenerateWindowRays(cams, res, torch::zeros({1, 2}, torch::kLong), size), InvalidInput);
  EXPECT_THROW(GenerateWindowRays(cams, res, torch::zeros({2, 2}, torch::kLong), res + 1), InvalidInput);
}

TEST(RenderWindow, PatchRenderEqualsTheCropOfTheWholeRender) {
  const Scene s = MakeScene(2, 21);
  const Cameras cams = TwoCameras();
  const std::vector<std::array<int64_t, 2>> at = {{{4, 1}}, {{0, 5}}};
  const int64_t size = 7;
  for (const torch::ScalarType dtype : {torch::kFloat64, torch::kFloat32}) {
    const torch::Tensor planes = s.planes().detach().to(dtype);
    const Cameras c = {cams.cam2world.to(dtype), cams.intrinsics.to(dtype)};
    const auto decoder_float = [&](const torch::Tensor& f) { return s.decoder()(f.to(torch::kFloat64)).to(dtype); };
    for (const bool grad : {true, false}) {
      torch::AutoGradMode mode(grad);
      RenderOptions whole = SmallOptions();
      const RenderOutput full = RenderTriplanes(planes, decoder_float, c, whole);
      RenderOptions window = whole;
      window.window_size = static_cast<int>(size);
      window.window_corners = torch::tensor({at[0][0], at[0][1], at[1][0], at[1][1]}, torch::kLong).view({2, 2});
      const RenderOutput patch = RenderTriplanes(planes, decoder_float, c, window);
      ASSERT_EQ(patch.features.sizes(), (std::vector<int64_t>{2, 3, size, size}));
      ASSERT_EQ(patch.depth.sizes(), (std::vector<int64_t>{2, 1, size, size}));
      const double rgb = (patch.rgb - Crop(full.rgb, at, size)).abs().max().item<double>();
      const double depth = (patch.depth - Crop(full.depth, at, size)).abs().max().item<double>();
      const double opacity = (patch.opacity - Crop(full.opacity, at, size)).abs().max().item<double>();
      std::cout << (dtype == torch::kFloat64 ? "double" : "float") << (grad ? ", grad mode" : ", no grad")
                << ": patch vs crop of the whole render: rgb " << rgb << ", depth " << depth << ", opacity " << opacity
                << "\n";
      EXPECT_LE(rgb, 1e-5);
      EXPECT_LE(depth, 1e-5);
      EXPECT_LE(opacity, 1e-5);
      EXPECT_GT(full.rgb.std().item<double>(), 0.01) << "a flat render would make the comparison empty";
    }
  }
  RenderOptions bad = SmallOptions();
  bad.window_size = 3;  // no corners
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  bad.window_size = 13;
  bad.window_corners = torch::zeros({2, 2}, torch::kLong);
  EXPECT_THROW(bad.Validate(), InvalidOptions);
}

// sum(rgb * weights) + mean(rgb^2) of a render and the gradients of the scene's leaves.
std::vector<torch::Tensor> LossGradients(const Scene& s, const Cameras& cams, RenderOptions o,
                                         c10::optional<at::Generator> generator = c10::nullopt,
                                         const std::function<void()>& between = {}) {
  o.grad_parameters = s.parameters();
  const RenderOutput r = RenderTriplanes(s.planes(), s.decoder(), cams, o, generator);
  const torch::Tensor w = torch::linspace(-1.0, 2.0, r.rgb.numel(), kF64).view(r.rgb.sizes());
  const torch::Tensor loss = (r.rgb * w).sum() + r.rgb.pow(2).mean();
  if (between) between();
  return torch::autograd::grad({loss}, s.leaves());
}

double WorstRelative(const std::vector<torch::Tensor>& a, const std::vector<torch::Tensor>& b) {
  double worst = 0.0;
  for (size_t i = 0; i < a.size(); ++i) {
    const double scale = std::max(1e-12, a[i].abs().max().item<double>());
    worst = std::max(worst, (a[i] - b[i]).abs().max().item<double>() / scale);
  }
  return worst;
}

TEST(RenderChunkedGrad, GradientsEqualTheUnchunkedOnesInDouble) {
  const Scene s = MakeScene(2, 22);
  const Cameras cams = TwoCameras();
  RenderOptions o = SmallOptions();
  const std::vector<torch::Tensor> plain = LossGradients(s, cams, o);
  for (const torch::Tensor& g : plain) ASSERT_GT(g.abs().sum().item<double>(), 0.0);
  for (const int chunk : {37, 64, 143}) {  // 144 rays per camera: uneven, even and one-ray-short chunks
    RenderOptions c = o;
    c.grad_chunk_rays = chunk;
    const double worst = WorstRelative(plain, LossGradients(s, cams, c));
    std::cout << "chunks of " << chunk << " rays: worst relative gradient difference " << worst << "\n";
    EXPECT_LE(worst, 1e-10) << "chunk " << chunk;
  }
  // A pixel window, chunked.
  RenderOptions w = o;
  w.window_size = 9;
  w.window_corners = torch::tensor({1, 2, 3, 0}, torch::kLong).view({2, 2});
  const std::vector<torch::Tensor> window_plain = LossGradients(s, cams, w);
  w.grad_chunk_rays = 20;
  const double worst = WorstRelative(window_plain, LossGradients(s, cams, w));
  std::cout << "9x9 windows in chunks of 20 rays: worst relative gradient difference " << worst << "\n";
  EXPECT_LE(worst, 1e-10);
  // Without grad_parameters the decoder's tensors get no gradient from a chunked render.
  RenderOptions unlisted = o;
  unlisted.grad_chunk_rays = 50;
  const RenderOutput r = RenderTriplanes(s.planes(), s.decoder(), cams, unlisted);
  const auto g = torch::autograd::grad({r.rgb.sum()}, {s.base, s.w1}, {}, false, false, /*allow_unused=*/true);
  EXPECT_TRUE(g[0].defined());
  EXPECT_FALSE(g[1].defined());
}

TEST(RenderChunkedGrad, JitteredBackwardUsesTheForwardSamples) {
  const Scene s = MakeScene(2, 23);
  const Cameras cams = TwoCameras();
  RenderOptions o = SmallOptions();
  o.deterministic = false;
  o.num_importance = 0;  // importance depths move with the planes: finite differences would see that
  o.grad_chunk_rays = 40;
  const auto seeded = [](uint64_t seed) {
    at::Generator g = at::make_generator<at::CPUGeneratorImpl>(seed);
    return c10::optional<at::Generator>(g);
  };
  // The loss at base + t * direction with the samples of seed 5.
  const torch::Tensor direction = torch::randn_like(s.base);
  const auto loss_at = [&](double t, uint64_t seed) {
    Scene moved = s;
    moved.base = (s.base.detach() + t * direction).requires_grad_(true);
    RenderOptions c = o;
    c.grad_parameters = moved.parameters();
    const RenderOutput r = RenderTriplanes(moved.planes(), moved.decoder(), cams, c, seeded(seed));
    const torch::Tensor w = torch::linspace(-1.0, 2.0, r.rgb.numel(), kF64).view(r.rgb.sizes());
    return ((r.rgb * w).sum() + r.rgb.pow(2).mean()).item<double>();
  };
  EXPECT_NE(loss_at(0.0, 5), loss_at(0.0, 6)) << "the samples are not jittered";
  const std::vector<torch::Tensor> g = LossGradients(s, cams, o, seeded(5));
  const double analytic = (g[0] * direction).sum().item<double>();
  const double h = 1e-5;
  const double numeric = (loss_at(h, 5) - loss_at(-h, 5)) / (2 * h);
  std::cout << "jittered chunked render: directional derivative " << analytic << " (autograd) vs " << numeric
            << " (central differences)\n";
  EXPECT_NEAR(analytic, numeric, 1e-6 * std::max(1.0, std::abs(numeric)));
  // The default generator: drawing from it between the forward and the backward pass changes nothing.
  torch::manual_seed(9);
  const std::vector<torch::Tensor> quiet = LossGradients(s, cams, o);
  torch::manual_seed(9);
  const std::vector<torch::Tensor> disturbed =
      LossGradients(s, cams, o, c10::nullopt, [] { (void)torch::rand({1000}); });
  EXPECT_EQ(WorstRelative(quiet, disturbed), 0.0);
}

// Inference renders run their ray chunks in parallel. With jittered samples, one seed gives one
// image whatever the thread count: each chunk draws from a generator of its own, seeded in chunk
// order (before, the chunks shared one generator in scheduling order).
TEST(RenderInference, JitteredChunksAreReproducibleOverThreadCounts) {
  const Scene s = MakeScene(2, 31);
  const Cameras cams = TwoCameras();
  RenderOptions o = SmallOptions();
  o.deterministic = false;
  o.chunk_rays = 16;  // 144 rays per image: 9 chunks
  const auto render = [&](uint64_t seed, int threads) {
    const int before = at::get_num_threads();
    at::set_num_threads(threads);
    torch::NoGradGuard no_grad;
    // The first decoder call sleeps, so that with two threads the other thread's chunk draws its
    // samples first: a shared generator would then hand out other samples than in chunk order.
    auto first = std::make_shared<std::atomic<bool>>(true);
    const PointDecoder inner = s.decoder();
    const PointDecoder slow_start = [first, inner](const torch::Tensor& f) {
      if (first->exchange(false)) std::this_thread::sleep_for(std::chrono::milliseconds(50));
      return inner(f);
    };
    const torch::Tensor rgb =
        RenderTriplanes(s.planes(), slow_start, cams, o, at::make_generator<at::CPUGeneratorImpl>(seed)).rgb;
    at::set_num_threads(before);
    return rgb;
  };
  const torch::Tensor one = render(7, 1);
  EXPECT_TRUE(torch::isfinite(one).all().item<bool>());
  for (int rep = 0; rep < 5; ++rep) EXPECT_TRUE(torch::equal(render(7, 2), one)) << "repeat " << rep;
  EXPECT_TRUE(torch::equal(render(7, 1), one));
  EXPECT_FALSE(torch::equal(render(8, 2), one)) << "the samples are not jittered";
  // Still a render of the same scene: close to one unchunked render with other samples.
  RenderOptions whole = o;
  whole.chunk_rays = 1 << 20;
  torch::NoGradGuard no_grad;
  const torch::Tensor unchunked =
      RenderTriplanes(s.planes(), s.decoder(), cams, whole, at::make_generator<at::CPUGeneratorImpl>(7)).rgb;
  EXPECT_EQ(unchunked.sizes(), one.sizes());
  const double mean_difference = (unchunked - one).abs().mean().item<double>();
  std::cout << "jittered inference render: mean |chunked - unchunked| " << mean_difference << "\n";
  EXPECT_GT(mean_difference, 0.0);
  EXPECT_LT(mean_difference, 0.05);  // the same scene, other samples
}

}  // namespace
}  // namespace avatar::render
