#pragma once
// Training the fusion net (core/model/fusion_net.h) on a fusion set (core/tools/fusion_set.h):
// the 3D core's frames were rendered once and stored, so a step is the 2D net alone. Random
// crops and mirror flips of the stored frames, Adam, L1 plus the MobileNetV2 perceptual distance
// against the target frame; NaN-safe, resumable, logged like the stage I/II runs:
//   RUN/state.pt         weights + Adam state + step (resumed from when present)
//   RUN/fusion.ckpt, RUN/fusion-fp16.ckpt   the weights (at every state write and at the end)
//   RUN/train.jsonl      one line per step ({"step", "loss", "terms": {"l1", "perceptual"}, "step_s", ...})
//                        and one per validation ({"step", "val": {...}})

#include <cstdint>
#include <string>
#include <vector>

#include <torch/torch.h>

#include "core/model/fusion_net.h"
#include "core/train/perceptual.h"
#include "core/util/run_context.h"

namespace avatar::train {

// One split of a fusion set in memory (uint8 on the CPU, as stored).
struct FusionSamples {
  torch::Tensor input;    // [N,11,S,S] fusion_input.h
  torch::Tensor target;   // [N,3,S,S] RGB, matted onto black
  torch::Tensor matte;    // [N,1,S,S]
  torch::Tensor preview;  // [N,3,S,S] RGB, the morphable preview
  torch::Tensor meta;     // [N,4] float: d yaw, d pitch (degrees), expression distance, kind (0 photo, 1 clip, 2 synthetic)
  int64_t size() const { return input.defined() ? input.size(0) : 0; }
  // The turn of each frame's view from its photo's (FusionTurnDegrees of meta's d yaw and d pitch), [N].
  torch::Tensor Turn() const;
};

// Every file of `split` ("train" or "val") of the fusion set in `dir`, in file-name order.
// Throws InvalidOptions (split), Io (no such folder), InvalidInput (a file that does not hold the
// five tensors of one size, naming it).
FusionSamples LoadFusionSplit(const std::string& dir, const std::string& split);

struct FusionLossOptions {
  double l1 = 1.0;          // weight of the mean absolute error (images in [-1,1])
  double perceptual = 0.5;  // weight of the MobileNetV2 perceptual distance
  double ssim = 0.0;        // weight of 1 - SSIM (11 px Gaussian window, as the eval's)
  void Validate() const;
};

// The loss of predictions against targets ([B,3,H,W] in [-1,1]): {total [], l1 [], perceptual [],
// ssim [] (1 - SSIM; 0 when its weight is 0)}. `perceptual` may be null (weight must then be 0).
struct FusionLoss {
  torch::Tensor total, l1, perceptual, ssim;
};
FusionLoss ComputeFusionLoss(const torch::Tensor& prediction, const torch::Tensor& target,
                             const PerceptualLoss* perceptual, const FusionLossOptions& options);

struct FusionTrainOptions {
  std::string data;     // fusion set folder
  std::string out_dir;  // run folder
  int64_t steps = 100000;  // train until this step (absolute)
  double hours = 0.0;      // stop after this many hours (0 = no limit)
  bool resume = true;      // continue from RUN/state.pt when present
  std::string init;        // a fresh run starts from these fusion weights ("" = the net's own init)
  int batch = 8;
  int crop = 128;          // side of the random crops (a multiple of 8, at most the stored size)
  double lr = 2e-4;  // 1e-3 killed a run (fusion-2); 2e-4 trained steadily (fusion-3)
  double color_jitter = 0.2;  // per crop: a random channel order and per-channel gain/offset of this size
  FusionLossOptions loss;
  int64_t seed = 1;
  double checkpoint_minutes = 10.0;
  int64_t validate_every = 500;   // steps between validations (0 = only at the end)
  int validate_samples = 64;      // validation frames (evenly spread), whole frames
  int max_bad_steps = 20;         // non-finite steps in a row before the run stops
  std::vector<int64_t> widths = {16, 32, 64, 96};
  bool keep_warped = true;  // FusionNetOptions::keep_warped; --init may start from a net without it
  bool turn = false;        // FusionNetOptions::turn; --init may start from a net without it
  bool gate_by_opacity = false;  // FusionNetOptions::gate_by_opacity
  bool turn_keeps_face = false;  // FusionNetOptions::turn_keeps_face (with turn)
  double turn_open = 1.0;        // FusionNetOptions::turn_open (with turn)
  bool keep_eye_mouth = false;   // FusionNetOptions::keep_eye_mouth
  bool progress = true;
  std::string data_dir;  // where the MobileNetV2 weights are ("" = default)

  template <typename V>
  void Visit(V&& v) {
    v("data", data, "Fusion set folder (avatar-studio fusion build)");
    v("out", out_dir, "Run folder");
    v("steps", steps, "Train until this step");
    v("hours", hours, "Stop after this many hours (0 = no limit)");
    v("resume", resume, "Continue from RUN/state.pt when it exists");
    v("init", init, "Fusion weights a fresh run starts from");
    v("batch", batch, "Crops per step");
    v("crop", crop, "Side of the random crops");
    v("lr", lr, "Adam learning rate");
    v("color_jitter", color_jitter, "Per-crop colour change (channel order, gain and offset) of the images; 0 = off");
    v("l1", loss.l1, "Weight of the L1 term");
    v("perceptual", loss.perceptual, "Weight of the MobileNetV2 perceptual term");
    v("ssim", loss.ssim, "Weight of the 1 - SSIM term");
    v("keep_warped", keep_warped, "Keep the photo wherever its warp reached (the residual acts only elsewhere)");
    v("turn", turn, "Give the net the view's turn from the photo and let it act on the warped photo in proportion");
    v("gate_by_opacity", gate_by_opacity, "Let the residual act only on the frame's opaque pixels");
    v("turn_keeps_face", turn_keeps_face, "With --turn: keep the face warp's photo at every turn (only the depth warp opens)");
    v("turn_open", turn_open, "With --turn: the share (0..1) of the turn's opening that the warped photo gets");
    v("keep_eye_mouth", keep_eye_mouth, "Keep the composite on the target's eyes and mouth (no residual there)");
    v("seed", seed, "Seed of the crops and batches");
    v("validate_every", validate_every, "Steps between validations");
    v("validate_samples", validate_samples, "Validation frames");
  }
  void Validate() const;
  // The net these options train (widths and the keep/turn/gate flags).
  FusionNetOptions NetOptions() const;
};

// Validation figures of the net against the geometric composite on whole frames.
struct FusionValidation {
  int64_t samples = 0;
  double loss = 0.0, l1 = 0.0, perceptual = 0.0, ssim = 0.0;                                // the net's output
  double composite_loss = 0.0, composite_l1 = 0.0, composite_perceptual = 0.0, composite_ssim = 0.0;  // its input
};
// The net in eval mode on `samples` (at most `count` of them, evenly spread; whole frames).
FusionValidation ValidateFusion(FusionNet& net, const FusionSamples& samples, int count,
                                const PerceptualLoss* perceptual, const FusionLossOptions& options);

struct FusionTrainResult {
  int64_t first_step = 0, last_step = 0, skipped = 0;
  std::string stopped_by;  // "steps" or "hours"
  FusionValidation last_validation;
};

// Runs (or resumes) a training run. On cancel writes the state and the weights and throws
// Cancelled; after max_bad_steps non-finite steps in a row writes the last good state and throws
// InvalidInput. Throws InvalidOptions, Io, ModelLoad.
FusionTrainResult TrainFusion(const FusionTrainOptions& options, RunContext& ctx);

}  // namespace avatar::train
