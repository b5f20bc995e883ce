#pragma once
// Helpers of the morphable tests: the installed topology and a synthetic model with smooth
// random bases (so that math tests do not depend on the committed model).

#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "core/io/data_paths.h"
#include "core/morphable/morphable.h"

namespace avatar::morphable::testing {

// The topology of the installed asset; a missing asset fails the test with the setup hint.
inline const Topology& InstalledTopology() { return LoadTopology(DataPaths::Resolve()); }

// Smooth random displacement field: low-order polynomial in the canonical coordinates.
inline std::vector<float> SmoothField(const Topology& topo, std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  double c[3][10];
  for (auto& row : c) {
    for (double& v : row) v = n(rng);
  }
  std::vector<float> out(topo.canonical_cm.size() * 3);
  double norm = 0.0;
  for (size_t i = 0; i < topo.canonical_cm.size(); ++i) {
    const double x = topo.canonical_cm[i].x / 8.0, y = topo.canonical_cm[i].y / 8.0, z = topo.canonical_cm[i].z / 8.0;
    const double terms[10] = {1, x, y, z, x * x, y * y, z * z, x * y, y * z, std::sin(3 * y)};
    for (int d = 0; d < 3; ++d) {
      double v = 0.0;
      for (int k = 0; k < 10; ++k) v += c[d][k] * terms[k];
      out[3 * i + d] = static_cast<float>(v);
      norm += v * v;
    }
  }
  for (float& v : out) v = static_cast<float>(v / std::sqrt(norm));
  return out;
}

// Mean = canonical mesh in model units; unit-norm smooth bases (column-major per component).
inline MorphableModel SyntheticModel(const Topology& topo, int kid, int kexp, unsigned seed = 7) {
  std::mt19937 rng(seed);
  const size_t n = topo.canonical_cm.size() * 3;
  std::vector<float> mean(n);
  for (size_t i = 0; i < topo.canonical_cm.size(); ++i) {
    mean[3 * i] = static_cast<float>(topo.canonical_cm[i].x * kUnitsPerCm);
    mean[3 * i + 1] = static_cast<float>(topo.canonical_cm[i].y * kUnitsPerCm);
    mean[3 * i + 2] = static_cast<float>(topo.canonical_cm[i].z * kUnitsPerCm);
  }
  auto basis = [&](int k, std::vector<float>& b, std::vector<float>& s, double std0) {
    b.assign(n * k, 0.0f);
    for (int c = 0; c < k; ++c) {
      const std::vector<float> f = SmoothField(topo, rng);
      for (size_t r = 0; r < n; ++r) b[r * k + c] = f[r];
      s.push_back(static_cast<float>(std0 / (1.0 + 0.3 * c)));
    }
  };
  std::vector<float> bid, sid, bexp, sexp;
  basis(kid, bid, sid, 0.08);
  basis(kexp, bexp, sexp, 0.05);
  MorphableModel model(topo, mean, bid, sid, bexp, sexp);
  std::vector<NamedControl> controls;
  for (size_t i = 0; i < RequiredControlNames().size(); ++i) {
    Beta d(kexp, 0.0f);
    if (kexp > 0) d[i % kexp] = sexp[i % kexp];
    controls.push_back({RequiredControlNames()[i], RequiredControlNames()[i], "synthetic", d});
  }
  model.SetControls(controls);
  return model;
}

// Landmarks of world vertices seen through `camera` in an image of `size`, with the facemesh
// depth convention (pixels, relative to the mean) and Gaussian pixel noise.
inline face::Landmarks ProjectLandmarks(const std::vector<cv::Point3f>& world, const CameraLabel& camera, cv::Size size,
                                        double noise_px, std::mt19937& rng) {
  const PinholeCamera cam = PinholeCamera::FromLabel(camera);
  std::normal_distribution<double> n(0.0, noise_px);
  face::Landmarks lm;
  lm.confidence = 1.0f;
  std::vector<cv::Vec3d> c(world.size());
  double zmean = 0.0;
  for (size_t i = 0; i < world.size(); ++i) {
    c[i] = cam.ToCamera(cv::Vec3d(world[i].x, world[i].y, world[i].z));
    zmean += c[i][2];
  }
  zmean /= static_cast<double>(world.size());
  const double f = cam.k_normalised(0, 0) * size.width;
  for (size_t i = 0; i < world.size(); ++i) {
    const cv::Point2d px = cam.ToPixel(c[i], size);
    lm.points.emplace_back(static_cast<float>(px.x + n(rng)), static_cast<float>(px.y + n(rng)),
                           static_cast<float>(f * (c[i][2] - zmean) / zmean + n(rng)));
  }
  return lm;
}

// A camera label at radius 2.7 orbiting the origin, in camera terms: `pitch` > 0 puts the camera
// above, `roll` > 0 turns its right axis towards its down axis (the head's pose has both negated).
inline CameraLabel OrbitLabel(double yaw, double pitch, double roll) {
  render::ViewPose pose;
  pose.yaw = yaw;
  pose.pitch = -pitch;
  pose.roll = -roll;
  const torch::Tensor c2w = render::OrbitCam2World(pose).unsqueeze(0);
  render::Cameras cams{c2w, render::DefaultIntrinsics().unsqueeze(0)};
  return LabelFromTensor(render::LabelsFromCameras(cams));
}

}  // namespace avatar::morphable::testing
