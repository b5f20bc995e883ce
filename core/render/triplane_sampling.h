#pragma once
// Tri-plane feature lookup (EG3D conventions as in GOHA's release).
//
// Planes [B,3,C,H,W]. A world point p is scaled to q = p * 2 / box_warp, so the box
// [-box_warp/2, box_warp/2]^3 maps to [-1,1]^3, then projected onto three planes whose
// (grid x = width axis, grid y = height axis) coordinates are
//   plane 0 "XY": (q.x, q.y)    plane 1 "XZ": (q.x, q.z)    plane 2 "ZY": (q.z, q.y)
// and sampled bilinearly with zero padding and align_corners = false (texel centres at
// -1 + (i + 0.5) * 2 / W). The result is the mean over the three planes.

#include <torch/torch.h>

namespace avatar::render {

// (grid x, grid y) world-axis indices of each plane.
inline constexpr int kPlaneAxes[3][2] = {{0, 1}, {0, 2}, {2, 1}};

// planes [B,3,C,H,W], points [B,P,3] world -> features [B,P,C].
// Chooses the implementation: when autograd needs gradients (grad mode on and planes or points
// require grad), or the tensors are not on the CPU, the reference path (grid_sample, fully
// differentiable, any device); otherwise the fast CPU kernel (same values to rounding).
// Throws InvalidInput for bad shapes, dtypes or box_warp <= 0.
torch::Tensor SampleTriplanes(const torch::Tensor& planes, const torch::Tensor& points, double box_warp);

// The reference path, always: grid_sample per plane, then the mean. Differentiable in planes and points.
torch::Tensor SampleTriplanesReference(const torch::Tensor& planes, const torch::Tensor& points, double box_warp);

// The fast CPU path, no autograd: planes_channels_last [B,3,H,W,C] (contiguous), points [B,P,3]
// -> [B,P,C]. One pass per point reads the 4 corner vectors of each plane (contiguous in C)
// and accumulates the mean. Float32 or float64 on the CPU.
torch::Tensor SampleTriplanesFast(const torch::Tensor& planes_channels_last, const torch::Tensor& points,
                                  double box_warp);

// [B,3,C,H,W] -> contiguous [B,3,H,W,C] for SampleTriplanesFast.
torch::Tensor PlanesChannelsLast(const torch::Tensor& planes);

}  // namespace avatar::render
