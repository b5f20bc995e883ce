#pragma once
// GOHA's training (Li et al. 2023, section 3.4) on one device: stage I (every branch, no
// super-resolution) and stage II (only the super-resolution module, with a dual discriminator).
//
// Stage I. One step, for a batch (I_s, I_exp, I_neu, M_neu, I_t, cameras C_s, C_t):
//   T_c = CanonicalPlanes(I_s); T_e = ExpressionPlanes(I_exp); T_p = AppearancePlanes(I_s, ..., C_s)
//   I_c = R(T_c, C_t), I_c+e = R(T_c + T_e, C_t), I_c+e+p = R(T_c + T_e + T_p, C_t)
//   each against the matted target resized to the render size: L1 + perceptual_weight x perceptual;
//   + neutral_weight x NeutralLoss(R(T_c, C_s), I_neu, M_neu)
//   + tv_weight x DensityTvLoss on the densities of the largest active plane sum.
// Terms with weight 0 (neutral_weight, tv_weight) are not computed at all (no render, no term).
//
// Ablations (issue 14, the paper's Table 4) follow the model config (core/model/model_config.h):
// without an appearance branch (appearance_branch false) I_c+e+p is never rendered and there is
// no "appearance" term (the phase stays "expression"); with expression bases (expression_model
// "bases") T_e = ExpressionPlanesFromCoefficients(beta_t) from the batch's target_expression
// instead of E_e(I_exp). The modules either switches off (FrozenByConfig) are not optimised and
// keep the values they were initialised with. The w/o-neutral ablation is neutral_weight 0.
//
// Training renders jitter their stratified and importance samples (RenderOptions::deterministic
// = false, unless TrainerOptions::deterministic_render); evaluation renders (Evaluate) are
// deterministic. Cheap steps (issue 12, off by default): with patch_size the target-camera
// renders and their targets are random windows of the render grid, one per sample; with
// grad_chunk_rays the renders with gradients are ray-chunked (same gradients, less memory).
//
// Curriculum (the paper's 750k stage-I steps: + expression at 120k = 16%, + appearance at
// 240k = 32%): steps [0, expression_start) train I_c only, [expression_start, appearance_start)
// add I_c+e, later steps add I_c+e+p. With `rotation` the release's rotation of step kinds
// (after expression_start, step mod 6: 0-1 all renders, 2-3 I_c+e only, 4-5 neutral only) is
// used; off by default (every step has every active term).
//
// Stage II (stage = 2; the paper fine-tunes only the super-resolution module, 75k steps). The
// stage-I parts are frozen: under NoGradGuard the full sum T_c + T_e + T_p is rendered once at
// C_t (jittered) -> I (r x r), then I_hr = SR(I) (S x S) with gradients to the SR only. With
// x_t the matted target at S and x_t,lo the matted target at r:
//   G (SR):  "sr" = L1 + perceptual_weight x perceptual of I_hr vs x_t (the stage-I image loss
//            at SR resolution), "gan" = gan_weight (0.1, as the release) x softplus(-D(I_hr, I))
//   D:       softplus(D(I_hr, I)) + softplus(-D(x_t, x_t,lo)) (core/train/gan.h), and every
//            r1_every (16) steps the lazy R1 penalty on the real pair: r1_gamma (10) / 2 x
//            r1_every x |grad D(x_t, x_t,lo)|^2 (gradient w.r.t. both inputs of the dual
//            discriminator, as EG3D does; the real low-res input is the target at render size).
//   D is core/model's DualDiscriminator (6 channels: the high-res image and the low-res image
//   upsampled); its own Adam (d_lr, same betas and eps). G and D gradients are taken from the
//   same forward pass (D sees the SR output before this step's update) and both optimisers step
//   only when every loss and gradient is finite. The SR's per-layer noise maps are drawn afresh
//   (N(0,1), global generator) for each training forward and put back after it, so inference
//   keeps its fixed maps. D's weights and Adam state are part of the training state; exported
//   checkpoints of stage II say CheckpointInfo::sr_trained = true.
//
// Optimiser: Adam (betas 0, 0.99, lr 1e-4, eps 1e-8) written out here so that its state is plain
// tensors in the training state; it follows torch::optim::Adam's update (bias-corrected moments, eps
// added after the square root, no weight decay). Lazy R1 keeps the betas as they are (StyleGAN2
// would rescale them by 16/17). Gradients are clipped to a global L2 norm of grad_clip (G and D
// separately). A step whose loss or gradient is not finite changes nothing and is counted;
// max_bad_steps such steps in a row stop the run.
//
// Initialisation from weights (InitFromCheckpoint, RunOptions::init_weights): a fresh run takes
// the model tensors of a model checkpoint (float16 files too) and its step (the curriculum and
// the log continue); Adam starts afresh. This is how stage II starts from stage-I weights. The
// checkpoint's config must equal the trained one except for the ablation fields
// (appearance_branch, expression_model, expression_coefficients): an ablation starts from the
// full model's weights, the expression bases (absent from an encoder checkpoint) keep their
// initialisation (zeros) and expression_std keeps what the caller set.
//
// Training state (TensorArchive kind "goha-train-state"): weights, Adam moments and step
// counts, D and its Adam state (stage II), the stage, the step, the global CPU (and device)
// generator state, the data source's cursor and the counters; written atomically and never when
// a tensor is not finite. Resuming continues the same run; a state of the other stage is refused.

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include "core/model/goha_model.h"
#include "core/render/camera.h"
#include "core/train/losses.h"
#include "core/train/sample.h"
#include "core/util/run_context.h"
#include "core/util/timer.h"

namespace avatar::train {

// Whether `config` switches off the module of parameter `name` (an ablation): the appearance
// encoder and upsamplers without an appearance branch, E_e and its head with expression bases.
// The trainer never optimises those parameters.
bool FrozenByConfig(const ModelConfig& config, const std::string& name);

// The model config stored in a training state file (RUN/state.ckpt). Throws Io / ModelLoad.
ModelConfig ReadStateModelConfig(const std::filesystem::path& path);

// Where the trainer gets its batches. The dataset loader implements it; tests feed synthetic ones.
class BatchSource {
 public:
  virtual ~BatchSource() = default;
  // The next batch (any device; the trainer moves it).
  virtual TrainBatch Next() = 0;
  // The cursor (what Restore needs to continue with the same next batch).
  virtual nlohmann::json State() const = 0;
  virtual void Restore(const nlohmann::json& state) = 0;
};

// Data-parallel training (core/train/distributed.h has the torch.distributed implementation):
// how the ranks of a group agree. Every rank calls every method in the same order.
class GradientReducer {
 public:
  virtual ~GradientReducer() = default;
  virtual int64_t rank() const = 0;
  virtual int64_t world_size() const = 0;
  // Called by the trainer on every rank once per step, after its backward pass (also when its own
  // loss was not finite: local_ok false, no backward). Sums the gradients of `params` over the
  // ranks and divides them by world_size() (a rank without a gradient for a parameter adds zeros;
  // one that no rank has stays undefined) and replaces `values` by their mean over the ranks.
  // Returns true when local_ok was true on every rank.
  virtual bool ReduceGradients(const std::vector<torch::Tensor>& params, bool local_ok,
                               std::vector<double>& values) = 0;
  // Rank 0's tensors to every rank, in place (same shapes and types on every rank).
  virtual void Broadcast(const std::vector<torch::Tensor>& tensors) = 0;
  // Element-wise maximum over the ranks, in place.
  virtual void AllMax(std::vector<double>& values) = 0;
};

struct TrainerOptions {
  // Device ("cpu", "cuda", "cuda:1").
  std::string device = "cpu";
  // Adam.
  double lr = 1e-4;
  double beta1 = 0.0;
  double beta2 = 0.99;
  double eps = 1e-8;
  // Global gradient L2-norm clip (release: 1000); <= 0 disables.
  double grad_clip = 1000.0;
  // Loss weights.
  double perceptual_weight = 1.0;
  double neutral_weight = 3.0;
  double tv_weight = 0.25;
  // TV loss points per sample and perturbation (normalised units).
  int64_t tv_points = 1000;
  double tv_sigma = 0.004;
  // Curriculum, in steps (see the header comment).
  int64_t expression_start = 0;
  int64_t appearance_start = 0;
  // The release's mod-6 rotation of step kinds after expression_start.
  bool rotation = false;
  // Non-finite steps in a row that stop the run.
  int64_t max_bad_steps = 5;
  // Seed of the global generator at the start of a fresh run.
  int64_t seed = 1;
  // Training stage: 1 (every branch but the SR) or 2 (only the SR, with the discriminator).
  int64_t stage = 1;
  // Stage II: weight of the generator's adversarial term (release: 0.1).
  double gan_weight = 0.1;
  // Stage II: R1 weight gamma and its lazy interval (R1 runs when step % r1_every == 0, weighted
  // gamma / 2 x r1_every); gamma 0 turns it off.
  double r1_gamma = 10.0;
  int64_t r1_every = 16;
  // Stage II: discriminator learning rate (Adam with beta1, beta2, eps as above; paper: 1e-4).
  double d_lr = 1e-4;
  // Stage II: fresh random SR noise maps in every training forward (off: the fixed maps).
  bool sr_random_noise = true;
  // Training renders at fixed sample positions (no jitter; evaluation renders always are). With
  // tv_weight 0 a stage-I step then draws no random numbers, which makes data-parallel runs equal
  // to a single-process run at the global batch (core/train/distributed.h).
  bool deterministic_render = false;
  // Stage I, cheap steps (issue 12). Patches: when 0 < patch_size < render size, each sample of a
  // step renders only a random patch_size x patch_size window of its target-camera image (drawn
  // per sample from the global CPU generator, so a resumed run draws the same windows; the same
  // window for I_c, I_c+e and I_c+e+p), and their image losses compare it with the same window of
  // the target resized to render size. The neutral render (source camera) stays whole, and so do
  // Evaluate's renders. With the MobileNetV2 perceptual term the patch must be >= 32 pixels.
  // 0 (or >= render size) = whole images.
  int64_t patch_size = 0;
  // Ray-chunked training renders (render::RenderOptions::grad_chunk_rays): rays per chunk of every
  // stage-I render with gradients; the forward pass renders without gradients and the backward
  // pass renders one chunk at a time again, so a render holds one chunk's activations, not the
  // whole image's. Gradients equal the unchunked ones (to float rounding). 0 = off.
  int64_t grad_chunk_rays = 0;

  template <typename V>
  void Visit(V&& v) {
    v("device", device, "Device: cpu or cuda[:N]");
    v("lr", lr, "Adam learning rate");
    v("beta1", beta1, "Adam beta1");
    v("beta2", beta2, "Adam beta2");
    v("eps", eps, "Adam epsilon");
    v("grad_clip", grad_clip, "Global gradient-norm clip (<= 0: none)");
    v("perceptual_weight", perceptual_weight, "Weight of the perceptual term of every image loss");
    v("neutral_weight", neutral_weight, "Weight of the neutral loss");
    v("tv_weight", tv_weight, "Weight of the density TV loss");
    v("tv_points", tv_points, "TV loss points per sample");
    v("tv_sigma", tv_sigma, "TV perturbation std (normalised plane units)");
    v("expression_start", expression_start, "First step with the expression planes");
    v("appearance_start", appearance_start, "First step with the appearance planes");
    v("rotation", rotation, "Release's mod-6 rotation of step kinds");
    v("max_bad_steps", max_bad_steps, "Non-finite steps in a row that stop the run");
    v("seed", seed, "Seed of a fresh run");
    v("stage", stage, "Training stage: 1 or 2 (super-resolution only)");
    v("gan_weight", gan_weight, "Stage II: weight of the generator's adversarial loss");
    v("r1_gamma", r1_gamma, "Stage II: R1 penalty gamma (0: off)");
    v("r1_every", r1_every, "Stage II: lazy R1 interval in steps");
    v("d_lr", d_lr, "Stage II: discriminator learning rate");
    v("sr_random_noise", sr_random_noise, "Stage II: random SR noise maps while training");
    v("deterministic_render", deterministic_render, "Training renders without sample jitter");
    v("patch_size", patch_size, "Stage I: render random patches of this side at the target camera (0 = whole images)");
    v("grad_chunk_rays", grad_chunk_rays, "Stage I: rays per chunk of ray-chunked renders with gradients (0 = off)");
  }
  // Throws InvalidOptions.
  void Validate() const;
  // Curriculum boundaries at the paper's proportions (16% / 32%) of `total_steps`.
  void ScheduleFor(int64_t total_steps);
};

// What one Step did.
struct StepResult {
  int64_t step = 0;                      // step index this was (0-based)
  std::map<std::string, double> terms;   // weighted batch-mean loss terms
  double loss = 0.0;                     // their sum
  double grad_norm = 0.0;                // before clipping
  // Stage II: the discriminator's terms ("d": GAN loss, "r1": weighted R1 when it ran; plus the
  // batch-mean logits "real_logit" and "fake_logit", not losses), its loss and gradient norm.
  std::map<std::string, double> d_terms;
  double d_loss = 0.0;
  double d_grad_norm = 0.0;
  bool skipped = false;                  // non-finite loss or gradient: nothing changed
  std::string skip_reason;
  double seconds = 0.0;
  std::string phase;                     // canonical, expression, appearance, super_resolution
};

class StageOneTrainer {
 public:
  // `model` is moved to the options' device. `perceptual` may be empty (L1 only).
  StageOneTrainer(GohaModel model, const TrainerOptions& options, PerceptualFn perceptual);

  // One optimiser step on `batch`. A non-finite step is counted (bad_in_a_row); RunTraining stops on it.
  StepResult Step(const TrainBatch& batch);

  // The weighted stage-I loss terms (canonical, expression, appearance, neutral, tv; each a
  // batch mean with its graph) that Step(`b`) takes at `step` (curriculum and rotation), for a
  // batch already on device(). Step sums and backpropagates them; `bench train` times them.
  std::map<std::string, torch::Tensor> LossTerms(const TrainBatch& b, int64_t step);

  // Deterministic renders (no gradient) of the three plane sums at the target camera, in [-1,1].
  struct Renders {
    torch::Tensor target, canonical, expression, full;  // [B,3,R,R]
    torch::Tensor source;                               // I_s [B,3,S,S] as given
    torch::Tensor super_resolved;                       // stage II: SR(full) [B,3,sr,sr] (fixed noise)
  };
  Renders Evaluate(const TrainBatch& batch);

  // Fresh-run initialisation from a model checkpoint: every model tensor and the step (see the
  // header comment). Throws Io / ModelLoad (unreadable file) or InvalidOptions when its model
  // config is not the one being trained (ablation fields aside).
  void InitFromCheckpoint(const std::filesystem::path& path);

  // State files (see the header comment). Save throws InvalidInput on a non-finite tensor (and
  // writes nothing); Load throws Io / ModelLoad and checks that the model config matches.
  void SaveState(const std::filesystem::path& path, const BatchSource* source = nullptr) const;
  // The same with the data cursor given (a BatchSource::State()), e.g. the one from before a
  // batch whose step was cancelled, so that a resume trains on that batch.
  void SaveStateAt(const std::filesystem::path& path, const nlohmann::json& data_cursor) const;
  void LoadState(const std::filesystem::path& path, BatchSource* source = nullptr);
  // Weights-only model checkpoint (LoadModelCheckpoint reads it). Throws on non-finite weights.
  // half_precision: float16 shipping weights (half the size; loads into the float32 model).
  void ExportWeights(const std::filesystem::path& path, const std::string& data_provenance,
                     bool half_precision = false) const;

  // Data parallelism: with a reducer every Step averages its gradients (and reported losses)
  // over the ranks before the non-finite check and clipping, so every rank takes the same
  // decision and update. RunTraining then broadcasts rank 0's weights at the start and only rank
  // 0 writes the state, log, samples and weights. Null: one process.
  void SetGradientReducer(std::shared_ptr<GradientReducer> reducer) { reducer_ = std::move(reducer); }
  // One process: a stage-I Step checks `ctx` between its renders and before the update, and a
  // cancel throws Cancelled with the weights, the optimiser and the step as they were (so a
  // cancel waits for one render, not a whole step). RunTraining sets it for its run without a
  // reducer (ranks must stop together, at a step boundary); null = never.
  void SetCancelContext(const RunContext* ctx) { cancel_ = ctx; }
  GradientReducer* gradient_reducer() const { return reducer_.get(); }
  // Rank 0's weights, buffers and optimiser moments to every rank (the discriminator's too);
  // throws InvalidInput when the ranks are not at the same step (e.g. a state resumed by only
  // some ranks: every rank must see the same run folder). No-op without a reducer.
  void SyncFromRankZero();

  GohaModel& model() { return model_; }
  // Stage II's discriminator (empty in stage I).
  DualDiscriminator& discriminator() { return disc_; }
  const TrainerOptions& options() const { return options_; }
  const torch::Device& device() const { return device_; }
  int64_t step() const { return step_; }
  int64_t skipped_steps() const { return skipped_; }
  int64_t bad_in_a_row() const { return bad_in_a_row_; }
  std::string PhaseAt(int64_t step) const;

 private:
  bool AllFinite() const;
  void CheckCancel() const {
    if (cancel_ != nullptr) cancel_->ThrowIfCancelled();
  }
  StepResult StepStageTwo(const TrainBatch& batch);
  // The update or the skip that ends a step (ok: every loss and gradient finite), then the
  // cleared gradients and the step count.
  void FinishStep(bool ok, StepResult& r, const Timer& timer);
  // A stage-I training render (with gradients, jittered unless deterministic_render) of `planes`
  // at `cameras`, rgb: the pixel windows `corners` ([B,2], patch_size) when defined, ray-chunked
  // when grad_chunk_rays > 0.
  torch::Tensor TrainingRender(const torch::Tensor& planes, const render::Cameras& cameras,
                               const torch::Tensor& corners = {});
  const RunContext* cancel_ = nullptr;
  TrainerOptions options_;
  torch::Device device_;
  GohaModel model_;
  DualDiscriminator disc_{nullptr};
  std::vector<std::string> d_names_;
  std::vector<torch::Tensor> d_params_, d_exp_avg_, d_exp_avg_sq_;
  std::vector<int64_t> d_param_steps_;
  // The SR was trained before this run (initialised from such a checkpoint).
  bool sr_trained_before_ = false;
  PerceptualFn perceptual_;
  std::shared_ptr<GradientReducer> reducer_;
  std::vector<std::string> names_;
  std::vector<torch::Tensor> params_;
  std::vector<torch::Tensor> exp_avg_, exp_avg_sq_;
  std::vector<int64_t> param_steps_;
  int64_t step_ = 0;
  int64_t skipped_ = 0;
  int64_t bad_in_a_row_ = 0;
};

// A whole run in a folder RUN: RUN/state.ckpt (training state), RUN/model.ckpt and
// RUN/model-fp16.ckpt (weights at the end, also after a cancel), RUN/train.jsonl (one JSON object per step: losses,
// lr, step_s, samples_per_s, ...; stage II adds d_loss, d_terms, d_grad_norm), and a one-line
// progress display with ETA on stderr. Every step appears once in the log: at the start, lines
// whose step is >= the run's first step (logged after the state being resumed was written, or
// by an earlier run in the folder) and unreadable lines (a line cut by a kill) are dropped, the
// log rewritten atomically, and new lines appended.
struct RunOptions {
  std::filesystem::path out_dir;
  // Train until this step (absolute).
  int64_t steps = 1000;
  // Stop after this many hours (0 = no limit).
  double hours = 0.0;
  // Continue from RUN/state.ckpt when it exists.
  bool resume = false;
  // Write the state every this many minutes (and at the end, and on cancel).
  double checkpoint_minutes = 10.0;
  // Also every this many steps (0 = off).
  int64_t checkpoint_steps = 0;
  // Progress line on stderr.
  bool progress = true;
  // What the weights are trained on (stored in model.ckpt).
  std::string data_provenance = "unknown";
  // A fresh run (no state resumed) starts from this model checkpoint (StageOneTrainer::
  // InitFromCheckpoint); empty = the trainer's own initialisation.
  std::filesystem::path init_weights;
  // Sample renders every this many steps (after the step; 0 = off) and after the last step:
  // on_samples(step, renders) gets Evaluate's renders of the first batch this call took (up to
  // four pairs), on the CPU, float, mapped to [0,1] and clamped.
  int64_t sample_every = 0;
  std::function<void(int64_t step, const StageOneTrainer::Renders& samples)> on_samples;
  // Called after each state write with the state's step (e.g. to redraw a loss curve).
  std::function<void(int64_t step)> on_state_written;
  void Validate() const;
};

struct RunResult {
  int64_t first_step = 0;   // step the run started (resumed) at
  int64_t last_step = 0;    // step reached
  int64_t skipped = 0;      // non-finite steps skipped, in total
  std::string stopped_by;   // "steps", "hours"
};

// Runs the trainer until options.steps / hours. With a gradient reducer (data parallelism) every
// rank runs it with its shard of each batch: the ranks agree on stopping (hours, cancel: any
// rank's cancel stops all) and only rank 0 touches the run folder (state, log, samples, exports,
// progress line); every rank resumes from the same RUN/state.ckpt (a shared folder).
// On cancel (ctx) it writes the state and throws
// Cancelled; after max_bad_steps bad steps in a row it writes the (last good) state and throws.
RunResult RunTraining(StageOneTrainer& trainer, BatchSource& source, const RunOptions& options, RunContext& ctx);

// The state file and log in a run folder.
std::filesystem::path StatePath(const std::filesystem::path& out_dir);
std::filesystem::path LogPath(const std::filesystem::path& out_dir);
// Drops the lines of a JSONL training log whose "step" is >= first_step and unreadable lines,
// rewriting the file atomically when anything is dropped. A missing file is left missing.
// Returns the number of lines dropped.
int64_t TruncateLog(const std::filesystem::path& log, int64_t first_step);

}  // namespace avatar::train
