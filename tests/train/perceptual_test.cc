// Perceptual distance on nsfwjs's ImageNet MobileNetV2 features: zero for identical images,
// monotonic in blur and noise on real photos, masks, and a double-precision gradient check.

#include "core/train/perceptual.h"

#include <iostream>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/temp_dir.h"
#include "core/io/data_paths.h"
#include "core/util/error.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;

// Five packaged photos, centre-cropped to a square and resized to `size` (test-only OpenCV).
std::vector<cv::Mat> Photos(int size) {
  const DataPaths data = DataPaths::Resolve();
  std::vector<cv::Mat> out;
  for (const char* name : {"samples/grace_hopper.jpg", "samples/franck_01829.jpg", "samples/sample1.jpg",
                           "samples/sample2.jpg", "samples/sample3.jpg"}) {
    const fs::path p = data.Require(name, "sample photos for the perceptual-loss test");
    cv::Mat img = cv::imread(p.string(), cv::IMREAD_COLOR);
    EXPECT_FALSE(img.empty()) << p << " unreadable: run scripts/setup";
    if (img.empty()) continue;
    const int side = std::min(img.cols, img.rows);
    cv::Mat crop = img(cv::Rect((img.cols - side) / 2, (img.rows - side) / 2, side, side));
    cv::Mat resized, rgb, f;
    cv::resize(crop, resized, cv::Size(size, size), 0, 0, cv::INTER_AREA);
    cv::cvtColor(resized, rgb, cv::COLOR_BGR2RGB);
    rgb.convertTo(f, CV_32FC3);
    out.push_back(f);
  }
  return out;
}

// float 0..255 RGB HxWx3 -> [1,3,H,W] in [-1,1] (Keras' x/127.5-1).
torch::Tensor ToTensor(const cv::Mat& rgb) {
  cv::Mat c;
  cv::min(cv::max(rgb, 0.0), 255.0, c);
  auto t = torch::from_blob(c.data, {c.rows, c.cols, 3}, torch::kFloat32).clone();
  return (t.permute({2, 0, 1}).unsqueeze(0) / 127.5 - 1.0).contiguous();
}

const PerceptualLoss& Loss() {
  static const PerceptualLoss loss;  // loads nsfwjs once per test binary
  return loss;
}

TEST(Perceptual, ReportName) { EXPECT_STREQ(PerceptualLoss::kReportName, "perceptual (MobileNetV2)"); }

TEST(Perceptual, ZeroForIdenticalImages) {
  const auto photos = Photos(224);
  ASSERT_EQ(photos.size(), 5u);
  std::vector<torch::Tensor> batch;
  for (const auto& p : photos) batch.push_back(ToTensor(p));
  const auto x = torch::cat(batch);
  torch::NoGradGuard no_grad;
  const auto d = Loss().Distance(x, x.clone());
  ASSERT_EQ(d.sizes().vec(), std::vector<int64_t>{5});
  for (int i = 0; i < 5; ++i) EXPECT_EQ(d[i].item<float>(), 0.0f) << "photo " << i;
  // And different photos are far apart.
  const auto other = Loss().Distance(x, x.roll(1, 0));
  EXPECT_GT(other.min().item<float>(), 0.1f) << other;
  std::cout << "[perceptual] different photos: " << other << "\n";
}

TEST(Perceptual, RisesWithBlur) {
  const auto photos = Photos(224);
  ASSERT_EQ(photos.size(), 5u);
  torch::NoGradGuard no_grad;
  const std::vector<double> sigmas = {0.5, 1.0, 1.5, 2.0, 3.0, 4.0};
  for (size_t i = 0; i < photos.size(); ++i) {
    const auto clean = ToTensor(photos[i]);
    double prev = 0.0;
    std::ostringstream line;
    for (const double s : sigmas) {
      cv::Mat blurred;
      cv::GaussianBlur(photos[i], blurred, cv::Size(0, 0), s, s, cv::BORDER_REFLECT);
      const double d = Loss().Distance(clean, ToTensor(blurred)).item<double>();
      line << " " << s << ":" << d;
      EXPECT_GT(d, prev) << "photo " << i << " blur sigma " << s;
      prev = d;
    }
    std::cout << "[perceptual] photo " << i << " blur" << line.str() << "\n";
  }
}

TEST(Perceptual, RisesWithNoise) {
  const auto photos = Photos(224);
  ASSERT_EQ(photos.size(), 5u);
  torch::NoGradGuard no_grad;
  const std::vector<double> sigmas = {2, 4, 8, 16, 32};  // grey levels
  for (size_t i = 0; i < photos.size(); ++i) {
    const auto clean = ToTensor(photos[i]);
    cv::Mat unit(photos[i].size(), CV_32FC3);
    cv::theRNG().state = 1234 + i;
    cv::randn(unit, 0.0, 1.0);
    double prev = 0.0;
    std::ostringstream line;
    for (const double s : sigmas) {
      const cv::Mat noisy = photos[i] + unit * s;
      const double d = Loss().Distance(clean, ToTensor(noisy)).item<double>();
      line << " " << s << ":" << d;
      EXPECT_GT(d, prev) << "photo " << i << " noise sigma " << s;
      prev = d;
    }
    std::cout << "[perceptual] photo " << i << " noise" << line.str() << "\n";
  }
}

TEST(Perceptual, MaskSelectsRegion) {
  const auto photos = Photos(128);
  ASSERT_FALSE(photos.empty());
  const auto a = ToTensor(photos[0]);
  auto b = a.clone();
  b.index({torch::indexing::Slice(), torch::indexing::Slice(), torch::indexing::Slice(),
           torch::indexing::Slice(64, torch::indexing::None)}) *= 0.3;  // darken the right half
  auto right = torch::zeros({1, 1, 128, 128});
  right.index_put_({torch::indexing::Slice(), torch::indexing::Slice(), torch::indexing::Slice(),
                    torch::indexing::Slice(64, torch::indexing::None)},
                   1.0);
  const auto left = 1.0 - right;
  torch::NoGradGuard no_grad;
  const double d_full = Loss().Distance(a, b).item<double>();
  const double d_ones = Loss().Distance(a, b, torch::ones({1, 1, 128, 128})).item<double>();
  const double d_right = Loss().Distance(a, b, right).item<double>();
  const double d_left = Loss().Distance(a, b, left).item<double>();
  EXPECT_NEAR(d_ones, d_full, 1e-5 * d_full);
  EXPECT_GT(d_right, 2.0 * d_left) << "right " << d_right << " left " << d_left;
  EXPECT_THROW(Loss().Distance(a, b, torch::ones({1, 1, 64, 64})), InvalidInput);
  EXPECT_THROW(Loss().Distance(a, b.narrow(3, 0, 64)), InvalidInput);
}

TEST(Perceptual, FrozenWeightsGradientsToInputs) {
  for (const auto& p : Loss().Network()->parameters()) ASSERT_FALSE(p.requires_grad());
  const auto photos = Photos(128);
  ASSERT_FALSE(photos.empty());
  auto a = ToTensor(photos[0]).requires_grad_(true);
  cv::Mat blurred;
  cv::GaussianBlur(photos[0], blurred, cv::Size(0, 0), 2.0);
  const auto b = ToTensor(blurred);
  Loss().Distance(a, b).sum().backward();
  ASSERT_TRUE(a.grad().defined());
  EXPECT_GT(a.grad().abs().sum().item<double>(), 0.0);
  for (const auto& p : Loss().Network()->parameters()) EXPECT_FALSE(p.grad().defined());
}

// Analytic gradients against central finite differences, in double precision, on 32x32 inputs.
TEST(Perceptual, GradientCheckDouble) {
  PerceptualLoss loss(LoadNsfwjsMobileNetV2(), PerceptualOptions{});
  loss.To(torch::kCPU, torch::kDouble);
  torch::manual_seed(7);
  const auto opts = torch::TensorOptions().dtype(torch::kDouble);
  // Smooth images with some texture, away from the [-1,1] ends.
  const auto base = torch::randn({1, 3, 8, 8}, opts);
  auto a = torch::upsample_bilinear2d(base, {32, 32}, false) * 0.4 + torch::randn({1, 3, 32, 32}, opts) * 0.05;
  auto b = a + torch::randn({1, 3, 32, 32}, opts) * 0.1;
  const auto mask = torch::rand({1, 1, 32, 32}, opts);
  for (const bool masked : {false, true}) {
    auto ar = a.clone().requires_grad_(true);
    auto br = b.clone().requires_grad_(true);
    const auto m = masked ? mask : torch::Tensor();
    loss.Distance(ar, br, m).sum().backward();
    const auto ga = ar.grad();
    const auto gb = br.grad();
    torch::NoGradGuard no_grad;
    std::mt19937 rng(11);
    std::uniform_int_distribution<int64_t> pick(0, a.numel() - 1);
    const double h = 1e-6;
    double worst = 0.0;
    for (int k = 0; k < 48; ++k) {
      const int64_t idx = pick(rng);
      const bool on_a = k % 2 == 0;
      auto plus = (on_a ? a : b).clone();
      auto minus = plus.clone();
      plus.view(-1)[idx] += h;
      minus.view(-1)[idx] -= h;
      const double fp = on_a ? loss.Distance(plus, b, m).item<double>() : loss.Distance(a, plus, m).item<double>();
      const double fm = on_a ? loss.Distance(minus, b, m).item<double>() : loss.Distance(a, minus, m).item<double>();
      const double numeric = (fp - fm) / (2 * h);
      const double analytic = (on_a ? ga : gb).view(-1)[idx].item<double>();
      const double err = std::abs(numeric - analytic);
      EXPECT_LE(err, 1e-7 + 1e-4 * std::abs(numeric))
          << (on_a ? "a" : "b") << "[" << idx << "] numeric " << numeric << " analytic " << analytic;
      worst = std::max(worst, err / (std::abs(numeric) + 1e-12));
    }
    std::cout << "[perceptual] gradcheck " << (masked ? "masked" : "unmasked") << ": worst relative error " << worst
              << "\n";
    EXPECT_GT(ga.abs().max().item<double>(), 0.0);
  }
}

TEST(Perceptual, MissingModelGivesModelLoad) {
  testing::TempDir dir;
  PerceptualOptions o;
  o.data_dir = dir.path().string();
  try {
    PerceptualLoss loss(o);
    ADD_FAILURE() << "no ModelLoad";
  } catch (const ModelLoad& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find((dir / "models" / "nsfwjs" / "model.min.js").string()), std::string::npos) << what;
    EXPECT_NE(what.find("scripts/setup"), std::string::npos) << what;
  }
  o.taps = {"no_such_layer"};
  EXPECT_THROW(o.Validate(), InvalidOptions);
}

// The trainer and the refinement take one distance per sample of a batch: each must be the
// distance of its own pair, whatever else is in the batch (a batch-wide normalisation or mean
// would mix them), and the distance is symmetric. At the 224 px the trainer's images have, on the
// five photos and a blurred copy of each. (Its speed: `avatar-studio bench train --perceptual
// mobilenet` against `--perceptual none`.)
TEST(Perceptual, BatchedDistancesAreEachPairsOwn) {
  const auto photos = Photos(224);
  ASSERT_EQ(photos.size(), 5u);
  std::vector<torch::Tensor> clean, blurred;
  for (size_t i = 0; i < photos.size(); ++i) {
    cv::Mat b;
    cv::GaussianBlur(photos[i], b, cv::Size(0, 0), 1.0 + static_cast<double>(i), 0, cv::BORDER_REFLECT);
    clean.push_back(ToTensor(photos[i]));
    blurred.push_back(ToTensor(b));
  }
  const auto a = torch::cat(clean), b = torch::cat(blurred);
  torch::NoGradGuard no_grad;
  const auto batched = Loss().Distance(a, b);
  ASSERT_EQ(batched.sizes().vec(), std::vector<int64_t>{5});
  EXPECT_TRUE(torch::allclose(Loss().Distance(b, a), batched, 1e-5, 1e-7)) << "not symmetric";
  for (int64_t i = 0; i < 5; ++i) {
    const double alone = Loss().Distance(clean[i], blurred[i]).item<double>();
    EXPECT_GT(alone, 0.0) << "photo " << i;
    // Float kernels may block a batch of 5 differently from a batch of 1: 1e-4 relative covers that.
    EXPECT_NEAR(batched[i].item<double>(), alone, 1e-4 * alone) << "photo " << i << " in a batch of 5";
  }
  // And a batch of one pair repeated five times gives that pair's distance five times.
  const auto repeated = Loss().Distance(clean[0].repeat({5, 1, 1, 1}), blurred[0].repeat({5, 1, 1, 1}));
  EXPECT_TRUE(torch::allclose(repeated, batched[0].expand({5}), 1e-4, 1e-7)) << repeated;
}

}  // namespace
}  // namespace avatar
