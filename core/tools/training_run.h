#pragma once
// GOHA's training run as `avatar-studio train` starts it: the model config (a config name or a JSON
// file of ModelConfig fields, then the ablation fields of a resumed state or --init-weights
// checkpoint, then the flags), the dataset loader (with synthetic pairs), the perceptual term,
// data parallelism, the sample grids (RUN/samples/step-N.png) and loss curves (RUN/curve.png by
// scripts/plot-training, when python3 is there), around core/train's RunTraining. Writes
// RUN/state.ckpt, RUN/train.jsonl, RUN/model.ckpt and RUN/model-fp16.ckpt; a cancel of the
// context writes the state and stops.
//
// Ablations (issue 14; docs/training/README.md "Ablations"): neutral_weight 0 (w/o neutral
// loss), appearance false (w/o appearance branch) and expression_model "bases" (linear
// expression bases mixed by the morphable coefficients). The last two are model-config fields:
// they are stored in the state and in the exported weights, and a run resumed or initialised
// from such files keeps them without repeating the flag.

#include <cstdint>
#include <functional>
#include <string>

#include "core/train/distributed.h"
#include "core/train/trainer.h"
#include "core/util/run_context.h"

namespace avatar {

struct TrainingRunOptions {
  // Model config name or JSON file.
  std::string config = "cpu";
  // Dataset folder (dataset.json + shards/).
  std::string data;
  // Run folder.
  std::string out;
  // Continue from RUN/state.ckpt.
  bool resume = false;
  // Train until this step.
  int64_t steps = 1000;
  // Stop after this many hours (0 = no limit).
  double hours = 0.0;
  // Curriculum length: the expression / appearance planes join at 16% / 32% of it (0 = --steps).
  int64_t curriculum_steps = 0;
  // Pairs per batch.
  int batch_size = 4;
  // Minutes between state writes.
  double checkpoint_minutes = 10.0;
  // Perceptual term: mobilenet (core/train/perceptual.h), pyramid (parameter-free stand-in), none.
  std::string perceptual = "mobilenet";
  // Progress line on stderr.
  bool progress = true;
  // Start a fresh run from these model weights (and their step).
  std::string init_weights;
  // Sample grid every this many steps (0 = only at the end).
  int64_t sample_every = 200;
  // Share of synthetic multi-view pairs per epoch (0 = none; needs a dataset built with --synthetic).
  double synthetic_fraction = 0.0;
  // Ablation: false = no appearance branch (ModelConfig::appearance_branch).
  bool appearance = true;
  // Ablation: expression branch, encoder or bases ("" = the config's, or that of the resumed state
  // or of --init-weights).
  std::string expression_model;
  // Stage, losses, optimiser, schedule, device, seed.
  train::TrainerOptions trainer;
  // Data parallelism.
  train::DistributedOptions dist;
  // Folder with the installed data ("" = AVATAR_DATA_DIR, then the default cache).
  std::string data_dir;

  template <typename V>
  void Visit(V&& v) {
    v("config", config, "Model config name (paper, lite, cpu, tiny) or a JSON file of model-config fields", 'c');
    v("data", data, "Dataset folder written by 'avatar-studio dataset build'", 'd');
    v("out", out, "Run folder (state.ckpt, train.jsonl, model.ckpt, samples/, curve.png)", 'o');
    v("stage", trainer.stage,
      "Training stage: 1 (all branches) or 2 (super-resolution only, with the dual discriminator)");
    v("init_weights", init_weights,
      "Fresh run (no RUN/state.ckpt) from this model checkpoint (fp16 too), counting on from its step (give "
      "the original --curriculum-steps to keep the schedule); stage II starts from stage-I weights this way");
    v("resume", resume, "Continue from RUN/state.ckpt");
    v("steps", steps, "Train until this step");
    v("hours", hours, "Stop after this many hours (0 = no limit)");
    v("curriculum_steps", curriculum_steps, "Curriculum length: +expression at 16%, +appearance at 32% (0 = --steps)");
    v("batch_size", batch_size, "Pairs per batch");
    v("checkpoint_minutes", checkpoint_minutes, "Minutes between state writes");
    v("perceptual", perceptual, "Perceptual term: mobilenet, pyramid (stand-in) or none");
    v("progress", progress, "Progress line on stderr");
    v("sample_every", sample_every, "Sample grid RUN/samples/step-N.png every N steps, and at the end (0 = end only)");
    v("synthetic_fraction", synthetic_fraction,
      "Share of synthetic multi-view pairs in each epoch, 0..1 (0 = none; the dataset needs --synthetic N)");
    v("appearance", appearance,
      "Appearance branch; --no-appearance trains without it (ablation: T_p = 0, no I_c+e+p term; kept by "
      "--resume and --init-weights of such a run)");
    v("expression_model", expression_model,
      "Expression branch: encoder (E_e over I_exp) or bases (ablation: learned tri-plane bases mixed by the "
      "target's morphable expression coefficients); default: the config's, or the resumed state's / "
      "--init-weights' model");
    v("device", trainer.device, "Device: cpu or cuda[:N]");
    v("lr", trainer.lr, "Adam learning rate");
    v("grad_clip", trainer.grad_clip, "Global gradient-norm clip (<= 0: none)");
    v("perceptual_weight", trainer.perceptual_weight, "Weight of the perceptual term");
    v("neutral_weight", trainer.neutral_weight, "Weight of the neutral loss");
    v("tv_weight", trainer.tv_weight, "Weight of the density TV loss");
    v("gan_weight", trainer.gan_weight, "Stage II: weight of the non-saturating adversarial loss of the SR");
    v("r1_gamma", trainer.r1_gamma, "Stage II: R1 gamma of the discriminator (lazy, every 16 steps; 0 = off)");
    v("d_lr", trainer.d_lr, "Stage II: discriminator learning rate");
    v("rotation", trainer.rotation, "The release's mod-6 rotation of step kinds");
    v("max_bad_steps", trainer.max_bad_steps, "Non-finite steps in a row that stop the run");
    v("patch_size", trainer.patch_size,
      "Stage I: render random target patches of this side at the target camera (0 = whole images)");
    v("grad_chunk_rays", trainer.grad_chunk_rays,
      "Stage I: rays per chunk of ray-chunked renders with gradients (0 = off; less memory, same gradients)");
    v("seed", trainer.seed, "Seed of the initialisation, the renders' jitter and the data order");
    v("deterministic_render", trainer.deterministic_render,
      "Training renders without sample jitter (with --tv-weight 0, W ranks then take exactly one process's steps)");
    v("world_size", dist.world_size, "Data parallelism: number of processes (1 = none); --batch-size is per process");
    v("rank", dist.rank, "Data parallelism: this process's rank in 0..world-size-1 (rank 0 writes the run folder)");
    v("init", dist.init,
      "Data parallelism: rendezvous, file:///PATH (one machine; the file must not exist yet) or tcp://HOST:PORT "
      "(rank 0's host)");
    v("backend", dist.backend, "Data parallelism: collective backend, gloo (CPU) or nccl (CUDA builds)");
    v("dist_timeout", dist.timeout_s, "Data parallelism: seconds to wait for the other ranks");
  }
  // Throws InvalidOptions.
  void Validate() const;
};

// Lines for the user while the run starts and runs (the setup summary, ablations, warnings about
// sample grids and curves), each ending in a newline; `train` writes them to stderr.
using TrainingNotes = std::function<void(const std::string& text)>;

struct TrainingRunResult {
  bool lead = true;          // rank 0 (the only rank that writes the run folder)
  train::RunResult run;      // steps, why it stopped, skipped steps
  std::string weights_path;  // RUN/model.ckpt
  std::string state_path;    // RUN/state.ckpt
};

// Runs (or resumes) the training. Throws InvalidOptions (also a --config that is neither a
// config name nor a file, or a bad config file); Io / InvalidInput naming the dataset (missing,
// corrupt, image size or expression coefficients that do not fit the model); ModelLoad (state,
// --init-weights); MissingData (pretrained backbones, perceptual network); Cancelled (during the
// steps, after the state and the weights of the last applied step are written).
TrainingRunResult RunTrainingRun(TrainingRunOptions options, RunContext& ctx, const TrainingNotes& notes = {});

}  // namespace avatar
