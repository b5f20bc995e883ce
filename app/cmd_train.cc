// `avatar-studio train --config C --data DIR --out RUN [--resume] [--steps N] [--hours H]`:
// stage I of GOHA's training (core/train/trainer.h) on a dataset written by `dataset build`.
// C is a preset (paper, lite, tiny) or a JSON file of ModelConfig fields (missing fields take
// the paper's values). Writes RUN/state.ckpt (resumable state), RUN/train.jsonl (per-step log)
// and RUN/model.ckpt (weights at the end); Ctrl+C or SIGTERM writes the state and stops.

#include <algorithm>
#include <csignal>
#include <filesystem>
#include <iostream>

#include <nlohmann/json.hpp>

#include "app/commands.h"
#include "core/io/atomic_file.h"
#include "core/model/goha_model.h"
#include "core/model/super_resolution.h"
#include "core/train/dataset.h"
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
  train::TrainerOptions trainer;
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("config", config, "Model preset (paper, lite, cpu, tiny) or a JSON file of model-config fields", 'c');
    v("data", data, "Dataset folder written by 'avatar-studio dataset build'", 'd');
    v("out", out, "Run folder (state.ckpt, train.jsonl, model.ckpt)", 'o');
    v("resume", resume, "Continue from RUN/state.ckpt");
    v("steps", steps, "Train until this step");
    v("hours", hours, "Stop after this many hours (0 = no limit)");
    v("curriculum_steps", curriculum_steps, "Curriculum length: +expression at 16%, +appearance at 32% (0 = --steps)");
    v("batch_size", batch_size, "Pairs per batch");
    v("checkpoint_minutes", checkpoint_minutes, "Minutes between state writes");
    v("perceptual", perceptual, "Perceptual term: mobilenet, pyramid (stand-in) or none");
    v("progress", progress, "Progress line on stderr");
    v("device", trainer.device, "Device: cpu or cuda[:N]");
    v("lr", trainer.lr, "Adam learning rate");
    v("grad_clip", trainer.grad_clip, "Global gradient-norm clip (<= 0: none)");
    v("perceptual_weight", trainer.perceptual_weight, "Weight of the perceptual term");
    v("neutral_weight", trainer.neutral_weight, "Weight of the neutral loss");
    v("tv_weight", trainer.tv_weight, "Weight of the density TV loss");
    v("rotation", trainer.rotation, "The release's mod-6 rotation of step kinds");
    v("max_bad_steps", trainer.max_bad_steps, "Non-finite steps in a row that stop the run");
    v("seed", trainer.seed, "Seed of the initialisation, the renders' jitter and the data order");
    common.Visit(v);
  }
  void Validate() const {
    AVATAR_CHECK_OPTION(!config.empty()) << "--config must name a preset or a JSON file";
    AVATAR_CHECK_OPTION(!data.empty()) << "--data must name the dataset folder";
    AVATAR_CHECK_OPTION(!out.empty()) << "--out must name the run folder";
    AVATAR_CHECK_OPTION(steps >= 0 && curriculum_steps >= 0) << "--steps and --curriculum-steps must be >= 0";
    AVATAR_CHECK_OPTION(batch_size >= 1) << "--batch-size must be >= 1";
    AVATAR_CHECK_OPTION(perceptual == "mobilenet" || perceptual == "pyramid" || perceptual == "none")
        << "--perceptual must be mobilenet, pyramid or none";
    trainer.Validate();
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
  LoaderSource(const train::TrainDataset& dataset, const train::LoaderOptions& options)
      : loader_(dataset, options) {
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

int RunTrainImpl(TrainCommandOptions o, RunContext& ctx) {
  o.Validate();
  const ModelConfig config = ResolveConfig(o.config);
  o.trainer.ScheduleFor(o.curriculum_steps > 0 ? o.curriculum_steps : o.steps);
  const train::TrainDataset dataset = train::TrainDataset::Open(o.data, "train");
  if (dataset.image_size() != config.image_size)
    throw InvalidInput(o.data + ": the dataset's images are " + std::to_string(dataset.image_size()) +
                       " px but config '" + config.name + "' wants " + std::to_string(config.image_size));
  train::LoaderOptions lo;
  lo.batch_size = o.batch_size;
  lo.seed = static_cast<uint64_t>(o.trainer.seed);
  LoaderSource source(dataset, lo);

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
  train::StageOneTrainer trainer(GohaModel(config), o.trainer, perceptual);
  train::RunOptions run;
  run.out_dir = o.out;
  run.steps = o.steps;
  run.hours = o.hours;
  run.resume = o.resume;
  run.checkpoint_minutes = o.checkpoint_minutes;
  run.progress = o.progress;
  run.data_provenance = "stage I on " + fs::absolute(o.data).string() + " (" + std::to_string(dataset.size()) + " pairs)";
  std::cerr << "train: config " << config.name << ", " << dataset.size() << " pairs, batch " << o.batch_size
            << ", steps to " << o.steps << " (expression from " << o.trainer.expression_start << ", appearance from "
            << o.trainer.appearance_start << "), device " << o.trainer.device << ", perceptual " << o.perceptual
            << "\n";
  const auto previous = std::signal(SIGTERM, OnSigterm);
  train::RunResult r;
  try {
    r = train::RunTraining(trainer, source, run, ctx);
  } catch (...) {
    std::signal(SIGTERM, previous);
    throw;
  }
  std::signal(SIGTERM, previous);
  std::cout << "trained steps " << r.first_step << " -> " << r.last_step << " (stopped by " << r.stopped_by << ", "
            << r.skipped << " non-finite steps skipped); weights: " << (fs::path(o.out) / "model.ckpt").string()
            << ", state: " << train::StatePath(o.out).string() << "\n";
  return kExitOk;
}

int RunTrain(const std::vector<std::string>& args) {
  return GuardedRun("train", [&] {
    TrainCommandOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio train --config C --data DIR --out RUN [--resume] [--steps N] [--hours H]",
                      "Stage I of GOHA's training: canonical, expression and appearance renders against the target "
                      "(L1 + perceptual), the neutral loss and the density TV loss, with the paper's curriculum.",
                      &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.empty()) << "train takes no positional arguments";
    return RunTrainImpl(options, ProcessContext());
  });
}

}  // namespace

AVATAR_REGISTER_COMMAND("train", "train the network (stage I)", RunTrain);

}  // namespace avatar::app
