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

}  // namespace avatar::render
