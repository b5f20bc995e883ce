// The neural source's camera mapping: turning the head in front of the frontal camera (our
// ViewPose) must look exactly like orbiting the session's camera around a still head.
#include <gtest/gtest.h>

#include "core/morphable/camera_label.h"
#include "core/pipeline/morphable_preview.h"
#include "core/pipeline/session_source.h"
#include "core/render/camera.h"

namespace avatar {
namespace {

morphable::PinholeCamera OrbitCamera(const View& v) {
  render::OrbitPose pose;
  pose.yaw = v.yaw;
  pose.pitch = v.pitch;
  pose.roll = v.roll;
  pose.radius = v.radius;
  render::Cameras cams{render::OrbitCam2World(pose).unsqueeze(0), render::DefaultIntrinsics().unsqueeze(0)};
  return morphable::PinholeCamera::FromLabel(morphable::LabelFromTensor(render::LabelsFromCameras(cams)));
}

TEST(SessionSource, ViewPoseMatchesTheSessionsOrbitCamera) {
  const morphable::PinholeCamera front = morphable::PinholeCamera::FromLabel(morphable::FrontalLabel());
  const std::vector<cv::Vec3d> head = {{0, 0, 0.12}, {0.08, 0.05, 0.05}, {-0.07, -0.09, 0.04}, {0.02, 0.1, -0.1}};
  const cv::Size size(512, 512);
  for (const ViewPose pose : {ViewPose{25, 0, 0, 1}, ViewPose{0, 15, 0, 1}, ViewPose{0, 0, 20, 1},
                              ViewPose{-30, -10, 8, 1}, ViewPose{10, 5, 0, 1.5}}) {
    const morphable::PinholeCamera orbit = OrbitCamera(SessionFrameSource::ToView(pose));
    const cv::Matx33d r = HeadRotation(pose);
    for (const cv::Vec3d& p : head) {
      // Zoom: the camera moves to 2.7 / zoom along its axis in both conventions.
      morphable::PinholeCamera near = front;
      near.centre = front.centre / pose.zoom;
      const cv::Point2d a = near.ToPixel(near.ToCamera(r * p), size);
      const cv::Point2d b = orbit.ToPixel(orbit.ToCamera(p), size);
      EXPECT_NEAR(a.x, b.x, 0.05) << pose.yaw << " " << pose.pitch << " " << pose.roll;
      EXPECT_NEAR(a.y, b.y, 0.05) << pose.yaw << " " << pose.pitch << " " << pose.roll;
    }
  }
}

TEST(SessionSource, RandomWeightsAreLabelledAsNotAResult) {
  EXPECT_NE(std::string(kRandomWeightsLabel).find("RANDOM"), std::string::npos);
  EXPECT_NE(std::string(kRandomWeightsLabel).find("not a result"), std::string::npos);
}

}  // namespace
}  // namespace avatar
