#include "core/train/fusion_training.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <random>
#include <sstream>

#include <nlohmann/json.hpp>

#include "core/io/atomic_file.h"
#include "core/train/metrics.h"
#include "core/train/trainer.h"
#include "core/util/error.h"
#include "core/util/progress_line.h"

namespace avatar::train {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

double FusionSeconds(Clock::time_point since) { return std::chrono::duration<double>(Clock::now() - since).count(); }

std::string FusionHms(double seconds) {
  if (!std::isfinite(seconds) || seconds < 0) return "?";
  const int64_t s = static_cast<int64_t>(seconds + 0.5);
  std::ostringstream o;
  o << s / 3600 << ":" << std::setw(2) << std::setfill('0') << (s / 60) % 60 << ":" << std::setw(2) << s % 60;
  return o.str();
}

// The crops of one step: deterministic in (seed, step), so a resumed run draws what the first
// would have.
struct FusionBatch {
  torch::Tensor input, target, turn;
};

FusionBatch DrawFusionBatch(const FusionSamples& s, const FusionTrainOptions& o, int64_t step) {
  std::mt19937_64 rng(static_cast<uint64_t>(o.seed) * 0x9E3779B97F4A7C15ull + static_cast<uint64_t>(step));
  const int64_t n = s.size(), side = s.input.size(2), crop = o.crop;
  std::uniform_int_distribution<int64_t> pick(0, n - 1), at(0, side - crop);
  std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
  std::vector<torch::Tensor> inputs, targets;
  std::vector<int64_t> picked;
  for (int b = 0; b < o.batch; ++b) {
    const int64_t i = pick(rng), y = at(rng), x = at(rng);
    picked.push_back(i);
    const bool flip = (rng() & 1u) != 0;
    torch::Tensor in = FusionInputFromBytes(s.input[i].narrow(1, y, crop).narrow(2, x, crop).unsqueeze(0));
    torch::Tensor tg = FusionInputFromBytes(s.target[i].narrow(1, y, crop).narrow(2, x, crop).unsqueeze(0), 3);
    if (flip) {
      in = in.flip({3});
      tg = tg.flip({3});
    }
    if (o.color_jitter > 0) {
      // The same colour change on every image of the crop (composite, network render, target):
      // the net learns how the layers relate, not one training person's skin and hair colours.
      std::array<int64_t, 3> order = {0, 1, 2};
      std::shuffle(order.begin(), order.end(), rng);
      std::array<float, 3> gain{}, offset{};
      for (int c = 0; c < 3; ++c) {
        gain[c] = 1.0f + static_cast<float>(o.color_jitter) * unit(rng);
        offset[c] = 0.5f * static_cast<float>(o.color_jitter) * unit(rng);
      }
      const torch::Tensor g = torch::tensor(std::vector<float>(gain.begin(), gain.end())).view({1, 3, 1, 1});
      const torch::Tensor off = torch::tensor(std::vector<float>(offset.begin(), offset.end())).view({1, 3, 1, 1});
      const torch::Tensor idx = torch::tensor(std::vector<int64_t>(order.begin(), order.end()));
      auto change = [&](const torch::Tensor& rgb) {
        return (rgb.index_select(1, idx) * g + off).clamp(-1.0, 1.0);
      };
      std::vector<torch::Tensor> parts;
      for (int64_t c0 = 0; c0 < kFusionImageChannels; c0 += 3) parts.push_back(change(in.slice(1, c0, c0 + 3)));
      parts.push_back(in.slice(1, kFusionImageChannels));
      in = torch::cat(parts, 1);
      tg = change(tg);
    }
    inputs.push_back(in);
    targets.push_back(tg);
  }
  return {torch::cat(inputs), torch::cat(targets), s.Turn().index_select(0, torch::tensor(picked))};
}

double FusionGradNorm(const FusionNet& net) {
  double sq = 0.0;
  for (const auto& p : net->parameters()) {
    if (p.grad().defined()) sq += p.grad().pow(2).sum().item<double>();
  }
  return std::sqrt(sq);
}

void SaveFusionState(const fs::path& path, FusionNet& net, torch::optim::Adam& adam, int64_t step) {
  WriteFileAtomically(path, [&](const fs::path& tmp) {
    torch::serialize::OutputArchive archive;
    net->save(archive);
    torch::serialize::OutputArchive opt;
    adam.save(opt);
    archive.write("adam", opt);
    archive.write("step", torch::tensor(step));
    archive.save_to(tmp.string());
  });
}

int64_t LoadFusionState(const fs::path& path, FusionNet& net, torch::optim::Adam& adam) {
  torch::serialize::InputArchive archive;
  try {
    archive.load_from(path.string());
    net->load(archive);
    torch::serialize::InputArchive opt;
    archive.read("adam", opt);
    adam.load(opt);
    torch::Tensor step;
    archive.read("step", step);
    return step.item<int64_t>();
  } catch (const c10::Error& e) {
    throw ModelLoad(path.string() + ": cannot resume from this training state (" + e.msg() +
                    "); delete it to start over, or pass --no-resume");
  }
}

}  // namespace

torch::Tensor FusionSamples::Turn() const {
  if (!meta.defined()) return torch::zeros({0});
  return torch::hypot(meta.select(1, 0), meta.select(1, 1));  // FusionTurnDegrees, per row
}

FusionSamples LoadFusionSplit(const std::string& dir, const std::string& split) {
  AVATAR_CHECK_OPTION(split == "train" || split == "val") << "a fusion split is train or val, got '" << split << "'";
  const fs::path folder = fs::path(dir) / split;
  if (!fs::is_directory(folder))
    throw Io(folder.string() + ": no such folder: build the fusion set with avatar-studio fusion build");
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(folder)) {
    if (e.path().extension() == ".pt") files.push_back(e.path());
  }
  std::sort(files.begin(), files.end());
  std::vector<torch::Tensor> parts[5];
  for (const auto& f : files) {
    std::vector<torch::Tensor> t;
    try {
      torch::load(t, f.string());
    } catch (const c10::Error& e) {
      throw InvalidInput(f.string() + ": not a fusion set file (" + e.msg() + "): delete it and rerun fusion build");
    }
    AVATAR_CHECK_INPUT(t.size() == 5 && t[0].dim() == 4 && t[0].size(1) == kFusionInputChannels &&
                       t[0].scalar_type() == torch::kUInt8 && t[1].dim() == 4 && t[1].size(1) == 3 &&
                       t[2].dim() == 4 && t[3].dim() == 4 && t[4].dim() == 2 && t[4].size(1) == 4)
        << f.string() << ": not a fusion set file of this version: delete it and rerun fusion build";
    const int64_t n = t[0].size(0);
    for (int k = 0; k < 5; ++k) {
      AVATAR_CHECK_INPUT(t[k].size(0) == n) << f.string() << ": its tensors hold different sample counts";
      if (k < 4) {
        AVATAR_CHECK_INPUT(t[k].size(2) == t[0].size(2) && t[k].size(3) == t[0].size(3))
            << f.string() << ": its frames differ in size";
      }
      parts[k].push_back(t[k]);
    }
  }
  FusionSamples s;
  if (files.empty()) return s;
  s.input = torch::cat(parts[0]);
  s.target = torch::cat(parts[1]);
  s.matte = torch::cat(parts[2]);
  s.preview = torch::cat(parts[3]);
  s.meta = torch::cat(parts[4]).to(torch::kFloat32);
  AVATAR_CHECK_INPUT(s.input.size(2) == s.input.size(3)) << folder.string() << ": the frames are not square";
  return s;
}

void FusionLossOptions::Validate() const {
  AVATAR_CHECK_OPTION(std::isfinite(l1) && l1 >= 0 && std::isfinite(perceptual) && perceptual >= 0 &&
                      std::isfinite(ssim) && ssim >= 0 && l1 + perceptual + ssim > 0)
      << "the fusion loss weights must be >= 0 and not all 0";
}

FusionLoss ComputeFusionLoss(const torch::Tensor& prediction, const torch::Tensor& target,
                             const PerceptualLoss* perceptual, const FusionLossOptions& options) {
  AVATAR_CHECK_INPUT(prediction.sizes() == target.sizes() && prediction.dim() == 4 && prediction.size(1) == 3)
      << "fusion loss: prediction " << prediction.sizes() << " and target " << target.sizes() << " differ";
  AVATAR_CHECK_INPUT(perceptual != nullptr || options.perceptual == 0.0)
      << "fusion loss: a perceptual weight without the perceptual network";
  FusionLoss out;
  out.l1 = (prediction - target).abs().mean();
  out.perceptual = perceptual != nullptr ? perceptual->Distance(prediction, target).mean()
                                         : torch::zeros({}, prediction.options());
  out.ssim = options.ssim > 0 ? 1.0 - train::SsimPerImage(prediction, target).mean()
                               : torch::zeros({}, prediction.options());
  out.total = options.l1 * out.l1 + options.perceptual * out.perceptual + options.ssim * out.ssim;
  return out;
}

void FusionTrainOptions::Validate() const {
  AVATAR_CHECK_OPTION(!data.empty()) << "--data must name a fusion set folder";
  AVATAR_CHECK_OPTION(!out_dir.empty()) << "--out must name the run folder";
  AVATAR_CHECK_OPTION(steps >= 0) << "--steps must be >= 0";
  AVATAR_CHECK_OPTION(std::isfinite(hours) && hours >= 0) << "--hours must be >= 0";
  AVATAR_CHECK_OPTION(batch >= 1 && batch <= 256) << "--batch must be within 1..256";
  AVATAR_CHECK_OPTION(crop >= 32 && crop % 8 == 0) << "--crop must be a multiple of 8, at least 32";
  AVATAR_CHECK_OPTION(std::isfinite(lr) && lr > 0 && lr < 1) << "--lr must be in (0, 1)";
  AVATAR_CHECK_OPTION(std::isfinite(color_jitter) && color_jitter >= 0 && color_jitter <= 0.5)
      << "--color-jitter must be within 0..0.5";
  AVATAR_CHECK_OPTION(checkpoint_minutes > 0) << "checkpoint_minutes must be > 0";
  AVATAR_CHECK_OPTION(validate_every >= 0 && validate_samples >= 1) << "bad validation schedule";
  AVATAR_CHECK_OPTION(max_bad_steps >= 1) << "max_bad_steps must be >= 1";
  loss.Validate();
  NetOptions().Validate();
}

FusionNetOptions FusionTrainOptions::NetOptions() const {
  FusionNetOptions net;
  net.widths = widths;
  net.keep_warped = keep_warped;
  net.turn = turn;
  net.gate_by_opacity = gate_by_opacity;
  net.turn_keeps_face = turn_keeps_face;
  net.turn_open = turn_open;
  net.keep_eye_mouth = keep_eye_mouth;
  return net;
}

FusionValidation ValidateFusion(FusionNet& net, const FusionSamples& samples, int count,
                                const PerceptualLoss* perceptual, const FusionLossOptions& options) {
  FusionValidation v;
  const int64_t n = std::min<int64_t>(count, samples.size());
  if (n <= 0) return v;
  torch::NoGradGuard no_grad;
  const bool was_training = net->is_training();
  net->eval();
  std::vector<int64_t> index;
  for (int64_t k = 0; k < n; ++k) index.push_back(k * samples.size() / n);
  for (size_t k = 0; k < index.size(); k += 4) {
    const int64_t m = std::min<int64_t>(4, static_cast<int64_t>(index.size() - k));
    const torch::Tensor idx = torch::tensor(std::vector<int64_t>(index.begin() + k, index.begin() + k + m));
    const torch::Tensor x = FusionInputFromBytes(samples.input.index_select(0, idx));
    const torch::Tensor y = FusionInputFromBytes(samples.target.index_select(0, idx), 3);
    const FusionLoss a = ComputeFusionLoss(net->forward(x, samples.Turn().index_select(0, idx)), y, perceptual, options);
    const FusionLoss b = ComputeFusionLoss(x.slice(1, 0, 3), y, perceptual, options);
    v.loss += a.total.item<double>() * m;
    v.l1 += a.l1.item<double>() * m;
    v.perceptual += a.perceptual.item<double>() * m;
    v.ssim += a.ssim.item<double>() * m;
    v.composite_ssim += b.ssim.item<double>() * m;
    v.composite_loss += b.total.item<double>() * m;
    v.composite_l1 += b.l1.item<double>() * m;
    v.composite_perceptual += b.perceptual.item<double>() * m;
  }
  v.samples = n;
  for (double* f : {&v.loss, &v.l1, &v.perceptual, &v.ssim, &v.composite_loss, &v.composite_l1,
                    &v.composite_perceptual, &v.composite_ssim})
    *f /= static_cast<double>(n);
  if (was_training) net->train();
  return v;
}

FusionTrainResult TrainFusion(const FusionTrainOptions& o, RunContext& ctx) {
  o.Validate();
  const FusionSamples train = LoadFusionSplit(o.data, "train");
  AVATAR_CHECK_INPUT(train.size() > 0) << o.data << ": the fusion set has no training frames";
  AVATAR_CHECK_OPTION(o.crop <= train.input.size(2))
      << "--crop " << o.crop << " is larger than the stored frames (" << train.input.size(2) << ")";
  FusionSamples val;
  if (fs::is_directory(fs::path(o.data) / "val")) val = LoadFusionSplit(o.data, "val");

  const fs::path out(o.out_dir);
  std::error_code ec;
  fs::create_directories(out, ec);
  if (ec) throw Io(o.out_dir + ": cannot create the run folder: " + ec.message());
  const FusionNetOptions net_options = o.NetOptions();
  torch::manual_seed(o.seed);  // a fresh run's initial weights depend on the seed only
  FusionNet net(net_options);
  torch::optim::Adam adam(net->parameters(), torch::optim::AdamOptions(o.lr).betas({0.9, 0.99}));
  const fs::path state = out / "state.pt", log_path = LogPath(out);
  int64_t step = 0;
  const bool resumed = o.resume && fs::exists(state);
  if (resumed) {
    step = LoadFusionState(state, net, adam);
  } else if (!o.init.empty()) {
    FusionNetInfo info;
    FusionNet init = LoadFusionNet(o.init, &info);
    try {
      CopyFusionWeights(init, net);
    } catch (const InvalidOptions& e) {
      throw InvalidOptions(o.init + ": cannot start this run from it: " + e.what());
    }
    step = info.step;
  }
  PerceptualOptions po;
  po.data_dir = o.data_dir;
  std::unique_ptr<PerceptualLoss> perceptual;
  if (o.loss.perceptual > 0) perceptual = std::make_unique<PerceptualLoss>(po);

  FusionTrainResult result;
  result.first_step = step;
  TruncateLog(log_path, step + 1);  // lines are numbered by the step they end: keep those up to here
  std::ofstream log(log_path, std::ios::app);
  if (!log) throw Io(log_path.string() + ": cannot open the training log");
  const std::string provenance = "fusion set " + fs::absolute(o.data).string() + " (" + std::to_string(train.size()) +
                                 " training frames)";
  auto export_weights = [&] {
    FusionNetInfo info;
    info.step = step;
    info.data_provenance = provenance;
    SaveFusionNet(out / "fusion.ckpt", net, info, false);
    SaveFusionNet(out / "fusion-fp16.ckpt", net, info, true);
  };
  int64_t validated_at = -1;
  auto validate = [&] {
    if (val.size() == 0) return;
    validated_at = step;
    result.last_validation = ValidateFusion(net, val, o.validate_samples, perceptual.get(), o.loss);
    const FusionValidation& v = result.last_validation;
    nlohmann::json line = {{"step", step},
                           {"val",
                            {{"samples", v.samples},
                             {"loss", v.loss},
                             {"l1", v.l1},
                             {"perceptual", v.perceptual},
                             {"composite_loss", v.composite_loss},
                             {"composite_l1", v.composite_l1},
                             {"composite_perceptual", v.composite_perceptual},
                             {"ssim", v.ssim},
                             {"composite_ssim", v.composite_ssim}}}};
    log << line.dump() << "\n";
    log.flush();
  };
  ProgressLine progress = ProgressLine::ForStderr();
  const auto start = Clock::now();
  auto last_save = start;
  int64_t bad_in_a_row = 0;
  double mean_step = 0.0;
  int64_t timed = 0;
  result.stopped_by = "steps";
  net->train();
  if (!resumed) validate();  // where this run starts (a resumed run validated here when it stopped)
  try {
    while (step < o.steps) {
      if (o.hours > 0 && FusionSeconds(start) >= o.hours * 3600.0) {
        result.stopped_by = "hours";
        break;
      }
      ctx.ThrowIfCancelled();
      const auto t0 = Clock::now();
      const FusionBatch batch = DrawFusionBatch(train, o, step);
      adam.zero_grad();
      const FusionLoss loss =
          ComputeFusionLoss(net->forward(batch.input, batch.turn), batch.target, perceptual.get(), o.loss);
      const double total = loss.total.item<double>();
      bool skipped = !std::isfinite(total);
      double grad_norm = 0.0;
      if (!skipped) {
        loss.total.backward();
        grad_norm = FusionGradNorm(net);
        skipped = !std::isfinite(grad_norm);
      }
      if (skipped) {
        adam.zero_grad();
        ++result.skipped;
        if (++bad_in_a_row >= o.max_bad_steps) {
          SaveFusionState(state, net, adam, step);
          throw InvalidInput("fusion training stopped: " + std::to_string(bad_in_a_row) +
                             " steps in a row had a non-finite loss or gradient; the last good state is in " +
                             state.string());
        }
      } else {
        bad_in_a_row = 0;
        torch::nn::utils::clip_grad_norm_(net->parameters(), 1.0);
        adam.step();
      }
      ++step;
      const double seconds = FusionSeconds(t0);
      ++timed;
      mean_step += (seconds - mean_step) / static_cast<double>(std::min<int64_t>(timed, 20));
      nlohmann::json line = {{"step", step},
                             {"loss", total},
                             {"terms",
                              {{"l1", loss.l1.item<double>()},
                               {"perceptual", loss.perceptual.item<double>()},
                               {"ssim", loss.ssim.item<double>()}}},
                             {"grad_norm", grad_norm},
                             {"lr", o.lr},
                             {"color_jitter", o.color_jitter},
                             {"batch", o.batch},
                             {"crop", o.crop},
                             {"step_s", seconds},
                             {"skipped", skipped},
                             {"skipped_total", result.skipped}};
      log << line.dump() << "\n";
      log.flush();
      if (o.progress) {
        double eta = mean_step * static_cast<double>(o.steps - step);
        if (o.hours > 0) eta = std::min(eta, o.hours * 3600.0 - FusionSeconds(start));
        std::ostringstream p;
        p << "fusion train: step " << step << "/" << o.steps << "  loss " << std::fixed << std::setprecision(4) << total
          << "  " << std::setprecision(2) << mean_step << " s/step  val " << std::setprecision(4)
          << result.last_validation.loss << " (composite " << result.last_validation.composite_loss << ")  ETA "
          << FusionHms(eta);
        progress.Update(p.str());
      }
      if (o.validate_every > 0 && step % o.validate_every == 0) validate();
      if (FusionSeconds(last_save) >= o.checkpoint_minutes * 60.0) {
        SaveFusionState(state, net, adam, step);
        export_weights();
        last_save = Clock::now();
      }
      ctx.Report("fusion train", o.steps > 0 ? static_cast<double>(step) / static_cast<double>(o.steps) : 1.0,
                 "step " + std::to_string(step));
    }
  } catch (const Cancelled&) {
    progress.Finish();
    SaveFusionState(state, net, adam, step);
    export_weights();
    throw;
  }
  progress.Finish();
  if (validated_at != step) validate();
  SaveFusionState(state, net, adam, step);
  export_weights();
  result.last_step = step;
  return result;
}

}  // namespace avatar::train
