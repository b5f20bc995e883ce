// MeasureShape and MeasureLandmarks on shapes whose measures are known by construction: a
// 468-point shape with only the measured landmarks placed (the rest at the origin), so each
// expected value is a hand-computed distance or height divided by the eye-centre distance.

#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "core/morphable/measures.h"
#include "core/util/error.h"
#include "morphable_test_util.h"

namespace avatar::morphable {
namespace {

// Eye corners put the eye centres at x = -3 (subject's right) and x = +3 (left): iod = 6.
constexpr double kIod = 6.0;

std::vector<cv::Point3f> KnownShape() {
  std::vector<cv::Point3f> p(468, cv::Point3f(0, 0, 0));
  p[33] = {-3.5f, 0.0f, 0.0f};  // right eye corners
  p[133] = {-2.5f, 0.0f, 0.0f};
  p[263] = {3.5f, 0.0f, 0.0f};  // left eye corners
  p[362] = {2.5f, 0.0f, 0.0f};
  p[13] = {0.0f, -4.0f, 1.0f};  // inner lips
  p[14] = {0.0f, -5.2f, 1.0f};
  p[61] = {-2.4f, -4.3f, 0.0f};  // mouth corners
  p[291] = {2.4f, -4.5f, 0.0f};
  p[105] = {-3.0f, 2.0f, 0.0f};  // brow middles and upper eyelids
  p[159] = {-3.0f, 0.6f, 0.0f};
  p[334] = {3.0f, 2.4f, 0.0f};
  p[386] = {3.0f, 0.6f, 0.0f};
  p[107] = {-1.0f, 1.8f, 0.0f};  // inner brow ends
  p[336] = {1.0f, 1.8f, 0.0f};
  p[145] = {-3.0f, -0.3f, 0.0f};  // lower eyelids
  p[374] = {3.0f, 0.1f, 0.0f};
  p[0] = {0.0f, -3.8f, 1.5f};  // lip centres, in front of the corners
  p[17] = {0.0f, -5.6f, 1.3f};
  return p;
}

void ExpectKnownMeasures(const ExpressionMeasures& m, double tol) {
  EXPECT_NEAR(m.lip_gap, 1.2 / kIod, tol);
  EXPECT_NEAR(m.mouth_width, std::hypot(4.8, 0.2) / kIod, tol);
  // Corners at mean height -4.4, inner-lip midpoint at -4.6: 0.2 above it.
  EXPECT_NEAR(m.corner_lift, 0.2 / kIod, tol);
  // Brows 1.4 (right) and 1.8 (left) above the upper eyelids.
  EXPECT_NEAR(m.brow_height, 1.6 / kIod, tol);
  EXPECT_NEAR(m.brow_inner_gap, 2.0 / kIod, tol);
  EXPECT_NEAR(m.eye_open_right, 0.9 / kIod, tol);
  EXPECT_NEAR(m.eye_open_left, 0.5 / kIod, tol);
  // Lip centres at mean depth 1.4, corners at 0.
  EXPECT_NEAR(m.lip_protrusion, 1.4 / kIod, tol);
}

TEST(Measures, KnownShapeGivesTheHandComputedValues) { ExpectKnownMeasures(MeasureShape(KnownShape()), 1e-6); }

TEST(Measures, AreInvariantToTranslationAndUniformScale) {
  std::vector<cv::Point3f> p = KnownShape();
  for (auto& q : p) q = q * 2.5f + cv::Point3f(0.7f, -1.1f, 3.0f);
  ExpectKnownMeasures(MeasureShape(p), 1e-5);
}

TEST(Measures, EachMeasureFollowsItsOwnLandmarks) {
  const ExpressionMeasures base = MeasureShape(KnownShape());
  // Lowering the inner lower lip by 0.6 opens the lips by 0.6 / iod and lowers their
  // midpoint by 0.3, which lifts the corners relative to it; nothing else moves.
  std::vector<cv::Point3f> p = KnownShape();
  p[14].y -= 0.6f;
  ExpressionMeasures m = MeasureShape(p);
  EXPECT_NEAR(m.lip_gap - base.lip_gap, 0.6 / kIod, 1e-6);
  EXPECT_NEAR(m.corner_lift - base.corner_lift, 0.3 / kIod, 1e-6);
  EXPECT_NEAR(m.eye_open_left, base.eye_open_left, 1e-9);
  EXPECT_NEAR(m.eye_open_right, base.eye_open_right, 1e-9);
  EXPECT_NEAR(m.brow_height, base.brow_height, 1e-9);
  // Closing the subject's left eye (lower lid up to the upper lid) leaves the right one.
  p = KnownShape();
  p[374] = p[386];
  m = MeasureShape(p);
  EXPECT_NEAR(m.eye_open_left, 0.0, 1e-9);
  EXPECT_NEAR(m.eye_open_right, 0.9 / kIod, 1e-6);
  // Raising one brow by 0.6 raises the two-sided mean by 0.3.
  p = KnownShape();
  p[334].y += 0.6f;
  EXPECT_NEAR(MeasureShape(p).brow_height - base.brow_height, 0.3 / kIod, 1e-6);
  // Pushing the lip centres back behind the corners makes the protrusion negative.
  p = KnownShape();
  p[0].z = p[17].z = -0.5f;
  EXPECT_NEAR(MeasureShape(p).lip_protrusion, -0.5 / kIod, 1e-6);
  // Wider eyes shrink every measure: the unit is the eye-centre distance.
  p = KnownShape();
  for (int i : {33, 133}) p[i].x -= 3.0f;
  for (int i : {263, 362}) p[i].x += 3.0f;
  EXPECT_NEAR(MeasureShape(p).lip_gap, 1.2 / 12.0, 1e-6);
}

TEST(Measures, LandmarksAreFlippedIntoTheModelFrame) {
  // facemesh landmarks: y down, smaller z closer. The same face in that frame measures the same.
  face::Landmarks lm;
  for (const auto& q : KnownShape()) lm.points.emplace_back(q.x, -q.y, -q.z);
  ExpectKnownMeasures(MeasureLandmarks(lm), 1e-6);
}

TEST(Measures, CanonicalMeshHasAClosedMouthAndOpenEyes) {
  // The installed neutral mesh: the measured landmarks are the intended ones (lips nearly closed,
  // mouth about as wide as the eye distance, brows above the eyes, lips in front of the corners).
  const Topology& topo = testing::InstalledTopology();
  const ExpressionMeasures m = MeasureShape(topo.canonical_cm);
  EXPECT_LT(m.lip_gap, 0.15);  // 0.09: the canonical lips are barely parted
  EXPECT_LT(m.lip_gap, 0.2 * m.mouth_width);
  EXPECT_GT(m.mouth_width, 0.6);
  EXPECT_LT(m.mouth_width, 1.2);
  EXPECT_GT(m.brow_height, 0.1);
  EXPECT_GT(m.eye_open_left, 0.05);
  EXPECT_NEAR(m.eye_open_left, m.eye_open_right, 0.02);
  EXPECT_GT(m.lip_protrusion, 0.0);
}

TEST(Measures, WrongPointCountAndCoincidentEyesAreRefused) {
  EXPECT_THROW(MeasureShape(std::vector<cv::Point3f>(100)), InvalidInput);
  EXPECT_THROW(MeasureShape(std::vector<cv::Point3f>(468, cv::Point3f(1, 2, 3))), InvalidInput);
  face::Landmarks empty;
  EXPECT_THROW(MeasureLandmarks(empty), InvalidInput);
}

}  // namespace
}  // namespace avatar::morphable
