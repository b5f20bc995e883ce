// The one pose conversion (CameraForView) and the neural frame source built on it: turning the
// head in front of a camera is orbiting the camera around the still head; the source pose
// gives back the source camera C_s, and the head stays where C_s sees it; the neural source
// renders Session::Animate at that camera and hands the frame's expression to the avatar's
// expression source unchanged (coefficients and absolute flag included).
#include <gtest/gtest.h>

#include <cmath>
#include <mutex>

#include <opencv2/imgproc.hpp>

#include "core/morphable/camera_label.h"
#include "core/pipeline/session_access.h"
#include "core/pipeline/session_source.h"
#include "core/render/camera.h"
#include "core/util/error.h"

namespace avatar {
namespace {

// The head rotation of a pose as an OpenCV matrix.
cv::Matx33d HeadMatrix(const ViewPose& pose) { return cv::Matx33d(render::HeadRotation(pose).data()); }

morphable::PinholeCamera Decode(const CameraLabel25& label) { return morphable::PinholeCamera::FromLabel(label); }

// A source camera that is neither frontal nor centred on the head, with its own intrinsics.
CameraLabel25 OffCentreCamera() {
  const cv::Matx33d front = Decode(morphable::FrontalLabel()).world_to_cam;
  const cv::Matx33d r = front * HeadMatrix(ViewPose{18, -9, 4, 1});
  const cv::Vec3d head_in_camera(0.07, -0.19, 2.65);  // the head's origin off the optical axis
  CameraLabel25 label = morphable::LabelFromPose(r, -(r.t() * head_in_camera));
  label[16 + 0] = label[16 + 4] = 4.1f;  // focal
  label[16 + 2] = 0.52f;                 // principal point x
  label[16 + 5] = 0.47f;                 // principal point y
  return label;
}

TEST(CameraForView, TurningTheHeadIsOrbitingTheCamera) {
  const CameraLabel25 frontal = morphable::FrontalLabel();
  const morphable::PinholeCamera front = Decode(frontal);
  const std::vector<cv::Vec3d> head = {{0, 0, 0.12}, {0.08, 0.05, 0.05}, {-0.07, -0.09, 0.04}, {0.02, 0.1, -0.1}};
  const cv::Size size(512, 512);
  for (const ViewPose pose : {ViewPose{25, 0, 0, 1}, ViewPose{0, 15, 0, 1}, ViewPose{0, 0, 20, 1},
                              ViewPose{-30, -10, 8, 1}, ViewPose{10, 5, 0, 1.5}}) {
    const morphable::PinholeCamera orbit = Decode(CameraForView(pose, frontal));
    const cv::Matx33d r = HeadMatrix(pose);
    for (const cv::Vec3d& p : head) {
      // Zoom: the frontal camera moves to 2.7 / zoom along its axis.
      morphable::PinholeCamera near = front;
      near.centre = front.centre / pose.zoom;
      const cv::Point2d a = near.ToPixel(near.ToCamera(r * p), size);
      const cv::Point2d b = orbit.ToPixel(orbit.ToCamera(p), size);
      EXPECT_NEAR(a.x, b.x, 0.05) << pose.yaw << " " << pose.pitch << " " << pose.roll;
      EXPECT_NEAR(a.y, b.y, 0.05) << pose.yaw << " " << pose.pitch << " " << pose.roll;
    }
  }
  // The frontal pose of the frontal camera is the session's default orbit camera.
  render::Cameras orbit{render::OrbitCam2World(render::ViewPose{}).unsqueeze(0),
                        render::DefaultIntrinsics().unsqueeze(0)};
  const CameraLabel25 session_front = morphable::LabelFromTensor(render::LabelsFromCameras(orbit));
  const CameraLabel25 ours = CameraForView(ViewPose{}, frontal);
  for (int i = 0; i < 25; ++i) EXPECT_NEAR(ours[i], session_front[i], 1e-6) << i;
}

TEST(CameraForView, TheSourcePoseIsTheSourceCamera) {
  const CameraLabel25 source = OffCentreCamera();
  const ViewPose pose = render::PoseOfCamera(source);
  EXPECT_NEAR(pose.yaw, 18.0, 1e-4);
  EXPECT_NEAR(pose.pitch, -9.0, 1e-4);
  EXPECT_NEAR(pose.roll, 4.0, 1e-4);
  const CameraLabel25 back = CameraForView(pose, source);
  for (int i = 0; i < 25; ++i) EXPECT_NEAR(back[i], source[i], 1e-5) << i;
}

TEST(CameraForView, TheHeadStaysWhereTheSourceCameraSeesIt) {
  const CameraLabel25 source = OffCentreCamera();
  const cv::Size size(400, 400);
  const morphable::PinholeCamera c = Decode(source);
  const cv::Point2d origin = c.ToPixel(c.ToCamera({0, 0, 0}), size);
  ASSERT_GT(cv::norm(origin - cv::Point2d(200, 200)), 10.0) << "the test camera must be off-centre";
  for (const ViewPose pose : {ViewPose{}, ViewPose{40, 0, 0, 1}, ViewPose{-20, 25, -10, 1}, ViewPose{5, 5, 5, 2}}) {
    const morphable::PinholeCamera v = Decode(CameraForView(pose, source));
    const cv::Point2d p = v.ToPixel(v.ToCamera({0, 0, 0}), size);
    EXPECT_NEAR(p.x, origin.x, 1e-3);
    EXPECT_NEAR(p.y, origin.y, 1e-3);
    EXPECT_NEAR(cv::norm(v.centre), cv::norm(c.centre) / pose.zoom, 1e-5);  // turns about the head
  }
  EXPECT_THROW(CameraForView(ViewPose{0, 0, 0, 0.0}, source), InvalidOptions);
  EXPECT_THROW(CameraForView(ViewPose{std::nan(""), 0, 0, 1}, source), InvalidOptions);
  CameraLabel25 broken = source;
  broken[0] = 3.0f;
  EXPECT_THROW(CameraForView(ViewPose{}, broken), InvalidInput);
}

// Remembers the last expression it was asked for; renders a grey disk.
class RecordingExpressionSource : public ExpressionImageSource {
 public:
  cv::Mat Render(const Expression& expression, int size) const override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      last_ = expression;
      ++calls_;
    }
    cv::Mat img = cv::Mat::zeros(size, size, CV_8UC3);
    const int shade = 100 + static_cast<int>(50 * expression.Get("jawOpen"));
    cv::circle(img, cv::Point(size / 2, size / 2), size / 3, cv::Scalar::all(shade), cv::FILLED);
    return img;
  }
  std::vector<std::string> ControlNames() const override { return {"jawOpen"}; }
  int CoefficientCount() const override { return 3; }
  std::string Kind() const override { return "test-recording"; }
  std::string Serialize() const override { return {}; }
  Expression Last() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return last_;
  }
  int Calls() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return calls_;
  }

 private:
  mutable std::mutex mutex_;
  mutable Expression last_;
  mutable int calls_ = 0;
};

TEST(SessionSource, RendersAtTheViewsCameraWithTheFramesExpressionUnchanged) {
  SessionOptions options;
  options.random_weights = true;
  options.config = "tiny";
  auto session = std::make_shared<const Session>(options);
  auto recorder = std::make_shared<RecordingExpressionSource>();
  SourceFit fit;
  fit.camera = OffCentreCamera();
  fit.expressions = recorder;
  cv::Mat portrait = cv::Mat::zeros(512, 512, CV_8UC3);
  cv::circle(portrait, cv::Point(256, 256), 170, cv::Scalar(120, 150, 200), cv::FILLED);
  RunContext ctx;
  const Avatar avatar = session->ReconstructFromAnalysis(PortraitFromAlignedImage(portrait), fit, ctx);
  const SessionFrameSource source(session, avatar, /*random_weights=*/true);
  EXPECT_EQ(source.CoefficientCount(), 3);
  EXPECT_EQ(source.Label(), kRandomWeightsLabel);
  EXPECT_NEAR(source.SourcePose().yaw, 18.0, 1e-4);

  const int n = session->Info().render_size;
  FrameRequest request;
  request.width = request.height = n;  // the render's own size: no resampling in the source
  request.view = source.SourcePose();
  request.view.yaw += 12.0;
  request.expression.controls["jawOpen"] = 0.4f;
  request.expression.coefficients = {0.25f, -1.5f, 3.0f};
  request.expression.coefficients_absolute = true;
  const RenderedFrame got = source.Render(request, ctx);
  EXPECT_EQ(recorder->Last(), request.expression);  // coefficients and `absolute` reach I_exp as given
  const int calls = recorder->Calls();

  const Frame want = session->Animate(avatar, request.expression, CameraForView(request.view, avatar.SourceCamera()),
                                      RenderMode::kStandard);
  EXPECT_EQ(recorder->Calls(), calls) << "the same expression must come from the session's cache";
  ASSERT_EQ(got.bgr.size(), want.bgr.size());
  EXPECT_EQ(cv::norm(got.bgr, want.bgr, cv::NORM_INF), 0.0);
  cv::Mat want_alpha;
  want.opacity.convertTo(want_alpha, CV_8UC1, 255.0);
  EXPECT_EQ(cv::norm(got.alpha, want_alpha, cv::NORM_INF), 0.0);

  // Relative and absolute are different expressions for the session (different cache entries).
  request.expression.coefficients_absolute = false;
  source.Render(request, ctx);
  EXPECT_EQ(recorder->Last(), request.expression);
  EXPECT_EQ(recorder->Calls(), calls + 1);

  request.view.zoom = 0.0;
  EXPECT_THROW(source.Render(request, ctx), InvalidOptions);
}

// What a viewer reads beside random-weight frames (the studio's viewport and status bar and
// `animate` show the source's Label()): the neural source of a random-weights session says RANDOM
// and "not a result", also once its avatar is refined; without the flag the source is labelled
// with the model's own description.
TEST(SessionSource, RandomWeightsAreLabelledAsNotAResult) {
  SessionOptions options;
  options.random_weights = true;
  options.config = "tiny";
  auto session = std::make_shared<const Session>(options);
  SourceFit fit;
  fit.camera = morphable::FrontalLabel();
  fit.expressions = std::make_shared<RecordingExpressionSource>();
  cv::Mat portrait = cv::Mat::zeros(512, 512, CV_8UC3);
  cv::circle(portrait, cv::Point(256, 256), 170, cv::Scalar(120, 150, 200), cv::FILLED);
  RunContext ctx;
  const Avatar avatar = session->ReconstructFromAnalysis(PortraitFromAlignedImage(portrait), fit, ctx);

  const std::string random = SessionFrameSource(session, avatar, /*random_weights=*/true).Label();
  EXPECT_NE(random.find("RANDOM"), std::string::npos) << random;
  EXPECT_NE(random.find("not a result"), std::string::npos) << random;

  const std::string named = SessionFrameSource(session, avatar, /*random_weights=*/false).Label();
  EXPECT_EQ(named, "Neural avatar: " + DescribeModel(session->Info()));

  // Refined planes add what the refinement measured, and keep the warning.
  const Avatar refined = SessionAccess::WithPlanes(avatar, SessionAccess::Canonical(avatar).clone(),
                                                   SessionAccess::Appearance(avatar).clone(),
                                                   R"({"steps": 3, "psnr_before": 10.0, "psnr_after": 11.5})");
  const std::string refined_label = SessionFrameSource(session, refined, /*random_weights=*/true).Label();
  EXPECT_NE(refined_label.find("RANDOM"), std::string::npos) << refined_label;
  EXPECT_NE(refined_label.find("not a result"), std::string::npos) << refined_label;
  EXPECT_NE(refined_label.find("refined on the photo: 3 steps, source-view PSNR 10.00 -> 11.50 dB"), std::string::npos)
      << refined_label;
}

}  // namespace
}  // namespace avatar
