#include "core/pipeline/frame_source.h"

#include <algorithm>
#include <cmath>

#include "core/morphable/camera_label.h"
#include "core/pipeline/portrait_preview.h"
#include "core/util/error.h"

namespace avatar {
namespace {

constexpr double kDegrees = 180.0 / 3.14159265358979323846;

cv::Matx33d RotX(double a) {
  const double c = std::cos(a), s = std::sin(a);
  return {1, 0, 0, 0, c, -s, 0, s, c};
}
cv::Matx33d RotY(double a) {
  const double c = std::cos(a), s = std::sin(a);
  return {c, 0, s, 0, 1, 0, -s, 0, c};
}
cv::Matx33d RotZ(double a) {
  const double c = std::cos(a), s = std::sin(a);
  return {c, -s, 0, s, c, 0, 0, 0, 1};
}

// World->camera rotation of the frontal camera C_front.
const cv::Matx33d& FrontalRotation() {
  static const cv::Matx33d r = morphable::PinholeCamera::FromLabel(morphable::FrontalLabel()).world_to_cam;
  return r;
}

morphable::PinholeCamera Decode(const CameraLabel25& label) {
  morphable::CameraLabel l;
  std::copy(label.begin(), label.end(), l.begin());
  return morphable::PinholeCamera::FromLabel(l);
}

}  // namespace

cv::Matx33d HeadRotation(const ViewPose& pose) {
  // World: y up, the face looks towards +z at the frontal camera, image right = +x. A
  // positive standard rotation about y moves the nose to image right, about x moves it
  // down, about z turns the face counter-clockwise: our positive angles are the opposites.
  // Order: yaw first, then pitch about the world x axis, then roll about the viewing axis,
  // which is exactly an orbit camera (azimuth, elevation, roll) around a still head.
  return RotZ(-pose.roll / kDegrees) * RotX(-pose.pitch / kDegrees) * RotY(-pose.yaw / kDegrees);
}

ViewPose PoseFromRotation(const cv::Matx33d& r) {
  // r = Rz(c) Rx(b) Ry(a): r(2,1) = sin b, r(2,0) = -cos b sin a, r(2,2) = cos b cos a,
  // r(0,1) = -sin c cos b, r(1,1) = cos c cos b.
  const double b = std::asin(std::clamp(r(2, 1), -1.0, 1.0));
  const double a = std::atan2(-r(2, 0), r(2, 2));
  const double c = std::atan2(-r(0, 1), r(1, 1));
  ViewPose p;
  p.yaw = -a * kDegrees;
  p.pitch = -b * kDegrees;
  p.roll = -c * kDegrees;
  return p;
}

ViewPose PoseOfCamera(const CameraLabel25& camera) {
  // world_to_cam = R_front * R_head: the head turned in front of the frontal camera.
  return PoseFromRotation(FrontalRotation().t() * Decode(camera).world_to_cam);
}

CameraLabel25 CameraForView(const ViewPose& view, const CameraLabel25& source_camera) {
  AVATAR_CHECK_OPTION(std::isfinite(view.yaw) && std::isfinite(view.pitch) && std::isfinite(view.roll) &&
                      std::isfinite(view.zoom) && view.zoom >= 0.1 && view.zoom <= 10.0)
      << "view pose must be finite with zoom in 0.1..10";
  const morphable::PinholeCamera source = Decode(source_camera);
  // Where C_s sees the world origin (the head's centre), in its camera coordinates.
  const cv::Vec3d head = source.world_to_cam * (-source.centre);
  const cv::Matx33d world_to_cam = FrontalRotation() * HeadRotation(view);
  const cv::Vec3d centre = -(world_to_cam.t() * (head / view.zoom));
  CameraLabel25 label{};
  const cv::Matx33d cam_to_world = world_to_cam.t();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) label[i * 4 + j] = static_cast<float>(cam_to_world(i, j));
    label[i * 4 + 3] = static_cast<float>(centre[i]);
  }
  label[15] = 1.0f;
  std::copy(source_camera.begin() + 16, source_camera.end(), label.begin() + 16);
  return label;
}

void ValidateFrameSize(int width, int height) {
  AVATAR_CHECK_OPTION(width >= 16 && width <= 4096 && height >= 16 && height <= 4096)
      << "frame size must be within 16..4096 pixels, got " << width << "x" << height;
}

PortraitFrameSource::PortraitFrameSource(cv::Mat bgr) : portrait_(std::move(bgr)) {
  AVATAR_CHECK_INPUT(!portrait_.empty() && portrait_.type() == CV_8UC3) << "the portrait must be a BGR8 image";
}

std::string PortraitFrameSource::Label() const { return "Portrait only (no 3D avatar yet)"; }

RenderedFrame PortraitFrameSource::Render(const FrameRequest& request, RunContext& ctx) const {
  ValidateFrameSize(request.width, request.height);
  ctx.ThrowIfCancelled();
  RenderedFrame frame;
  cv::Rect placed;
  frame.bgr = LetterboxImage(portrait_, request.width, request.height, &placed);
  frame.alpha = cv::Mat(request.height, request.width, CV_8UC1, cv::Scalar(0));
  frame.alpha(placed).setTo(255);
  return frame;
}

}  // namespace avatar
