#pragma once
// GOHA's "rasterization": a neural point cloud -> three feature planes. For each plane a
// G x G grid of query points (plane coordinates linspace(-1, 1, G) on both axes, endpoints
// included, as in the release) takes the feature of the nearest projected point (2-D Euclidean
// distance after dropping one axis, no radius limit, no occlusion test).
//
// Exactness and ties: squared distances are computed in double precision as dx*dx + dy*dy; the
// nearest point is the one with the smallest squared distance, and among exactly equal squared
// distances the one with the smallest point index (ray order row * R + column). The brute-force
// reference implements the same rule; the k-d tree search (nanoflann, O(N log N) build,
// O(log N) per query, no N x N matrix) returns the identical index because its result set
// compares (distance, index) itself and keeps a small pruning slack so that equal-distance
// candidates in neighbouring cells are never pruned.
//
// Gradients flow to the point features (a gather), never to the positions.

#include <cstdint>
#include <vector>

#include <torch/torch.h>

namespace avatar {

// Indices into `points` of the nearest point of each grid query (row-major, row = plane y,
// column = plane x), for 2-D points [N,2] (any float dtype, CPU; N >= 1). k-d tree search,
// queries in parallel.
std::vector<int64_t> NearestPointIndices(const torch::Tensor& points2d, int64_t grid);
// The O(N G^2) reference with the same tie rule (tests only).
std::vector<int64_t> NearestPointIndicesBruteForce(const torch::Tensor& points2d, int64_t grid);

// World points [B,N,3], foreground mask [B,N] (bool; only these points enter the cloud) and
// features [B,N,C] -> planes [B,3,C,G,G] in the tri-plane layout of triplane_sampling.h
// (plane 0 = (x,y), 1 = (x,z), 2 = (z,y); point coordinates scaled by 2 / box_warp). A batch
// item with no foreground point gets zero planes. Throws InvalidInput on shape mismatches.
torch::Tensor RasterizePointFeatures(const torch::Tensor& points, const torch::Tensor& mask,
                                     const torch::Tensor& features, int64_t grid, double box_warp);

}  // namespace avatar
