#pragma once
// Occupancy grid for empty-space skipping at inference (RenderOptions::skip_empty_space).
//
// A cube of G^3 cells around the tri-plane box; each cell holds an upper bound of the raw density
// that the tri-plane field (planes + a two-layer softplus decoder) can take anywhere inside it.
// The bound is guaranteed, not sampled:
//   - the field's hidden pre-activation of unit h at p is  b1_h + sum_k bilerp(Q_kh, proj_k(p))
//     with the "hidden planes" Q_k = W1 . plane_k / 3 (the sampler's mean over the three planes
//     commutes with the linear layer);
//   - a bilinear lookup with zero padding is a convex combination of the texels next to it (and
//     zeros), so over a cell it lies between the minimum and the maximum of Q_kh over the texels
//     the cell's projection touches (zero included where the footprint reaches the padding);
//   - softplus is increasing, so raw <= b2 + sum_h w2_h softplus(w2_h > 0 ? upper_h : lower_h).
// A cell is empty when softplus(bound - 1) < sigma_threshold (the renderer's density); the bound
// carries a relative margin for float rounding. Points outside the cube count as occupied.
//
// Using it (renderer.cc): a sample is skipped when its cell and every cell within `dilation`
// cells of it are empty, with dilation = floor(sample spacing / cell side) + 1; then both ends of
// every interval that touches a skipped sample have a density below the threshold, so each ray
// loses at most sigma_threshold x (far - near) of optical depth (1.05e-3 with the defaults).
//
// Building first evaluates the field's density at the G^3 cell centres (one plane lookup and MLP
// per cell): a cell whose centre reaches the threshold is occupied whatever its bound, so the
// bound is computed only for the other cells (a few GEMMs on the planes for the per-plane
// footprint minima and maxima, then one hidden layer per candidate cell). A field that is dense
// everywhere costs just the centre evaluation.
//
// The grid belongs to one set of planes: build it again whenever they change (the session keeps
// one per cached T_c + T_p + T_e).

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>

#include <torch/torch.h>

namespace avatar::render {

// The density part of a two-layer decoder raw = w2 . softplus(w1 f + b1) + b2 with its
// effective weights (after any equalised-learning-rate gain).
struct DensityMlp {
  torch::Tensor w1;  // [H,C]
  torch::Tensor b1;  // [H]
  torch::Tensor w2;  // [H] (the raw-density row of the output layer)
  double b2 = 0.0;
};

struct OccupancyGridOptions {
  // Cells per axis; 0 = half the planes' texels per axis, clamped to 16..64 (about two texels per
  // cell: tight bounds at a build cost of G^3 x hidden softplus evaluations).
  int resolution = 0;
  // Side of the covered cube (centred at the origin) as a multiple of box_warp. The default
  // covers the samples of every camera on the default orbit sphere between near and far.
  double extent = 1.25;
  // A cell is empty when its density bound (softplus(raw - 1), per world unit) is below this.
  double sigma_threshold = 1e-3;
  // Throws InvalidOptions: resolution 0 or 2..512, extent in (0, 16], sigma_threshold in (0, 1].
  void Validate() const;
};

class OccupancyGrid {
 public:
  OccupancyGrid(torch::Tensor max_raw, double half, double sigma_threshold);

  int64_t batch() const { return max_raw_.size(0); }
  int64_t resolution() const { return max_raw_.size(1); }
  // Half the side of the covered cube (world units) and the side of one cell.
  double half() const { return half_; }
  double cell() const { return 2.0 * half_ / static_cast<double>(resolution()); }
  double sigma_threshold() const { return sigma_threshold_; }
  // The raw density whose softplus(raw - 1) equals sigma_threshold.
  double raw_threshold() const { return raw_threshold_; }
  // [B,G,G,G] float32 upper bound of the raw density per cell, indexed [b][x][y][z]; +inf for
  // cells whose centre already reaches the threshold (occupied, bound not computed).
  const torch::Tensor& max_raw() const { return max_raw_; }
  // [B,G,G,G] bool: the bound reaches the threshold.
  const torch::Tensor& occupied() const { return occupied_; }
  // Fraction of empty cells (over the batch).
  double EmptyFraction() const;

  // [B,G^3] bool: occupied cells grown by `dilation` cells; cells within `dilation` of the cube's
  // faces count as occupied too (the outside does). Computed once per dilation and kept.
  torch::Tensor Dilated(int64_t dilation) const;
  // True when Dilated(dilation) has no empty cell (then there is nothing to skip).
  bool AllOccupied(int64_t dilation) const;
  // points [B,P,3] (world) -> [B,P] bool: true where the point may have density, i.e. it lies
  // outside the cube or in a cell of Dilated(dilation).
  torch::Tensor MayBeOccupied(const torch::Tensor& points, int64_t dilation) const;

 private:
  torch::Tensor max_raw_, occupied_;
  double half_ = 0.0, sigma_threshold_ = 0.0, raw_threshold_ = 0.0;
  mutable std::mutex mutex_;
  struct Grown {
    torch::Tensor mask;  // [B,G^3]
    bool all = false;    // every cell occupied
  };
  const Grown& GrownBy(int64_t dilation) const;
  mutable std::map<int64_t, Grown> dilated_;
};

// The grid of planes [B,3,C,H,W] (any float dtype on the CPU) under `mlp` for a box of side
// box_warp. Runs without gradients. Throws InvalidInput (shapes), InvalidOptions.
std::shared_ptr<const OccupancyGrid> BuildOccupancyGrid(const torch::Tensor& planes, const DensityMlp& mlp,
                                                        double box_warp, const OccupancyGridOptions& options = {});

}  // namespace avatar::render
