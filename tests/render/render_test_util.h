#pragma once
// Helpers for the render tests: hand-made tri-planes + decoder that encode analytic shapes,
// and checks on render outputs.

#include <gtest/gtest.h>
#include <torch/torch.h>

#include <array>
#include <cmath>

#include "core/model/triplane_decoder.h"
#include "core/render/renderer.h"

namespace avatar::render::testing {

// A look-at camera on a sphere around `target`, in camera terms (pitch > 0: the camera above; roll
// as LookAtCam2World), built without ViewPose: for cameras a pose about the frontal camera cannot
// express (off-origin targets, radii inside the head's box) and as the reference OrbitCam2World is
// checked against. cam2world [4,4].
inline torch::Tensor LookAtOrbit(double yaw, double pitch, double roll, double radius,
                                 const std::array<double, 3>& target = {0.0, 0.0, 0.0},
                                 const torch::TensorOptions& options = torch::kFloat32) {
  const double d = M_PI / 180.0;
  const auto f64 = torch::TensorOptions().dtype(torch::kFloat64);
  const torch::Tensor t = torch::tensor({target[0], target[1], target[2]}, f64).view({1, 3});
  const torch::Tensor dir = torch::tensor(
      {std::sin(yaw * d) * std::cos(pitch * d), std::sin(pitch * d), std::cos(yaw * d) * std::cos(pitch * d)}, f64);
  return LookAtCam2World(t + radius * dir.view({1, 3}), t, torch::full({1}, roll * d, f64))
      .squeeze(0)
      .to(options.dtype().toScalarType());
}

// Plane channels of the analytic scene (all other channels are 0).
inline constexpr int kChannelZ = 0;       // mean over planes = 2 z_n / 3 (z_n = 2 z / box_warp)
inline constexpr int kChannelRadius = 1;  // mean = |p_n|^2 / 3
inline constexpr int kChannelBox = 2;     // 1 on every plane: mean 1 inside the box, < 1 outside

// Planes [1,3,32,G,G] whose texels hold coordinate functions at the texel centres
// (align_corners = false): bilinear interpolation reproduces the linear channel exactly
// and the quadratic one within G^-2 (normalised units).
inline torch::Tensor CoordinatePlanes(int64_t g, torch::ScalarType dtype = torch::kFloat64) {
  const auto opts = torch::TensorOptions().dtype(dtype);
  const torch::Tensor centres = (torch::arange(g, opts) + 0.5) * (2.0 / static_cast<double>(g)) - 1.0;
  const torch::Tensor row = centres.view({g, 1}).expand({g, g});  // grid y (v)
  const torch::Tensor col = centres.view({1, g}).expand({g, g});  // grid x (u)
  torch::Tensor planes = torch::zeros({1, 3, kDecoderInputChannels, g, g}, opts);
  // Plane 1 (XZ): v = z. Plane 2 (ZY): u = z.
  planes[0][1][kChannelZ].copy_(row);
  planes[0][2][kChannelZ].copy_(col);
  for (int k = 0; k < 3; ++k) {
    planes[0][k][kChannelRadius].copy_(0.5 * (row * row + col * col));
    planes[0][k][kChannelBox].fill_(1.0);
  }
  return planes;
}

// Raw density that gives softplus(raw - 1) = sigma.
// softplus^-1(s) = log(expm1(s)) = s + log(-expm1(-s)), the second form without overflow.
inline double RawForSigma(double sigma) { return 1.0 + sigma + std::log(-std::expm1(-sigma)); }

// Raw density outside the shape (sigma = softplus(-31) ~ 3e-14).
inline constexpr double kRawOutside = -30.0;

enum class Shape { kSlab, kSphere };

// A decoder (float64) for CoordinatePlanes: density sigma inside the shape and ~0 outside
// the shape or the box; feature channel 0 = `colour` everywhere, other channels 0.5.
// Slab: |z| < half (world). Sphere: |p| < half. Steps are built from pairs of hidden
// softplus units sp(k t + 0.5) - sp(k t - 0.5), symmetric around t = 0, width ~ 40 / k.
inline TriplaneDecoder ShapeDecoder(Shape shape, double half, double sigma, double colour = 0.8,
                                    double box_warp = 1.0) {
  TriplaneDecoder decoder;
  decoder->to(torch::kFloat64);
  const auto opts = torch::TensorOptions().dtype(torch::kFloat64);
  torch::Tensor w1 = torch::zeros({kDecoderHiddenChannels, kDecoderInputChannels}, opts);
  torch::Tensor b1 = torch::zeros({kDecoderHiddenChannels}, opts);
  torch::Tensor w2 = torch::zeros({1 + kDecoderFeatureChannels, kDecoderHiddenChannels}, opts);
  torch::Tensor b2 = torch::zeros({1 + kDecoderFeatureChannels}, opts);
  const double k = 1e6;
  const double r_in = RawForSigma(sigma), r_out = kRawOutside, box_penalty = 100.0;
  const double half_n = half * 2.0 / box_warp;
  // A step unit pair on feature `channel`: t = gain * f + offset; contributes `height` * step(t).
  int unit = 0;
  auto add_step = [&](int channel, double gain, double offset, double height) {
    for (int s = 0; s < 2; ++s) {
      w1[unit][channel] = k * gain;
      b1[unit] = k * offset + (s == 0 ? 0.5 : -0.5);
      w2[0][unit] = s == 0 ? height : -height;
      ++unit;
    }
  };
  if (shape == Shape::kSlab) {
    const double a = 2.0 * half_n / 3.0;            // |f0| < a  <=>  |z| < half
    add_step(kChannelZ, 1.0, a, r_in - r_out);      // f0 > -a
    add_step(kChannelZ, 1.0, -a, -(r_in - r_out));  // minus (f0 > a)
  } else {
    add_step(kChannelRadius, -1.0, half_n * half_n / 3.0, r_in - r_out);  // |p_n|^2 / 3 < half_n^2 / 3
  }
  add_step(kChannelBox, 1.0, -0.9, box_penalty);  // inside the box in all three planes
  b2[0] = r_out - box_penalty;
  const double logit_colour = std::log((colour + 0.001) / (1.001 - colour));
  b2[1] = logit_colour;
  decoder->SetEffectiveWeights(w1, b1, w2, b2);
  return decoder;
}

inline PointDecoder Decode(TriplaneDecoder decoder) {
  return [decoder](const torch::Tensor& f) mutable { return decoder->forward(f); };
}

// Rays from `origin` through targets [N,3]: origins, unit directions [1,N,3].
inline std::pair<torch::Tensor, torch::Tensor> RaysThrough(const torch::Tensor& origin, const torch::Tensor& targets) {
  const torch::Tensor d = targets - origin.view({1, 3});
  return {origin.view({1, 1, 3}).expand({1, targets.size(0), 3}).contiguous(), (d / d.norm(2, -1, true)).unsqueeze(0)};
}

// Every output finite; features in [-1.002, 1.002], opacity in [0,1], depth in [near, far].
inline void ExpectValidOutputs(const RenderOutput& out, const RenderOptions& options, const std::string& what) {
  SCOPED_TRACE(what);
  const double slack = 1e-6;
  ASSERT_TRUE(torch::isfinite(out.features).all().item<bool>());
  ASSERT_TRUE(torch::isfinite(out.opacity).all().item<bool>());
  ASSERT_TRUE(torch::isfinite(out.depth).all().item<bool>());
  EXPECT_GE(out.features.min().item<double>(), -1.002 - slack);
  EXPECT_LE(out.features.max().item<double>(), 1.002 + slack);
  EXPECT_GE(out.opacity.min().item<double>(), 0.0);
  EXPECT_LE(out.opacity.max().item<double>(), 1.0);
  EXPECT_GE(out.depth.min().item<double>(), options.near - slack);
  EXPECT_LE(out.depth.max().item<double>(), options.far + slack);
  if (out.weights.defined()) {
    ASSERT_TRUE(torch::isfinite(out.weights).all().item<bool>());
    EXPECT_GE(out.weights.min().item<double>(), 0.0);
    EXPECT_LE(out.weights.sum(-1).max().item<double>(), 1.0 + slack);
  }
}

}  // namespace avatar::render::testing
