#pragma once
// The one pose type of the project and the one conversion from a pose to a camera.
//
// A ViewPose says how the head is seen: turned (yaw), tilted (pitch) and rolled relative to the
// frontal view, and magnified (zoom). Turning the head in front of a still camera and orbiting the
// camera about the still head give the same picture, so the same four numbers describe a
// driver's head pose, the studio's orbit drag, an export's turntable and the `render` command's
// camera. The pipeline, the studio and the CLI all pass this type; CameraForView (and
// OrbitCam2World in camera.h, which is CameraForView about the frontal camera) turn it into the
// camera that renders it.
//
// Plain C++ (no LibTorch, no OpenCV), so every header can use it. Conventions: core/render/camera.h.

#include <array>

namespace avatar::render {

// Normalised focal length of the published camera (fx = fy; horizontal FOV 13.37 degrees).
inline constexpr double kFocal = 4.2647;
// Normalised principal point (cx = cy).
inline constexpr double kPrincipalPoint = 0.5;
// Distance from the camera centre to the look-at point.
inline constexpr double kCameraRadius = 2.7;

// C_front: the fixed frontal camera (row-major cam2world): centre (0,0,2.7), looking at the
// origin along -z, camera y pointing down the world y axis.
inline constexpr std::array<double, 16> kFrontalCam2World = {1.0, 0.0,  0.0,  0.0,            //
                                                             0.0, -1.0, 0.0,  0.0,            //
                                                             0.0, 0.0,  -1.0, kCameraRadius,  //
                                                             0.0, 0.0,  0.0,  1.0};

// Zoom range every pose accepts.
inline constexpr double kMinZoom = 0.1;
inline constexpr double kMaxZoom = 10.0;

struct ViewPose {
  double yaw = 0.0;    // Degrees; > 0 turns the head to the image's left (the camera moves towards +x).
  double pitch = 0.0;  // Degrees; > 0 tilts the head up (the camera moves below it and looks up).
  double roll = 0.0;   // Degrees; > 0 rolls the head clockwise in the image.
  double zoom = 1.0;   // Magnification; 1 = the default framing (about C_front: distance kCameraRadius).

  bool operator==(const ViewPose& o) const {
    return yaw == o.yaw && pitch == o.pitch && roll == o.roll && zoom == o.zoom;
  }
  bool operator!=(const ViewPose& o) const { return !(*this == o); }
  // Throws InvalidOptions for non-finite angles or a zoom outside kMinZoom..kMaxZoom.
  void Validate() const;
};

// Row-major 3x3 matrix.
using Matrix3 = std::array<double, 9>;
// An EG3D camera label: row-major cam2world 4x4 + row-major normalised intrinsics 3x3.
using CameraLabel25 = std::array<float, 25>;

// Head rotation of a pose, as a matrix applied to world points (about the origin): yaw first
// (> 0: the nose towards the image's left), then pitch about the world x axis (> 0: up), then
// roll about the viewing axis (> 0: clockwise in the image). Zoom is ignored.
Matrix3 HeadRotation(const ViewPose& pose);
// Inverse of HeadRotation for the angles (zoom = 1). Angles in (-180, 180], pitch in [-90, 90].
ViewPose PoseFromRotation(const Matrix3& rotation);

// Throws InvalidInput unless `label` is a rigid camera: finite, orthonormal cam2world rotation,
// last cam2world row (0,0,0,1), intrinsics with fx, fy > 0 and K[2][2] = 1.
void CheckCameraLabel(const CameraLabel25& label);

// THE pose conversion: the cam2world (row-major 4x4) that shows the still head of a portrait
// photographed by `source_cam2world` (C_s) at pose `view`. Its rotation is the frontal camera's
// turned by HeadRotation(view); the head's origin stays where C_s sees it (C_s's camera-space
// translation divided by the zoom, so the head grows in place). About C_front this is a camera
// on a sphere of radius kCameraRadius / zoom around the origin. Throws InvalidOptions for a bad
// pose (ViewPose::Validate).
std::array<double, 16> ViewCam2World(const ViewPose& view, const std::array<double, 16>& source_cam2world);

// ViewCam2World on labels, with the intrinsics of C_s. So CameraForView(PoseOfCamera(C_s), C_s)
// is C_s itself: the source view lines up with the photo, and every other view turns about the
// head from there. Throws InvalidOptions (bad pose), InvalidInput (CheckCameraLabel).
CameraLabel25 CameraForView(const ViewPose& view, const CameraLabel25& source_camera);

// The pose a camera sees: its world->camera rotation relative to the frontal camera's (zoom 1).
// PoseOfCamera(CameraForView(p, any C_s)) has p's angles. Throws InvalidInput (CheckCameraLabel).
ViewPose PoseOfCamera(const CameraLabel25& camera);

// The OpenGL clip-space matrix (column-major, as glUniformMatrix4fv takes it with transpose
// false) of `camera` for a viewport showing the whole image: a world point p lands at the
// window position (u * width, (1 - v) * height) where (u, v) are the label's normalised pixel
// coordinates of p (x right, y down; pixel i covers [i, i+1)), so a GL frame lines up pixel for
// pixel with the CPU renderer's. Depth maps [near_plane, far_plane] (camera z) to [-1, 1].
// Throws InvalidInput (CheckCameraLabel) and InvalidOptions unless 0 < near_plane < far_plane.
std::array<float, 16> GlClipFromWorld(const CameraLabel25& camera, double near_plane, double far_plane);

}  // namespace avatar::render
