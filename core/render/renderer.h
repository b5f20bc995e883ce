#pragma once
// The volume renderer shared by the three branches: cameras -> rays -> depth samples ->
// field (tri-planes + decoder, or any injected field) -> ray marching -> images.
//
// Typical use (network code):
//   render::RenderOptions opts;                       // 128^2, 48 + 48 samples, deterministic
//   auto decode = [&](const torch::Tensor& f) { return decoder->forward(f); };
//   auto out = render::RenderTriplanes(planes, decode, render::CamerasFromLabels(labels), opts);
//   out.rgb  // [B,3,128,128] in [-1,1]
//
// Gradients flow to the planes, the decoder and any tensors an injected field uses. In grad
// mode the whole batch is rendered as one autograd graph (RenderTriplanes with
// RenderOptions::grad_chunk_rays: one chunk of rays at a time); with grad mode off (NoGradGuard or
// InferenceMode) rays are rendered in chunks in parallel with the fast CPU plane sampler.
// The result is the same either way (to float rounding).

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include <torch/torch.h>

#include "core/render/camera.h"
#include "core/render/occupancy_grid.h"
#include "core/render/rays.h"

namespace avatar::render {

struct RenderOptions {
  // Output image side in pixels (square images, R x R rays per camera).
  int resolution = 128;
  // Stratified (coarse) samples per ray.
  int num_coarse = 48;
  // Importance (fine) samples per ray, drawn from the coarse weights; 0 disables the fine pass.
  int num_importance = 48;
  // Depth of the first sample range boundary along each ray (world units).
  double near = 2.25;
  // Depth of the far boundary; also the depth reported for empty rays.
  double far = 3.3;
  // Side of the cube (centred at the origin) that the planes span, world units.
  double box_warp = 1.0;
  // Fixed sample positions and quantiles (bit-identical frames); off = random jitter for training.
  bool deterministic = true;
  // Also return per-interval weights and their midpoint depths.
  bool return_weights = false;
  // Rays per parallel work item when rendering without gradients (memory/cache trade-off).
  int chunk_rays = 256;
  // Inference-only skips. They take effect only while grad mode is off (the chunked path), so a
  // training render is computed exactly as without them; all default off.
  // Early ray termination: coarse samples are evaluated in blocks of `termination_block`; a ray
  // whose transmittance fell below `termination_transmittance` evaluates no further coarse
  // samples, and no importance samples behind the coarse sample where it fell below.
  bool early_termination = false;
  double termination_transmittance = 1e-3;
  int termination_block = 8;
  // Rays whose [near, far] segment misses the tri-plane box (side box_warp, grown by
  // miss_margin * box_warp on each side for the bilinear footprint) are not marched: features
  // -1 (background), opacity 0, depth far. Assumes the field is empty outside the box.
  bool skip_missed_rays = false;
  double miss_margin = 0.02;
  // Empty-space skipping: samples that `occupancy` (occupancy_grid.h, built from the planes being
  // rendered, batch B) places in empty space, grown by floor(sample spacing / cell) + 1 cells,
  // are not evaluated (no plane lookup, no decoder). Each ray loses at most
  // occupancy->sigma_threshold() x (far - near) of optical depth. Needs `occupancy`; without it
  // the flag does nothing (GohaModelImpl::RenderWith builds one when the flag is set).
  bool skip_empty_space = false;
  std::shared_ptr<const OccupancyGrid> occupancy;
  // Outputs computed only when asked (default: both; undefined tensors when off).
  bool return_depth = true;
  bool return_opacity = true;
  // Training on patches: render only a window of the resolution x resolution image of each
  // camera, window_size x window_size pixels whose top-left pixel (row, column) is
  // window_corners[b] (an integer tensor [B,2], any device). The rays are the whole image's rays
  // of those pixels (GenerateWindowRays), so a window render equals the crop of the whole render;
  // image outputs are [B,C,window_size,window_size], weights [B,window_size^2,S-1].
  // 0 = the whole image.
  int window_size = 0;
  torch::Tensor window_corners;
  // Ray-chunked renders with gradients (RenderTriplanes only; training memory): when > 0, grad
  // mode is on and a camera has more rays than this, the image is rendered without gradients in
  // chunks of grad_chunk_rays rays (each with its own copy of the jitter generator's state), and
  // the backward pass renders each chunk again with gradients from a detached copy of the planes
  // and the same sample positions, and sums the gradients of the planes and of grad_parameters.
  // Only the activations of one chunk are held at a time. Features (and rgb) carry the
  // gradient; opacity, depth and weights come without one. The inference skips are not used.
  // 0 = off (one autograd graph for every ray).
  int grad_chunk_rays = 0;
  // Chunked renders: the tensors the decoder reads that need gradients (e.g. the decoder's
  // parameters). A tensor not listed gets no gradient from a chunked render.
  std::vector<torch::Tensor> grad_parameters;

  // Turns on every inference skip above (not the output flags).
  void EnableInferenceSkips() {
    early_termination = true;
    skip_missed_rays = true;
    skip_empty_space = true;
  }

  template <typename V>
  void Visit(V&& v) {
    v("resolution", resolution, "Rendered image side in pixels");
    v("num_coarse", num_coarse, "Stratified samples per ray");
    v("num_importance", num_importance, "Importance samples per ray (0 = none)");
    v("near", near, "Near depth of the sampled range (world units)");
    v("far", far, "Far depth of the sampled range; depth of empty rays");
    v("box_warp", box_warp, "Side of the cube the tri-planes span (world units)");
    v("deterministic", deterministic, "Fixed sample positions (inference); --no-deterministic jitters (training)");
    v("return_weights", return_weights, "Return per-sample weights and depths");
    v("chunk_rays", chunk_rays, "Rays per parallel work item without gradients");
  }
  // Throws InvalidOptions: resolution 1..4096, num_coarse >= 2 (>= 4 with importance samples),
  // num_importance >= 0, 0 <= near < far finite, box_warp > 0, chunk_rays >= 1,
  // termination_transmittance in [0,1), termination_block >= 1, miss_margin in [0,1],
  // 0 <= window_size <= resolution (with corners when > 0), grad_chunk_rays >= 0.
  void Validate() const;
};

// What a field returns for points [B,P,3].
struct FieldSamples {
  torch::Tensor raw_density;  // [B,P]   before softplus(raw - 1)
  torch::Tensor features;     // [B,P,C] decoded features (about [0,1])
};

// A radiance field: world points [B,P,3] -> samples. Must be safe to call from several threads
// at once when rendering without gradients.
using Field = std::function<FieldSamples(const torch::Tensor& points)>;

// Optional time accounting for benchmarks: nanoseconds summed over all threads.
struct RenderProfile {
  std::atomic<int64_t> total_ns{0};   // inside RenderRays (all stages)
  std::atomic<int64_t> sample_ns{0};  // tri-plane lookups
  std::atomic<int64_t> decode_ns{0};  // decoder MLP
  std::atomic<int64_t> points{0};     // field evaluations (points)
};

// A point decoder: plane features [..., C] -> [..., 1 + C'] (raw density, features), e.g.
// TriplaneDecoder::forward.
using PointDecoder = std::function<torch::Tensor(const torch::Tensor& features)>;

// The tri-plane field: planes [B,3,C,H,W] sampled as in triplane_sampling.h, then decoded.
// Holds a channels-last copy of the planes for the fast sampler when no gradient is needed.
// Throws InvalidInput for bad planes or box_warp.
Field MakeTriplaneField(const torch::Tensor& planes, PointDecoder decoder, double box_warp,
                        RenderProfile* profile = nullptr);

// Per-ray results.
struct RayRenderOutput {
  torch::Tensor features;   // [B,N,C] in [-1,1] (decoder margin: [-1.002,1.002]); -1 for empty rays
  torch::Tensor opacity;    // [B,N]   in [0,1] (return_opacity)
  torch::Tensor depth;      // [B,N]   expected depth; `far` for empty rays (return_depth)
  torch::Tensor weights;    // [B,N,S-1] interval weights (return_weights), S = coarse + importance
  torch::Tensor midpoints;  // [B,N,S-1] interval midpoint depths (return_weights)
};

// Image results, R = options.resolution.
struct RenderOutput {
  torch::Tensor features;   // [B,C,R,R] in [-1,1] as above
  torch::Tensor rgb;        // [B,3,R,R] = features channels 0..2 (a view)
  torch::Tensor opacity;    // [B,1,R,R] in [0,1] (return_opacity)
  torch::Tensor depth;      // [B,1,R,R] (return_depth)
  torch::Tensor weights;    // [B,R*R,S-1] (return_weights)
  torch::Tensor midpoints;  // [B,R*R,S-1] (return_weights)
};

// Renders arbitrary rays (origins, directions [B,N,3], directions unit length) through a field.
// Uses options except resolution. Throws InvalidOptions/InvalidInput.
RayRenderOutput RenderRays(const Field& field, const torch::Tensor& origins, const torch::Tensor& directions,
                           const RenderOptions& options, c10::optional<at::Generator> generator = c10::nullopt,
                           RenderProfile* profile = nullptr);

// Renders images of a field from cameras.
RenderOutput RenderField(const Field& field, const Cameras& cameras, const RenderOptions& options,
                         c10::optional<at::Generator> generator = c10::nullopt, RenderProfile* profile = nullptr);

// Renders tri-planes [B,3,C,H,W] from cameras (B cameras, one per plane set). With
// options.grad_chunk_rays (see there) a render with gradients is ray-chunked.
RenderOutput RenderTriplanes(const torch::Tensor& planes, const PointDecoder& decoder, const Cameras& cameras,
                             const RenderOptions& options, c10::optional<at::Generator> generator = c10::nullopt,
                             RenderProfile* profile = nullptr);
// Same with camera labels [B,25].
RenderOutput RenderTriplanes(const torch::Tensor& planes, const PointDecoder& decoder, const torch::Tensor& labels,
                             const RenderOptions& options, c10::optional<at::Generator> generator = c10::nullopt,
                             RenderProfile* profile = nullptr);

}  // namespace avatar::render
