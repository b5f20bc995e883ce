#pragma once
// Stage I of GOHA's training (Li et al. 2023, section 3.4) on one device.
//
// One step, for a batch (I_s, I_exp, I_neu, M_neu, I_t, cameras C_s, C_t):
//   T_c = CanonicalPlanes(I_s); T_e = ExpressionPlanes(I_exp); T_p = AppearancePlanes(I_s, ..., C_s)
//   I_c = R(T_c, C_t), I_c+e = R(T_c + T_e, C_t), I_c+e+p = R(T_c + T_e + T_p, C_t)
//   each against the matted target resized to the render size: L1 + perceptual_weight x perceptual;
//   + neutral_weight x NeutralLoss(R(T_c, C_s), I_neu, M_neu)
//   + tv_weight x DensityTvLoss on the densities of the largest active plane sum.
// Training renders jitter their stratified and importance samples (RenderOptions::deterministic
// = false); evaluation renders (Evaluate) are deterministic.
//
// Curriculum (the paper's 750k stage-I steps: + expression at 120k = 16%, + appearance at
// 240k = 32%): steps [0, expression_start) train I_c only, [expression_start, appearance_start)
// add I_c+e, later steps add I_c+e+p. With `rotation` the release's rotation of step kinds
// (after expression_start, step mod 6: 0-1 all renders, 2-3 I_c+e only, 4-5 neutral only) is
// used; off by default (every step has every active term).
//
// Optimiser: Adam (betas 0, 0.99, lr 1e-4, eps 1e-8) written out here so that its state is plain
// tensors in the training state; it follows torch::optim::Adam's update (bias-corrected moments, eps
// added after the square root, no weight decay). Gradients are clipped to a global
// L2 norm of grad_clip. A step whose loss or gradient is not finite changes nothing and is
// counted; max_bad_steps such steps in a row stop the run.
//
// Training state (TensorArchive kind "goha-train-state"): weights, Adam moments and step
// counts, the step, the global CPU generator state, the data source's cursor and the counters;
// written atomically and never when a tensor is not finite. Resuming continues the same run.

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include "core/model/goha_model.h"
#include "core/train/losses.h"
#include "core/train/sample.h"
#include "core/util/run_context.h"

namespace avatar::train {

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
  bool skipped = false;                  // non-finite loss or gradient: nothing changed
  std::string skip_reason;
  double seconds = 0.0;
  std::string phase;                     // canonical, expression, appearance
};

class StageOneTrainer {
 public:
  // `model` is moved to the options' device. `perceptual` may be empty (L1 only).
  StageOneTrainer(GohaModel model, const TrainerOptions& options, PerceptualFn perceptual);

  // One optimiser step on `batch`. A non-finite step is counted (bad_in_a_row); RunTraining stops on it.
  StepResult Step(const TrainBatch& batch);

  // Deterministic renders (no gradient) of the three plane sums at the target camera.
  struct Renders {
    torch::Tensor target, canonical, expression, full;  // [B,3,R,R]
  };
  Renders Evaluate(const TrainBatch& batch);

  // State files (see the header comment). Save throws InvalidInput on a non-finite tensor (and
  // writes nothing); Load throws Io / ModelLoad and checks that the model config matches.
  void SaveState(const std::filesystem::path& path, const BatchSource* source = nullptr) const;
  void LoadState(const std::filesystem::path& path, BatchSource* source = nullptr);
  // Weights-only model checkpoint (LoadModelCheckpoint reads it). Throws on non-finite weights.
  // half_precision: float16 shipping weights (half the size; loads into the float32 model).
  void ExportWeights(const std::filesystem::path& path, const std::string& data_provenance,
                     bool half_precision = false) const;

  GohaModel& model() { return model_; }
  const TrainerOptions& options() const { return options_; }
  const torch::Device& device() const { return device_; }
  int64_t step() const { return step_; }
  int64_t skipped_steps() const { return skipped_; }
  int64_t bad_in_a_row() const { return bad_in_a_row_; }
  std::string PhaseAt(int64_t step) const;

 private:
  bool AllFinite() const;
  TrainerOptions options_;
  torch::Device device_;
  GohaModel model_;
  PerceptualFn perceptual_;
  std::vector<std::string> names_;
  std::vector<torch::Tensor> params_;
  std::vector<torch::Tensor> exp_avg_, exp_avg_sq_;
  std::vector<int64_t> param_steps_;
  int64_t step_ = 0;
  int64_t skipped_ = 0;
  int64_t bad_in_a_row_ = 0;
};

// A whole run in a folder RUN: RUN/state.ckpt (training state), RUN/model.ckpt (weights at the
// end), RUN/train.jsonl (one JSON object per step: losses, lr, step_s, samples_per_s, ...),
// and a one-line progress display with ETA on stderr.
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
  void Validate() const;
};

struct RunResult {
  int64_t first_step = 0;   // step the run started (resumed) at
  int64_t last_step = 0;    // step reached
  int64_t skipped = 0;      // non-finite steps skipped, in total
  std::string stopped_by;   // "steps", "hours"
};

// Runs the trainer until options.steps / hours. On cancel (ctx) it writes the state and throws
// Cancelled; after max_bad_steps bad steps in a row it writes the (last good) state and throws.
RunResult RunTraining(StageOneTrainer& trainer, BatchSource& source, const RunOptions& options, RunContext& ctx);

// The state file and log in a run folder.
std::filesystem::path StatePath(const std::filesystem::path& out_dir);
std::filesystem::path LogPath(const std::filesystem::path& out_dir);

}  // namespace avatar::train
