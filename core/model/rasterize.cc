#include "core/model/rasterize.h"

#include <ATen/Parallel.h>

#include <cmath>
#include <limits>

#include <nanoflann.hpp>

#include "core/render/triplane_sampling.h"
#include "core/util/error.h"

namespace avatar {

namespace {

// The one distance formula shared by both searches (see the header).
inline double SquaredDistance(double ax, double ay, double bx, double by) {
  const double dx = ax - bx;
  const double dy = ay - by;
  return dx * dx + dy * dy;
}

struct Cloud2d {
  const double* xy = nullptr;  // [N,2] row-major
  size_t n = 0;
  size_t kdtree_get_point_count() const { return n; }
  double kdtree_get_pt(size_t idx, size_t dim) const { return xy[2 * idx + dim]; }
  template <class Box>
  bool kdtree_get_bbox(Box& /*box*/) const {
    return false;
  }
};

// Keeps the lexicographically smallest (distance, index); reports a slightly larger worst
// distance so that the tree never prunes a cell that might hold an exact tie.
class NearestWithTies {
 public:
  NearestWithTies(const Cloud2d& cloud, double qx, double qy) : cloud_(cloud), qx_(qx), qy_(qy) {}
  // Starts from a known point (e.g. the neighbouring cell's answer): a tight bound from the
  // first node on. Exactness is unaffected: any closer or tied smaller-index point still wins.
  void Seed(uint32_t index) { addPoint(0.0, index); }
  size_t size() const { return best_ < 0 ? 0 : 1; }
  bool full() const { return best_ >= 0; }
  bool addPoint(double /*tree_dist*/, uint32_t index) {
    const double d = SquaredDistance(qx_, qy_, cloud_.xy[2 * index], cloud_.xy[2 * index + 1]);
    if (best_ < 0 || d < best_dist_ || (d == best_dist_ && index < best_)) {
      best_dist_ = d;
      best_ = index;
    }
    return true;
  }
  double worstDist() const {
    if (best_ < 0) return std::numeric_limits<double>::max();
    return best_dist_ * (1.0 + 1e-9) + 1e-300;
  }
  int64_t best() const { return best_; }

 private:
  const Cloud2d& cloud_;
  double qx_, qy_;
  double best_dist_ = std::numeric_limits<double>::max();
  int64_t best_ = -1;
};

using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, Cloud2d>, Cloud2d, 2, uint32_t>;

torch::Tensor CheckedPoints(const torch::Tensor& points2d) {
  AVATAR_CHECK_INPUT(points2d.dim() == 2 && points2d.size(1) == 2 && points2d.size(0) >= 1)
      << "rasterization needs 2-D points [N,2] with N >= 1, got " << points2d.sizes();
  AVATAR_CHECK_INPUT(points2d.size(0) < (int64_t{1} << 31)) << "too many points for rasterization";
  return points2d.detach().to(torch::kCPU, torch::kFloat64).contiguous();
}

inline double GridCoordinate(int64_t i, int64_t grid) {
  return grid == 1 ? 0.0 : -1.0 + 2.0 * static_cast<double>(i) / static_cast<double>(grid - 1);
}

}  // namespace

std::vector<int64_t> NearestPointIndices(const torch::Tensor& points2d, int64_t grid) {
  AVATAR_CHECK_INPUT(grid >= 1) << "rasterization grid must be >= 1, got " << grid;
  const torch::Tensor pts = CheckedPoints(points2d);
  Cloud2d cloud{pts.data_ptr<double>(), static_cast<size_t>(pts.size(0))};
  Tree tree(2, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(16));
  tree.buildIndex();
  std::vector<int64_t> nearest(static_cast<size_t>(grid * grid), -1);
  at::parallel_for(0, grid, 8, [&](int64_t begin, int64_t end) {
    for (int64_t row = begin; row < end; ++row) {
      const double qy = GridCoordinate(row, grid);
      int64_t previous = -1;
      for (int64_t col = 0; col < grid; ++col) {
        const double query[2] = {GridCoordinate(col, grid), qy};
        NearestWithTies result(cloud, query[0], query[1]);
        if (previous >= 0) result.Seed(static_cast<uint32_t>(previous));
        tree.findNeighbors(result, query, nanoflann::SearchParams(32, 0.0f, false));
        previous = result.best();
        nearest[static_cast<size_t>(row * grid + col)] = previous;
      }
    }
  });
  return nearest;
}

std::vector<int64_t> NearestPointIndicesBruteForce(const torch::Tensor& points2d, int64_t grid) {
  AVATAR_CHECK_INPUT(grid >= 1) << "rasterization grid must be >= 1, got " << grid;
  const torch::Tensor pts = CheckedPoints(points2d);
  const double* xy = pts.data_ptr<double>();
  const int64_t n = pts.size(0);
  std::vector<int64_t> nearest(static_cast<size_t>(grid * grid), -1);
  for (int64_t row = 0; row < grid; ++row) {
    for (int64_t col = 0; col < grid; ++col) {
      const double qx = GridCoordinate(col, grid), qy = GridCoordinate(row, grid);
      double best = std::numeric_limits<double>::infinity();
      int64_t best_index = -1;
      for (int64_t i = 0; i < n; ++i) {
        const double d = SquaredDistance(qx, qy, xy[2 * i], xy[2 * i + 1]);
        if (d < best) {  // strict: the first (smallest) index wins a tie
          best = d;
          best_index = i;
        }
      }
      nearest[static_cast<size_t>(row * grid + col)] = best_index;
    }
  }
  return nearest;
}

torch::Tensor RasterizePointFeatures(const torch::Tensor& points, const torch::Tensor& mask,
                                     const torch::Tensor& features, int64_t grid, double box_warp) {
  AVATAR_CHECK_INPUT(points.dim() == 3 && points.size(2) == 3) << "points must be [B,N,3], got " << points.sizes();
  AVATAR_CHECK_INPUT(mask.dim() == 2 && mask.size(0) == points.size(0) && mask.size(1) == points.size(1))
      << "mask must be [B,N] matching points " << points.sizes() << ", got " << mask.sizes();
  AVATAR_CHECK_INPUT(features.dim() == 3 && features.size(0) == points.size(0) && features.size(1) == points.size(1))
      << "features must be [B,N,C] matching points " << points.sizes() << ", got " << features.sizes();
  AVATAR_CHECK_INPUT(grid >= 1 && box_warp > 0) << "bad rasterization grid " << grid << " or box_warp " << box_warp;
  const int64_t b = points.size(0), c = features.size(2);
  const torch::Tensor scaled = (points.detach() * (2.0 / box_warp)).to(torch::kCPU);  // [B,N,3]
  const torch::Tensor keep = mask.to(torch::kCPU, torch::kBool);
  const bool track_grad = torch::GradMode::is_enabled() && features.requires_grad();
  std::vector<torch::Tensor> batch_planes;
  for (int64_t i = 0; i < b; ++i) {
    const torch::Tensor fg = torch::nonzero(keep[i]).flatten();  // [M] original point indices
    if (fg.numel() == 0) {
      batch_planes.push_back(torch::zeros({3, c, grid, grid}, features.options()));
      continue;
    }
    const torch::Tensor pts = scaled[i].index_select(0, fg);  // [M,3]
    const torch::Tensor fg_device = fg.to(features.device());
    // One search per plane, each parallel over grid rows inside.
    std::vector<int64_t> idx[3];
    for (int p = 0; p < 3; ++p) {
      const torch::Tensor xy =
          torch::stack({pts.select(1, render::kPlaneAxes[p][0]), pts.select(1, render::kPlaneAxes[p][1])}, 1);
      idx[p] = NearestPointIndices(xy, grid);
    }
    if (track_grad) {
      const torch::Tensor feats = features[i].index_select(0, fg_device);  // [M,C]
      std::vector<torch::Tensor> planes;
      for (int p = 0; p < 3; ++p) {
        const torch::Tensor index = torch::tensor(idx[p], torch::kLong).to(features.device());  // [G*G]
        planes.push_back(feats.index_select(0, index).t().reshape({c, grid, grid}));            // [C,G,G]
      }
      batch_planes.push_back(torch::stack(planes, 0));  // [3,C,G,G]
    } else {
      // No autograd: gather whole feature rows (contiguous copies of C floats) straight into a
      // [3, G, G, C] buffer and return it as a channels-last view [3, C, G, G]: no transpose.
      const torch::Tensor feats = features[i].contiguous();  // [N,C]
      torch::Tensor out = torch::empty({3, grid * grid, c}, features.options());
      for (int p = 0; p < 3; ++p) {
        const torch::Tensor index =
            fg_device.index_select(0, torch::tensor(idx[p], torch::kLong).to(features.device()));
        torch::Tensor slice = out[p];  // [G*G,C], contiguous view
        torch::index_select_out(slice, feats, 0, index);
      }
      batch_planes.push_back(out.view({3, grid, grid, c}).permute({0, 3, 1, 2}));  // [3,C,G,G] channels-last
    }
  }
  if (b == 1) return batch_planes[0].unsqueeze(0);  // keeps the channels-last strides
  return torch::stack(batch_planes, 0);             // [B,3,C,G,G]
}

}  // namespace avatar
