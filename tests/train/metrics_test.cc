// Image metrics against independent references: OpenCV's PSNR, SSIM written out as loops over
// windows, and hand-computed cases.

#include "core/train/metrics.h"

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <cmath>
#include <random>

#include "core/util/error.h"

namespace avatar::train {
namespace {

cv::Mat RandomImage(int h, int w, unsigned seed) {
  cv::Mat img(h, w, CV_8UC3);
  cv::RNG rng(seed);
  rng.fill(img, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(img, img, cv::Size(5, 5), 1.2);  // some structure, not pure noise
  return img;
}

// 8-bit RGB -> [1,3,H,W] in [-1,1], double precision.
torch::Tensor ToTensor(const cv::Mat& bgr) {
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  torch::Tensor t = torch::from_blob(rgb.data, {rgb.rows, rgb.cols, 3}, torch::kUInt8).clone();
  return t.permute({2, 0, 1}).unsqueeze(0).to(torch::kFloat64) / 127.5 - 1.0;
}

// SSIM of one channel by explicit loops over every valid 11x11 window (intensities in [0,1]).
double LoopSsim(const cv::Mat& a8, const cv::Mat& b8, int channel) {
  const int k = 11;
  const double sigma = 1.5, c1 = 1e-4, c2 = 9e-4;
  double g[11], sum = 0;
  for (int i = 0; i < k; ++i) sum += g[i] = std::exp(-(i - 5) * (i - 5) / (2 * sigma * sigma));
  for (double& v : g) v /= sum;
  double total = 0;
  int count = 0;
  for (int y = 0; y + k <= a8.rows; ++y) {
    for (int x = 0; x + k <= a8.cols; ++x) {
      double ma = 0, mb = 0, saa = 0, sbb = 0, sab = 0;
      for (int j = 0; j < k; ++j) {
        for (int i = 0; i < k; ++i) {
          const double w = g[i] * g[j];
          const double va = a8.at<cv::Vec3b>(y + j, x + i)[channel] / 255.0;
          const double vb = b8.at<cv::Vec3b>(y + j, x + i)[channel] / 255.0;
          ma += w * va;
          mb += w * vb;
          saa += w * va * va;
          sbb += w * vb * vb;
          sab += w * va * vb;
        }
      }
      const double va = saa - ma * ma, vb = sbb - mb * mb, cov = sab - ma * mb;
      total += ((2 * ma * mb + c1) * (2 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2));
      ++count;
    }
  }
  return total / count;
}

TEST(Metrics, PsnrEqualsOpenCv) {
  const cv::Mat a = RandomImage(40, 52, 1);
  for (int noise : {2, 8, 32}) {
    cv::Mat n(a.size(), CV_16SC3);
    cv::RNG(noise).fill(n, cv::RNG::NORMAL, 0, noise);
    cv::Mat b;
    a.convertTo(b, CV_16SC3);
    b += n;
    b.convertTo(b, CV_8UC3);  // saturates
    const double want = cv::PSNR(a, b, 255.0);
    const double got = PsnrPerImage(ToTensor(a), ToTensor(b)).item<double>();
    EXPECT_NEAR(got, want, 1e-9) << "noise " << noise;
  }
  EXPECT_TRUE(std::isinf(PsnrPerImage(ToTensor(a), ToTensor(a)).item<double>()));
}

TEST(Metrics, MaskedPsnrCountsOnlyMaskedPixels) {
  const torch::Tensor a = torch::zeros({1, 3, 8, 8}, torch::kFloat64);
  torch::Tensor b = a.clone();
  b.narrow(3, 4, 4).fill_(1.0);  // right half differs by 1
  torch::Tensor mask = torch::zeros({1, 1, 8, 8}, torch::kFloat64);
  mask.narrow(3, 0, 4).fill_(1.0);
  EXPECT_TRUE(std::isinf(PsnrPerImage(a, b, mask).item<double>()));
  mask.fill_(1.0);
  // MSE 0.5 -> 10 log10(4 / 0.5).
  EXPECT_NEAR(PsnrPerImage(a, b, mask).item<double>(), 10.0 * std::log10(8.0), 1e-12);
}

TEST(Metrics, SsimEqualsAnExplicitWindowLoop) {
  const cv::Mat a = RandomImage(24, 30, 3);
  cv::Mat b;
  cv::GaussianBlur(a, b, cv::Size(3, 3), 0.8);
  b += cv::Scalar(10, 0, -10);
  double want = 0;
  for (int c = 0; c < 3; ++c) want += LoopSsim(a, b, c) / 3.0;
  const double got = SsimPerImage(ToTensor(a), ToTensor(b)).item<double>();
  EXPECT_NEAR(got, want, 1e-9);
  EXPECT_LT(got, 0.99);
  EXPECT_NEAR(SsimPerImage(ToTensor(a), ToTensor(a)).item<double>(), 1.0, 1e-12);
}

TEST(Metrics, SsimOfUniformImagesIsTheLuminanceTerm) {
  // Flat images have zero variance: SSIM = (2 mu_a mu_b + C1) / (mu_a^2 + mu_b^2 + C1).
  const double ua = 0.2, ub = 0.7, c1 = 1e-4;
  const torch::Tensor a = torch::full({2, 3, 16, 16}, ua * 2 - 1, torch::kFloat64);
  const torch::Tensor b = torch::full({2, 3, 16, 16}, ub * 2 - 1, torch::kFloat64);
  const double want = (2 * ua * ub + c1) / (ua * ua + ub * ub + c1);
  const torch::Tensor got = SsimPerImage(a, b);
  ASSERT_EQ(got.numel(), 2);
  EXPECT_NEAR(got[0].item<double>(), want, 1e-9);
  EXPECT_NEAR(got[1].item<double>(), want, 1e-9);
}

TEST(Metrics, BatchValuesAreIndependentAndMasksWork) {
  const torch::Tensor a = ToTensor(RandomImage(20, 20, 5));
  const torch::Tensor b = ToTensor(RandomImage(20, 20, 6));
  const torch::Tensor batch_a = torch::cat({a, a}), batch_b = torch::cat({a, b});
  const ImageMetrics m = ComputeImageMetrics(batch_a, batch_b);
  EXPECT_TRUE(std::isinf(m.psnr[0].item<double>()));
  EXPECT_NEAR(m.ssim[0].item<double>(), 1.0, 1e-12);
  EXPECT_EQ(m.l1[0].item<double>(), 0.0);
  EXPECT_NEAR(m.ssim[1].item<double>(), SsimPerImage(a, b).item<double>(), 1e-12);
  EXPECT_FALSE(m.perceptual.defined());
  const torch::Tensor ones = torch::ones({2, 1, 20, 20}, torch::kFloat64);
  EXPECT_NEAR(SsimPerImage(batch_a, batch_b, ones)[1].item<double>(), m.ssim[1].item<double>(), 1e-12);
}

TEST(Metrics, BadShapesAreInvalidInput) {
  const torch::Tensor a = torch::zeros({1, 3, 16, 16});
  EXPECT_THROW(PsnrPerImage(a, torch::zeros({1, 3, 16, 15})), InvalidInput);
  EXPECT_THROW(SsimPerImage(torch::zeros({1, 3, 8, 8}), torch::zeros({1, 3, 8, 8})), InvalidInput);
  EXPECT_THROW(SsimPerImage(a, a, torch::zeros({1, 3, 16, 16})), InvalidInput);
}

}  // namespace
}  // namespace avatar::train
