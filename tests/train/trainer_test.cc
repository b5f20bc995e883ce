// The stage-I losses (analytic values and double-precision finite-difference gradient checks)
// and the trainer: resume, non-finite steps, cancel, weights export and overfitting one pair.

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <thread>
#include <vector>

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/model/goha_model.h"
#include "core/render/camera.h"
#include "core/train/losses.h"
#include "core/train/trainer.h"
#include "core/util/error.h"
#include "core/util/run_context.h"
#include "train/trainer_test_util.h"

namespace avatar::train {
namespace {

namespace fs = std::filesystem;

const auto kF64 = torch::TensorOptions().dtype(torch::kFloat64);

TEST(TrainLosses, L1AndMaskedL1Values) {
  const torch::Tensor a = torch::zeros({2, 3, 4, 4}), b = torch::full({2, 3, 4, 4}, 0.5);
  EXPECT_NEAR(L1Distance(a, b)[1].item<double>(), 0.5, 1e-7);
  torch::Tensor mask = torch::zeros({2, 1, 4, 4});
  mask.narrow(3, 0, 1).fill_(1.0);
  torch::Tensor c = b.clone();
  c.narrow(3, 1, 3).fill_(100.0);  // outside the mask: ignored
  const torch::Tensor d = L1Distance(a, c, mask);
  ASSERT_EQ(d.sizes(), (std::vector<int64_t>{2}));
  EXPECT_NEAR(d[0].item<double>(), 0.5, 1e-6);
  EXPECT_THROW(L1Distance(a, torch::zeros({2, 3, 4, 5})), InvalidInput);
}

TEST(TrainLosses, NeutralLossAnalytic) {
  // I_c = 0.2 everywhere, I_neu = -0.2, M_neu = left half: inside the matted images differ by
  // 0.4, outside both are background (-1). L1 = 0.4 x 1/2 = 0.2; the pyramid stand-in keeps the
  // mean of a one-signed difference on every (aligned) level: 0.2. With weight 1: 0.4.
  const torch::Tensor ic = torch::full({1, 3, 16, 16}, 0.2);
  const torch::Tensor neu = torch::full({1, 3, 64, 64}, -0.2);
  torch::Tensor mask = torch::zeros({1, 1, 64, 64});
  mask.narrow(3, 0, 32).fill_(1.0);
  const PerceptualFn pyramid = [](const torch::Tensor& a, const torch::Tensor& b) { return PyramidL1Distance(a, b); };
  EXPECT_NEAR(NeutralLoss(ic, neu, mask, nullptr).item<double>(), 0.2, 1e-6);
  EXPECT_NEAR(NeutralLoss(ic, neu, mask, pyramid, 1.0).item<double>(), 0.4, 1e-6);
  // Outside M_neu nothing counts: changing I_c there changes nothing.
  torch::Tensor ic2 = ic.clone();
  ic2.narrow(3, 8, 8).fill_(0.9);
  EXPECT_NEAR(NeutralLoss(ic2, neu, mask, pyramid, 1.0).item<double>(), 0.4, 1e-6);
}

TEST(TrainLosses, TvLossAnalyticOnALinearField) {
  // sigma(p) = a.p: |sigma(p) - sigma(p')| = |a.(p - p')| exactly, and for p' - p ~ N(0, s^2 I)
  // its mean is |a| s sqrt(2/pi), with s = sigma x box/2 in world units.
  const torch::Tensor a = torch::tensor({3.0, 4.0, 0.0}, kF64);
  double max_coord = 0.0;
  const DensityFn linear = [&](const torch::Tensor& p) {
    max_coord = std::max(max_coord, p.abs().max().item<double>());
    return p.matmul(a.to(p.scalar_type()));
  };
  const torch::Tensor p = torch::tensor({0.1, 0.2, 0.3, -0.4, 0.0, 0.25}, kF64).view({1, 2, 3});
  const torch::Tensor q = p + torch::tensor({0.01, 0.0, 0.0, 0.0, -0.02, 0.5}, kF64).view({1, 2, 3});
  EXPECT_NEAR(DensityTvAt(linear, p, q).item<double>(), (0.03 + 0.08) / 2.0, 1e-12);

  torch::manual_seed(3);
  TvOptions o;
  o.num_points = 200000;
  o.box_warp = 1.0;
  max_coord = 0.0;
  const double expected = 5.0 * (o.sigma * 0.5) * std::sqrt(2.0 / M_PI);
  EXPECT_NEAR(DensityTvLoss(linear, 1, o, kF64).item<double>(), expected, expected * 0.01);
  EXPECT_LT(max_coord, 0.5 + 0.02) << "TV points must lie in the planes' box [-box/2, box/2]^3";
  EXPECT_GT(max_coord, 0.49);
}

TEST(TrainLosses, GradientChecksInDoublePrecision) {
  torch::manual_seed(4);
  const torch::Tensor a = torch::rand({2, 3, 8, 8}, kF64) * 2 - 1;
  const torch::Tensor b = torch::rand({2, 3, 8, 8}, kF64) * 2 - 1;
  const torch::Tensor mask = torch::rand({2, 1, 8, 8}, kF64);
  ExpectGradMatches([&](const torch::Tensor& x) { return L1Distance(x, b).sum(); }, a, "L1");
  ExpectGradMatches([&](const torch::Tensor& x) { return L1Distance(x, b, mask).sum(); }, a, "masked L1");
  ExpectGradMatches([&](const torch::Tensor& m) { return L1Distance(a, b, m).sum(); }, mask, "masked L1 (mask)");
  ExpectGradMatches([&](const torch::Tensor& x) { return PyramidL1Distance(x, b).sum(); }, a, "pyramid stand-in");
  const PerceptualFn pyramid = [](const torch::Tensor& x, const torch::Tensor& y) { return PyramidL1Distance(x, y); };
  const torch::Tensor neu = torch::rand({2, 3, 16, 16}, kF64) * 2 - 1;
  const torch::Tensor mneu = torch::rand({2, 1, 16, 16}, kF64);
  ExpectGradMatches([&](const torch::Tensor& x) { return NeutralLoss(x, neu, mneu, pyramid).sum(); }, a, "neutral");
  ExpectGradMatches([&](const torch::Tensor& x) { return ImageLoss(x, b, pyramid, 0.5).sum(); }, a, "image loss");
  // TV with respect to the parameters of a smooth field sigma(p) = sum_k sin(p A)_k.
  const torch::Tensor p = torch::rand({2, 16, 3}, kF64) - 0.5;
  const torch::Tensor q = p + 0.05 * torch::randn({2, 16, 3}, kF64);
  const torch::Tensor a0 = torch::randn({3, 4}, kF64) * 3;
  ExpectGradMatches(
      [&](const torch::Tensor& A) {
        const DensityFn f = [&](const torch::Tensor& x) { return x.matmul(A).sin().sum(-1); };
        return DensityTvAt(f, p, q);
      },
      a0, "TV");
}

TEST(Trainer, CurriculumAndTermsPerPhase) {
  torch::manual_seed(5);
  const ModelConfig c = ModelConfig::Tiny();
  StageOneTrainer trainer(GohaModel(c), TestOptions(), kStandIn);
  SyntheticSource source(c, 1, false);
  std::vector<std::string> phases;
  for (int i = 0; i < 7; ++i) {
    const StepResult r = trainer.Step(source.Next());
    ASSERT_FALSE(r.skipped) << r.skip_reason;
    phases.push_back(r.phase);
    EXPECT_EQ(r.terms.count("canonical"), 1u);
    EXPECT_EQ(r.terms.count("neutral"), 1u);
    EXPECT_EQ(r.terms.count("tv"), 1u);
    EXPECT_EQ(r.terms.count("expression"), i >= 3 ? 1u : 0u) << "step " << i;
    EXPECT_EQ(r.terms.count("appearance"), i >= 6 ? 1u : 0u) << "step " << i;
    EXPECT_TRUE(std::isfinite(r.loss));
  }
  EXPECT_EQ(phases.front(), "canonical");
  EXPECT_EQ(phases[3], "expression");
  EXPECT_EQ(phases[6], "appearance");
  TrainerOptions paper;
  paper.ScheduleFor(750000);
  EXPECT_EQ(paper.expression_start, 120000);
  EXPECT_EQ(paper.appearance_start, 240000);
}

TEST(Trainer, TrainingRendersAreJitteredEvaluationIsNot) {
  torch::manual_seed(6);
  const ModelConfig c = ModelConfig::Tiny();
  GohaModel model(c);
  const torch::Tensor planes = torch::randn({1, 3, c.plane_channels, c.plane_size(), c.plane_size()});
  const auto cams = render::FrontalCameras(1);
  torch::NoGradGuard g;
  const auto a = model->Render(planes, cams, 0, false).rgb, b = model->Render(planes, cams, 0, false).rgb;
  EXPECT_GT((a - b).abs().max().item<double>(), 0.0) << "deterministic=false should jitter the samples";
  StageOneTrainer trainer(model, TestOptions(), kStandIn);
  SyntheticSource source(c, 1, false);
  const TrainBatch batch = source.Next();
  const auto e1 = trainer.Evaluate(batch), e2 = trainer.Evaluate(batch);
  EXPECT_TRUE(torch::equal(e1.full, e2.full));
}

TEST(Trainer, ResumeContinuesExactly) {
  const ModelConfig c = ModelConfig::Tiny();
  const fs::path dir = TempDir("resume");
  // 20 steps in one go.
  torch::manual_seed(7);
  StageOneTrainer whole(GohaModel(c), TestOptions(), kStandIn);
  SyntheticSource s1(c, 2, true);
  for (int i = 0; i < 20; ++i) ASSERT_FALSE(whole.Step(s1.Next()).skipped);
  // 10 steps, save, a new process-like trainer (different init, RNG disturbed), load, 10 more.
  torch::manual_seed(7);
  {
    StageOneTrainer first(GohaModel(c), TestOptions(), kStandIn);
    SyntheticSource s2(c, 2, true);
    for (int i = 0; i < 10; ++i) ASSERT_FALSE(first.Step(s2.Next()).skipped);
    first.SaveState(dir / "state.ckpt", &s2);
  }
  torch::manual_seed(999);
  StageOneTrainer second(GohaModel(c), TestOptions(), kStandIn);
  (void)torch::rand({100});
  SyntheticSource s3(c, 2, true);
  second.LoadState(dir / "state.ckpt", &s3);
  EXPECT_EQ(second.step(), 10);
  EXPECT_EQ(s3.cursor(), 10);
  for (int i = 0; i < 10; ++i) ASSERT_FALSE(second.Step(s3.Next()).skipped);
  const auto wa = Weights(whole.model()), wb = Weights(second.model());
  ASSERT_EQ(wa.size(), wb.size());
  double worst = 0.0;
  for (size_t i = 0; i < wa.size(); ++i) worst = std::max(worst, (wa[i] - wb[i]).abs().max().item<double>());
  EXPECT_LE(worst, 1e-6) << "20 steps != 10 + resume + 10";
  // A state of another config is refused.
  StageOneTrainer other(GohaModel(ModelConfig::Lite()), TestOptions(), kStandIn);
  EXPECT_THROW(other.LoadState(dir / "state.ckpt"), ModelLoad);
  fs::remove_all(dir);
}

TEST(Trainer, PoisonedBatchIsSkippedCountedAndSurvived) {
  torch::manual_seed(8);
  const ModelConfig c = ModelConfig::Tiny();
  const fs::path dir = TempDir("poison");
  StageOneTrainer trainer(GohaModel(c), TestOptions(), kStandIn);
  SyntheticSource source(c, 1, false);
  source.poison_at_ = 2;
  RunOptions run;
  run.out_dir = dir;
  run.steps = 6;
  run.progress = false;
  RunContext ctx;
  const RunResult r = RunTraining(trainer, source, run, ctx);
  EXPECT_EQ(r.last_step, 6);
  EXPECT_EQ(r.skipped, 1);
  for (const auto& w : Weights(trainer.model())) ASSERT_TRUE(torch::isfinite(w).all().item<bool>());
  // The log counts it; the state and the weights load.
  std::ifstream log(LogPath(dir));
  std::string line;
  int lines = 0, skipped = 0;
  while (std::getline(log, line)) {
    const auto j = nlohmann::json::parse(line);
    ++lines;
    if (j.at("skipped").get<bool>()) {
      ++skipped;
      EXPECT_EQ(j.at("step").get<int64_t>(), 2);
    }
    EXPECT_TRUE(j.contains("lr") && j.contains("step_s") && j.contains("samples_per_s") && j.contains("terms"));
  }
  EXPECT_EQ(lines, 6);
  EXPECT_EQ(skipped, 1);
  StageOneTrainer again(GohaModel(c), TestOptions(), kStandIn);
  again.LoadState(StatePath(dir));
  EXPECT_EQ(again.skipped_steps(), 1);
  EXPECT_NO_THROW(LoadModelCheckpoint(dir / "model.ckpt"));
  fs::remove_all(dir);
}

TEST(Trainer, BadStepsInARowStopTheRunAndNonFiniteStateIsNeverWritten) {
  torch::manual_seed(9);
  const ModelConfig c = ModelConfig::Tiny();
  const fs::path dir = TempDir("bad");
  TrainerOptions o = TestOptions();
  o.max_bad_steps = 3;
  StageOneTrainer trainer(GohaModel(c), o, kStandIn);
  SyntheticSource source(c, 1, false);
  source.poison_at_ = 1;
  source.poison_all_ = true;
  RunOptions run;
  run.out_dir = dir;
  run.steps = 50;
  run.progress = false;
  RunContext ctx;
  EXPECT_THROW(RunTraining(trainer, source, run, ctx), InvalidInput);
  EXPECT_EQ(trainer.step(), 4);  // 1 good + 3 bad
  EXPECT_EQ(trainer.skipped_steps(), 3);
  ASSERT_TRUE(fs::exists(StatePath(dir)));
  StageOneTrainer loaded(GohaModel(c), o, kStandIn);
  loaded.LoadState(StatePath(dir));
  for (const auto& w : Weights(loaded.model())) ASSERT_TRUE(torch::isfinite(w).all().item<bool>());
  // Poisoned weights: neither the state nor the export is written.
  {
    torch::NoGradGuard g;
    trainer.model()->parameters()[0].view(-1)[0] = NAN;
  }
  EXPECT_THROW(trainer.SaveState(dir / "nan.ckpt"), InvalidInput);
  EXPECT_THROW(trainer.ExportWeights(dir / "nan_model.ckpt", "test"), InvalidInput);
  EXPECT_FALSE(fs::exists(dir / "nan.ckpt"));
  EXPECT_FALSE(fs::exists(dir / "nan_model.ckpt"));
  fs::remove_all(dir);
}

TEST(Trainer, CancelWritesTheStateAndResumeFinishes) {
  torch::manual_seed(10);
  const ModelConfig c = ModelConfig::Tiny();
  const fs::path dir = TempDir("cancel");
  RunContext ctx;
  RunOptions run;
  run.out_dir = dir;
  run.steps = 6;
  run.progress = false;
  {
    StageOneTrainer trainer(GohaModel(c), TestOptions(), kStandIn);
    SyntheticSource source(c, 1, true);
    source.cancel_at_ = 2;
    source.ctx_ = &ctx;
    EXPECT_THROW(RunTraining(trainer, source, run, ctx), Cancelled);
    // The cancel came with the third batch: its step stops at the first check and is not applied.
    EXPECT_EQ(trainer.step(), 2);
    // The cancelled run also leaves usable weights of its last applied step, equal to the trainer's.
    const LoadedModel kept = LoadModelCheckpoint(dir / "model.ckpt");
    EXPECT_EQ(kept.info.step, 2);
    GohaModel m = kept.model;
    const auto wa = Weights(trainer.model()), wb = Weights(m);
    ASSERT_EQ(wa.size(), wb.size());
    for (size_t i = 0; i < wa.size(); ++i) ASSERT_TRUE(torch::equal(wa[i], wb[i])) << i;
    EXPECT_EQ(LoadModelCheckpoint(dir / "model-fp16.ckpt").info.step, 2);
  }
  ASSERT_TRUE(fs::exists(StatePath(dir)));
  RunContext fresh;
  StageOneTrainer trainer(GohaModel(c), TestOptions(), kStandIn);
  SyntheticSource source(c, 1, true);
  run.resume = true;
  const RunResult r = RunTraining(trainer, source, run, fresh);
  EXPECT_EQ(r.first_step, 2);
  EXPECT_EQ(r.last_step, 6);
  EXPECT_EQ(source.cursor(), 6);  // The cancelled step's batch was trained on after the resume.
  fs::remove_all(dir);
}

// Helper process of the next test (disabled: it only runs when that test starts it): writes
// the training state over and over until it is killed.
TEST(Trainer, DISABLED_StateWriterProcess) {
  const char* dir = std::getenv("AVATAR_TRAINER_KILL_DIR");
  ASSERT_NE(dir, nullptr) << "run by Trainer.KillDuringAStateWriteLeavesTheLastStateLoadable";
  torch::manual_seed(13);
  const ModelConfig c = ModelConfig::Tiny();
  StageOneTrainer trainer(GohaModel(c), TestOptions(), kStandIn);
  SyntheticSource source(c, 1, false);
  trainer.Step(source.Next());
  for (int i = 0; i < 1000000; ++i) trainer.SaveState(fs::path(dir) / "state.ckpt", &source);
}

extern "C" char** environ;

// The names of the files directly in `dir` that process `pid` holds open for writing (its
// /proc/PID/fd links and the access mode in /proc/PID/fdinfo).
std::vector<std::string> FilesOpenForWriting(pid_t pid, const fs::path& dir) {
  std::vector<std::string> names;
  const std::string proc = "/proc/" + std::to_string(pid);
  std::error_code ec;
  for (fs::directory_iterator it(proc + "/fd", ec), end; !ec && it != end; it.increment(ec)) {
    std::error_code link_ec;
    const fs::path target = fs::read_symlink(it->path(), link_ec);
    if (link_ec || target.parent_path() != dir) continue;
    std::ifstream info(proc + "/fdinfo/" + it->path().filename().string());
    std::string key;
    long flags = -1;  // "flags:\t0100001", octal
    while (info >> key) {
      if (key == "flags:") {
        info >> std::oct >> flags;
        break;
      }
    }
    if (flags >= 0 && (flags & O_ACCMODE) != O_RDONLY) names.push_back(target.filename().string());
  }
  return names;
}

TEST(Trainer, KillDuringAStateWriteLeavesTheLastStateLoadable) {
  const fs::path dir = fs::canonical(TempDir("kill"));
  const std::string var = "AVATAR_TRAINER_KILL_DIR=" + dir.string();
  std::vector<char*> env;
  for (char** e = environ; *e != nullptr; ++e) env.push_back(*e);
  env.push_back(const_cast<char*>(var.c_str()));
  env.push_back(nullptr);
  const fs::path self = fs::read_symlink("/proc/self/exe");
  std::string filter = "--gtest_filter=Trainer.DISABLED_StateWriterProcess", disabled = "--gtest_also_run_disabled_tests";
  std::vector<char*> argv = {const_cast<char*>(self.c_str()), filter.data(), disabled.data(), nullptr};
  for (int round = 0; round < 3; ++round) {
    SCOPED_TRACE("round " + std::to_string(round));
    pid_t pid = 0;
    ASSERT_EQ(posix_spawn(&pid, self.c_str(), nullptr, nullptr, argv.data(), env.data()), 0);
    // The writer is stopped (SIGSTOP) when it holds a file of the folder open for writing, and
    // killed while stopped: the kill lands inside a state write, between the open of the file
    // being written and its rename. A write that ended between the look and the stop is let go on.
    // In round 0 the first write is let through (a state to fall back on); later rounds kill the
    // new writer's first write, beside the state the earlier rounds left. The deadline is a hang
    // limit (the writer writes a state every few milliseconds), not a speed target.
    std::string writing;
    int status = 0;
    bool ended = false;
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(120);
    while (writing.empty() && !ended && std::chrono::steady_clock::now() < until) {
      if ((round == 0 && !fs::exists(dir / "state.ckpt")) || FilesOpenForWriting(pid, dir).empty()) {
        ended = ::waitpid(pid, &status, WNOHANG) == pid;
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
        continue;
      }
      ASSERT_EQ(::kill(pid, SIGSTOP), 0);
      ASSERT_EQ(::waitpid(pid, &status, WUNTRACED), pid);
      if (!WIFSTOPPED(status)) {
        ended = true;
        break;
      }
      const std::vector<std::string> open = FilesOpenForWriting(pid, dir);
      if (!open.empty()) {
        writing = open.front();
        break;
      }
      ASSERT_EQ(::kill(pid, SIGCONT), 0);
    }
    if (!ended) {
      ASSERT_EQ(::kill(pid, SIGKILL), 0);
      ASSERT_EQ(::waitpid(pid, &status, 0), pid);
    }
    ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL) << "the writer ended before it was killed";
    ASSERT_FALSE(writing.empty()) << "the writer was never caught writing within the hang limit";
    // The kill landed while writing: the file open at that moment is a hidden work file of the
    // writer (never the state itself), and it is left there, unrenamed, beside the last state.
    EXPECT_EQ(writing.rfind(".state.tmp" + std::to_string(pid) + "_", 0), 0u) << "written in place: " << writing;
    EXPECT_TRUE(fs::exists(dir / writing)) << writing;
    std::cout << "round " << round << ": killed while writing " << writing << " ("
              << (fs::exists(dir / writing) ? fs::file_size(dir / writing) : 0) << " of "
              << fs::file_size(dir / "state.ckpt") << " bytes)\n";
    StageOneTrainer loaded(GohaModel(ModelConfig::Tiny()), TestOptions(), kStandIn);
    SyntheticSource source(ModelConfig::Tiny(), 1, false);
    EXPECT_NO_THROW(loaded.LoadState(dir / "state.ckpt", &source));
    EXPECT_EQ(loaded.step(), 1);
    EXPECT_EQ(source.cursor(), 1);
  }
  fs::remove_all(dir);
}

TEST(Trainer, WeightsExportLoadsAsAModelCheckpoint) {
  torch::manual_seed(11);
  const ModelConfig c = ModelConfig::Tiny();
  const fs::path dir = TempDir("export");
  StageOneTrainer trainer(GohaModel(c), TestOptions(), kStandIn);
  SyntheticSource source(c, 1, false);
  for (int i = 0; i < 2; ++i) trainer.Step(source.Next());
  trainer.ExportWeights(dir / "model.ckpt", "synthetic test pair");
  const LoadedModel loaded = LoadModelCheckpoint(dir / "model.ckpt");
  EXPECT_EQ(loaded.info.step, 2);
  EXPECT_EQ(loaded.info.data_provenance, "synthetic test pair");
  GohaModel m = loaded.model;
  const auto wa = Weights(trainer.model()), wb = Weights(m);
  ASSERT_EQ(wa.size(), wb.size());
  for (size_t i = 0; i < wa.size(); ++i) ASSERT_TRUE(torch::equal(wa[i], wb[i]));
  // Shipping weights in float16: about half the bytes, loaded back as float32 equal to the
  // weights rounded to float16.
  trainer.ExportWeights(dir / "model-fp16.ckpt", "synthetic test pair", /*half_precision=*/true);
  EXPECT_LT(fs::file_size(dir / "model-fp16.ckpt"), 0.6 * fs::file_size(dir / "model.ckpt"));
  GohaModel half = LoadModelCheckpoint(dir / "model-fp16.ckpt").model;
  const auto wh = Weights(half);
  ASSERT_EQ(wh.size(), wa.size());
  for (size_t i = 0; i < wa.size(); ++i) {
    ASSERT_EQ(wh[i].scalar_type(), torch::kFloat32);
    ASSERT_TRUE(torch::equal(wh[i], wa[i].to(torch::kFloat16).to(torch::kFloat32))) << i;
  }
  fs::remove_all(dir);
}

// Judged against the untrained network (its PSNR at step 0), by the mean PSNR of the evaluations
// over the last 100 steps: jittered training renders at lr 3e-3 make the curve noisy (+-2 dB
// from one evaluation to the next), so neither the best nor the last evaluation is a stable
// measure. Measured 2026-12-04 (AMD EPYC, AVX-512) over AVATAR_THREADS 1 and 2 and the
// OpenBLAS core types Haswell (this CPU's default; Zen gives the same numbers), SkylakeX,
// Sandybridge, Prescott, and Haswell with oneDNN and ATen limited to AVX2 (a machine without
// AVX-512): start 11.26 dB everywhere; mean of the evaluations at steps 210-300 30.12 (Haswell,
// both thread counts) to 31.21 dB (Sandybridge), i.e. 18.86-19.95 dB above the start (a spread of
// 1.1 dB; the thread count changes nothing). The bar asks for 16 dB (the MSE falls 40x): 2.9 dB
// below the lowest measurement, more than twice the spread.
TEST(Trainer, TinyOverfitsOnePair) {
  torch::manual_seed(12);
  const ModelConfig c = ModelConfig::Tiny();
  TrainerOptions o = TestOptions();
  o.lr = 3e-3;  // tuned for the tiny test config only (the paper's 1e-4 is the default)
  o.expression_start = 20;
  o.appearance_start = 40;
  StageOneTrainer trainer(GohaModel(c), o, kStandIn);
  SyntheticSource source(c, 1, false);
  const TrainBatch batch = source.Next();
  const auto psnr = [&] {
    const auto e = trainer.Evaluate(batch);  // deterministic renders; draws no random numbers
    return Psnr(e.full, e.target);
  };
  const double start = psnr();
  const int steps = 300, every = 10, judged = 10;
  std::vector<double> curve;
  for (int i = 0; i < steps; ++i) {
    ASSERT_FALSE(trainer.Step(batch).skipped);
    if ((i + 1) % every == 0) curve.push_back(psnr());
  }
  double end = 0.0;
  for (int k = 0; k < judged; ++k) end += curve[curve.size() - 1 - k] / judged;
  std::cout << "overfit: PSNR I_c+e+p every " << every << " steps:";
  for (const double p : curve) std::cout << " " << p;
  std::cout << "\noverfit: start " << start << " dB, mean of the last " << judged << " evaluations " << end << " dB (+"
            << end - start << " dB)\n";
  EXPECT_GT(end, start + 16.0) << "tiny did not overfit one pair in " << steps << " steps";
}

}  // namespace
}  // namespace avatar::train
