// The run loop: a run folder's steps, log, samples, state writes and stops around Step.

#include "core/train/trainer.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <string>
#include <vector>

#include "core/util/error.h"
#include "core/util/progress_line.h"

namespace avatar::train {

namespace fs = std::filesystem;

namespace {

std::string FormatDuration(double seconds) {
  if (!std::isfinite(seconds) || seconds < 0) return "?";
  const int64_t s = static_cast<int64_t>(seconds + 0.5);
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%lld:%02lld:%02lld", static_cast<long long>(s / 3600),
                static_cast<long long>((s / 60) % 60), static_cast<long long>(s % 60));
  return buf;
}

// The first `n` pairs of a batch (copies).
TrainBatch FirstPairs(const TrainBatch& b, int64_t n) {
  n = std::min(n, b.size());
  return b.Map([n](const torch::Tensor& t) { return t.narrow(0, 0, n).clone(); });
}

// [-1,1] renders -> CPU float in [0,1].
StageOneTrainer::Renders ForDisplay(const StageOneTrainer::Renders& r) {
  auto show = [](const torch::Tensor& t) {
    return t.defined() ? ((t.detach().to(torch::kCPU, torch::kFloat32) + 1.0) * 0.5).clamp(0.0, 1.0).nan_to_num(0.0)
                       : t;
  };
  StageOneTrainer::Renders out;
  out.target = show(r.target);
  out.canonical = show(r.canonical);
  out.expression = show(r.expression);
  out.full = show(r.full);
  out.source = show(r.source);
  out.super_resolved = show(r.super_resolved);
  return out;
}

}  // namespace

void RunOptions::Validate() const {
  AVATAR_CHECK_OPTION(!out_dir.empty()) << "--out must name the run folder";
  AVATAR_CHECK_OPTION(steps >= 0) << "--steps must be >= 0";
  AVATAR_CHECK_OPTION(hours >= 0 && std::isfinite(hours)) << "--hours must be >= 0";
  AVATAR_CHECK_OPTION(checkpoint_minutes > 0) << "checkpoint_minutes must be > 0";
  AVATAR_CHECK_OPTION(checkpoint_steps >= 0) << "checkpoint_steps must be >= 0";
  AVATAR_CHECK_OPTION(sample_every >= 0) << "sample_every must be >= 0";
}

RunResult RunTraining(StageOneTrainer& trainer, BatchSource& source, const RunOptions& options, RunContext& ctx) {
  options.Validate();
  // Data parallelism: every rank trains, only rank 0 writes (state, log, samples, exports).
  GradientReducer* const reducer = trainer.gradient_reducer();
  const bool lead = reducer == nullptr || reducer->rank() == 0;
  const int64_t world = reducer != nullptr ? reducer->world_size() : 1;
  std::error_code ec;
  if (lead) fs::create_directories(options.out_dir, ec);
  if (ec) throw Io(options.out_dir.string() + ": cannot create the run folder: " + ec.message());
  const fs::path state = StatePath(options.out_dir);
  if (options.resume && fs::exists(state))
    trainer.LoadState(state, &source);
  else if (!options.init_weights.empty())
    trainer.InitFromCheckpoint(options.init_weights);
  trainer.SyncFromRankZero();
  RunResult result;
  result.first_step = trainer.step();
  std::ofstream log;
  if (lead) {
    // Every step once in the log: drop what was logged at or after the step this run starts at.
    TruncateLog(LogPath(options.out_dir), result.first_step);
    log.open(LogPath(options.out_dir), std::ios::app);
    if (!log) throw Io(LogPath(options.out_dir).string() + ": cannot open the training log");
  }
  const bool progress = options.progress && lead;
  ProgressLine progress_line = ProgressLine::ForStderr();

  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  auto last_save = start;
  auto elapsed = [](Clock::time_point since) { return std::chrono::duration<double>(Clock::now() - since).count(); };
  // The source's cursor before the batch in flight (one process: a step can be cancelled).
  nlohmann::json cursor_before;
  bool cancelled_in_step = false;
  auto save = [&] {
    if (!lead) return;
    if (cancelled_in_step)
      trainer.SaveStateAt(state, cursor_before);
    else
      trainer.SaveState(state, &source);
    last_save = Clock::now();
    if (options.on_state_written) options.on_state_written(trainer.step());
  };
  // Sample renders of the first batch this call takes.
  TrainBatch sample_batch;
  int64_t last_sampled = -1;
  auto sample = [&] {
    if (!lead || !options.on_samples || sample_batch.size() == 0 || last_sampled == trainer.step()) return;
    last_sampled = trainer.step();
    options.on_samples(trainer.step(), ForDisplay(trainer.Evaluate(sample_batch)));
  };
  auto export_weights = [&] {
    if (!lead) return;
    trainer.ExportWeights(options.out_dir / "model.ckpt", options.data_provenance);
    trainer.ExportWeights(options.out_dir / "model-fp16.ckpt", options.data_provenance, /*half_precision=*/true);
  };
  double mean_step = 0.0;
  int64_t timed = 0;
  result.stopped_by = "steps";
  // A cancel inside a step (one process only), undone when this run ends however it ends.
  struct CancelScope {
    StageOneTrainer& t;
    CancelScope(StageOneTrainer& trainer, const RunContext* ctx) : t(trainer) { t.SetCancelContext(ctx); }
    ~CancelScope() { t.SetCancelContext(nullptr); }
  } cancel_scope(trainer, reducer == nullptr ? &ctx : nullptr);
  try {
    while (trainer.step() < options.steps) {
      bool out_of_time = options.hours > 0 && elapsed(start) >= options.hours * 3600.0;
      if (reducer != nullptr) {
        // The ranks stop together: at the first step any of them is out of time or cancelled.
        std::vector<double> stop = {out_of_time ? 1.0 : 0.0, ctx.IsCancelled() ? 1.0 : 0.0};
        reducer->AllMax(stop);
        out_of_time = stop[0] > 0;
        if (stop[1] > 0) ctx.RequestCancel();
      }
      if (out_of_time) {
        result.stopped_by = "hours";
        break;
      }
      ctx.ThrowIfCancelled();
      if (reducer == nullptr) cursor_before = source.State();
      const TrainBatch batch = source.Next();
      if (lead && options.on_samples && sample_batch.size() == 0) sample_batch = FirstPairs(batch, 4);
      StepResult r;
      try {
        r = trainer.Step(batch);
      } catch (const Cancelled&) {
        cancelled_in_step = true;  // Nothing of this batch was applied: the state points at it.
        throw;
      }
      ++timed;
      mean_step += (r.seconds - mean_step) / static_cast<double>(std::min<int64_t>(timed, 20));
      // Samples of the global batch (every rank's shard) per second.
      const int64_t global_batch = batch.size() * world;
      const double samples_per_s = r.seconds > 0 ? global_batch / r.seconds : 0.0;
      nlohmann::json line = {{"step", r.step},
                             {"phase", r.phase},
                             {"loss", r.loss},
                             {"terms", r.terms},
                             {"grad_norm", r.grad_norm},
                             {"lr", trainer.options().lr},
                             {"step_s", r.seconds},
                             {"samples_per_s", samples_per_s},
                             {"batch", global_batch},
                             {"skipped", r.skipped},
                             {"skipped_total", trainer.skipped_steps()}};
      if (world > 1) line["world_size"] = world;
      if (trainer.options().stage == 2) {
        line["d_loss"] = r.d_loss;
        line["d_terms"] = r.d_terms;
        line["d_grad_norm"] = r.d_grad_norm;
        line["d_lr"] = trainer.options().d_lr;
      }
      if (r.skipped) line["skip_reason"] = r.skip_reason;
      // nlohmann writes non-finite doubles as null, which keeps each line valid JSON.
      if (lead) {
        log << line.dump() << "\n";
        log.flush();
      }
      const int64_t done = trainer.step() - result.first_step, total = options.steps - result.first_step;
      double eta = mean_step * static_cast<double>(options.steps - trainer.step());
      if (options.hours > 0) eta = std::min(eta, options.hours * 3600.0 - elapsed(start));
      if (progress) {
        std::ostringstream p;
        p << "train: step " << trainer.step() << "/" << options.steps << "  " << r.phase << "  loss " << std::fixed
          << std::setprecision(4) << r.loss << "  " << std::setprecision(2) << mean_step << " s/step  "
          << std::setprecision(1) << samples_per_s << " samples/s  skipped " << trainer.skipped_steps() << "  ETA "
          << FormatDuration(eta);
        progress_line.Update(p.str());
      }
      if (trainer.bad_in_a_row() >= trainer.options().max_bad_steps) {
        if (progress) progress_line.Finish();
        save();
        throw InvalidInput("training stopped: " + std::to_string(trainer.bad_in_a_row()) +
                           " steps in a row had a non-finite loss or gradient (last: " + r.skip_reason +
                           "); the last good state is in " + state.string());
      }
      if (elapsed(last_save) >= options.checkpoint_minutes * 60.0 ||
          (options.checkpoint_steps > 0 && trainer.step() % options.checkpoint_steps == 0))
        save();
      if (options.sample_every > 0 && trainer.step() % options.sample_every == 0) sample();
      try {
        ctx.Report("train", total > 0 ? static_cast<double>(done) / static_cast<double>(total) : 1.0,
                   "step " + std::to_string(trainer.step()));
      } catch (const Cancelled&) {
        // Data parallelism: a cancel stops the ranks together, at the next step's agreement.
        if (reducer == nullptr) throw;
      }
    }
  } catch (const Cancelled&) {
    // A cancelled run keeps its work twice: the state to resume from and usable weights of the
    // last applied step (hours of training should not need a resume only to get a model).
    if (progress) progress_line.Finish();
    save();
    export_weights();
    throw;
  }
  if (progress) progress_line.Finish();
  sample();
  save();
  export_weights();
  result.last_step = trainer.step();
  result.skipped = trainer.skipped_steps();
  return result;
}

}  // namespace avatar::train
