// The one pose type (core/render/view_pose.h) and its one conversion to a camera: pose -> camera
// -> pose is the identity, and the pose about the frontal camera is the look-at orbit camera of
// the same picture.

#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <vector>

#include "core/render/camera.h"
#include "core/render/view_pose.h"
#include "core/util/error.h"
#include "render/render_test_util.h"

namespace avatar::render {
namespace {

const auto kF64 = torch::TensorOptions().dtype(torch::kFloat64);

CameraLabel25 ToLabel(const std::array<double, 16>& cam2world, double cx) {
  CameraLabel25 label{};
  for (int i = 0; i < 16; ++i) label[i] = static_cast<float>(cam2world[i]);
  const double k[9] = {kFocal, 0.0, cx, 0.0, kFocal, kPrincipalPoint, 0.0, 0.0, 1.0};
  for (int i = 0; i < 9; ++i) label[16 + i] = static_cast<float>(k[i]);
  return label;
}

CameraLabel25 FrontalLabel() { return ToLabel(kFrontalCam2World, kPrincipalPoint); }

// A rigid camera that is not an orbit of the origin: turned, off-centre, off-centre intrinsics.
CameraLabel25 OffCentreLabel() {
  std::array<double, 16> m = ViewCam2World(ViewPose{18.0, -9.0, 4.0, 1.0}, kFrontalCam2World);
  m[3] += 0.1;
  m[7] -= 0.2;
  m[11] -= 0.15;
  return ToLabel(m, 0.47);
}

// Distance from a camera's centre to the world origin (the head's centre).
double HeadDistance(const CameraLabel25& c) {
  return std::sqrt(static_cast<double>(c[3]) * c[3] + static_cast<double>(c[7]) * c[7] +
                   static_cast<double>(c[11]) * c[11]);
}

// a - b in (-180, 180].
double AngleDifference(double a, double b) { return std::remainder(a - b, 360.0); }

// Yaw and roll over the whole circle, pitch short of the poles (where yaw and roll merge).
std::vector<ViewPose> Grid() {
  std::vector<ViewPose> poses;
  for (double yaw = -170.0; yaw <= 180.0; yaw += 25.0) {
    for (double pitch = -85.0; pitch <= 85.0; pitch += 17.0) {
      for (double roll = -175.0; roll <= 180.0; roll += 35.0) {
        for (double zoom : {0.5, 1.0, 2.5}) poses.push_back({yaw, pitch, roll, zoom});
      }
    }
  }
  return poses;
}

TEST(ViewPose, PoseToCameraToPoseIsTheIdentityOverAGridOfAngles) {
  const std::vector<ViewPose> grid = Grid();
  ASSERT_GT(grid.size(), 1000u);
  for (const CameraLabel25& source : {FrontalLabel(), OffCentreLabel()}) {
    const double source_distance = HeadDistance(source);
    for (const ViewPose& pose : grid) {
      const CameraLabel25 camera = CameraForView(pose, source);
      const ViewPose back = PoseOfCamera(camera);
      // Float labels: 1e-7 of a radian, a few 1e-5 degrees after the poles' amplification.
      EXPECT_NEAR(AngleDifference(back.yaw, pose.yaw), 0.0, 1e-3) << pose.yaw << " " << pose.pitch << " " << pose.roll;
      EXPECT_NEAR(AngleDifference(back.pitch, pose.pitch), 0.0, 1e-3) << pose.yaw << " " << pose.pitch << " " << pose.roll;
      EXPECT_NEAR(AngleDifference(back.roll, pose.roll), 0.0, 1e-3) << pose.yaw << " " << pose.pitch << " " << pose.roll;
      // The zoom is how much nearer the head is than C_s sees it.
      EXPECT_NEAR(source_distance / HeadDistance(camera), pose.zoom, 1e-5 * pose.zoom);
      // The camera keeps the source's intrinsics.
      for (int i = 16; i < 25; ++i) EXPECT_EQ(camera[i], source[i]);
      // In double, without the label's rounding, the angles come back to 1e-9 degrees.
      const ViewPose exact = PoseFromRotation(HeadRotation(pose));
      EXPECT_NEAR(AngleDifference(exact.yaw, pose.yaw), 0.0, 1e-9);
      EXPECT_NEAR(AngleDifference(exact.pitch, pose.pitch), 0.0, 1e-9);
      EXPECT_NEAR(AngleDifference(exact.roll, pose.roll), 0.0, 1e-9);
    }
  }
  // The source pose renders the source camera itself.
  const CameraLabel25 source = OffCentreLabel();
  const CameraLabel25 again = CameraForView(PoseOfCamera(source), source);
  for (int i = 0; i < 25; ++i) EXPECT_NEAR(again[i], source[i], 1e-5) << i;
}

TEST(ViewPose, AboutTheFrontalCameraItIsTheLookAtOrbitOfTheSamePicture) {
  // The head turned by (yaw, pitch, roll) is the camera at yaw, -pitch (below the head when it
  // looks up) and -roll, at distance 2.7 / zoom.
  for (const ViewPose& pose : Grid()) {
    const torch::Tensor ours = OrbitCam2World(pose, kF64);
    const torch::Tensor look_at =
        testing::LookAtOrbit(pose.yaw, -pose.pitch, -pose.roll, kCameraRadius / pose.zoom, {0.0, 0.0, 0.0}, kF64);
    EXPECT_LE((ours - look_at).abs().max().item<double>(), 1e-12)
        << pose.yaw << " " << pose.pitch << " " << pose.roll << " " << pose.zoom;
    // And OrbitCam2World is CameraForView about C_front, not a second conversion.
    const CameraLabel25 label = CameraForView(pose, FrontalLabel());
    const torch::Tensor as_float = OrbitCam2World(pose);
    for (int i = 0; i < 16; ++i) EXPECT_NEAR(label[i], as_float.view({16})[i].item<float>(), 1e-6) << i;
  }
  EXPECT_TRUE(torch::equal(OrbitCam2World({}, kF64), FrontalCam2World(kF64)));
}

TEST(ViewPose, BadPosesAndBadLabelsAreRefused) {
  for (const ViewPose& bad : {ViewPose{0, 0, 0, 0.05}, ViewPose{0, 0, 0, 11.0}, ViewPose{std::nan(""), 0, 0, 1},
                              ViewPose{0, INFINITY, 0, 1}, ViewPose{0, 0, 0, -1}}) {
    EXPECT_THROW(bad.Validate(), InvalidOptions);
    EXPECT_THROW(CameraForView(bad, FrontalLabel()), InvalidOptions);
    EXPECT_THROW(OrbitCam2World(bad), InvalidOptions);
  }
  EXPECT_NO_THROW((ViewPose{0, 90, 0, kMaxZoom}.Validate()));  // Looking straight up is a pose.
  CameraLabel25 sheared = FrontalLabel();
  sheared[1] = 0.3f;
  EXPECT_THROW(CheckCameraLabel(sheared), InvalidInput);
  EXPECT_THROW(PoseOfCamera(sheared), InvalidInput);
  EXPECT_THROW(CameraForView(ViewPose{}, sheared), InvalidInput);
  CameraLabel25 no_focal = FrontalLabel();
  no_focal[16] = 0.0f;
  EXPECT_THROW(CheckCameraLabel(no_focal), InvalidInput);
  CameraLabel25 projective = FrontalLabel();
  projective[14] = 0.5f;
  EXPECT_THROW(CheckCameraLabel(projective), InvalidInput);
  CameraLabel25 nan = FrontalLabel();
  nan[3] = std::nanf("");
  EXPECT_THROW(CheckCameraLabel(nan), InvalidInput);
  EXPECT_NO_THROW(CheckCameraLabel(OffCentreLabel()));
}

// The GL matrix puts a world point where the label's pinhole does (window x = u * width, window
// y = (1 - v) * height), and its depth maps the near and far planes to -1 and +1.
TEST(ViewPose, GlClipFromWorldProjectsLikeTheLabel) {
  for (const CameraLabel25& label : {FrontalLabel(), OffCentreLabel()}) {
    const std::array<float, 16> m = GlClipFromWorld(label, 1.0, 5.0);
    for (const std::array<double, 3>& p : std::vector<std::array<double, 3>>{
             {0.0, 0.0, 0.3}, {0.12, -0.08, 0.1}, {-0.2, 0.15, -0.05}, {0.05, 0.25, -0.3}}) {
      // The label's own pinhole: camera point R^T (p - c), then the normalised intrinsics.
      double cam[3] = {0.0, 0.0, 0.0};
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) cam[i] += label[j * 4 + i] * (p[j] - label[j * 4 + 3]);
      const double u = label[16] * cam[0] / cam[2] + label[17] * cam[1] / cam[2] + label[18];
      const double v = label[20] * cam[1] / cam[2] + label[21];
      double clip[4] = {0.0, 0.0, 0.0, 0.0};
      for (int r = 0; r < 4; ++r)
        clip[r] = m[0 * 4 + r] * p[0] + m[1 * 4 + r] * p[1] + m[2 * 4 + r] * p[2] + m[3 * 4 + r];
      EXPECT_NEAR(clip[3], cam[2], 1e-5);
      EXPECT_NEAR((clip[0] / clip[3] + 1.0) / 2.0, u, 1e-5);
      EXPECT_NEAR((1.0 - clip[1] / clip[3]) / 2.0, v, 1e-5);
      const double depth = clip[2] / clip[3];
      EXPECT_GT(depth, -1.0);
      EXPECT_LT(depth, 1.0);
    }
    // Depth: near maps to -1 and far to +1 along the optical axis.
    const double c[3] = {label[3], label[7], label[11]};
    const double axis[3] = {label[2], label[6], label[10]};  // cam2world's z column: the viewing direction
    for (const auto& [t, expected] : std::vector<std::pair<double, double>>{{1.0, -1.0}, {5.0, 1.0}}) {
      double clip[4] = {0.0, 0.0, 0.0, 0.0};
      for (int r = 0; r < 4; ++r) {
        clip[r] = m[3 * 4 + r];
        for (int j = 0; j < 3; ++j) clip[r] += m[j * 4 + r] * (c[j] + t * axis[j]);
      }
      EXPECT_NEAR(clip[2] / clip[3], expected, 1e-5);
    }
  }
  EXPECT_THROW(GlClipFromWorld(FrontalLabel(), 0.0, 5.0), InvalidOptions);
  EXPECT_THROW(GlClipFromWorld(FrontalLabel(), 3.0, 2.0), InvalidOptions);
}

}  // namespace
}  // namespace avatar::render
