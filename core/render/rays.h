#pragma once
// Camera rays through pixel centres.

#include <torch/torch.h>

#include "core/render/camera.h"

namespace avatar::render {

struct Rays {
  torch::Tensor origins;     // [B,N,3] world, N = R*R, ray n = row * R + column
  torch::Tensor directions;  // [B,N,3] unit length
};

// Rays of an R x R image for each camera: pixel (row i, column j) passes through the
// normalised image point u = (j + 0.5) / R, v = (i + 0.5) / R. Same dtype/device as the cameras.
// Throws InvalidInput for R < 1 or malformed cameras.
Rays GenerateRays(const Cameras& cameras, int64_t resolution);

// The rays of a window of the R x R image (training on patches): `size` x `size` pixels per
// camera, whose top-left pixel (row, column) is corners[b] (corners [B,2], integer, any device);
// ray n = (row - corner row) * size + (column - corner column). Every ray is the ray
// GenerateRays(cameras, resolution) gives for the same pixel (same arithmetic). Throws
// InvalidInput for a bad size, corners that are not [B,2] integers, or a window that leaves the
// image.
Rays GenerateWindowRays(const Cameras& cameras, int64_t resolution, const torch::Tensor& corners, int64_t size);

}  // namespace avatar::render
