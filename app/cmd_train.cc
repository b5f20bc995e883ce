// `avatar-studio train --config C --data DIR --out RUN [--stage 1|2] [--init-weights CKPT]
// [--resume] [--steps N] [--hours H]`: stage I or II of GOHA's training (core/train/trainer.h)
// on a dataset written by `dataset build`. C is a preset (paper, lite, cpu, tiny) or a JSON file
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

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <optional>

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "app/commands.h"
#include "core/io/atomic_file.h"
#include "core/io/image_io.h"
#include "core/model/goha_model.h"
#include "core/model/super_resolution.h"
#include "core/train/dataset.h"
#include "core/train/distributed.h"
#include "core/train/losses.h"
#include "core/train/perceptual.h"
#include "core/train/trainer.h"
#include "core/util/error.h"

namespace avatar::app {
namespace {

namespace fs = std::filesystem;

struct TrainCommandOptions {
  // Model preset or JSON file.
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
  train::TrainerOptions trainer;
  train::DistributedOptions dist;
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("config", config, "Model preset (paper, lite, cpu, tiny) or a JSON file of model-config fields", 'c');
    v("data", data, "Dataset folder written by 'avatar-studio dataset build'", 'd');
    v("out", out, "Run folder (state.ckpt, train.jsonl, model.ckpt, samples/, curve.png)", 'o');
    v("stage", trainer.stage, "Training stage: 1 (all branches) or 2 (super-resolution only, with the dual discriminator)");
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
    common.Visit(v);
  }
  void Validate() const {
    AVATAR_CHECK_OPTION(!config.empty()) << "--config must name a preset or a JSON file";
    AVATAR_CHECK_OPTION(!data.empty()) << "--data must name the dataset folder";
    AVATAR_CHECK_OPTION(!out.empty()) << "--out must name the run folder";
    AVATAR_CHECK_OPTION(steps >= 0 && curriculum_steps >= 0) << "--steps and --curriculum-steps must be >= 0";
    AVATAR_CHECK_OPTION(batch_size >= 1) << "--batch-size must be >= 1";
    AVATAR_CHECK_OPTION(sample_every >= 0) << "--sample-every must be >= 0";
    AVATAR_CHECK_OPTION(synthetic_fraction >= 0.0 && synthetic_fraction <= 1.0) << "--synthetic-fraction must be in 0..1";
    AVATAR_CHECK_OPTION(init_weights.empty() || fs::exists(init_weights))
        << "--init-weights: no such file '" << init_weights << "'";
    AVATAR_CHECK_OPTION(perceptual == "mobilenet" || perceptual == "pyramid" || perceptual == "none")
        << "--perceptual must be mobilenet, pyramid or none";
    trainer.Validate();
    dist.Validate();
    AVATAR_CHECK_OPTION(!dist.enabled() || dist.backend != "nccl" || trainer.device.rfind("cuda", 0) == 0)
        << "--backend nccl needs a CUDA --device (cuda:N for each rank)";
    common.Validate();
  }
};

ModelConfig ResolveConfig(const std::string& c) {
  if (c == "paper" || c == "lite" || c == "cpu" || c == "tiny") return ModelConfig::FromName(c);
  if (!fs::exists(c)) throw InvalidOptions("--config '" + c + "' is neither a preset (paper, lite, cpu, tiny) nor a file");
  try {
    return ModelConfigFromJson(ReadFileBytes(c));
  } catch (const InvalidOptions& e) {
    throw InvalidOptions(c + ": " + e.what());
  }
}

// The dataset loader as the trainer's batch source: epochs follow each other; the cursor is
// (epoch, batches taken in it), restored by replaying the epoch's order up to it.
class LoaderSource : public train::BatchSource {
 public:
  LoaderSource(const train::TrainDataset& dataset, const train::TrainDataset* synthetic,
               const train::LoaderOptions& options)
      : loader_(dataset, synthetic, options) {
    if (loader_.BatchesPerEpoch() == 0) throw InvalidInput("the training split has no batches");
    loader_.StartEpoch(0);
  }
  train::TrainBatch Next() override {
    train::TrainBatch b;
    while (!loader_.Next(&b)) {
      ++epoch_;
      taken_ = 0;
      loader_.StartEpoch(epoch_);
    }
    ++taken_;
    return b;
  }
  nlohmann::json State() const override { return {{"epoch", epoch_}, {"batches", taken_}}; }
  void Restore(const nlohmann::json& state) override {
    epoch_ = state.at("epoch").get<int64_t>();
    const int64_t n = state.at("batches").get<int64_t>();
    loader_.StartEpoch(epoch_);
    taken_ = 0;
    train::TrainBatch skip;
    for (int64_t i = 0; i < n && loader_.Next(&skip); ++i) ++taken_;
  }

 private:
  train::DataLoader loader_;
  int64_t epoch_ = 0;
  int64_t taken_ = 0;
};

void OnSigterm(int) { ProcessContext().RequestCancel(); }

// [3,H,W] in [0,1] -> 8-bit BGR cell x cell.
cv::Mat ToCell(const torch::Tensor& chw, int cell) {
  const torch::Tensor hwc =
      (chw.detach().to(torch::kCPU, torch::kFloat32).clamp(0, 1) * 255.0 + 0.5).to(torch::kUInt8).permute({1, 2, 0})
          .contiguous();
  cv::Mat rgb(static_cast<int>(hwc.size(0)), static_cast<int>(hwc.size(1)), CV_8UC3, hwc.data_ptr<uint8_t>());
  cv::Mat bgr, out;
  cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
  cv::resize(bgr, out, cv::Size(cell, cell), 0, 0, bgr.cols > cell ? cv::INTER_AREA : cv::INTER_NEAREST);
  return out;
}

// RUN/samples/step-XXXXXXX.png: one row per pair: source, target, I_c, I_c+e, I_c+e+p[, SR].
void WriteSampleGrid(const fs::path& run, int64_t step, const train::StageOneTrainer::Renders& r, int cell) {
  std::vector<torch::Tensor> columns = {r.source, r.target, r.canonical, r.expression, r.full};
  if (r.super_resolved.defined()) columns.push_back(r.super_resolved);
  std::vector<cv::Mat> rows;
  for (int64_t i = 0; i < r.full.size(0); ++i) {
    std::vector<cv::Mat> cells;
    for (const auto& c : columns) cells.push_back(ToCell(c[i], cell));
    cv::Mat row;
    cv::hconcat(cells, row);
    rows.push_back(row);
  }
  cv::Mat grid;
  cv::vconcat(rows, grid);
  fs::create_directories(run / "samples");
  char name[64];
  std::snprintf(name, sizeof(name), "step-%07lld.png", static_cast<long long>(step));
  SaveImage(run / "samples" / name, grid);
}

// scripts/plot-training next to the source tree the binary was built in (searched upwards from
// the executable, then from the working directory); empty when absent.
fs::path FindPlotScript() {
  std::error_code ec;
  std::vector<fs::path> starts = {fs::read_symlink("/proc/self/exe", ec).parent_path(), fs::current_path(ec)};
  for (fs::path dir : starts) {
    for (int up = 0; up < 6 && !dir.empty(); ++up, dir = dir.parent_path()) {
      const fs::path candidate = dir / "scripts" / "plot-training";
      if (fs::exists(candidate, ec)) return candidate;
      if (dir == dir.parent_path()) break;
    }
  }
  return {};
}

extern "C" char** environ;

// Redraws RUN/curve.png; every failure is a warning.
void PlotCurve(const fs::path& run, const fs::path& script) {
  if (script.empty()) return;
  const std::string log = train::LogPath(run).string(), png = (run / "curve.png").string(), py = "python3",
                    s = script.string();
  std::vector<char*> argv = {const_cast<char*>(py.c_str()), const_cast<char*>(s.c_str()),
                             const_cast<char*>(log.c_str()), const_cast<char*>(png.c_str()), nullptr};
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
  pid_t pid = 0;
  const int rc = posix_spawnp(&pid, py.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) {
    std::cerr << "\ntrain: warning: cannot start python3 for the loss curve\n";
    return;
  }
  int status = 0;
  if (::waitpid(pid, &status, 0) != pid || !WIFEXITED(status) || WEXITSTATUS(status) != 0)
    std::cerr << "\ntrain: warning: scripts/plot-training failed; " << png << " not updated\n";
}

int RunTrainImpl(TrainCommandOptions o, RunContext& ctx) {
  o.Validate();
  const ModelConfig config = ResolveConfig(o.config);
  o.trainer.ScheduleFor(o.curriculum_steps > 0 ? o.curriculum_steps : o.steps);
  const train::TrainDataset dataset = train::TrainDataset::Open(o.data, "train");
  if (dataset.image_size() != config.image_size)
    throw InvalidInput(o.data + ": the dataset's images are " + std::to_string(dataset.image_size()) +
                       " px but config '" + config.name + "' wants " + std::to_string(config.image_size));
  const bool parallel = o.dist.enabled();
  const bool lead = o.dist.rank == 0;
  train::LoaderOptions lo;
  // Data parallelism: every rank reads the global batches in the same order and takes its shard.
  lo.batch_size = o.batch_size * static_cast<int>(o.dist.world_size);
  lo.drop_last = parallel;
  lo.seed = static_cast<uint64_t>(o.trainer.seed);
  lo.synthetic_fraction = o.synthetic_fraction;
  std::optional<train::TrainDataset> synthetic;
  if (o.synthetic_fraction > 0.0) synthetic = train::TrainDataset::Open(o.data, "synthetic");
  LoaderSource loader_source(dataset, synthetic ? &*synthetic : nullptr, lo);
  std::unique_ptr<train::ShardedBatchSource> shards;
  if (parallel) shards = std::make_unique<train::ShardedBatchSource>(loader_source, o.dist.rank, o.dist.world_size);
  train::BatchSource& source = parallel ? static_cast<train::BatchSource&>(*shards) : loader_source;

  train::PerceptualFn perceptual;
  std::shared_ptr<PerceptualLoss> net;
  if (o.perceptual == "mobilenet") {
    PerceptualOptions po;
    po.data_dir = o.common.data_dir;
    net = std::make_shared<PerceptualLoss>(po);
    net->To(torch::Device(o.trainer.device));
    // MobileNetV2 wants >= 32 px: smaller renders (tiny) are upsampled for this term only.
    perceptual = [net](const torch::Tensor& a, const torch::Tensor& b) {
      if (a.size(2) >= 32) return net->Distance(a, b);
      return net->Distance(ResizeBilinear(a, 32, 32), ResizeBilinear(b, 32, 32));
    };
  } else if (o.perceptual == "pyramid") {
    perceptual = [](const torch::Tensor& a, const torch::Tensor& b) { return train::PyramidL1Distance(a, b); };
  }

  torch::manual_seed(static_cast<uint64_t>(o.trainer.seed));
  // Weights that come from a file (a state to resume, --init-weights) need no pretrained backbones.
  const bool resuming = o.resume && fs::exists(train::StatePath(o.out));
  GohaModelOptions model_options;
  model_options.data_dir = o.common.data_dir;
  model_options.pretrained = !resuming && o.init_weights.empty();
  train::StageOneTrainer trainer(GohaModel(config, model_options), o.trainer, perceptual);
  if (parallel) {
    if (lead)
      std::cerr << "train: data parallel, " << o.dist.world_size << " ranks (" << o.dist.backend << ", " << o.dist.init
                << "), global batch " << lo.batch_size << "; waiting for the other ranks\n";
    trainer.SetGradientReducer(std::make_shared<train::ProcessGroupReducer>(o.dist));
    if (!lead) std::cerr << "train: rank " << o.dist.rank << " of " << o.dist.world_size << " joined\n";
  }
  train::RunOptions run;
  run.out_dir = o.out;
  run.steps = o.steps;
  run.hours = o.hours;
  run.resume = o.resume;
  run.checkpoint_minutes = o.checkpoint_minutes;
  run.progress = o.progress;
  run.data_provenance = std::string(o.trainer.stage == 2 ? "stage II" : "stage I") + " on " +
                        fs::absolute(o.data).string() + " (" + std::to_string(dataset.size()) + " pairs)";
  if (!o.init_weights.empty()) {
    if (resuming)
      std::cerr << "train: " << train::StatePath(o.out).string() << " exists: resuming it, --init-weights ignored\n";
    else
      run.init_weights = o.init_weights;
  }
  const fs::path out_dir = o.out;
  const int cell = std::clamp(config.render_size, 128, 256);
  run.sample_every = o.sample_every;
  run.on_samples = [out_dir, cell](int64_t step, const train::StageOneTrainer::Renders& r) {
    try {
      WriteSampleGrid(out_dir, step, r, cell);
    } catch (const std::exception& e) {
      std::cerr << "\ntrain: warning: sample grid of step " << step << " not written: " << e.what() << "\n";
    }
  };
  const fs::path script = lead ? FindPlotScript() : fs::path();
  if (script.empty() && lead) std::cerr << "train: scripts/plot-training not found: no RUN/curve.png\n";
  run.on_state_written = [out_dir, script](int64_t) { PlotCurve(out_dir, script); };
  if (lead) {
    std::cerr << "train: stage " << o.trainer.stage << ", config " << config.name << ", " << dataset.size()
              << " pairs, batch " << o.batch_size << ", steps to " << o.steps;
    if (o.trainer.stage == 1)
      std::cerr << " (expression from " << o.trainer.expression_start << ", appearance from "
                << o.trainer.appearance_start << ")";
    else
      std::cerr << " (super-resolution only, GAN weight " << o.trainer.gan_weight << ", R1 gamma " << o.trainer.r1_gamma
                << ")";
    std::cerr << ", device " << o.trainer.device << ", perceptual " << o.perceptual << "\n";
    if (o.trainer.stage == 2 && run.init_weights.empty() && !resuming)
      std::cerr
          << "train: warning: stage II without --init-weights trains the SR behind an untrained stage-I network\n";
  }
  const auto previous = std::signal(SIGTERM, OnSigterm);
  train::RunResult r;
  try {
    r = train::RunTraining(trainer, source, run, ctx);
  } catch (...) {
    std::signal(SIGTERM, previous);
    throw;
  }
  std::signal(SIGTERM, previous);
  if (!lead) return kExitOk;
  std::cout << "trained steps " << r.first_step << " -> " << r.last_step << " (stopped by " << r.stopped_by << ", "
            << r.skipped << " non-finite steps skipped); weights: " << (fs::path(o.out) / "model.ckpt").string()
            << ", state: " << train::StatePath(o.out).string() << "\n";
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
