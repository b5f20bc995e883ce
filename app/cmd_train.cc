// `avatar-studio train --config C --data DIR --out RUN [--stage 1|2] [--init-weights CKPT]
// [--resume] [--steps N] [--hours H]`: stage I or II of GOHA's training (core/train/trainer.h)
// on a dataset written by `dataset build`. C is a config name (paper, lite, cpu, tiny) or a JSON file
// of ModelConfig fields (missing fields take the paper's values). Writes RUN/state.ckpt
// (resumable state), RUN/train.jsonl (per-step log), RUN/model.ckpt and RUN/model-fp16.ckpt
// (weights at the end), RUN/samples/step-XXXXXXX.png (sample grids) and RUN/curve.png (loss
// curves by scripts/plot-training at each state write, when python3 is there); Ctrl+C or
// SIGTERM writes the state and stops.
//
// Data parallelism (core/train/distributed.h): start W processes with --world-size W --rank R
// --init file:///PATH (one machine) or tcp://HOST:PORT (rank 0's host); --batch-size is per
// process, so the global batch is W x --batch-size (incomplete batches at an epoch's end are
// dropped). Every rank reads the same dataset and --out; only rank 0 writes the run folder.
//
// Ablations (issue 14; docs/training/README.md "Ablations"): --neutral-weight 0 (w/o neutral
// loss), --no-appearance (w/o appearance branch) and --expression-model bases (linear expression
// bases mixed by the morphable coefficients). The last two are model-config fields: they are
// stored in the state and in the exported weights, and a run resumed (--resume) or initialised
// (--init-weights) from such files keeps them without repeating the flag.

#include <csignal>
#include <filesystem>
#include <iostream>

#include "app/commands.h"
#include "core/tools/training_run.h"
#include "core/util/error.h"

namespace avatar::app {
namespace {

struct TrainCommandOptions {
  // The run: config, data, run folder, schedule, losses, ablations, data parallelism.
  TrainingRunOptions run;
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    run.Visit(v);
    common.Visit(v);
  }
  void Validate() const {
    run.Validate();
    common.Validate();
  }
};

void OnSigterm(int) { ProcessContext().RequestCancel(); }

int RunTrainImpl(TrainCommandOptions o, RunContext& ctx) {
  o.Validate();
  o.run.data_dir = o.common.data_dir;
  // SIGTERM stops the run the way Ctrl+C does (the state is written).
  const auto previous = std::signal(SIGTERM, OnSigterm);
  TrainingRunResult result;
  try {
    result = RunTrainingRun(o.run, ctx, [](const std::string& text) { std::cerr << text; });
  } catch (const Cancelled&) {
    std::signal(SIGTERM, previous);
    // The trainer wrote both before it gave up: say where, and how to go on.
    const std::filesystem::path run_dir = o.run.out;
    if (o.run.dist.rank == 0 && std::filesystem::exists(run_dir / "model.ckpt") &&
        std::filesystem::exists(run_dir / "state.ckpt"))
      std::cerr << "train: cancelled; weights of the last finished step: " << (run_dir / "model.ckpt").string()
              << ", state: " << (run_dir / "state.ckpt").string() << " (continue with --resume)\n";
    throw;
  } catch (...) {
    std::signal(SIGTERM, previous);
    throw;
  }
  std::signal(SIGTERM, previous);
  if (!result.lead) return kExitOk;
  const train::RunResult& r = result.run;
  std::cout << "trained steps " << r.first_step << " -> " << r.last_step << " (stopped by " << r.stopped_by << ", "
            << r.skipped << " non-finite steps skipped); weights: " << result.weights_path
            << ", state: " << result.state_path << "\n";
  return kExitOk;
}

int RunTrain(const std::vector<std::string>& args) {
  return GuardedRun("train", [&] {
    TrainCommandOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(
            options, args,
            "avatar-studio train --config C --data DIR --out RUN [--stage 1|2] [--init-weights CKPT] "
            "[--resume] [--steps N] [--hours H] [--world-size W --rank R --init file:///PATH|tcp://HOST:PORT]",
            "GOHA's training. Stage I (--stage 1): canonical, expression and appearance renders against the "
            "target (L1 + perceptual), the neutral loss and the density TV loss, with the paper's curriculum. "
            "Stage II (--stage 2): the stage-I network frozen, only the super-resolution module trains: L1 + "
            "perceptual of its output against the target at SR resolution, plus --gan-weight x the "
            "non-saturating loss of a dual discriminator (SR output + raw render; R1 gamma 10 every 16 "
            "steps). Start stage II in a new folder with --init-weights STAGE1_RUN/model.ckpt; "
            "--steps counts from the checkpoint's step. Samples: RUN/samples/step-N.png (rows: source, "
            "target, I_c, I_c+e, I_c+e+p[, SR]); loss curves: RUN/curve.png. Data parallelism: W processes "
            "started with --world-size W and ranks 0..W-1 share a rendezvous (--init) and the run folder; "
            "each takes its share of a global batch of W x --batch-size, the gradients are averaged, only "
            "rank 0 writes.",
            &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.empty()) << "train takes no positional arguments";
    return RunTrainImpl(options, ProcessContext());
  });
}

}  // namespace

AVATAR_REGISTER_COMMAND("train", "train the network (stage I or II)", RunTrain);

}  // namespace avatar::app
