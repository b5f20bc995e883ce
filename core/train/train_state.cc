// The training state's format and what moves it: state files, checkpoint init, the rank-0 sync, the log's cut.

#include "core/train/trainer.h"

#include <filesystem>
#include <fstream>
#include <mutex>
#include <string>
#include <vector>

#include "core/io/atomic_file.h"
#include "core/model/checkpoint.h"
#include "core/util/error.h"
#include "core/util/options.h"

namespace avatar::train {

namespace fs = std::filesystem;

namespace {

constexpr const char* kStateKind = "goha-train-state";

bool Finite(const torch::Tensor& t) {
  if (!t.defined() || !t.is_floating_point()) return true;
  return torch::isfinite(t).all().item<bool>();
}

at::Generator DefaultGenerator(const torch::Device& device) {
  return at::globalContext().defaultGenerator(device.is_cpu() ? torch::Device(torch::kCPU) : device);
}

// Adam moments of `names` into the archive as <m>NAME / <v>NAME (parameters never stepped have none).
void StoreAdamMoments(TensorArchive& archive, const std::vector<std::string>& names,
                      const std::vector<torch::Tensor>& exp_avg, const std::vector<torch::Tensor>& exp_avg_sq,
                      const std::string& m, const std::string& v) {
  for (size_t i = 0; i < names.size(); ++i) {
    if (!exp_avg[i].defined()) continue;
    archive.tensors.emplace_back(m + names[i], exp_avg[i]);
    archive.tensors.emplace_back(v + names[i], exp_avg_sq[i]);
  }
}

// The inverse of StoreAdamMoments, with the per-parameter step counts `step_counts` (JSON array).
void RestoreAdamMoments(const TensorArchive& archive, const std::string& file, const std::vector<std::string>& names,
                        const nlohmann::json& step_counts, std::vector<int64_t>& steps,
                        std::vector<torch::Tensor>& exp_avg, std::vector<torch::Tensor>& exp_avg_sq,
                        const std::string& m, const std::string& v, const torch::Device& device,
                        const char* what) {
  if (step_counts.size() != names.size()) throw ModelLoad(file + ": " + what + " state of another model");
  for (size_t i = 0; i < names.size(); ++i) {
    steps[i] = step_counts[i].get<int64_t>();
    exp_avg[i] = torch::Tensor();
    exp_avg_sq[i] = torch::Tensor();
    if (steps[i] == 0) continue;
    exp_avg[i] = archive.Get(m + names[i], file).to(device).clone();
    exp_avg_sq[i] = archive.Get(v + names[i], file).to(device).clone();
  }
}

}  // namespace

ModelConfig ReadStateModelConfig(const fs::path& path) {
  const TensorArchive archive = ReadTensorArchive(path, kStateKind);
  try {
    return ModelConfigFromJson(archive.meta.at("config").dump());
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(path.string() + ": malformed training state (" + e.what() + ")");
  } catch (const InvalidOptions& e) {
    throw ModelLoad(path.string() + ": the training state holds an invalid model config: " + e.what());
  }
}

void StageOneTrainer::InitFromCheckpoint(const fs::path& path) {
  const LoadedModel loaded = LoadModelCheckpoint(path);
  const ModelConfig& stored = loaded.model->config();
  // The ablation fields may differ (e.g. expression bases trained from encoder weights): every
  // tensor the two networks share is taken, the bases start afresh.
  const auto sizes_only = [](const ModelConfig& c) {
    nlohmann::json j = nlohmann::json::parse(ModelConfigToJson(c));
    for (const char* k : {"appearance_branch", "expression_model", "expression_coefficients"}) j.erase(k);
    return j;
  };
  const nlohmann::json a = sizes_only(stored), b = sizes_only(model_->config());
  if (a != b) {
    std::string differ;
    for (auto it = a.begin(); it != a.end(); ++it)
      if (!b.contains(it.key()) || b.at(it.key()) != it.value()) differ += (differ.empty() ? "" : ", ") + it.key();
    throw InvalidOptions(path.string() + ": the checkpoint is of model config '" + stored.name +
                         "', not of the model being trained ('" + model_->config().name + "'; fields that differ: " +
                         differ + "); train with the checkpoint's config");
  }
  torch::NoGradGuard no_grad;
  GohaModel source = loaded.model;
  const auto src_params = source->named_parameters(true);
  const auto src_buffers = source->named_buffers(true);
  // Tensors only this network has: the expression bases of a bases model initialised from an
  // encoder model (they keep their initialisation; the std buffer keeps what was set).
  const auto fresh = [&](const std::string& name) {
    return model_->config().expression_bases() && !stored.expression_bases() &&
           (name == "expression_bases" || name == "expression_std");
  };
  const auto take = [&](const std::string& name, torch::Tensor& dst, const torch::Tensor* src) {
    if (src == nullptr && fresh(name)) return;
    if (src == nullptr || src->sizes() != dst.sizes())
      throw ModelLoad(path.string() + ": tensor '" + name + "' does not match the model");
    dst.copy_(*src);
  };
  for (auto& item : model_->named_parameters(true)) take(item.key(), item.value(), src_params.find(item.key()));
  for (auto& item : model_->named_buffers(true)) take(item.key(), item.value(), src_buffers.find(item.key()));
  step_ = loaded.info.step;
  sr_trained_before_ = loaded.info.sr_trained;
}

void StageOneTrainer::SyncFromRankZero() {
  if (!reducer_) return;
  std::vector<double> at = {static_cast<double>(step_), -static_cast<double>(step_)};
  reducer_->AllMax(at);
  if (at[0] != -at[1])
    throw InvalidInput("data-parallel training: the ranks start at different steps (" + std::to_string(-at[1]) +
                       " to " + std::to_string(at[0]) +
                       "); every rank must resume the same RUN/state.ckpt "
                       "(a run folder shared by all ranks) or start afresh");
  torch::NoGradGuard no_grad;
  std::vector<torch::Tensor> tensors;
  for (const auto& p : model_->parameters(true)) tensors.push_back(p.detach());
  for (const auto& b : model_->buffers(true)) tensors.push_back(b);
  if (!disc_.is_empty()) {
    for (const auto& p : disc_->parameters(true)) tensors.push_back(p.detach());
    for (const auto& b : disc_->buffers(true)) tensors.push_back(b);
  }
  // Adam moments where rank 0 has them (a rank that lacks one starts it at zero to receive it).
  auto moments = [&](std::vector<torch::Tensor>& params, std::vector<torch::Tensor>& m, std::vector<torch::Tensor>& v,
                     std::vector<int64_t>& steps) {
    std::vector<torch::Tensor> counts = {torch::empty({static_cast<int64_t>(steps.size())}, torch::kFloat64)};
    for (size_t i = 0; i < steps.size(); ++i) counts[0][static_cast<int64_t>(i)] = static_cast<double>(steps[i]);
    reducer_->Broadcast(counts);
    for (size_t i = 0; i < steps.size(); ++i) {
      steps[i] = static_cast<int64_t>(counts[0][static_cast<int64_t>(i)].item<double>());
      if (steps[i] == 0) continue;
      if (!m[i].defined()) m[i] = torch::zeros_like(params[i]);
      if (!v[i].defined()) v[i] = torch::zeros_like(params[i]);
      tensors.push_back(m[i]);
      tensors.push_back(v[i]);
    }
  };
  moments(params_, exp_avg_, exp_avg_sq_, param_steps_);
  if (!disc_.is_empty()) moments(d_params_, d_exp_avg_, d_exp_avg_sq_, d_param_steps_);
  reducer_->Broadcast(tensors);
}

bool StageOneTrainer::AllFinite() const {
  for (const auto& p : params_)
    if (!Finite(p)) return false;
  for (const auto& item : model_->named_buffers(true))
    if (!Finite(item.value())) return false;
  for (size_t i = 0; i < params_.size(); ++i)
    if (!Finite(exp_avg_[i]) || !Finite(exp_avg_sq_[i])) return false;
  for (size_t i = 0; i < d_params_.size(); ++i)
    if (!Finite(d_params_[i]) || !Finite(d_exp_avg_[i]) || !Finite(d_exp_avg_sq_[i])) return false;
  return true;
}

void StageOneTrainer::SaveState(const fs::path& path, const BatchSource* source) const {
  SaveStateAt(path, source != nullptr ? source->State() : nlohmann::json());
}

void StageOneTrainer::SaveStateAt(const fs::path& path, const nlohmann::json& data_cursor) const {
  if (!AllFinite())
    throw InvalidInput(path.string() + ": not written: the training state has a non-finite tensor");
  TensorArchive archive;
  archive.kind = kStateKind;
  nlohmann::json steps = nlohmann::json::array();
  for (int64_t s : param_steps_) steps.push_back(s);
  archive.meta = {{"config", nlohmann::json::parse(ModelConfigToJson(model_->config()))},
                  {"options", options::ToJson(options_)},
                  {"step", step_},
                  {"skipped", skipped_},
                  {"bad_in_a_row", bad_in_a_row_},
                  {"param_steps", steps},
                  {"stage", options_.stage},
                  {"sr_trained_before", sr_trained_before_},
                  {"data", data_cursor}};
  for (const auto& item : model_->named_parameters(true)) archive.tensors.emplace_back("w/" + item.key(), item.value());
  for (const auto& item : model_->named_buffers(true)) archive.tensors.emplace_back("w/" + item.key(), item.value());
  StoreAdamMoments(archive, names_, exp_avg_, exp_avg_sq_, "m/", "v/");
  if (!disc_.is_empty()) {
    nlohmann::json d_steps = nlohmann::json::array();
    for (int64_t s : d_param_steps_) d_steps.push_back(s);
    archive.meta["d_param_steps"] = d_steps;
    for (const auto& item : disc_->named_parameters(true)) archive.tensors.emplace_back("d/" + item.key(), item.value());
    for (const auto& item : disc_->named_buffers(true)) archive.tensors.emplace_back("d/" + item.key(), item.value());
    StoreAdamMoments(archive, d_names_, d_exp_avg_, d_exp_avg_sq_, "dm/", "dv/");
  }
  {
    at::Generator cpu = DefaultGenerator(torch::kCPU);
    std::lock_guard<std::mutex> lock(cpu.mutex());
    archive.tensors.emplace_back("rng/cpu", cpu.get_state());
  }
  if (!device_.is_cpu()) {
    at::Generator dev = DefaultGenerator(device_);
    std::lock_guard<std::mutex> lock(dev.mutex());
    archive.tensors.emplace_back("rng/device", dev.get_state());
  }
  WriteTensorArchive(path, archive);
}

void StageOneTrainer::LoadState(const fs::path& path, BatchSource* source) {
  const TensorArchive archive = ReadTensorArchive(path, kStateKind);
  const std::string file = path.string();
  try {
    const ModelConfig stored = ModelConfigFromJson(archive.meta.at("config").dump());
    if (stored != model_->config()) {
      const nlohmann::json a = nlohmann::json::parse(ModelConfigToJson(stored));
      const nlohmann::json b = nlohmann::json::parse(ModelConfigToJson(model_->config()));
      std::string differ;
      for (auto it = a.begin(); it != a.end(); ++it)
        if (!b.contains(it.key()) || b.at(it.key()) != it.value()) differ += (differ.empty() ? "" : ", ") + it.key();
      throw ModelLoad(file + ": the training state is of model config '" + stored.name +
                      "', not of the model being trained ('" + model_->config().name +
                      "'; fields that differ: " + differ + ")");
    }
    const int64_t stage = archive.meta.value("stage", int64_t{1});
    if (stage != options_.stage)
      throw ModelLoad(file + ": the training state is of stage " + std::to_string(stage) + ", not of stage " +
                      std::to_string(options_.stage) +
                      (stage == 1 ? std::string(" (to start stage II from stage-I weights, train in a new folder "
                                                "with --init-weights RUN/model.ckpt)")
                                  : std::string(" (continue it with --stage 2)")));
    torch::NoGradGuard no_grad;
    auto copy = [&](const std::string& name, torch::Tensor& dst) {
      const torch::Tensor& src = archive.Get(name, file);
      if (src.sizes() != dst.sizes() || src.scalar_type() != dst.scalar_type())
        throw ModelLoad(file + ": tensor '" + name + "' does not match the model");
      dst.copy_(src);
    };
    for (auto& item : model_->named_parameters(true)) copy("w/" + item.key(), item.value());
    for (auto& item : model_->named_buffers(true)) copy("w/" + item.key(), item.value());
    RestoreAdamMoments(archive, file, names_, archive.meta.at("param_steps"), param_steps_, exp_avg_, exp_avg_sq_,
                       "m/", "v/", device_, "optimiser");
    if (!disc_.is_empty()) {
      for (auto& item : disc_->named_parameters(true)) copy("d/" + item.key(), item.value());
      for (auto& item : disc_->named_buffers(true)) copy("d/" + item.key(), item.value());
      RestoreAdamMoments(archive, file, d_names_, archive.meta.at("d_param_steps"), d_param_steps_, d_exp_avg_,
                         d_exp_avg_sq_, "dm/", "dv/", device_, "discriminator");
    }
    sr_trained_before_ = archive.meta.value("sr_trained_before", false);
    step_ = archive.meta.at("step").get<int64_t>();
    skipped_ = archive.meta.at("skipped").get<int64_t>();
    bad_in_a_row_ = archive.meta.at("bad_in_a_row").get<int64_t>();
    {
      at::Generator cpu = DefaultGenerator(torch::kCPU);
      std::lock_guard<std::mutex> lock(cpu.mutex());
      cpu.set_state(archive.Get("rng/cpu", file));
    }
    if (!device_.is_cpu()) {
      at::Generator dev = DefaultGenerator(device_);
      std::lock_guard<std::mutex> lock(dev.mutex());
      dev.set_state(archive.Get("rng/device", file));
    }
    if (source != nullptr) source->Restore(archive.meta.at("data"));
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(file + ": malformed training state (" + e.what() + ")");
  }
}

void StageOneTrainer::ExportWeights(const fs::path& path, const std::string& data_provenance,
                                    bool half_precision) const {
  if (!AllFinite()) throw InvalidInput(path.string() + ": not written: the weights have a non-finite value");
  CheckpointInfo info;
  info.step = step_;
  info.data_provenance = data_provenance;
  info.sr_trained = options_.stage == 2 || sr_trained_before_;
  GohaModel model = model_;
  SaveModelCheckpoint(path, model, info, half_precision);
}

fs::path StatePath(const fs::path& out_dir) { return out_dir / "state.ckpt"; }
fs::path LogPath(const fs::path& out_dir) { return out_dir / "train.jsonl"; }

int64_t TruncateLog(const fs::path& log, int64_t first_step) {
  if (!fs::exists(log)) return 0;
  std::ifstream in(log, std::ios::binary);
  if (!in) throw Io(log.string() + ": cannot read the training log");
  std::string kept, line;
  int64_t dropped = 0;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    bool keep = false;
    try {
      const nlohmann::json j = nlohmann::json::parse(line);
      keep = j.is_object() && (!j.contains("step") || !j.at("step").is_number_integer() ||
                               j.at("step").get<int64_t>() < first_step);
    } catch (const nlohmann::json::exception&) {
      keep = false;  // a line cut short (killed while writing)
    }
    if (keep) {
      kept += line;
      kept += '\n';
    } else {
      ++dropped;
    }
  }
  in.close();
  if (dropped > 0) WriteBytesAtomically(log, kept);
  return dropped;
}

}  // namespace avatar::train
