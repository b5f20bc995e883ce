// Analytic tests of the face geometry: similarity fit, crop template equivariance, head pose
// of synthetic rotated faces, masks, anchors, weighted NMS and the One-Euro filter.
#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "core/face/blazeface.h"
#include "core/face/face_geometry.h"
#include "core/face/warp.h"
#include "core/face/one_euro.h"
#include "core/util/error.h"

namespace avatar::face {
namespace {

// A synthetic face: random points plus the named vertices at plausible frontal positions
// (units: pixels, z away from the camera), rotated by yaw/pitch/roll about the face centre.
Landmarks SyntheticFace(double yaw_deg, double pitch_deg, double roll_deg, unsigned seed = 1) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-60.0f, 60.0f);
  Landmarks lm;
  lm.confidence = 1.0f;
  lm.points.resize(kMeshPoints);
  for (auto& p : lm.points) p = cv::Point3f(u(rng), u(rng), u(rng) * 0.3f);
  auto set = [&](const std::vector<int>& idx, cv::Point3f c) {
    for (size_t k = 0; k < idx.size(); ++k) {
      const float a = static_cast<float>(2 * M_PI * k / idx.size());
      lm.points[idx[k]] = c + cv::Point3f(8.0f * std::cos(a), 3.0f * std::sin(a), 0.0f);
    }
  };
  set(mesh_index::RightEye(), {-30, -10, 0});
  set(mesh_index::LeftEye(), {30, -10, 0});
  lm.points[mesh_index::kRightEyeOuter] = {-40, -10, 0};
  lm.points[mesh_index::kLeftEyeOuter] = {40, -10, 0};
  lm.points[mesh_index::kForehead] = {0, -60, 0};
  lm.points[mesh_index::kChin] = {0, 70, 0};
  lm.points[mesh_index::kMouthRight] = {-22, 35, 0};
  lm.points[mesh_index::kMouthLeft] = {22, 35, 0};
  const double y = yaw_deg * M_PI / 180, p = pitch_deg * M_PI / 180, r = roll_deg * M_PI / 180;
  // Camera frame x right, y down, z away. Yaw about y, pitch about x, roll about z.
  const cv::Matx33d ry(std::cos(y), 0, std::sin(y), 0, 1, 0, -std::sin(y), 0, std::cos(y));
  const cv::Matx33d rx(1, 0, 0, 0, std::cos(p), -std::sin(p), 0, std::sin(p), std::cos(p));
  const cv::Matx33d rz(std::cos(r), -std::sin(r), 0, std::sin(r), std::cos(r), 0, 0, 0, 1);
  const cv::Matx33d rot = rz * ry * rx;
  for (auto& q : lm.points) {
    const cv::Vec3d v = rot * cv::Vec3d(q.x, q.y, q.z);
    q = cv::Point3f(static_cast<float>(v[0] + 300), static_cast<float>(v[1] + 200), static_cast<float>(v[2]));
  }
  return lm;
}

TEST(HeadPose, RecoversSyntheticRotations) {
  for (double yaw : {-50.0, -20.0, 0.0, 15.0, 45.0}) {
    const HeadPose p = HeadPoseFromLandmarks(SyntheticFace(yaw, 0, 0));
    EXPECT_NEAR(p.yaw, yaw, 1e-3);
    EXPECT_NEAR(p.pitch, 0.0, 1e-3);
    EXPECT_NEAR(p.roll, 0.0, 1e-3);
  }
  // Pitch sign (face_types.h: pitch > 0 is up). The synthetic rotation about x by +p moves the
  // forehead (image y < 0) towards the camera (z < 0) and the chin away: the face looks down,
  // so the measured pitch is -p.
  for (double pitch : {-30.0, -10.0, 20.0}) {
    const HeadPose p = HeadPoseFromLandmarks(SyntheticFace(0, pitch, 0));
    EXPECT_NEAR(p.pitch, -pitch, 1e-3);
    EXPECT_NEAR(p.yaw, 0.0, 1e-3);
  }
  for (double roll : {-40.0, 12.0, 80.0}) {
    const HeadPose p = HeadPoseFromLandmarks(SyntheticFace(0, 0, roll));
    EXPECT_NEAR(p.roll, roll, 1e-3);
    EXPECT_NEAR(p.yaw, 0.0, 1e-3);
  }
}

TEST(HeadPose, DegenerateLandmarksThrow) {
  Landmarks lm;
  lm.points.assign(kMeshPoints, cv::Point3f(5, 5, 5));
  EXPECT_THROW(HeadPoseFromLandmarks(lm), InvalidInput);
  lm.points.resize(10);
  EXPECT_THROW(HeadPoseFromLandmarks(lm), InvalidInput);
}

TEST(Similarity, RecoversAKnownTransform) {
  const double a = 1.7 * std::cos(0.4), b = 1.7 * std::sin(0.4);
  const cv::Matx23d truth(a, -b, 12.5, b, a, -7.25);
  std::vector<cv::Point2f> src = {{0, 0}, {10, 3}, {-4, 8}, {7, -9}, {2, 2}}, dst;
  for (const auto& p : src) dst.push_back(ApplyAffine(truth, p));
  const cv::Matx23d fit = SimilarityFromPoints(src, dst);
  for (int i = 0; i < 2; ++i) {
    for (int j = 0; j < 3; ++j) EXPECT_NEAR(fit(i, j), truth(i, j), 1e-5);
  }
  EXPECT_THROW(SimilarityFromPoints({{1, 1}, {1, 1}}, {{0, 0}, {1, 1}}), InvalidInput);
}

TEST(CropTemplate, EquivariantUnderSimilarities) {
  // Moving the face by any similarity T must not change the crop: Crop(T lm) * T == Crop(lm).
  const Landmarks lm = SyntheticFace(10, -5, 8);
  const cv::Matx23d base = CropTransform(lm, 512);
  for (double angle : {-1.0, 0.3, 2.5}) {
    const double s = 0.6 + angle * angle * 0.2;
    const cv::Matx23d t(s * std::cos(angle), -s * std::sin(angle), 40, s * std::sin(angle), s * std::cos(angle), -15);
    const Landmarks moved = TransformLandmarks(lm, t);
    const cv::Matx23d crop = CropTransform(moved, 512);
    for (int i : {0, 33, 263, 61, 152}) {
      const cv::Point2f p(lm.points[i].x, lm.points[i].y);
      const cv::Point2f a = ApplyAffine(base, p);
      const cv::Point2f b = ApplyAffine(crop, ApplyAffine(t, p));
      EXPECT_NEAR(a.x, b.x, 1e-2);
      EXPECT_NEAR(a.y, b.y, 1e-2);
    }
  }
  // Eyes level (the template mixes the eye line with the eye-mouth axis, so exactly level only
  // for a mouth perpendicular to the eyes; within a pixel for this turned face); a larger scale
  // zooms out around the same centre.
  const Landmarks crop_lm = TransformLandmarks(lm, base);
  const cv::Point2f re = RegionCentre(crop_lm, mesh_index::RightEye());
  const cv::Point2f le = RegionCentre(crop_lm, mesh_index::LeftEye());
  EXPECT_NEAR(re.y, le.y, 1.0);
  const cv::Matx23d wide = CropTransform(lm, 512, 2.0);
  EXPECT_NEAR(AffineScale(wide), AffineScale(base) / 2.0, 1e-6);
}

TEST(Masks, CoverTheRegionsAndGrowWithDilation) {
  const Landmarks lm = SyntheticFace(0, 0, 0);
  const cv::Matx23d crop = CropTransform(lm, 256);
  const Landmarks c = TransformLandmarks(lm, crop);
  const cv::Mat m0 = EyeMouthMask(c, 256, 0);
  const cv::Mat m4 = EyeMouthMask(c, 256, 4);
  EXPECT_GT(cv::countNonZero(m4), cv::countNonZero(m0));
  const cv::Point2f eye = RegionCentre(c, mesh_index::LeftEye());
  EXPECT_EQ(m0.at<uint8_t>(cvRound(eye.y), cvRound(eye.x)), 255);
  EXPECT_EQ(cv::countNonZero(EyeMouthMask(Landmarks(), 64, 3)), 0);
}

TEST(BlazeFace, AnchorGrids) {
  const auto front = BlazeFaceAnchors(128, {8, 16}, {2, 6});
  const auto back = BlazeFaceAnchors(256, {16, 32}, {2, 6});
  ASSERT_EQ(front.size(), 896u);
  ASSERT_EQ(back.size(), 896u);
  EXPECT_FLOAT_EQ(front[0].x, 0.5f / 16);
  EXPECT_FLOAT_EQ(front[1].x, 0.5f / 16);  // two anchors per cell
  EXPECT_FLOAT_EQ(front[2].x, 1.5f / 16);
  EXPECT_FLOAT_EQ(front[512].x, 0.5f / 8);  // first coarse anchor
  EXPECT_FLOAT_EQ(back.back().y, 7.5f / 8);
}

TEST(BlazeFace, WeightedNmsAveragesOverlapsByScore) {
  Detection a, b, c;
  a.box = {0, 0, 10, 10};
  a.score = 0.9f;
  b.box = {2, 0, 10, 10};
  b.score = 0.3f;
  c.box = {50, 50, 10, 10};
  c.score = 0.95f;
  a.keypoints[0] = {1, 1};
  b.keypoints[0] = {5, 1};
  const auto out = WeightedNms({a, b, c}, 0.3f);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_FLOAT_EQ(out[0].score, 0.95f);
  EXPECT_FLOAT_EQ(out[1].score, 0.9f);
  EXPECT_NEAR(out[1].box.x, (0.9 * 0 + 0.3 * 2) / 1.2, 1e-5);
  EXPECT_NEAR(out[1].keypoints[0].x, (0.9 * 1 + 0.3 * 5) / 1.2, 1e-5);
  EXPECT_TRUE(WeightedNms({}, 0.3f).empty());
  EXPECT_FLOAT_EQ(BoxIou({0, 0, 0, 0}, {0, 0, 0, 0}), 0.0f);
}

TEST(OneEuro, ConstantPassesStaticNoiseIsReducedRampIsFollowed) {
  OneEuroFilter constant;
  for (int i = 0; i < 50; ++i) EXPECT_DOUBLE_EQ(constant.Filter(3.5, i / 25.0), 3.5);
  OneEuroFilter noisy({1.0, 0.0, 1.0});
  std::mt19937 rng(7);
  std::normal_distribution<double> n(0.0, 1.0);
  double raw = 0, filtered = 0;
  for (int i = 0; i < 500; ++i) {
    const double x = n(rng);
    const double y = noisy.Filter(x, i / 25.0);
    if (i > 50) {
      raw += x * x;
      filtered += y * y;
    }
  }
  EXPECT_LT(filtered, 0.4 * raw);
  // A fast ramp: with beta > 0 the lag shrinks compared with beta = 0.
  OneEuroFilter adaptive({1.0, 0.5, 1.0}), fixed({1.0, 0.0, 1.0});
  double lag_adaptive = 0, lag_fixed = 0;
  for (int i = 0; i < 100; ++i) {
    const double t = i / 25.0, x = 100.0 * t;
    lag_adaptive = x - adaptive.Filter(x, t);
    lag_fixed = x - fixed.Filter(x, t);
  }
  EXPECT_GT(lag_adaptive, 0.0);
  EXPECT_LT(lag_adaptive, 0.5 * lag_fixed);
  // Repeated timestamps keep the last estimate instead of dividing by zero.
  EXPECT_TRUE(std::isfinite(adaptive.Filter(1e6, 99 / 25.0)));
}

}  // namespace
}  // namespace avatar::face
