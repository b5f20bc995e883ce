#include "core/render/renderer.h"

#include <ATen/Parallel.h>

#include <cmath>

#include "core/render/depth_sampling.h"
#include "core/render/ray_marcher.h"
#include "core/render/triplane_sampling.h"
#include "core/util/error.h"
#include "core/util/timer.h"

namespace avatar::render {

namespace {

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
  const torch::Tensor coarse_depths = StratifiedDepths(b, n, num_coarse, options.near, options.far,
                                                       options.deterministic, origins.options(), generator);
  const Evaluated coarse = Evaluate(field, origins, directions, coarse_depths);
  const int64_t channels = coarse.features.size(3);
  RayRenderOutput out;
  MarchWeights weights;
  torch::Tensor composite;  // [B,N,C] in about [0,1]
  if (num_fine == 0) {
    weights = ComputeMarchWeights(coarse.raw, coarse_depths, options.far);
    composite = CompositeFeatures(weights.sample_weights, coarse.features);
  } else {
    torch::Tensor fine_depths;
    {
      torch::NoGradGuard no_grad;
      const MarchWeights coarse_weights = ComputeMarchWeights(coarse.raw.detach(), coarse_depths, options.far);
      fine_depths =
          ImportanceDepths(coarse_depths, coarse_weights.interval_weights, num_fine, options.deterministic, generator);
    }
    const Evaluated fine = Evaluate(field, origins, directions, fine_depths);
    AVATAR_CHECK_INPUT(fine.features.size(3) == channels) << "the field changed its channel count between calls";
    // Sort the union once; only the scalar densities are permuted. The per-sample weights are
    // mapped back to the unsorted order, so the features never need a gather.
    torch::Tensor sorted_depths, order;
    std::tie(sorted_depths, order) = torch::sort(torch::cat({coarse_depths, fine_depths}, 2), c10::optional<bool>(true),
                                                 /*dim=*/2, /*descending=*/false);
    const torch::Tensor sorted_raw = torch::cat({coarse.raw, fine.raw}, 2).gather(2, order);
    weights = ComputeMarchWeights(sorted_raw, sorted_depths, options.far);
    torch::Tensor inverse;
    {
      torch::NoGradGuard no_grad;
      const int64_t total = num_coarse + num_fine;
      inverse = torch::empty_like(order).scatter_(
          2, order, torch::arange(total, order.options()).view({1, 1, total}).expand_as(order));
    }
    const torch::Tensor unsorted = weights.sample_weights.gather(2, inverse);
    composite = CompositeFeatures(unsorted.narrow(2, 0, num_coarse), coarse.features) +
                CompositeFeatures(unsorted.narrow(2, num_coarse, num_fine), fine.features);
  }
  out.features = composite * 2.0 - 1.0;
  out.opacity = weights.opacity;
  out.depth = weights.depth;
  if (options.return_weights) {
    out.weights = weights.interval_weights;
    out.midpoints = weights.midpoints;
  }
  if (profile != nullptr) profile->total_ns += Nanoseconds(timer);
  return out;
}

RenderOutput RenderField(const Field& field, const Cameras& cameras, const RenderOptions& options,
                         c10::optional<at::Generator> generator, RenderProfile* profile) {
  options.Validate();
  CheckCameras(cameras);
  const int64_t res = options.resolution;
  const int64_t b = cameras.batch();
  const Rays rays = GenerateRays(cameras, res);
  const int64_t n = res * res;
  RayRenderOutput rendered;
  if (torch::GradMode::is_enabled()) {
    rendered = RenderRays(field, rays.origins, rays.directions, options, generator, profile);
  } else {
    // Inference: independent ray chunks in parallel, each small enough to stay in cache.
    const int64_t chunk = options.chunk_rays;
    const int64_t chunks = (n + chunk - 1) / chunk;
    std::vector<RayRenderOutput> parts(static_cast<size_t>(chunks));
    const bool inference_mode = c10::InferenceMode::is_enabled();
    at::parallel_for(0, chunks, 1, [&](int64_t begin, int64_t end) {
      // Grad and inference modes are per thread: restore the caller's in the workers.
      c10::InferenceMode inference_guard(inference_mode);
      torch::NoGradGuard no_grad;
      for (int64_t i = begin; i < end; ++i) {
        const int64_t start = i * chunk, len = std::min(chunk, n - start);
        parts[static_cast<size_t>(i)] = RenderRays(field, rays.origins.narrow(1, start, len),
                                                   rays.directions.narrow(1, start, len), options, generator, profile);
      }
    });
    const auto gather = [&](auto member) {
      std::vector<torch::Tensor> pieces;
      pieces.reserve(parts.size());
      for (const auto& p : parts) pieces.push_back(p.*member);
      return torch::cat(pieces, 1);
    };
    rendered.features = gather(&RayRenderOutput::features);
    rendered.opacity = gather(&RayRenderOutput::opacity);
    rendered.depth = gather(&RayRenderOutput::depth);
    if (options.return_weights) {
      rendered.weights = gather(&RayRenderOutput::weights);
      rendered.midpoints = gather(&RayRenderOutput::midpoints);
    }
  }
  RenderOutput out;
  const int64_t c = rendered.features.size(2);
  out.features = rendered.features.view({b, res, res, c}).permute({0, 3, 1, 2}).contiguous();
  if (c >= 3) out.rgb = out.features.narrow(1, 0, 3);
  out.opacity = rendered.opacity.view({b, 1, res, res});
  out.depth = rendered.depth.view({b, 1, res, res});
  out.weights = rendered.weights;
  out.midpoints = rendered.midpoints;
  return out;
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
  return RenderField(MakeTriplaneField(planes, decoder, options.box_warp, profile), cameras, options, generator,
                     profile);
}

RenderOutput RenderTriplanes(const torch::Tensor& planes, const PointDecoder& decoder, const torch::Tensor& labels,
                             const RenderOptions& options, c10::optional<at::Generator> generator,
                             RenderProfile* profile) {
  return RenderTriplanes(planes, decoder, CamerasFromLabels(labels), options, generator, profile);
}

}  // namespace avatar::render
