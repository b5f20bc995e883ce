// The morphable-model preview source: pose conventions (round trips and which way the nose
// moves), the pose recovered from a fit of landmarks rendered at a known head pose, opacity at
// the head's edge, expression changes confined to the head, and bad requests.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <cmath>
#include <random>

#include <unistd.h>

#include <filesystem>

#include <opencv2/imgcodecs.hpp>

#include "core/pipeline/animate.h"
#include "core/pipeline/morphable_preview.h"
#include "core/util/error.h"
#include "morphable/morphable_test_util.h"

namespace avatar {
namespace {

// The head rotation of a pose as an OpenCV matrix.
cv::Matx33d HeadMatrix(const ViewPose& pose) { return cv::Matx33d(render::HeadRotation(pose).data()); }

namespace mt = morphable::testing;

const morphable::MorphableModel& Model() {
  static const morphable::MorphableModel model = mt::SyntheticModel(mt::InstalledTopology(), 4, 6);
  return model;
}

// Landmarks of the model's mean face turned by `pose` in front of the frontal camera.
face::Landmarks LandmarksAt(const ViewPose& pose, cv::Size size) {
  std::vector<cv::Point3f> v = Model().Vertices({}, {});
  const cv::Matx33d r = HeadMatrix(pose);
  for (auto& p : v) {
    const cv::Vec3d q = r * cv::Vec3d(p.x, p.y, p.z);
    p = cv::Point3f(float(q[0]), float(q[1]), float(q[2]));
  }
  std::mt19937 rng(3);
  return mt::ProjectLandmarks(v, morphable::FrontalLabel(), size, 0.0, rng);
}

MorphablePreviewSource SourceAt(const ViewPose& pose) {
  const cv::Size size(512, 512);
  const morphable::FitResult fit = morphable::Fit(Model(), LandmarksAt(pose, size), size);
  // A texture with a left-right gradient so that turning the head changes colours too.
  morphable::Texture texture;
  for (const auto& p : Model().topology().canonical_cm) {
    texture.vertex_colors.emplace_back(0.3f + 0.04f * p.x, 0.5f, 0.6f - 0.02f * p.y);
  }
  return MorphablePreviewSource(Model(), fit, texture);
}

TEST(HeadPose, RotationAndAnglesRoundTrip) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> yaw(-80, 80), pitch(-60, 60), roll(-60, 60);
  for (int i = 0; i < 200; ++i) {
    const ViewPose p{yaw(rng), pitch(rng), roll(rng), 1.0};
    const ViewPose q = render::PoseFromRotation(render::HeadRotation(p));
    EXPECT_NEAR(q.yaw, p.yaw, 1e-9);
    EXPECT_NEAR(q.pitch, p.pitch, 1e-9);
    EXPECT_NEAR(q.roll, p.roll, 1e-9);
  }
  const cv::Matx33d r = HeadMatrix({30, 20, 10, 1});
  EXPECT_NEAR(cv::determinant(r), 1.0, 1e-12);
  EXPECT_LT(cv::norm(r * r.t() - cv::Matx33d::eye()), 1e-12);
}

TEST(HeadPose, PositiveAnglesTurnTheNoseLeftAndUp) {
  const cv::Vec3d nose(0, 0, 1);  // The face looks along +z; image right is +x, up is +y.
  EXPECT_LT((HeadMatrix({20, 0, 0, 1}) * nose)[0], -0.3);
  EXPECT_GT((HeadMatrix({0, 20, 0, 1}) * nose)[1], 0.3);
  const cv::Vec3d right(1, 0, 0);
  EXPECT_LT((HeadMatrix({0, 0, 20, 1}) * right)[1], -0.3);  // Clockwise on screen: +x dips.
}

TEST(MorphablePreview, RecoversTheHeadPoseOfThePortrait) {
  for (const ViewPose truth : {ViewPose{0, 0, 0, 1}, ViewPose{20, 0, 0, 1}, ViewPose{-15, 8, 5, 1}}) {
    const ViewPose got = SourceAt(truth).SourcePose();
    EXPECT_NEAR(got.yaw, truth.yaw, 2.0);
    EXPECT_NEAR(got.pitch, truth.pitch, 2.0);
    EXPECT_NEAR(got.roll, truth.roll, 2.0);
  }
}

TEST(MorphablePreview, RendersTheHeadWithSoftEdgesAndFollowsTheYaw) {
  const MorphablePreviewSource source = SourceAt({});
  EXPECT_EQ(source.Label().rfind("Preview: morphable model", 0), 0u) << source.Label();
  RunContext ctx;
  FrameRequest r;
  r.width = r.height = 256;
  const RenderedFrame front = source.Render(r, ctx);
  ASSERT_EQ(front.bgr.type(), CV_8UC3);
  ASSERT_EQ(front.alpha.type(), CV_8UC1);
  const int covered = cv::countNonZero(front.alpha);
  EXPECT_GT(covered, 256 * 256 / 20);
  EXPECT_EQ(front.alpha.at<uchar>(0, 0), 0);
  const int partial = cv::countNonZero((front.alpha > 0) & (front.alpha < 255));
  EXPECT_GT(partial, 50) << "the head's outline must have partial opacity";
  // Nothing outside the head: colour is black where alpha is 0.
  cv::Mat outside;
  front.bgr.copyTo(outside, front.alpha == 0);
  EXPECT_EQ(cv::norm(outside, cv::NORM_INF), 0.0);
  ASSERT_EQ(front.vertices.size(), 468u);
  EXPECT_EQ(front.triangles.size(), Model().topology().triangles.size());

  r.view.yaw = 30;
  const RenderedFrame turned = source.Render(r, ctx);
  EXPECT_GT(cv::norm(front.bgr, turned.bgr, cv::NORM_L1) / (256.0 * 256.0), 1.0);
  // The nose tip (vertex 1 of the facemesh topology) moves to the image's left.
  EXPECT_LT(turned.vertices[1].x, front.vertices[1].x - 10.0f);
  // Zoom makes the head bigger.
  r.view = {};
  r.view.zoom = 1.5;
  EXPECT_GT(cv::countNonZero(source.Render(r, ctx).alpha), covered * 1.8);
}

TEST(MorphablePreview, ExpressionChangesStayInsideTheHead) {
  const MorphablePreviewSource source = SourceAt({});
  RunContext ctx;
  FrameRequest r;
  r.width = r.height = 256;
  const RenderedFrame neutral = source.Render(r, ctx);
  r.expression.controls["jawOpen"] = 1.0f;
  const RenderedFrame open = source.Render(r, ctx);
  cv::Mat diff;
  cv::absdiff(neutral.bgr, open.bgr, diff);
  cv::cvtColor(diff, diff, cv::COLOR_BGR2GRAY);
  EXPECT_GT(cv::countNonZero(diff > 2), 100) << "the control changed nothing";
  const cv::Mat head = (neutral.alpha > 0) | (open.alpha > 0);
  EXPECT_EQ(cv::countNonZero((diff > 2) & ~head), 0) << "pixels changed outside the head";
  // Raw coefficients act like the control they equal.
  r.expression.controls.clear();
  r.expression.coefficients = Model().Control("jawOpen").direction;
  EXPECT_EQ(cv::norm(source.Render(r, ctx).bgr, open.bgr, cv::NORM_INF), 0.0);
}

TEST(MorphablePreview, BadRequestsAreClearErrors) {
  const MorphablePreviewSource source = SourceAt({});
  RunContext ctx;
  FrameRequest r;
  r.expression.coefficients = {1.0f, 2.0f};
  EXPECT_THROW(source.Render(r, ctx), InvalidInput);
  r.expression.coefficients.clear();
  r.expression.controls["wink"] = 1.0f;
  EXPECT_THROW(source.Render(r, ctx), InvalidInput);
  r.expression.controls.clear();
  r.view.zoom = 0.0;
  EXPECT_THROW(source.Render(r, ctx), InvalidOptions);
  r.view = {};
  r.view.yaw = std::nan("");
  EXPECT_THROW(source.Render(r, ctx), InvalidOptions);
  r.view = {180, 89, -180, 1};  // Extreme but valid: a finite frame.
  const RenderedFrame back = source.Render(r, ctx);
  EXPECT_EQ(back.bgr.rows, 512);
  ctx.RequestCancel();
  EXPECT_THROW(source.Render(FrameRequest{}, ctx), Cancelled);
}

TEST(MorphablePreview, TurntablePngSequenceHasVaryingAlphaAtTheHeadsEdge) {
  const MorphablePreviewSource source = SourceAt({});
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("avatar_orbit_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  AnimationPlan plan;
  plan.view.mode = "orbit";
  plan.view.orbit_degrees = 40;
  plan.width = plan.height = 128;
  plan.fps = 10;
  plan.seconds = 0.4;
  ExportOptions out;
  out.output = (dir / "frames").string();
  RunContext ctx;
  EXPECT_EQ(ExportAnimation(source, nullptr, plan, out, ctx).frames, 4);
  const cv::Mat a = cv::imread((dir / "frames" / "frame_000000.png").string(), cv::IMREAD_UNCHANGED);
  const cv::Mat b = cv::imread((dir / "frames" / "frame_000001.png").string(), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(a.type(), CV_8UC4);
  std::vector<cv::Mat> ca, cb;
  cv::split(a, ca);
  cv::split(b, cb);
  EXPECT_GT(cv::countNonZero((ca[3] > 0) & (ca[3] < 255)), 30) << "no soft edge in the alpha channel";
  EXPECT_GT(cv::countNonZero(ca[3] == 255), 500);
  EXPECT_GT(cv::norm(ca[3], cb[3], cv::NORM_L1), 1000.0) << "the turntable did not turn";
  std::filesystem::remove_all(dir);
}

TEST(MorphableFrameAnalyzer, MeasuresPoseAndExpressionOrReportsNoFace) {
  const cv::Size size(320, 320);  // Square: ProjectLandmarks' label intrinsics assume it.
  bool have_face = true;
  ViewPose truth{12, -6, 0, 1};
  MorphableFrameAnalyzer analyzer(Model(), [&](const cv::Mat& bgr, face::Landmarks* lm) {
    if (!have_face) return false;
    *lm = LandmarksAt(truth, bgr.size());
    return true;
  });
  RunContext ctx;
  const cv::Mat frame(size, CV_8UC3, cv::Scalar::all(0));
  FrameMeasurement m = analyzer.Measure(frame, ctx);
  ASSERT_TRUE(m.face_found);
  EXPECT_NEAR(m.pose.yaw, truth.yaw, 2.5);
  EXPECT_NEAR(m.pose.pitch, truth.pitch, 2.5);
  EXPECT_EQ(static_cast<int>(m.coefficients.size()), Model().num_expression());
  have_face = false;
  EXPECT_FALSE(analyzer.Measure(frame, ctx).face_found);
}

}  // namespace
}  // namespace avatar
