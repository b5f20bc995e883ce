#include "core/render/view_pose.h"

#include <algorithm>
#include <cmath>

#include "core/util/error.h"

namespace avatar::render {
namespace {

constexpr double kDegrees = 180.0 / 3.14159265358979323846;

Matrix3 Multiply(const Matrix3& a, const Matrix3& b) {
  Matrix3 m{};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      double sum = 0.0;
      for (int k = 0; k < 3; ++k) sum += a[i * 3 + k] * b[k * 3 + j];
      m[i * 3 + j] = sum;
    }
  }
  return m;
}

Matrix3 Transpose(const Matrix3& a) {
  return {a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8]};
}

std::array<double, 3> Apply(const Matrix3& a, const std::array<double, 3>& v) {
  return {a[0] * v[0] + a[1] * v[1] + a[2] * v[2], a[3] * v[0] + a[4] * v[1] + a[5] * v[2],
          a[6] * v[0] + a[7] * v[1] + a[8] * v[2]};
}

Matrix3 RotX(double a) {
  const double c = std::cos(a), s = std::sin(a);
  return {1, 0, 0, 0, c, -s, 0, s, c};
}
Matrix3 RotY(double a) {
  const double c = std::cos(a), s = std::sin(a);
  return {c, 0, s, 0, 1, 0, -s, 0, c};
}
Matrix3 RotZ(double a) {
  const double c = std::cos(a), s = std::sin(a);
  return {c, -s, 0, s, c, 0, 0, 0, 1};
}

// The 3x3 rotation block of a row-major 4x4.
template <typename T>
Matrix3 RotationOf(const T& m) {
  Matrix3 r{};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) r[i * 3 + j] = static_cast<double>(m[i * 4 + j]);
  }
  return r;
}

// World->camera rotation of C_front.
Matrix3 FrontalWorldToCam() { return Transpose(RotationOf(kFrontalCam2World)); }

}  // namespace

void ViewPose::Validate() const {
  AVATAR_CHECK_OPTION(std::isfinite(yaw) && std::isfinite(pitch) && std::isfinite(roll) && std::isfinite(zoom) &&
                      zoom >= kMinZoom && zoom <= kMaxZoom)
      << "view pose must be finite with zoom in " << kMinZoom << ".." << kMaxZoom << ", got yaw " << yaw
      << ", pitch " << pitch << ", roll " << roll << ", zoom " << zoom;
}

Matrix3 HeadRotation(const ViewPose& pose) {
  // World: y up, the face looks towards +z at the frontal camera, image right = +x. A positive
  // standard rotation about y moves the nose to image right, about x moves it down, about z turns
  // the face counter-clockwise: our positive angles are the opposites. Yaw, then pitch about the
  // world x axis, then roll about the viewing axis is an orbit camera (azimuth, elevation, roll).
  return Multiply(RotZ(-pose.roll / kDegrees), Multiply(RotX(-pose.pitch / kDegrees), RotY(-pose.yaw / kDegrees)));
}

ViewPose PoseFromRotation(const Matrix3& r) {
  // r = Rz(c) Rx(b) Ry(a): r(2,1) = sin b, r(2,0) = -cos b sin a, r(2,2) = cos b cos a,
  // r(0,1) = -sin c cos b, r(1,1) = cos c cos b.
  const double b = std::asin(std::clamp(r[7], -1.0, 1.0));
  const double a = std::atan2(-r[6], r[8]);
  const double c = std::atan2(-r[1], r[4]);
  ViewPose p;
  p.yaw = -a * kDegrees;
  p.pitch = -b * kDegrees;
  p.roll = -c * kDegrees;
  return p;
}

void CheckCameraLabel(const CameraLabel25& label) {
  for (float v : label) AVATAR_CHECK_INPUT(std::isfinite(v)) << "camera label has non-finite values";
  const Matrix3 r = RotationOf(label);
  const Matrix3 should_be_eye = Multiply(Transpose(r), r);
  double worst = 0.0;
  for (int i = 0; i < 9; ++i) worst = std::max(worst, std::abs(should_be_eye[i] - (i % 4 == 0 ? 1.0 : 0.0)));
  AVATAR_CHECK_INPUT(worst < 1e-3) << "camera label: the cam2world rotation is not orthonormal";
  AVATAR_CHECK_INPUT(std::abs(label[12]) + std::abs(label[13]) + std::abs(label[14]) < 1e-4 &&
                     std::abs(label[15] - 1.0f) < 1e-4)
      << "camera label: the last cam2world row must be (0,0,0,1)";
  AVATAR_CHECK_INPUT(label[16] > 0 && label[20] > 0 && std::abs(label[24] - 1.0f) < 1e-4)
      << "camera label: invalid intrinsics";
}

std::array<double, 16> ViewCam2World(const ViewPose& view, const std::array<double, 16>& source_cam2world) {
  view.Validate();
  const Matrix3 source_world_to_cam = Transpose(RotationOf(source_cam2world));
  const std::array<double, 3> source_centre = {source_cam2world[3], source_cam2world[7], source_cam2world[11]};
  // Where C_s sees the world origin (the head's centre), in its camera coordinates.
  const std::array<double, 3> head =
      Apply(source_world_to_cam, {-source_centre[0], -source_centre[1], -source_centre[2]});
  const Matrix3 world_to_cam = Multiply(FrontalWorldToCam(), HeadRotation(view));
  const Matrix3 cam_to_world = Transpose(world_to_cam);
  const std::array<double, 3> centre = Apply(cam_to_world, {head[0] / view.zoom, head[1] / view.zoom, head[2] / view.zoom});
  std::array<double, 16> m{};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m[i * 4 + j] = cam_to_world[i * 3 + j];
    m[i * 4 + 3] = -centre[i];
  }
  m[15] = 1.0;
  return m;
}

CameraLabel25 CameraForView(const ViewPose& view, const CameraLabel25& source_camera) {
  view.Validate();
  CheckCameraLabel(source_camera);
  std::array<double, 16> source{};
  for (int i = 0; i < 16; ++i) source[i] = source_camera[i];
  const std::array<double, 16> m = ViewCam2World(view, source);
  CameraLabel25 label{};
  for (int i = 0; i < 16; ++i) label[i] = static_cast<float>(m[i]);
  std::copy(source_camera.begin() + 16, source_camera.end(), label.begin() + 16);
  return label;
}

ViewPose PoseOfCamera(const CameraLabel25& camera) {
  CheckCameraLabel(camera);
  // world_to_cam = R_front * R_head: the head turned in front of the frontal camera.
  return PoseFromRotation(Multiply(Transpose(FrontalWorldToCam()), Transpose(RotationOf(camera))));
}

std::array<float, 16> GlClipFromWorld(const CameraLabel25& camera, double near_plane, double far_plane) {
  CheckCameraLabel(camera);
  AVATAR_CHECK_OPTION(near_plane > 0.0 && far_plane > near_plane)
      << "GL depth range needs 0 < near < far, got " << near_plane << " and " << far_plane;
  // World -> camera: x_c = R^T (p - c), R the cam2world rotation and c its centre.
  double view[4][4] = {};
  for (int i = 0; i < 3; ++i) {
    double t = 0.0;
    for (int j = 0; j < 3; ++j) {
      view[i][j] = camera[j * 4 + i];
      t -= camera[j * 4 + i] * camera[j * 4 + 3];
    }
    view[i][3] = t;
  }
  view[3][3] = 1.0;
  // Camera -> clip. Normalised pixel u = fx x/z + s y/z + cx, v = fy y/z + cy; the window's x is
  // 2u - 1 in NDC and its y (up) is 1 - 2v.
  const double fx = camera[16], s = camera[17], cx = camera[18], fy = camera[20], cy = camera[21];
  const double a = (far_plane + near_plane) / (far_plane - near_plane);
  const double b = -2.0 * far_plane * near_plane / (far_plane - near_plane);
  const double proj[4][4] = {{2.0 * fx, 2.0 * s, 2.0 * cx - 1.0, 0.0},
                             {0.0, -2.0 * fy, 1.0 - 2.0 * cy, 0.0},
                             {0.0, 0.0, a, b},
                             {0.0, 0.0, 1.0, 0.0}};
  std::array<float, 16> out{};
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) {
      double v = 0.0;
      for (int k = 0; k < 4; ++k) v += proj[r][k] * view[k][c];
      out[c * 4 + r] = static_cast<float>(v);  // column-major
    }
  }
  return out;
}

}  // namespace avatar::render
