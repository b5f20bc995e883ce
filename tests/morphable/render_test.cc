#include <cmath>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "core/util/error.h"
#include "morphable_test_util.h"

namespace avatar::morphable {
namespace {

using testing::InstalledTopology;
using testing::OrbitLabel;
using testing::ProjectLandmarks;
using testing::SyntheticModel;

// A smooth colour pattern over the UV square.
Texture PatternTexture(int size) {
  Texture t;
  t.uv_image = cv::Mat(size, size, CV_32FC3);
  for (int y = 0; y < size; ++y) {
    for (int x = 0; x < size; ++x) {
      const float u = (x + 0.5f) / size, v = (y + 0.5f) / size;
      t.uv_image.at<cv::Vec3f>(y, x) = cv::Vec3f(0.2f + 0.6f * u, 0.2f + 0.6f * v, 0.5f + 0.3f * std::sin(12.0f * u));
    }
  }
  return t;
}

cv::Mat To8(const cv::Mat& f) {
  cv::Mat out;
  f.convertTo(out, CV_8UC3, 255.0);
  return out;
}

TEST(Texture, SampledTextureReproducesTheSourceView) {
  const MorphableModel m = SyntheticModel(InstalledTopology(), 3, 3);
  const CameraLabel cam = OrbitLabel(15, 5, 0);
  const cv::Size size(256, 256);
  const RenderResult source = Render(m, {}, {}, 1.0f, PatternTexture(128), cam, size);
  std::mt19937 rng(3);
  const face::Landmarks lm = ProjectLandmarks(m.Vertices({}, {}), cam, size, 0.0, rng);
  FitOptions fo;
  fo.fit_identity = false;
  fo.fit_expression = false;
  const FitResult fit = Fit(m, lm, size, fo);
  const Texture tex = SampleTexture(m, fit, To8(source.image));
  ASSERT_EQ(tex.uv_image.size(), cv::Size(256, 256));
  EXPECT_GT(cv::countNonZero(tex.uv_visible), 10000);
  EXPECT_TRUE(cv::checkRange(tex.uv_image, true, nullptr, 0.0, 1.0001));
  const RenderResult again = Render(m, fit.alpha, fit.beta, fit.scale, tex, fit.camera, size);
  double err = 0.0;
  int n = 0;
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      if (source.mask.at<float>(y, x) == 0.0f || again.mask.at<float>(y, x) == 0.0f) continue;
      err += cv::norm(source.image.at<cv::Vec3f>(y, x) - again.image.at<cv::Vec3f>(y, x), cv::NORM_L1) / 3.0;
      ++n;
    }
  }
  ASSERT_GT(n, 5000);
  std::cout << "[texture] mean abs colour error of the re-render " << err / n << "\n";
  EXPECT_LT(err / n, 0.02);
  // Vertex colours agree with the pattern where visible: a vertex whose texel was sampled from
  // the image carries the pattern's colour at its UV (8-bit image, bilinear sampling).
  ASSERT_EQ(tex.vertex_colors.size(), 468u);
  const Topology& topo = m.topology();
  const Texture pattern = PatternTexture(128);
  std::vector<double> errors;
  for (int i = 0; i < 468; ++i) {
    const cv::Point2f uv = topo.uv[i];
    const int tx = std::clamp(static_cast<int>(uv.x * tex.uv_visible.cols), 0, tex.uv_visible.cols - 1);
    const int ty = std::clamp(static_cast<int>(uv.y * tex.uv_visible.rows), 0, tex.uv_visible.rows - 1);
    if (tex.uv_visible.at<uint8_t>(ty, tx) == 0) continue;
    const int px = std::clamp(static_cast<int>(uv.x * 128), 0, 127), py = std::clamp(static_cast<int>(uv.y * 128), 0, 127);
    errors.push_back(cv::norm(tex.vertex_colors[i] - pattern.uv_image.at<cv::Vec3f>(py, px), cv::NORM_INF));
  }
  ASSERT_GT(errors.size(), 200u) << "too few visible vertices to compare";
  std::nth_element(errors.begin(), errors.begin() + errors.size() / 2, errors.end());
  std::cout << "[texture] median vertex colour error " << errors[errors.size() / 2] << " over " << errors.size()
            << " visible vertices\n";
  EXPECT_LT(errors[errors.size() / 2], 0.03);
  // A mismatched image is refused.
  EXPECT_THROW(SampleTexture(m, fit, cv::Mat(10, 10, CV_8UC3)), InvalidInput);
}

TEST(Render, NeutralAndExpressionImagesFollowTheirDefinitions) {
  const MorphableModel m = SyntheticModel(InstalledTopology(), 3, 4);
  std::mt19937 rng(6);
  Beta b = {0.04f, -0.03f, 0.02f, 0.0f};
  const CameraLabel cam = OrbitLabel(-25, 8, 4);
  std::vector<cv::Point3f> w = m.Vertices({0.05f, 0.0f, -0.04f}, b);
  const face::Landmarks lm = ProjectLandmarks(w, cam, cv::Size(512, 512), 0.3, rng);
  const FitResult fit = Fit(m, lm, cv::Size(512, 512));
  const Texture tex = UniformTexture({0.2f, 0.6f, 0.9f});
  const cv::Size size(96, 80);
  // I_neu = beta 0 at the source camera.
  const RenderResult neu = RenderNeutral(m, fit, tex, size);
  const RenderResult neu_ref = Render(m, fit.alpha, m.ZeroBeta(), fit.scale, tex, fit.camera, size);
  EXPECT_EQ(cv::norm(neu.image, neu_ref.image, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(neu.mask, neu_ref.mask, cv::NORM_INF), 0.0);
  // I_exp = target expression at C_front.
  Beta target = {0.0f, 0.05f, 0.0f, 0.0f};
  const RenderResult ex = RenderExpressionImage(m, fit, tex, target, size);
  const RenderResult ex_ref = Render(m, fit.alpha, target, fit.scale, tex, FrontalLabel(), size);
  EXPECT_EQ(cv::norm(ex.image, ex_ref.image, cv::NORM_INF), 0.0);
  // The frontal render of a face is roughly centred and left-right balanced.
  const cv::Moments mo = cv::moments(ex.mask);
  ASSERT_GT(mo.m00, 100.0);
  EXPECT_NEAR(mo.m10 / mo.m00, size.width / 2.0, size.width * 0.08);
  // Masks are coverage: binary without supersampling, fractional at edges with it.
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const float v = neu.mask.at<float>(y, x);
      ASSERT_TRUE(v == 0.0f || v == 1.0f);
      ASSERT_EQ(v > 0.0f, neu.depth.at<float>(y, x) > 0.0f);
    }
  }
  RenderOptions aa;
  aa.supersample = 3;
  const RenderResult soft = RenderNeutral(m, fit, tex, size, aa);
  int fractional = 0;
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x)
      fractional += soft.mask.at<float>(y, x) > 0.0f && soft.mask.at<float>(y, x) < 1.0f;
  }
  EXPECT_GT(fractional, 10);
  EXPECT_NEAR(cv::sum(soft.mask)[0], cv::sum(neu.mask)[0], 0.05 * cv::sum(neu.mask)[0]);
  // Batched calls equal single ones.
  const auto batch = RenderNeutrals(m, {fit, fit}, {tex, tex}, size);
  ASSERT_EQ(batch.size(), 2u);
  EXPECT_EQ(cv::norm(batch[1].image, neu.image, cv::NORM_INF), 0.0);
  const auto eb = RenderExpressionImages(m, {fit}, {tex}, {target}, size);
  EXPECT_EQ(cv::norm(eb[0].image, ex.image, cv::NORM_INF), 0.0);
  EXPECT_THROW(RenderNeutrals(m, {fit}, {}, size), InvalidInput);
}

TEST(Render, FittedCameraPutsTheMeshOnTheLandmarks) {
  // The mesh rendered through the fitted label covers the landmarks' positions in the crop.
  const MorphableModel m = SyntheticModel(InstalledTopology(), 3, 3);
  std::mt19937 rng(2);
  const cv::Size size(512, 512);
  const face::Landmarks lm = ProjectLandmarks(m.Vertices({}, {}), OrbitLabel(10, -5, 0), size, 0.5, rng);
  const FitResult fit = Fit(m, lm, size);
  const RenderResult r = Render(m, fit.alpha, fit.beta, fit.scale, UniformTexture(), fit.camera, size);
  int inside = 0;
  for (const auto& p : lm.points) {
    const int x = std::clamp(static_cast<int>(p.x), 0, 511), y = std::clamp(static_cast<int>(p.y), 0, 511);
    inside += r.mask.at<float>(y, x) > 0.0f;
  }
  EXPECT_GT(inside, 440);  // boundary landmarks may fall just outside
}

}  // namespace
}  // namespace avatar::morphable
