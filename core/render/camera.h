#pragma once
// Cameras in GOHA's (EG3D's) conventions.
//
// World: y up; the head sits in the box [-0.5,0.5]^3 around the origin, facing +z.
// Camera: OpenCV axes (x right, y down, z forward); cam2world is a 4x4 matrix whose
// columns 0..2 are those axes in world coordinates and column 3 the camera centre.
// Intrinsics are normalised by the image size: pixel (u,v) in [0,1]^2 with
// u = fx * x/z + skew * y/z + cx, v = fy * y/z + cy.
// Label: the 25 floats of a dataset.json entry = row-major cam2world (16) + row-major K (9).
//
// Every function works on any device and floating dtype, and keeps the input's.

#include <array>

#include <torch/torch.h>

namespace avatar::render {

// Normalised focal length of the published camera (fx = fy; horizontal FOV 13.37 degrees).
inline constexpr double kFocal = 4.2647;
// Normalised principal point (cx = cy).
inline constexpr double kPrincipalPoint = 0.5;
// Distance from the camera centre to the look-at point.
inline constexpr double kCameraRadius = 2.7;
// Floats in one camera label.
inline constexpr int64_t kCameraLabelSize = 25;

// C_front: the fixed frontal camera (row-major cam2world): centre (0,0,2.7), looking at the
// origin along -z, camera y pointing down the world y axis.
inline constexpr std::array<double, 16> kFrontalCam2World = {1.0, 0.0,  0.0,  0.0,            //
                                                             0.0, -1.0, 0.0,  0.0,            //
                                                             0.0, 0.0,  -1.0, kCameraRadius,  //
                                                             0.0, 0.0,  0.0,  1.0};

// A batch of cameras.
struct Cameras {
  torch::Tensor cam2world;   // [B,4,4]
  torch::Tensor intrinsics;  // [B,3,3] normalised by image size

  int64_t batch() const { return cam2world.size(0); }
};

// The published intrinsics (fx = fy = kFocal, cx = cy = kPrincipalPoint, no skew). [3,3]
torch::Tensor DefaultIntrinsics(const torch::TensorOptions& options = torch::kFloat32);
// kFrontalCam2World as a tensor. [4,4]
torch::Tensor FrontalCam2World(const torch::TensorOptions& options = torch::kFloat32);
// `batch` copies of the frontal camera with the default intrinsics.
Cameras FrontalCameras(int64_t batch = 1, const torch::TensorOptions& options = torch::kFloat32);

// cam2world [B,4,4] + intrinsics [B,3,3] -> labels [B,25]. Throws InvalidInput on bad shapes.
torch::Tensor LabelsFromCameras(const Cameras& cameras);
// labels [B,25] or [25] -> cameras (B = 1 for a single label). Throws InvalidInput on bad shapes
// or a label whose last cam2world row is not (0,0,0,1) or whose K[2] row is not (0,0,1).
Cameras CamerasFromLabels(const torch::Tensor& labels);

// Checks shapes and dtypes of a camera batch; throws InvalidInput naming the problem.
void CheckCameras(const Cameras& cameras);

// Look-at cam2world: eye [B,3], target [B,3], roll [B] radians (rotation about the viewing
// axis; positive roll turns the camera's right axis towards its down axis), world up +y.
// Returns [B,4,4]. Throws InvalidInput when eye == target or the view is vertical.
torch::Tensor LookAtCam2World(const torch::Tensor& eye, const torch::Tensor& target, const torch::Tensor& roll);

// A camera on a sphere around a target.
struct OrbitPose {
  // Rotation about the world y axis in degrees; positive moves the camera towards +x.
  double yaw = 0.0;
  // Elevation in degrees, in (-90, 90); positive moves the camera up (it looks down).
  double pitch = 0.0;
  // Rotation about the viewing axis in degrees (see LookAtCam2World).
  double roll = 0.0;
  // Distance from the target.
  double radius = kCameraRadius;
  // Look-at point, x (world units).
  double target_x = 0.0;
  // Look-at point, y.
  double target_y = 0.0;
  // Look-at point, z.
  double target_z = 0.0;

  template <typename V>
  void Visit(V&& v) {
    v("yaw", yaw, "Camera yaw in degrees (positive: camera moves towards +x)");
    v("pitch", pitch, "Camera pitch in degrees, -90..90 exclusive (positive: camera above)");
    v("roll", roll, "Camera roll about the viewing axis in degrees");
    v("radius", radius, "Distance from the camera to the look-at point");
    v("target_x", target_x, "Look-at point x");
    v("target_y", target_y, "Look-at point y");
    v("target_z", target_z, "Look-at point z");
  }
  // Throws InvalidOptions for non-finite values, radius <= 0 or |pitch| >= 90.
  void Validate() const;
};

// The cam2world of an orbit pose: eye = target + radius * (sin(yaw)cos(pitch), sin(pitch),
// cos(yaw)cos(pitch)). OrbitCam2World({}) equals FrontalCam2World(). [4,4]
torch::Tensor OrbitCam2World(const OrbitPose& pose, const torch::TensorOptions& options = torch::kFloat32);

// Projects world points [B,P,3] into each camera: returns [B,P,3] = (u, v, z) with (u,v) the
// normalised image position and z the depth along the camera's optical axis.
torch::Tensor ProjectPoints(const torch::Tensor& points, const Cameras& cameras);

}  // namespace avatar::render
