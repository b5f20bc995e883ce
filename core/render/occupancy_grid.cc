#include "core/render/occupancy_grid.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "core/render/triplane_sampling.h"
#include "core/util/error.h"

namespace avatar::render {

namespace {

// Relative and absolute slack added to every bound for float rounding (the renderer samples and
// decodes in float32; the bound's own sums are float32 too).
constexpr double kRelativeMargin = 1e-4;
constexpr double kAbsoluteMargin = 1e-5;

// Indices [first, last] of the zero-padded plane (texel i of the plane is index i + 1; 0 and
// size + 1 are the padding) that bilinear lookups at world coordinates in [a, b] along one plane
// axis read, for a plane axis of `size` texels (align_corners = false, as triplane_sampling.h).
std::pair<int64_t, int64_t> TexelRange(double a, double b, double box_warp, int64_t size) {
  const auto texel = [&](double x) { return ((x * 2.0 / box_warp + 1.0) * static_cast<double>(size) - 1.0) * 0.5; };
  const double slack = 1e-3;  // texels; covers rounding of the sampler's coordinates
  const double lo = std::floor(texel(a) - slack), hi = std::floor(texel(b) + slack) + 1.0;
  const auto padded = [&](double i) {
    return static_cast<int64_t>(std::clamp(i + 1.0, 0.0, static_cast<double>(size + 1)));
  };
  return {padded(lo), padded(hi)};
}

// Minimum and maximum over each cell's texel footprint of q [H, rows + 2, cols + 2] (padded),
// for the cells' world ranges along the rows (grid y) and the columns (grid x) ->
// [H, G(rows), G(cols)] each.
std::pair<torch::Tensor, torch::Tensor> FootprintMinMax(const torch::Tensor& q, const std::vector<double>& edges,
                                                        double box_warp) {
  const int64_t rows = q.size(1) - 2, cols = q.size(2) - 2;
  const int64_t g = static_cast<int64_t>(edges.size()) - 1;
  std::vector<torch::Tensor> col_min, col_max;
  for (int64_t c = 0; c < g; ++c) {
    const auto [first, last] = TexelRange(edges[c], edges[c + 1], box_warp, cols);
    const auto mm = torch::aminmax(q.narrow(2, first, last - first + 1), 2);
    col_min.push_back(std::get<0>(mm));
    col_max.push_back(std::get<1>(mm));
  }
  const torch::Tensor by_col_min = torch::stack(col_min, 2), by_col_max = torch::stack(col_max, 2);  // [H,rows+2,G]
  std::vector<torch::Tensor> mins, maxs;
  for (int64_t r = 0; r < g; ++r) {
    const auto [first, last] = TexelRange(edges[r], edges[r + 1], box_warp, rows);
    mins.push_back(std::get<0>(torch::min(by_col_min.narrow(1, first, last - first + 1), 1)));
    maxs.push_back(std::get<0>(torch::max(by_col_max.narrow(1, first, last - first + 1), 1)));
  }
  return {torch::stack(mins, 1), torch::stack(maxs, 1)};  // [H,G,G]
}

}  // namespace

void OccupancyGridOptions::Validate() const {
  AVATAR_CHECK_OPTION(resolution == 0 || (resolution >= 2 && resolution <= 512))
      << "occupancy grid resolution must be 0 (automatic) or 2..512, got " << resolution;
  AVATAR_CHECK_OPTION(std::isfinite(extent) && extent > 0.0 && extent <= 16.0)
      << "occupancy grid extent must be in (0, 16] box sides, got " << extent;
  AVATAR_CHECK_OPTION(std::isfinite(sigma_threshold) && sigma_threshold > 0.0 && sigma_threshold <= 1.0)
      << "occupancy grid density threshold must be in (0, 1], got " << sigma_threshold;
}

OccupancyGrid::OccupancyGrid(torch::Tensor max_raw, double half, double sigma_threshold)
    : max_raw_(std::move(max_raw)), half_(half), sigma_threshold_(sigma_threshold) {
  AVATAR_CHECK_INPUT(max_raw_.defined() && max_raw_.dim() == 4 && max_raw_.size(1) == max_raw_.size(2) &&
                     max_raw_.size(1) == max_raw_.size(3) && max_raw_.size(1) >= 2)
      << "occupancy bounds must be [B,G,G,G]";
  AVATAR_CHECK_INPUT(half > 0.0 && std::isfinite(half)) << "occupancy grid half side must be > 0, got " << half;
  AVATAR_CHECK_INPUT(sigma_threshold > 0.0 && sigma_threshold <= 1.0)
      << "occupancy density threshold must be in (0, 1], got " << sigma_threshold;
  // softplus(raw - 1) = sigma  <=>  raw = 1 + log(expm1(sigma)).
  raw_threshold_ = 1.0 + std::log(std::expm1(sigma_threshold));
  // NaN bounds (non-finite planes) count as occupied.
  occupied_ = torch::logical_not(max_raw_ < raw_threshold_);
}

double OccupancyGrid::EmptyFraction() const {
  return 1.0 - occupied_.to(torch::kFloat64).mean().item<double>();
}

const OccupancyGrid::Grown& OccupancyGrid::GrownBy(int64_t dilation) const {
  AVATAR_CHECK_INPUT(dilation >= 0) << "occupancy dilation must be >= 0, got " << dilation;
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = dilated_.find(dilation);
  if (it != dilated_.end()) return it->second;  // std::map nodes stay put
  torch::NoGradGuard no_grad;
  const int64_t b = batch(), g = resolution();
  torch::Tensor grown = occupied_.to(torch::kFloat32).unsqueeze(1);  // [B,1,G,G,G]
  if (dilation > 0) {
    const int64_t d = dilation, k = 2 * d + 1;
    grown = torch::constant_pad_nd(grown, {d, d, d, d, d, d}, 1.0);  // the outside is occupied
    // Separable: a max over a (2d+1)^3 box = three maxima along the axes.
    grown = torch::max_pool3d(grown, {k, 1, 1}, {1, 1, 1});
    grown = torch::max_pool3d(grown, {1, k, 1}, {1, 1, 1});
    grown = torch::max_pool3d(grown, {1, 1, k}, {1, 1, 1});
  }
  Grown out;
  out.mask = (grown > 0.5).reshape({b, g * g * g}).contiguous();
  out.all = out.mask.all().item<bool>();
  return dilated_.emplace(dilation, std::move(out)).first->second;
}

torch::Tensor OccupancyGrid::Dilated(int64_t dilation) const { return GrownBy(dilation).mask; }

bool OccupancyGrid::AllOccupied(int64_t dilation) const { return GrownBy(dilation).all; }

torch::Tensor OccupancyGrid::MayBeOccupied(const torch::Tensor& points, int64_t dilation) const {
  AVATAR_CHECK_INPUT(points.dim() == 3 && points.size(2) == 3 && (points.size(0) == batch()))
      << "occupancy lookup needs points [B,P,3] with B = " << batch() << ", got " << points.sizes();
  const torch::Tensor grid = Dilated(dilation);  // [B,G^3]
  const int64_t g = resolution();
  const torch::Tensor cell_index = ((points.to(torch::kFloat64) + half_) / cell()).floor();  // [B,P,3]
  const torch::Tensor inside = ((cell_index >= 0) & (cell_index < static_cast<double>(g))).all(2);
  const torch::Tensor idx = cell_index.clamp(0, static_cast<double>(g - 1)).to(torch::kLong);
  const torch::Tensor flat = (idx.select(2, 0) * g + idx.select(2, 1)) * g + idx.select(2, 2);  // [B,P]
  return grid.gather(1, flat) | torch::logical_not(inside);
}

std::shared_ptr<const OccupancyGrid> BuildOccupancyGrid(const torch::Tensor& planes, const DensityMlp& mlp,
                                                        double box_warp, const OccupancyGridOptions& options) {
  options.Validate();
  AVATAR_CHECK_INPUT(planes.defined() && planes.dim() == 5 && planes.size(1) == 3 &&
                     torch::isFloatingType(planes.scalar_type()))
      << "tri-planes must be floating [B,3,C,H,W], got " << (planes.defined() ? planes.sizes() : c10::IntArrayRef{});
  AVATAR_CHECK_INPUT(box_warp > 0.0 && std::isfinite(box_warp)) << "box_warp must be > 0, got " << box_warp;
  const int64_t c = planes.size(2);
  AVATAR_CHECK_INPUT(mlp.w1.defined() && mlp.w1.dim() == 2 && mlp.w1.size(1) == c && mlp.b1.defined() &&
                     mlp.b1.dim() == 1 && mlp.b1.size(0) == mlp.w1.size(0) && mlp.w2.defined() &&
                     mlp.w2.sizes() == mlp.b1.sizes() && std::isfinite(mlp.b2))
      << "the density MLP must be w1 [H," << c << "], b1 [H], w2 [H] and a finite b2";
  torch::NoGradGuard no_grad;
  const int64_t batch = planes.size(0), hidden = mlp.w1.size(0);
  const int64_t g = options.resolution > 0 ? options.resolution : std::clamp<int64_t>(planes.size(4) / 2, 16, 64);
  const auto dtype = planes.scalar_type();
  const torch::Tensor w1 = mlp.w1.to(planes.device(), dtype);
  const torch::Tensor b1 = mlp.b1.to(planes.device(), dtype);
  const torch::Tensor w2 = mlp.w2.to(planes.device(), dtype);
  const torch::Tensor positive = w2 > 0;  // which bound of each hidden unit maximises the density
  const double half = 0.5 * box_warp * options.extent;
  const double raw_threshold = 1.0 + std::log(std::expm1(options.sigma_threshold));
  std::vector<double> edges(static_cast<size_t>(g + 1));
  for (int64_t i = 0; i <= g; ++i) edges[i] = -half + 2.0 * half * static_cast<double>(i) / static_cast<double>(g);
  // Cell centres [G^3,3] in the flat order (x * G + y) * G + z.
  const torch::Tensor axis = torch::arange(g, planes.options()).add(0.5).mul(2.0 * half / static_cast<double>(g)).sub(half);
  const std::vector<torch::Tensor> mesh = torch::meshgrid({axis, axis, axis}, "ij");
  const torch::Tensor centres = torch::stack({mesh[0], mesh[1], mesh[2]}, 3).reshape({g * g * g, 3});
  const torch::Tensor cell_index = torch::arange(g * g * g, torch::TensorOptions().dtype(torch::kLong));
  // Output layer split into its positive and negative parts: raw = b2 + P - N, both >= 0, so the
  // rounding margin can be relative to P + N + |b2|.
  const torch::Tensor out_cols = torch::stack({w2.clamp_min(0.0), (-w2).clamp_min(0.0)}, 1);  // [H,2]
  std::vector<torch::Tensor> per_batch;
  for (int64_t b = 0; b < batch; ++b) {
    // Cells whose centre already has a density at or above the threshold are occupied whatever
    // the bound says: only the others (candidates) need it. The field at the centres is the
    // renderer's (plane lookup + the MLP's density); a foggy field ends here.
    const torch::Tensor features = SampleTriplanes(planes.narrow(0, b, 1), centres.unsqueeze(0), box_warp)[0];
    const torch::Tensor centre_raw =
        torch::mv(torch::softplus(torch::addmm(b1, features, w1.t())), w2) + mlp.b2;  // [G^3]
    const torch::Tensor candidates = cell_index.masked_select((centre_raw < raw_threshold).cpu());
    torch::Tensor max_raw = torch::full({g * g * g}, std::numeric_limits<float>::infinity(),
                                        torch::TensorOptions().dtype(torch::kFloat32));
    const int64_t k = candidates.numel();
    if (k > 0) {
      // Per plane: the selected bound of every hidden unit per 2-D cell, [G(grid y) * G(grid x), H].
      torch::Tensor selected[3];
      for (int p = 0; p < 3; ++p) {
        const torch::Tensor plane = planes[b][p];  // [C,rows,cols]
        const int64_t rows = plane.size(1), cols = plane.size(2);
        // The sampler's mean over the planes commutes with the first layer: W1 / 3 per plane.
        const torch::Tensor q = torch::mm(w1 / 3.0, plane.reshape({c, rows * cols})).view({hidden, rows, cols});
        const auto [lo, hi] = FootprintMinMax(torch::constant_pad_nd(q, {1, 1, 1, 1}, 0.0), edges, box_warp);
        selected[p] = torch::where(positive.view({hidden, 1, 1}), hi, lo).permute({1, 2, 0}).reshape({g * g, hidden});
      }
      const torch::Tensor cand = candidates.to(planes.device());
      const torch::Tensor ix = torch::div(cand, g * g, "floor"), iy = torch::div(cand, g, "floor").remainder(g),
                          iz = cand.remainder(g);
      // World axes: plane 0 (x,y) -> [y,x]; plane 1 (x,z) -> [z,x]; plane 2 (z,y) -> [y,z].
      const torch::Tensor z = selected[0].index_select(0, iy * g + ix) + selected[1].index_select(0, iz * g + ix) +
                              selected[2].index_select(0, iy * g + iz) + b1;  // [K,H]
      const torch::Tensor parts = torch::mm(torch::softplus(z), out_cols);     // [K,2]
      const torch::Tensor pos = parts.select(1, 0), neg = parts.select(1, 1);
      const torch::Tensor bound =
          (mlp.b2 + pos - neg) + kRelativeMargin * (pos + neg + std::abs(mlp.b2)) + kAbsoluteMargin;
      max_raw.index_copy_(0, candidates, bound.to(torch::kCPU, torch::kFloat32));
    }
    per_batch.push_back(max_raw.view({g, g, g}));
  }
  return std::make_shared<const OccupancyGrid>(torch::stack(per_batch, 0).contiguous(), half,
                                               options.sigma_threshold);
}

}  // namespace avatar::render
