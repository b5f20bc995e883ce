#include "core/tools/training_run.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <sstream>

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/io/image_tensor.h"
#include "core/model/goha_model.h"
#include "core/model/super_resolution.h"
#include "core/morphable/morphable_model.h"
#include "core/train/dataset.h"
#include "core/train/losses.h"
#include "core/train/perceptual.h"
#include "core/util/error.h"

extern "C" char** environ;

namespace avatar {
namespace {

namespace fs = std::filesystem;

ModelConfig ResolveConfig(const std::string& c) {
  if (c == "paper" || c == "lite" || c == "cpu" || c == "tiny") return ModelConfig::FromName(c);
  if (!fs::exists(c))
    throw InvalidOptions("--config '" + c + "' is neither a config name (paper, lite, cpu, tiny) nor a file");
  try {
    return ModelConfigFromJson(ReadFileBytes(c));
  } catch (const InvalidOptions& e) {
    throw InvalidOptions(c + ": " + e.what());
  }
}

// The config of the model in a checkpoint file (its metadata only).
ModelConfig CheckpointModelConfig(const std::string& path) {
  const TensorArchive archive = ReadTensorArchive(path, "goha-model");
  try {
    return ModelConfigFromJson(archive.meta.at("config").dump());
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(path + ": checkpoint metadata is incomplete: " + e.what());
  }
}

// The ablation fields of the model to train: those of the state being resumed or of the
// --init-weights checkpoint (`inherited`, may be null), then the flags. An appearance branch
// once off stays off; --expression-model overrides; K of the bases is the dataset's.
void ApplyAblations(ModelConfig& config, const ModelConfig* inherited, const TrainingRunOptions& o,
                    int64_t dataset_coefficients) {
  if (inherited != nullptr) {
    config.appearance_branch = config.appearance_branch && inherited->appearance_branch;
    if (o.expression_model.empty()) {
      config.expression_model = inherited->expression_model;
      config.expression_coefficients = inherited->expression_coefficients;
    }
  }
  if (!o.appearance) config.appearance_branch = false;
  if (!o.expression_model.empty()) config.expression_model = o.expression_model;
  if (config.expression_bases() &&
      !(inherited != nullptr && inherited->expression_bases() && o.expression_model.empty()))
    config.expression_coefficients = static_cast<int>(dataset_coefficients);
  if (config.expression_bases() && config.expression_coefficients != dataset_coefficients)
    throw InvalidInput(o.data + ": the dataset has " + std::to_string(dataset_coefficients) +
                       " expression coefficients per frame but the model's expression bases take " +
                       std::to_string(config.expression_coefficients) +
                       " (a dataset built with another morphable model: rebuild it)");
  config.Validate();
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

// [3,H,W] in [0,1] -> 8-bit BGR cell x cell.
cv::Mat ToCell(const torch::Tensor& chw, int cell) {
  const cv::Mat bgr = TensorToBgr(chw, /*unit_range=*/true);
  cv::Mat out;
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

// Redraws RUN/curve.png; every failure is a warning.
void PlotCurve(const fs::path& run, const fs::path& script, const TrainingNotes& note) {
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
    note("\ntrain: warning: cannot start python3 for the loss curve\n");
    return;
  }
  int status = 0;
  if (::waitpid(pid, &status, 0) != pid || !WIFEXITED(status) || WEXITSTATUS(status) != 0)
    note("\ntrain: warning: scripts/plot-training failed; " + png + " not updated\n");
}

}  // namespace

void TrainingRunOptions::Validate() const {
  AVATAR_CHECK_OPTION(!config.empty()) << "--config must name a config (paper, lite, cpu, tiny) or a JSON file";
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
  AVATAR_CHECK_OPTION(expression_model.empty() || expression_model == "encoder" || expression_model == "bases")
      << "--expression-model must be encoder or bases, got '" << expression_model << "'";
  trainer.Validate();
  dist.Validate();
  AVATAR_CHECK_OPTION(!dist.enabled() || dist.backend != "nccl" || trainer.device.rfind("cuda", 0) == 0)
      << "--backend nccl needs a CUDA --device (cuda:N for each rank)";
}

TrainingRunResult RunTrainingRun(TrainingRunOptions o, RunContext& ctx, const TrainingNotes& notes) {
  o.Validate();
  const TrainingNotes note = notes ? notes : TrainingNotes([](const std::string&) {});
  std::ostringstream log;  // one note at a time: written, then handed to `note`
  const auto send = [&] {
    note(log.str());
    log.str({});
  };
  ModelConfig config = ResolveConfig(o.config);
  o.trainer.ScheduleFor(o.curriculum_steps > 0 ? o.curriculum_steps : o.steps);
  const train::TrainDataset dataset = train::TrainDataset::Open(o.data, "train");
  // Weights that come from a file (a state to resume, --init-weights) need no pretrained backbones.
  const bool resuming = o.resume && fs::exists(train::StatePath(o.out));
  {
    std::optional<ModelConfig> inherited;
    if (resuming)
      inherited = train::ReadStateModelConfig(train::StatePath(o.out));
    else if (!o.init_weights.empty())
      inherited = CheckpointModelConfig(o.init_weights);
    const int64_t coefficients = dataset.size() > 0 ? dataset.Get(0).target_expression.size(0) : 0;
    ApplyAblations(config, inherited ? &*inherited : nullptr, o, coefficients);
  }
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
    po.data_dir = o.data_dir;
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
  GohaModelOptions model_options;
  model_options.data_dir = o.data_dir;
  model_options.pretrained = !resuming && o.init_weights.empty();
  GohaModel model(config, model_options);
  if (config.expression_bases()) {
    // The bases are mixed by beta_k / std_k with the std of the morphable model that made the
    // data (a resumed state or a bases checkpoint brings its own values back).
    const morphable::MorphableModel& mm = morphable::LoadDefaultModel(DataPaths::Resolve(o.data_dir));
    if (mm.num_expression() != config.expression_coefficients)
      throw InvalidInput("the installed morphable model has " + std::to_string(mm.num_expression()) +
                         " expression components but the dataset " + o.data + " has " +
                         std::to_string(config.expression_coefficients) + " (rebuild the dataset)");
    model->SetExpressionStd(mm.expression_std());
  }
  train::StageOneTrainer trainer(model, o.trainer, perceptual);
  if (parallel) {
    if (lead) {
      log << "train: data parallel, " << o.dist.world_size << " ranks (" << o.dist.backend << ", " << o.dist.init
          << "), global batch " << lo.batch_size << "; waiting for the other ranks\n";
      send();
    }
    trainer.SetGradientReducer(std::make_shared<train::ProcessGroupReducer>(o.dist));
    if (!lead) {
      log << "train: rank " << o.dist.rank << " of " << o.dist.world_size << " joined\n";
      send();
    }
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
      note("train: " + train::StatePath(o.out).string() + " exists: resuming it, --init-weights ignored\n");
    else
      run.init_weights = o.init_weights;
  }
  const fs::path out_dir = o.out;
  const int cell = std::clamp(config.render_size, 128, 256);
  run.sample_every = o.sample_every;
  run.on_samples = [out_dir, cell, note](int64_t step, const train::StageOneTrainer::Renders& r) {
    try {
      WriteSampleGrid(out_dir, step, r, cell);
    } catch (const std::exception& e) {
      note("\ntrain: warning: sample grid of step " + std::to_string(step) + " not written: " + e.what() + "\n");
    }
  };
  const fs::path script = lead ? FindPlotScript() : fs::path();
  if (script.empty() && lead) note("train: scripts/plot-training not found: no RUN/curve.png\n");
  run.on_state_written = [out_dir, script, note](int64_t) { PlotCurve(out_dir, script, note); };
  if (lead) {
    log << "train: stage " << o.trainer.stage << ", config " << config.name << ", " << dataset.size()
        << " pairs, batch " << o.batch_size << ", steps to " << o.steps;
    if (o.trainer.stage == 1)
      log << " (expression from " << o.trainer.expression_start << ", appearance from "
          << o.trainer.appearance_start << ")";
    else
      log << " (super-resolution only, GAN weight " << o.trainer.gan_weight << ", R1 gamma " << o.trainer.r1_gamma
          << ")";
    log << ", device " << o.trainer.device << ", perceptual " << o.perceptual << "\n";
    if (!config.appearance_branch || config.expression_bases() || o.trainer.neutral_weight == 0) {
      log << "train: ablation:";
      if (!config.appearance_branch) log << " no appearance branch (T_p = 0, output I_c+e);";
      if (config.expression_bases())
        log << " linear expression bases (" << config.expression_coefficients << " x [3," << config.plane_channels
            << "," << config.plane_size() << "," << config.plane_size() << "], "
            << model->expression_bases.numel() << " parameters) instead of E_e;";
      if (o.trainer.neutral_weight == 0) log << " no neutral loss;";
      log << "\n";
    }
    if (o.trainer.stage == 2 && run.init_weights.empty() && !resuming)
      log << "train: warning: stage II without --init-weights trains the SR behind an untrained stage-I network\n";
    send();
  }
  TrainingRunResult result;
  result.lead = lead;
  result.run = train::RunTraining(trainer, source, run, ctx);
  result.weights_path = (fs::path(o.out) / "model.ckpt").string();
  result.state_path = train::StatePath(o.out).string();
  return result;
}

}  // namespace avatar
