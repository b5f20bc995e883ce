#include "core/render/renderer.h"

#include <ATen/Parallel.h>
#include <torch/csrc/autograd/function.h>
#include <torch/csrc/autograd/functions/utils.h>

#include <cmath>
#include <limits>
#include <mutex>

#include "core/render/depth_sampling.h"
#include "core/render/ray_marcher.h"
#include "core/render/triplane_sampling.h"
#include "core/util/error.h"
#include "core/util/timer.h"

namespace avatar::render {

namespace {

// A copy of a generator's state. LibTorch 1.13's GeneratorImpl::clone hands back an object whose
// weak count is 0, so its last owner never frees it (2,632 bytes per copy of a CPU generator; seen
// by LeakSanitizer). The missing weak reference is added here, and only when it is missing, so a
// LibTorch that gets this right is left alone.
at::Generator CopyGenerator(const at::Generator& generator) {
  at::Generator copy = generator.clone();
  if (copy.getIntrusivePtr().weak_use_count() == 0)
    c10::raw::weak_intrusive_ptr::incref(copy.unsafeGetGeneratorImpl());
  return copy;
}

int64_t Nanoseconds(const Timer& timer) { return static_cast<int64_t>(timer.Seconds() * 1e9); }

struct Evaluated {
  torch::Tensor raw;       // [B,N,S]
  torch::Tensor features;  // [B,N,S,C]
};

Evaluated Evaluate(const Field& field, const torch::Tensor& origins, const torch::Tensor& directions,
                   const torch::Tensor& depths) {
  const int64_t b = depths.size(0), n = depths.size(1), s = depths.size(2);
  const torch::Tensor points =
      (origins.unsqueeze(2) + depths.unsqueeze(3) * directions.unsqueeze(2)).reshape({b, n * s, 3});
  FieldSamples samples = field(points);
  AVATAR_CHECK_INPUT(samples.raw_density.defined() && samples.features.defined() &&
                     samples.raw_density.numel() == b * n * s && samples.features.dim() == 3 &&
                     samples.features.size(0) == b && samples.features.size(1) == n * s)
      << "the field must return raw density [B,P] and features [B,P,C] for P = " << n * s << " points";
  Evaluated e;
  e.raw = samples.raw_density.reshape({b, n, s});
  e.features = samples.features.view({b, n, s, samples.features.size(2)});
  return e;
}

}  // namespace

void RenderOptions::Validate() const {
  AVATAR_CHECK_OPTION(resolution >= 1 && resolution <= 4096) << "--resolution must be 1..4096, got " << resolution;
  AVATAR_CHECK_OPTION(num_coarse >= 2) << "--num-coarse must be >= 2, got " << num_coarse;
  AVATAR_CHECK_OPTION(num_importance >= 0) << "--num-importance must be >= 0, got " << num_importance;
  AVATAR_CHECK_OPTION(num_importance == 0 || num_coarse >= 4)
      << "importance sampling needs --num-coarse >= 4, got " << num_coarse;
  AVATAR_CHECK_OPTION(std::isfinite(near) && std::isfinite(far) && near >= 0.0 && far > near)
      << "the depth range needs 0 <= near < far, got [" << near << ", " << far << "]";
  AVATAR_CHECK_OPTION(std::isfinite(box_warp) && box_warp > 0.0) << "--box-warp must be > 0, got " << box_warp;
  AVATAR_CHECK_OPTION(chunk_rays >= 1) << "--chunk-rays must be >= 1, got " << chunk_rays;
  AVATAR_CHECK_OPTION(std::isfinite(termination_transmittance) && termination_transmittance >= 0.0 &&
                      termination_transmittance < 1.0)
      << "termination_transmittance must be in [0,1), got " << termination_transmittance;
  AVATAR_CHECK_OPTION(termination_block >= 1) << "termination_block must be >= 1, got " << termination_block;
  AVATAR_CHECK_OPTION(std::isfinite(miss_margin) && miss_margin >= 0.0 && miss_margin <= 1.0)
      << "miss_margin must be in [0,1], got " << miss_margin;
  AVATAR_CHECK_OPTION(window_size >= 0 && window_size <= resolution)
      << "window_size must be 0 (whole image) or 1.." << resolution << ", got " << window_size;
  AVATAR_CHECK_OPTION(window_size == 0 || window_corners.defined())
      << "a pixel window (window_size " << window_size << ") needs window_corners [B,2]";
  AVATAR_CHECK_OPTION(grad_chunk_rays >= 0) << "grad_chunk_rays must be >= 0, got " << grad_chunk_rays;
}

Field MakeTriplaneField(const torch::Tensor& planes, PointDecoder decoder, double box_warp, RenderProfile* profile) {
  AVATAR_CHECK_INPUT(planes.defined() && planes.dim() == 5 && planes.size(1) == 3)
      << "tri-planes must be [B,3,C,H,W], got " << (planes.defined() ? planes.sizes() : c10::IntArrayRef{});
  AVATAR_CHECK_INPUT(box_warp > 0.0 && std::isfinite(box_warp)) << "box_warp must be > 0, got " << box_warp;
  AVATAR_CHECK_INPUT(static_cast<bool>(decoder)) << "the tri-plane field needs a decoder";
  const bool planes_need_grad = torch::GradMode::is_enabled() && planes.requires_grad();
  const bool fast_ok =
      planes.device().is_cpu() && (planes.scalar_type() == torch::kFloat32 || planes.scalar_type() == torch::kFloat64);
  torch::Tensor channels_last;
  if (!planes_need_grad && fast_ok) {
    torch::NoGradGuard no_grad;
    channels_last = PlanesChannelsLast(planes);
  }
  return [planes, channels_last, decoder = std::move(decoder), box_warp, profile](const torch::Tensor& points) {
    Timer timer;
    const bool grad_path = torch::GradMode::is_enabled() && (planes.requires_grad() || points.requires_grad());
    const torch::Tensor features = (channels_last.defined() && !grad_path)
                                       ? SampleTriplanesFast(channels_last, points, box_warp)
                                       : SampleTriplanesReference(planes, points, box_warp);
    if (profile != nullptr) {
      profile->sample_ns += Nanoseconds(timer);
      profile->points += points.size(0) * points.size(1);
      timer.Restart();
    }
    const torch::Tensor decoded = decoder(features);  // [B,P,1+C']
    AVATAR_CHECK_INPUT(decoded.dim() == 3 && decoded.size(0) == points.size(0) && decoded.size(1) == points.size(1) &&
                       decoded.size(2) >= 2)
        << "the decoder must map [B,P,C] to [B,P,1+C'], got " << decoded.sizes();
    if (profile != nullptr) profile->decode_ns += Nanoseconds(timer);
    FieldSamples out;
    out.raw_density = decoded.select(2, 0);
    out.features = decoded.narrow(2, 1, decoded.size(2) - 1);
    return out;
  };
}

namespace {

// Raw density of samples that are not evaluated: softplus(-31) ~ 3e-14 per unit length, empty.
constexpr double kSkippedRaw = -30.0;

// Marches the union of coarse and importance samples (or the coarse ones alone when `fine` is
// null) and composites the features.
void MarchUnion(const Evaluated& coarse, const torch::Tensor& coarse_depths, const Evaluated* fine,
                const torch::Tensor& fine_depths, const RenderOptions& options, MarchWeights& weights,
                torch::Tensor& composite) {
  if (fine == nullptr) {
    weights = ComputeMarchWeights(coarse.raw, coarse_depths, options.far, options.return_depth);
    composite = CompositeFeatures(weights.sample_weights, coarse.features);
    return;
  }
  const int64_t num_coarse = coarse_depths.size(2), num_fine = fine_depths.size(2);
  // Sort the union once; only the scalar densities are permuted. The per-sample weights are
  // mapped back to the unsorted order, so the features never need a gather.
  torch::Tensor sorted_depths, order;
  std::tie(sorted_depths, order) = torch::sort(torch::cat({coarse_depths, fine_depths}, 2), c10::optional<bool>(true),
                                               /*dim=*/2, /*descending=*/false);
  const torch::Tensor sorted_raw = torch::cat({coarse.raw, fine->raw}, 2).gather(2, order);
  weights = ComputeMarchWeights(sorted_raw, sorted_depths, options.far, options.return_depth);
  torch::Tensor inverse;
  {
    torch::NoGradGuard no_grad;
    const int64_t total = num_coarse + num_fine;
    inverse = torch::empty_like(order).scatter_(
        2, order, torch::arange(total, order.options()).view({1, 1, total}).expand_as(order));
  }
  const torch::Tensor unsorted = weights.sample_weights.gather(2, inverse);
  composite = CompositeFeatures(unsorted.narrow(2, 0, num_coarse), coarse.features) +
              CompositeFeatures(unsorted.narrow(2, num_coarse, num_fine), fine->features);
}

// Rays [B,N] whose segment [near, far] meets the cube |x|, |y|, |z| <= half (slab test).
torch::Tensor SegmentsHitBox(const torch::Tensor& origins, const torch::Tensor& directions, double near, double far,
                             double half) {
  // A zero direction component becomes tiny: the slab is then all or nothing along that axis.
  const double tiny = 1e-12;
  const torch::Tensor d = torch::where(directions.abs() < tiny, torch::full_like(directions, tiny), directions);
  const torch::Tensor t0 = (-half - origins) / d, t1 = (half - origins) / d;
  const torch::Tensor enter = torch::minimum(t0, t1).amax(2).clamp_min(near);
  const torch::Tensor leave = torch::maximum(t0, t1).amin(2).clamp_max(far);
  return enter <= leave;
}

// Evaluates the field at the samples points [B,N*S,3] where keep [N*S] is true (for every batch
// element) and writes them into `into` (raw [B,N,S] preset to kSkippedRaw, features [B,N,S,C]
// zeros, allocated at the first call once C is known).
void EvaluateWhere(const Field& field, const torch::Tensor& points, const torch::Tensor& keep, int64_t n, int64_t s,
                   Evaluated& into) {
  const int64_t b = points.size(0);
  const torch::Tensor idx = keep.nonzero().view({-1});
  const int64_t k = idx.numel();
  if (k == 0 && into.features.defined()) return;
  // With nothing to evaluate, one point still tells the channel count.
  const torch::Tensor sel = k == 0 ? torch::zeros({1}, idx.options()) : idx;
  const torch::Tensor pts = points.index_select(1, sel);
  FieldSamples samples = field(pts);
  AVATAR_CHECK_INPUT(samples.raw_density.defined() && samples.features.defined() &&
                     samples.raw_density.numel() == b * sel.numel() && samples.features.dim() == 3 &&
                     samples.features.size(0) == b && samples.features.size(1) == sel.numel())
      << "the field must return raw density [B,P] and features [B,P,C] for P = " << sel.numel() << " points";
  const int64_t c = samples.features.size(2);
  if (!into.features.defined()) {
    into.features = torch::zeros({b, n, s, c}, samples.features.options());
  }
  AVATAR_CHECK_INPUT(into.features.size(3) == c) << "the field changed its channel count between calls";
  if (!into.raw.defined()) into.raw = torch::full({b, n, s}, kSkippedRaw, samples.raw_density.options());
  if (k == 0) return;
  into.raw.view({b, n * s}).index_copy_(1, idx, samples.raw_density.reshape({b, k}));
  into.features.view({b, n * s, c}).index_copy_(1, idx, samples.features);
}

// Evaluates samples [start, start + len) of every ray, points [B,N,S,3], into `into` (allocated
// as in EvaluateWhere): no index bookkeeping when every ray wants these samples.
void EvaluateColumns(const Field& field, const torch::Tensor& points, int64_t start, int64_t len, Evaluated& into) {
  const int64_t b = points.size(0), n = points.size(1), s = points.size(2);
  FieldSamples samples = field(points.narrow(2, start, len).reshape({b, n * len, 3}));
  AVATAR_CHECK_INPUT(samples.raw_density.defined() && samples.features.defined() &&
                     samples.raw_density.numel() == b * n * len && samples.features.dim() == 3 &&
                     samples.features.size(0) == b && samples.features.size(1) == n * len)
      << "the field must return raw density [B,P] and features [B,P,C] for P = " << n * len << " points";
  const int64_t c = samples.features.size(2);
  if (len == s && !into.features.defined()) {
    into.raw = samples.raw_density.reshape({b, n, s});
    into.features = samples.features.reshape({b, n, s, c});
    return;
  }
  if (!into.features.defined()) into.features = torch::zeros({b, n, s, c}, samples.features.options());
  AVATAR_CHECK_INPUT(into.features.size(3) == c) << "the field changed its channel count between calls";
  if (!into.raw.defined()) into.raw = torch::full({b, n, s}, kSkippedRaw, samples.raw_density.options());
  into.raw.narrow(2, start, len).copy_(samples.raw_density.reshape({b, n, len}));
  into.features.narrow(2, start, len).copy_(samples.features.reshape({b, n, len, c}));
}

// Transmittance before each sample [B,N,S] (1 at the first) from raw densities and depths [B,N,S].
torch::Tensor TransmittanceBefore(const torch::Tensor& raw, const torch::Tensor& depths) {
  const int64_t s = raw.size(2);
  const torch::Tensor delta = depths.narrow(2, 1, s - 1) - depths.narrow(2, 0, s - 1);
  const torch::Tensor raw_mid = 0.5 * (raw.narrow(2, 0, s - 1) + raw.narrow(2, 1, s - 1));
  const torch::Tensor tau = torch::softplus(raw_mid - 1.0).clamp_max(kMaxDensity) * delta;
  const torch::Tensor cum = torch::cumsum(tau, 2);
  return torch::exp(-torch::cat({torch::zeros_like(raw.narrow(2, 0, 1)), cum}, 2));
}

// Cells by which the occupancy grid's occupied cells are grown so that both ends of any interval
// touching a skipped sample lie in empty cells: consecutive samples are at most one coarse
// stratum apart (two with jitter), i.e. at most floor(spacing / cell) + 1 cells along each axis.
int64_t OccupancyDilation(const RenderOptions& options, const OccupancyGrid& grid) {
  const double spacing =
      (options.far - options.near) / static_cast<double>(options.num_coarse) * (options.deterministic ? 1.0 : 2.0);
  return static_cast<int64_t>(std::floor(spacing / grid.cell())) + 1;
}

// The inference path with early termination, missed-ray and/or empty-space skipping (grad mode off).
void RenderRaysSkipping(const Field& field, const torch::Tensor& origins, const torch::Tensor& directions,
                        const RenderOptions& options, c10::optional<at::Generator> generator, MarchWeights& weights,
                        torch::Tensor& composite, torch::Tensor& hit_per_batch) {
  const int64_t b = origins.size(0), n = origins.size(1);
  const int64_t num_coarse = options.num_coarse, num_fine = options.num_importance;
  const auto bool_opts = origins.options().dtype(torch::kBool);
  const torch::Tensor coarse_depths = StratifiedDepths(b, n, num_coarse, options.near, options.far,
                                                       options.deterministic, origins.options(), generator);
  const OccupancyGrid* grid = options.skip_empty_space ? options.occupancy.get() : nullptr;
  const int64_t dilation = grid != nullptr ? OccupancyDilation(options, *grid) : 0;
  if (grid != nullptr && grid->AllOccupied(dilation)) grid = nullptr;  // nothing to skip: no lookups
  // [N,S] samples that may have density for some batch element (undefined: all may).
  const auto may_be_occupied = [&](const torch::Tensor& points, int64_t samples) {
    return grid->MayBeOccupied(points, dilation).view({b, n, samples}).any(0);
  };
  torch::Tensor active = torch::ones({n}, bool_opts);
  if (options.skip_missed_rays) {
    const double half = options.box_warp * (0.5 + options.miss_margin);
    hit_per_batch = SegmentsHitBox(origins, directions, options.near, options.far, half);  // [B,N]
    active = hit_per_batch.any(0);
    if (hit_per_batch.all().item<bool>()) hit_per_batch = torch::Tensor();  // every ray is marched
  }
  const torch::Tensor hit = active.clone();
  const auto points_at = [&](const torch::Tensor& depths) {
    return (origins.unsqueeze(2) + depths.unsqueeze(3) * directions.unsqueeze(2)).reshape({b, -1, 3});
  };
  // Coarse samples in blocks; rays leave the active set once opaque.
  const torch::Tensor coarse_points = points_at(coarse_depths);
  const torch::Tensor coarse_grid = coarse_points.view({b, n, num_coarse, 3});
  const torch::Tensor coarse_occupied = grid != nullptr ? may_be_occupied(coarse_points, num_coarse) : torch::Tensor();
  const int64_t block = options.early_termination ? options.termination_block : num_coarse;
  Evaluated coarse;
  for (int64_t start = 0, len = 0; start < num_coarse; start += len) {
    len = std::min(block, num_coarse - start);
    torch::Tensor wanted = active.unsqueeze(1).expand({n, len});
    if (coarse_occupied.defined()) wanted = wanted & coarse_occupied.narrow(1, start, len);
    if (wanted.all().item<bool>()) {
      EvaluateColumns(field, coarse_grid, start, len, coarse);
    } else {
      torch::Tensor keep = torch::zeros({n, num_coarse}, bool_opts);
      keep.narrow(1, start, len).copy_(wanted);
      EvaluateWhere(field, coarse_points, keep.view({-1}), n, num_coarse, coarse);
    }
    if (options.early_termination && start + len < num_coarse) {
      const torch::Tensor t =
          TransmittanceBefore(coarse.raw.narrow(2, 0, start + len), coarse_depths.narrow(2, 0, start + len));
      const torch::Tensor t_last = t.select(2, start + len - 1);  // [B,N]
      active = active & (t_last > options.termination_transmittance).any(0);
      if (!active.any().item<bool>()) break;
    }
  }
  if (num_fine == 0) {
    MarchUnion(coarse, coarse_depths, nullptr, torch::Tensor(), options, weights, composite);
    return;
  }
  const MarchWeights coarse_weights = ComputeMarchWeights(coarse.raw, coarse_depths, options.far, false);
  const torch::Tensor fine_depths =
      ImportanceDepths(coarse_depths, coarse_weights.interval_weights, num_fine, options.deterministic, generator);
  torch::Tensor keep = hit.unsqueeze(1).expand({n, num_fine});
  if (options.early_termination) {
    // Importance samples behind the first coarse sample seen through less than the threshold.
    const torch::Tensor t = TransmittanceBefore(coarse.raw, coarse_depths);
    const torch::Tensor stop = torch::where(t < options.termination_transmittance, coarse_depths,
                                            torch::full_like(coarse_depths, std::numeric_limits<double>::infinity()))
                                   .amin(2);  // [B,N]
    keep = keep & (fine_depths < stop.unsqueeze(2)).any(0);
  }
  const torch::Tensor fine_points = points_at(fine_depths);
  if (grid != nullptr) keep = keep & may_be_occupied(fine_points, num_fine);
  Evaluated fine;
  if (keep.all().item<bool>()) {
    EvaluateColumns(field, fine_points.view({b, n, num_fine, 3}), 0, num_fine, fine);
  } else {
    EvaluateWhere(field, fine_points, keep.reshape({-1}), n, num_fine, fine);
  }
  MarchUnion(coarse, coarse_depths, &fine, fine_depths, options, weights, composite);
}

}  // namespace

RayRenderOutput RenderRays(const Field& field, const torch::Tensor& origins, const torch::Tensor& directions,
                           const RenderOptions& options, c10::optional<at::Generator> generator,
                           RenderProfile* profile) {
  options.Validate();
  AVATAR_CHECK_INPUT(origins.dim() == 3 && origins.size(2) == 3 && directions.sizes() == origins.sizes())
      << "rays must be origins and directions [B,N,3], got " << origins.sizes() << " and " << directions.sizes();
  AVATAR_CHECK_INPUT(torch::isFloatingType(origins.scalar_type()) && origins.scalar_type() == directions.scalar_type())
      << "ray origins and directions must share one floating dtype";
  Timer timer;
  const int64_t b = origins.size(0), n = origins.size(1);
  const int64_t num_coarse = options.num_coarse, num_fine = options.num_importance;
  RayRenderOutput out;
  MarchWeights weights;
  torch::Tensor composite;  // [B,N,C] in about [0,1]
  torch::Tensor hit;        // [B,N] rays that meet the box (skip_missed_rays)
  const bool empty_space = options.skip_empty_space && options.occupancy != nullptr;
  if (empty_space && !torch::GradMode::is_enabled()) {
    AVATAR_CHECK_INPUT(options.occupancy->batch() == b)
        << "the occupancy grid has " << options.occupancy->batch() << " plane sets for " << b
        << " ray batches; build it from the planes being rendered";
  }
  const bool skipping = !torch::GradMode::is_enabled() &&
                        (options.early_termination || options.skip_missed_rays || empty_space) && n > 0;
  if (skipping) {
    RenderRaysSkipping(field, origins, directions, options, generator, weights, composite, hit);
  } else {
    const torch::Tensor coarse_depths = StratifiedDepths(b, n, num_coarse, options.near, options.far,
                                                         options.deterministic, origins.options(), generator);
    const Evaluated coarse = Evaluate(field, origins, directions, coarse_depths);
    if (num_fine == 0) {
      MarchUnion(coarse, coarse_depths, nullptr, torch::Tensor(), options, weights, composite);
    } else {
      torch::Tensor fine_depths;
      {
        torch::NoGradGuard no_grad;
        const MarchWeights coarse_weights = ComputeMarchWeights(coarse.raw.detach(), coarse_depths, options.far);
        fine_depths = ImportanceDepths(coarse_depths, coarse_weights.interval_weights, num_fine, options.deterministic,
                                       generator);
      }
      const Evaluated fine = Evaluate(field, origins, directions, fine_depths);
      AVATAR_CHECK_INPUT(fine.features.size(3) == coarse.features.size(3))
          << "the field changed its channel count between calls";
      MarchUnion(coarse, coarse_depths, &fine, fine_depths, options, weights, composite);
    }
  }
  out.features = composite * 2.0 - 1.0;
  if (options.return_opacity) out.opacity = weights.opacity;
  if (options.return_depth) out.depth = weights.depth;
  if (hit.defined()) {
    // Missed rays: background, no opacity, far depth.
    out.features = torch::where(hit.unsqueeze(2), out.features, torch::full_like(out.features, -1.0));
    if (out.opacity.defined()) out.opacity = torch::where(hit, out.opacity, torch::zeros_like(out.opacity));
    if (out.depth.defined()) out.depth = torch::where(hit, out.depth, torch::full_like(out.depth, options.far));
  }
  if (options.return_weights) {
    out.weights = weights.interval_weights;
    out.midpoints = weights.midpoints;
  }
  if (profile != nullptr) profile->total_ns += Nanoseconds(timer);
  return out;
}

namespace {

// Image side of a render: the window's or the whole image's.
int64_t ImageSide(const RenderOptions& options) {
  return options.window_size > 0 ? options.window_size : options.resolution;
}

// The rays of the whole image or of its window.
Rays RaysFor(const Cameras& cameras, const RenderOptions& options) {
  if (options.window_size > 0)
    return GenerateWindowRays(cameras, options.resolution, options.window_corners, options.window_size);
  return GenerateRays(cameras, options.resolution);
}

// Ray chunks [start, start + len) concatenated along the rays.
RayRenderOutput Concatenate(const std::vector<RayRenderOutput>& parts, const RenderOptions& options) {
  const auto gather = [&](auto member) {
    std::vector<torch::Tensor> pieces;
    pieces.reserve(parts.size());
    for (const auto& p : parts) pieces.push_back(p.*member);
    return torch::cat(pieces, 1);
  };
  RayRenderOutput out;
  out.features = gather(&RayRenderOutput::features);
  if (options.return_opacity) out.opacity = gather(&RayRenderOutput::opacity);
  if (options.return_depth) out.depth = gather(&RayRenderOutput::depth);
  if (options.return_weights) {
    out.weights = gather(&RayRenderOutput::weights);
    out.midpoints = gather(&RayRenderOutput::midpoints);
  }
  return out;
}

// Per-ray results [B, side^2, ...] as images [B, C, side, side].
RenderOutput ToImages(const RayRenderOutput& rendered, int64_t b, int64_t side) {
  RenderOutput out;
  const int64_t c = rendered.features.size(2);
  out.features = rendered.features.view({b, side, side, c}).permute({0, 3, 1, 2}).contiguous();
  if (c >= 3) out.rgb = out.features.narrow(1, 0, 3);
  if (rendered.opacity.defined()) out.opacity = rendered.opacity.view({b, 1, side, side});
  if (rendered.depth.defined()) out.depth = rendered.depth.view({b, 1, side, side});
  out.weights = rendered.weights;
  out.midpoints = rendered.midpoints;
  return out;
}

// The backward pass of a ray-chunked render (RenderOptions::grad_chunk_rays): renders each chunk
// again with gradients, from a detached copy of the planes and with the jitter generator's state
// that chunk's forward render started from, and returns the summed gradients of the planes
// (input 0) and of the grad_parameters (inputs 1..).
class ChunkedRenderBackward : public torch::autograd::Node {
 public:
  explicit ChunkedRenderBackward(torch::autograd::edge_list&& next) : Node(std::move(next)) {}
  std::string name() const override { return "avatar::render::ChunkedRenderBackward"; }

  torch::autograd::variable_list apply(torch::autograd::variable_list&& grads) override {
    torch::autograd::variable_list out(num_outputs());
    AVATAR_CHECK(!released_) << "a ray-chunked render was backpropagated twice without retain_graph";
    const torch::Tensor& grad = grads.at(0);  // [B,N,C] of the ray features
    if (!grad.defined()) return out;
    torch::AutoGradMode grad_mode(true);
    torch::Tensor leaf = planes.detach();
    std::vector<torch::Tensor> inputs;
    std::vector<size_t> slots;
    if (should_compute_output(0) && planes_need_grad) {
      leaf.requires_grad_(true);
      inputs.push_back(leaf);
      slots.push_back(0);
    }
    for (size_t i = 0; i < parameters.size(); ++i) {
      if (!should_compute_output(i + 1) || !parameters[i].requires_grad()) continue;
      inputs.push_back(parameters[i]);
      slots.push_back(i + 1);
    }
    if (inputs.empty()) return out;
    const Field field = MakeTriplaneField(leaf, decoder, options.box_warp);
    std::vector<torch::Tensor> sums(inputs.size());
    const int64_t n = origins.size(1);
    for (int64_t start = 0, i = 0; start < n; start += chunk, ++i) {
      const int64_t len = std::min(chunk, n - start);
      c10::optional<at::Generator> generator;
      const auto& state = generators[static_cast<size_t>(i)];
      if (state.has_value()) generator = CopyGenerator(*state);
      const RayRenderOutput r =
          RenderRays(field, origins.narrow(1, start, len), directions.narrow(1, start, len), options, generator);
      const torch::autograd::variable_list g = torch::autograd::grad({r.features}, inputs, {grad.narrow(1, start, len)},
                                                                     /*retain_graph=*/false, /*create_graph=*/false,
                                                                     /*allow_unused=*/true);
      for (size_t k = 0; k < g.size(); ++k)
        if (g[k].defined()) sums[k] = sums[k].defined() ? sums[k] + g[k] : g[k];
    }
    for (size_t k = 0; k < slots.size(); ++k) out[slots[k]] = sums[k];
    return out;
  }

  void release_variables() override {
    planes = torch::Tensor();
    origins = torch::Tensor();
    directions = torch::Tensor();
    generators.clear();
    released_ = true;
  }

  torch::Tensor planes;  // detached
  bool planes_need_grad = false;
  std::vector<torch::Tensor> parameters;  // as given: their gradients are returned
  PointDecoder decoder;
  RenderOptions options;              // the chunks' options
  torch::Tensor origins, directions;  // [B,N,3], detached
  int64_t chunk = 1;
  std::vector<c10::optional<at::Generator>> generators;  // per chunk (none: deterministic)

 private:
  bool released_ = false;
};

// RenderTriplanes with options.grad_chunk_rays in grad mode (see RenderOptions).
RenderOutput RenderChunkedWithGrad(const torch::Tensor& planes, const PointDecoder& decoder, const Cameras& cameras,
                                   const RenderOptions& options, c10::optional<at::Generator> generator,
                                   RenderProfile* profile) {
  const Rays rays = RaysFor(cameras, options);
  const torch::Tensor origins = rays.origins.detach(), directions = rays.directions.detach();
  RenderOptions chunk_options = options;
  chunk_options.window_size = 0;
  chunk_options.window_corners = torch::Tensor();
  chunk_options.grad_chunk_rays = 0;
  chunk_options.grad_parameters.clear();
  // Computed exactly as an unchunked training render: no inference skips.
  chunk_options.early_termination = false;
  chunk_options.skip_missed_rays = false;
  chunk_options.skip_empty_space = false;
  chunk_options.occupancy.reset();
  const int64_t n = origins.size(1), chunk = options.grad_chunk_rays;
  // Jittered samples: the generator given, or the default one of the rays' device (the one
  // RenderRays would use); each chunk's backward render restarts from a copy of its state.
  c10::optional<at::Generator> jitter = generator;
  if (!chunk_options.deterministic && !jitter.has_value())
    jitter = at::globalContext().defaultGenerator(origins.device());
  std::vector<c10::optional<at::Generator>> states;
  std::vector<RayRenderOutput> parts;
  {
    torch::NoGradGuard no_grad;
    const Field field = MakeTriplaneField(planes, decoder, chunk_options.box_warp, profile);
    for (int64_t start = 0; start < n; start += chunk) {
      const int64_t len = std::min(chunk, n - start);
      if (jitter.has_value()) {
        std::lock_guard<std::mutex> lock(jitter->mutex());
        states.emplace_back(CopyGenerator(*jitter));
      } else {
        states.emplace_back(c10::nullopt);
      }
      parts.push_back(RenderRays(field, origins.narrow(1, start, len), directions.narrow(1, start, len), chunk_options,
                                 jitter, profile));
    }
  }
  RayRenderOutput rendered = Concatenate(parts, chunk_options);
  parts.clear();
  bool any_grad = planes.requires_grad();
  for (const auto& p : options.grad_parameters) any_grad = any_grad || (p.defined() && p.requires_grad());
  if (any_grad) {
    torch::autograd::edge_list edges = torch::autograd::collect_next_edges(planes);
    for (const auto& p : options.grad_parameters) {
      torch::autograd::edge_list e = torch::autograd::collect_next_edges(p);
      edges.insert(edges.end(), e.begin(), e.end());
    }
    auto node = std::shared_ptr<ChunkedRenderBackward>(new ChunkedRenderBackward(std::move(edges)),
                                                       torch::autograd::deleteNode);
    node->planes = planes.detach();
    node->planes_need_grad = planes.requires_grad();
    node->parameters = options.grad_parameters;
    node->decoder = decoder;
    node->options = chunk_options;
    node->origins = origins;
    node->directions = directions;
    node->chunk = chunk;
    node->generators = std::move(states);
    torch::autograd::set_history(rendered.features, node);
  }
  return ToImages(rendered, cameras.batch(), ImageSide(options));
}

}  // namespace

RenderOutput RenderField(const Field& field, const Cameras& cameras, const RenderOptions& options,
                         c10::optional<at::Generator> generator, RenderProfile* profile) {
  options.Validate();
  CheckCameras(cameras);
  const int64_t b = cameras.batch();
  const int64_t side = ImageSide(options);
  const Rays rays = RaysFor(cameras, options);
  const int64_t n = side * side;
  RayRenderOutput rendered;
  if (torch::GradMode::is_enabled()) {
    rendered = RenderRays(field, rays.origins, rays.directions, options, generator, profile);
  } else {
    // Inference: independent ray chunks in parallel, each small enough to stay in cache.
    const int64_t chunk = options.chunk_rays;
    const int64_t chunks = (n + chunk - 1) / chunk;
    std::vector<RayRenderOutput> parts(static_cast<size_t>(chunks));
    // Jittered samples: the chunks run on any thread in any order, so each gets a generator of
    // its own, seeded in chunk order from the caller's (or the device's default) generator.
    // One seed gives one image, whatever the thread count or scheduling.
    std::vector<c10::optional<at::Generator>> chunk_generators(static_cast<size_t>(chunks), generator);
    if (!options.deterministic && chunks > 1) {
      at::Generator source =
          generator.has_value() ? *generator : at::globalContext().defaultGenerator(rays.origins.device());
      // (The draw locks the generator itself; the clones below need the lock held.)
      const torch::Tensor seeds =
          torch::randint(std::numeric_limits<int64_t>::max(), {chunks}, source,
                         torch::TensorOptions().dtype(torch::kLong).device(rays.origins.device()))
              .cpu();
      const int64_t* seed = seeds.data_ptr<int64_t>();
      std::lock_guard<std::mutex> lock(source.mutex());
      for (int64_t i = 0; i < chunks; ++i) {
        at::Generator own = CopyGenerator(source);
        own.set_current_seed(static_cast<uint64_t>(seed[i]));
        chunk_generators[static_cast<size_t>(i)] = own;
      }
    }
    const bool inference_mode = c10::InferenceMode::is_enabled();
    at::parallel_for(0, chunks, 1, [&](int64_t begin, int64_t end) {
      // Grad and inference modes are per thread: restore the caller's in the workers.
      c10::InferenceMode inference_guard(inference_mode);
      torch::NoGradGuard no_grad;
      for (int64_t i = begin; i < end; ++i) {
        const int64_t start = i * chunk, len = std::min(chunk, n - start);
        parts[static_cast<size_t>(i)] = RenderRays(field, rays.origins.narrow(1, start, len),
                                                   rays.directions.narrow(1, start, len), options,
                                                   chunk_generators[static_cast<size_t>(i)], profile);
      }
    });
    rendered = Concatenate(parts, options);
  }
  return ToImages(rendered, b, side);
}

RenderOutput RenderTriplanes(const torch::Tensor& planes, const PointDecoder& decoder, const Cameras& cameras,
                             const RenderOptions& options, c10::optional<at::Generator> generator,
                             RenderProfile* profile) {
  CheckCameras(cameras);
  AVATAR_CHECK_INPUT(planes.defined() && planes.dim() == 5 && planes.size(0) == cameras.batch())
      << "tri-planes must be [B,3,C,H,W] with B = " << cameras.batch() << " cameras";
  AVATAR_CHECK_INPUT(planes.scalar_type() == cameras.cam2world.scalar_type() &&
                     planes.device() == cameras.cam2world.device())
      << "tri-planes and cameras must share dtype and device";
  options.Validate();
  const int64_t side = ImageSide(options);
  if (options.grad_chunk_rays > 0 && torch::GradMode::is_enabled() && side * side > options.grad_chunk_rays) {
    return RenderChunkedWithGrad(planes, decoder, cameras, options, generator, profile);
  }
  return RenderField(MakeTriplaneField(planes, decoder, options.box_warp, profile), cameras, options, generator,
                     profile);
}

RenderOutput RenderTriplanes(const torch::Tensor& planes, const PointDecoder& decoder, const torch::Tensor& labels,
                             const RenderOptions& options, c10::optional<at::Generator> generator,
                             RenderProfile* profile) {
  return RenderTriplanes(planes, decoder, CamerasFromLabels(labels), options, generator, profile);
}

}  // namespace avatar::render
