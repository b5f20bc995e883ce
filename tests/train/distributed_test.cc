// Data-parallel training (core/train/distributed.h): option validation, the batch shards, and
// real c10d Gloo groups of processes spawned from this test (this executable again, running
// the disabled DistributedChild test with its settings in the environment, a FileStore in a
// temporary folder, a deadline so that a hang fails instead of blocking): 2 ranks at batch 2
// end with the weights of 1 process at batch 4 (stage I and stage II), and a rank whose peers
// never come fails with a clear error within its timeout.

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "common/temp_dir.h"
#include "core/model/goha_model.h"
#include "core/train/distributed.h"
#include "core/train/trainer.h"
#include "core/util/error.h"
#include "train/trainer_test_util.h"

extern "C" char** environ;

namespace avatar::train {
namespace {

namespace fs = std::filesystem;

// ---------------------------------------------------------------------------------------------
// Child mode: the settings come from the environment (AVATAR_DIST_*).

std::string Env(const char* name, const std::string& fallback = "") {
  const char* v = std::getenv(name);
  return v != nullptr ? std::string(v) : fallback;
}

TrainerOptions EqualityOptions(int64_t stage) {
  TrainerOptions o = TestOptions();
  // No random numbers that depend on the batch: fixed render samples and no TV points.
  o.deterministic_render = true;
  o.tv_weight = 0.0;
  o.lr = 1e-3;
  // Three steps through the three phases: canonical, + expression, + appearance.
  o.expression_start = 1;
  o.appearance_start = 2;
  o.stage = stage;
  // Stage II: the discriminator's minibatch standard deviation mixes the samples of a batch, so
  // D sees each rank's shard as a batch of its own (as in StyleGAN-style multi-GPU training) and
  // its gradients are not those of the global batch. With no adversarial term in G's loss the
  // SR's steps stay exactly those of the single process; D is checked for agreement between
  // the ranks.
  o.gan_weight = 0.0;
  o.d_lr = 1e-3;
  // The SR's modulated convolutions are demodulated (their output does not change with the scale
  // of a weight), so parts of their gradients cancel to rounding noise; Adam divides by
  // sqrt(v) + eps, which turns a rounding difference of a gradient near eps into up to lr/eps
  // times as much in the update (2e-5 after 3 steps at eps 1e-8). A larger eps keeps the
  // comparison about the data parallelism, not about float32 summation order.
  if (stage == 2) o.eps = 1e-6;
  o.r1_every = 2;  // R1 at steps 0 and 2
  return o;
}

// Trains `steps` steps of the tiny config at global batch `batch` as rank R of W and writes
// every parameter of the model (and of D in stage II) to AVATAR_DIST_WEIGHTS.
int RunChildTraining() {
  const int64_t world = std::stoll(Env("AVATAR_DIST_WORLD", "1"));
  const int64_t rank = std::stoll(Env("AVATAR_DIST_RANK", "0"));
  const int64_t batch = std::stoll(Env("AVATAR_DIST_BATCH", "4"));
  const int64_t stage = std::stoll(Env("AVATAR_DIST_STAGE", "1"));
  const ModelConfig c = ModelConfig::Tiny();
  torch::manual_seed(7);
  TrainerOptions options = EqualityOptions(stage);
  StageOneTrainer trainer(GohaModel(c), options, kStandIn);
  SyntheticSource data(c, batch, /*vary=*/true);
  // A NaN in the first pair of this batch (rank 0's shard only): every rank must skip the step.
  data.poison_at_ = std::stoll(Env("AVATAR_DIST_POISON", "-1"));
  std::unique_ptr<ShardedBatchSource> shards;
  BatchSource* source = &data;
  if (world > 1) {
    DistributedOptions d;
    d.world_size = world;
    d.rank = rank;
    d.init = Env("AVATAR_DIST_INIT");
    d.timeout_s = std::stod(Env("AVATAR_DIST_TIMEOUT", "60"));
    trainer.SetGradientReducer(std::make_shared<ProcessGroupReducer>(d));
    shards = std::make_unique<ShardedBatchSource>(data, rank, world);
    source = shards.get();
  }
  RunOptions run;
  run.out_dir = Env("AVATAR_DIST_OUT");
  run.steps = std::stoll(Env("AVATAR_DIST_STEPS", "3"));
  run.resume = !Env("AVATAR_DIST_RESUME").empty();
  run.progress = false;
  run.checkpoint_minutes = 1000;
  RunContext ctx;
  if (!Env("AVATAR_DIST_CANCEL_RANK").empty() && std::stoll(Env("AVATAR_DIST_CANCEL_RANK")) == rank) {
    // This rank alone is cancelled while it takes batch 1: every rank stops before step 2.
    data.ctx_ = &ctx;
    data.cancel_at_ = 1;
  }
  RunResult r;
  try {
    r = RunTraining(trainer, *source, run, ctx);
  } catch (const Cancelled&) {
    std::cout << "child rank " << rank << " cancelled at step " << trainer.step() << "\n";
    return trainer.step() == 2 ? 7 : 8;
  }
  std::vector<torch::Tensor> weights;
  for (const auto& p : trainer.model()->parameters(true)) weights.push_back(p.detach().clone());
  if (stage == 2)
    for (const auto& p : trainer.discriminator()->parameters(true)) weights.push_back(p.detach().clone());
  torch::save(weights, Env("AVATAR_DIST_WEIGHTS"));
  std::cout << "child rank " << rank << " of " << world << ": steps " << r.first_step << " -> " << r.last_step
            << ", skipped " << r.skipped << "\n";
  return r.last_step == run.steps && r.skipped == (data.poison_at_ >= 0 ? 1 : 0) ? 0 : 4;
}

// Joins a group whose other ranks never come: exit 3 with the error on stderr, and how long the
// join waited ("gave up after S s").
int RunChildJoin() {
  DistributedOptions d;
  d.world_size = 2;
  d.rank = 0;
  d.init = Env("AVATAR_DIST_INIT");
  d.timeout_s = std::stod(Env("AVATAR_DIST_TIMEOUT", "2"));
  const auto start = std::chrono::steady_clock::now();
  try {
    ProcessGroupReducer reducer(d);
  } catch (const Io& e) {
    const double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::cerr << "Io: " << e.what() << "\ngave up after " << waited << " s\n";
    return 3;
  }
  std::cerr << "joined a group of 2 with one process\n";
  return 5;
}

// Not a test of its own: the body of the processes the tests below start.
TEST(DistributedChild, DISABLED_Run) {
  const std::string mode = Env("AVATAR_DIST_MODE");
  ASSERT_FALSE(mode.empty()) << "run by the distributed tests only (AVATAR_DIST_MODE unset)";
  int code = 0;
  try {
    code = mode == "join" ? RunChildJoin() : RunChildTraining();
  } catch (const std::exception& e) {
    std::cerr << "child failed: " << e.what() << "\n";
    code = 6;
  }
  std::cout.flush();
  std::cerr.flush();
  std::_Exit(code);
}

// ---------------------------------------------------------------------------------------------
// Parent side.

struct Child {
  pid_t pid = -1;
  fs::path out, err;
  int code = -1;
  bool finished = false;
};

std::string Slurp(const fs::path& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// This executable in child mode with `vars` added to the environment.
Child Spawn(const std::vector<std::string>& vars, const fs::path& log_stem) {
  Child child;
  child.out = log_stem.string() + ".out";
  child.err = log_stem.string() + ".err";
  std::vector<std::string> env_strings;
  for (char** e = environ; *e != nullptr; ++e) env_strings.emplace_back(*e);
  for (const auto& v : vars) env_strings.push_back(v);
  std::vector<char*> envp;
  for (auto& s : env_strings) envp.push_back(s.data());
  envp.push_back(nullptr);
  std::string exe = fs::read_symlink("/proc/self/exe").string(), also = "--gtest_also_run_disabled_tests",
              filter = "--gtest_filter=DistributedChild.DISABLED_Run";
  std::vector<char*> argv = {exe.data(), also.data(), filter.data(), nullptr};
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, child.out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, child.err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  const int rc = posix_spawn(&child.pid, exe.c_str(), &actions, nullptr, argv.data(), envp.data());
  posix_spawn_file_actions_destroy(&actions);
  EXPECT_EQ(rc, 0) << "cannot start " << exe;
  if (rc != 0) child.pid = -1;
  return child;
}

// Waits for every child until `deadline_s`; the ones still running then are killed and fail.
void WaitAll(std::vector<Child>& children, double deadline_s) {
  const auto start = std::chrono::steady_clock::now();
  for (;;) {
    bool running = false;
    for (auto& c : children) {
      if (c.pid < 0 || c.finished) continue;
      int status = 0;
      const pid_t done = ::waitpid(c.pid, &status, WNOHANG);
      if (done == c.pid) {
        c.finished = true;
        c.code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
      } else {
        running = true;
      }
    }
    if (!running) return;
    if (std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() > deadline_s) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  for (auto& c : children) {
    if (c.pid < 0 || c.finished) continue;
    ::kill(c.pid, SIGKILL);
    int status = 0;
    ::waitpid(c.pid, &status, 0);
    c.finished = true;
    c.code = -1;
    ADD_FAILURE() << "child " << c.pid << " still running after " << deadline_s << " s (a hang): killed\n"
                  << Slurp(c.err);
  }
}

std::vector<torch::Tensor> LoadWeights(const fs::path& path) {
  std::vector<torch::Tensor> w;
  torch::load(w, path.string());
  return w;
}

double MaxDifference(const std::vector<torch::Tensor>& a, const std::vector<torch::Tensor>& b) {
  EXPECT_EQ(a.size(), b.size());
  double worst = 0.0;
  for (size_t i = 0; i < std::min(a.size(), b.size()); ++i) {
    EXPECT_EQ(a[i].sizes(), b[i].sizes()) << "tensor " << i;
    if (a[i].sizes() != b[i].sizes()) return INFINITY;
    worst = std::max(worst, (a[i].to(torch::kFloat64) - b[i].to(torch::kFloat64)).abs().max().item<double>());
  }
  return worst;
}

double MaxChange(const std::vector<torch::Tensor>& a, const std::vector<torch::Tensor>& b) {
  return MaxDifference(a, b);
}

std::vector<nlohmann::json> ReadLog(const fs::path& path) {
  std::vector<nlohmann::json> lines;
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line))
    if (!line.empty()) lines.push_back(nlohmann::json::parse(line));
  return lines;
}

// 1 process at batch 4 vs 2 Gloo ranks at batch 2 (the same global batches), 3 steps.
// With `poison_step` >= 0 that step's first pair has a NaN (on rank 0 only): both runs skip it.
void ExpectDataParallelEqualsSingle(int64_t stage, int64_t poison_step = -1) {
  avatar::testing::TempDir dir;
  const std::string st = "AVATAR_DIST_STAGE=" + std::to_string(stage),
                    poison = "AVATAR_DIST_POISON=" + std::to_string(poison_step);
  const double deadline = 240.0;

  std::vector<Child> single = {
      Spawn({"AVATAR_DIST_MODE=train", "AVATAR_DIST_WORLD=1", "AVATAR_DIST_RANK=0", "AVATAR_DIST_BATCH=4", st, poison,
             "AVATAR_DIST_OUT=" + (dir / "single").string(), "AVATAR_DIST_WEIGHTS=" + (dir / "single.pt").string()},
            dir / "single")};
  WaitAll(single, deadline);
  ASSERT_EQ(single[0].code, 0) << Slurp(single[0].out) << Slurp(single[0].err);

  const std::string init = "AVATAR_DIST_INIT=file://" + (dir / "store").string();
  std::vector<Child> ranks;
  for (int r = 0; r < 2; ++r) {
    const std::string name = "rank" + std::to_string(r);
    ranks.push_back(
        Spawn({"AVATAR_DIST_MODE=train", "AVATAR_DIST_WORLD=2", "AVATAR_DIST_RANK=" + std::to_string(r),
               "AVATAR_DIST_BATCH=4", st, poison, init, "AVATAR_DIST_TIMEOUT=60",
               "AVATAR_DIST_OUT=" + (dir / name).string(), "AVATAR_DIST_WEIGHTS=" + (dir / (name + ".pt")).string()},
              dir / name));
  }
  WaitAll(ranks, deadline);
  for (const auto& c : ranks) ASSERT_EQ(c.code, 0) << Slurp(c.out) << Slurp(c.err);

  const auto w1 = LoadWeights(dir / "single.pt");
  const auto w2a = LoadWeights(dir / "rank0.pt");
  const auto w2b = LoadWeights(dir / "rank1.pt");
  ASSERT_FALSE(w1.empty());
  // Fresh weights of the same seed, for the size of the change.
  torch::manual_seed(7);
  GohaModel fresh(ModelConfig::Tiny());
  std::vector<torch::Tensor> w0;
  for (const auto& p : fresh->parameters(true)) w0.push_back(p.detach().clone());
  // The model's tensors first, then (stage II) D's.
  const auto model_part = [&](const std::vector<torch::Tensor>& w) {
    return std::vector<torch::Tensor>(w.begin(),
                                      w.begin() + static_cast<std::ptrdiff_t>(std::min(w0.size(), w.size())));
  };
  const double moved = MaxChange(w0, model_part(w1));
  const double between_ranks = MaxDifference(w2a, w2b);
  const double versus_single = MaxDifference(model_part(w1), model_part(w2a));
  std::cout << "stage " << stage << ": max |w| change in 3 steps " << moved << ", rank 0 vs rank 1 " << between_ranks
            << ", 2 ranks x batch 2 vs 1 process x batch 4 " << versus_single;
  EXPECT_GT(moved, 1e-4) << "the training did not change the weights";
  EXPECT_EQ(between_ranks, 0.0) << "the ranks' weights differ";
  EXPECT_LE(versus_single, 1e-5);
  if (stage == 2) {
    // D: trained (its weights moved) and finite on both sides; not equal (minibatch stddev).
    ASSERT_GT(w1.size(), w0.size());
    const std::vector<torch::Tensor> d1(w1.begin() + static_cast<std::ptrdiff_t>(w0.size()), w1.end()),
        d2(w2a.begin() + static_cast<std::ptrdiff_t>(w0.size()), w2a.end());
    const double d_between = MaxDifference(d1, d2);
    std::cout << ", discriminator 2 ranks vs 1 process " << d_between;
    EXPECT_TRUE(std::isfinite(d_between));
    for (const auto& t : d2) EXPECT_TRUE(torch::isfinite(t).all().item<bool>());
  }
  std::cout << "\n";

  // Only rank 0 writes the run folder; its log has the global batch and the single run's losses.
  EXPECT_TRUE(fs::exists(dir / "rank0" / "state.ckpt"));
  EXPECT_TRUE(fs::exists(dir / "rank0" / "model.ckpt"));
  EXPECT_FALSE(fs::exists(dir / "rank1")) << "rank 1 wrote a run folder";
  const auto log1 = ReadLog(dir / "single" / "train.jsonl");
  const auto log2 = ReadLog(dir / "rank0" / "train.jsonl");
  ASSERT_EQ(log1.size(), 3u);
  ASSERT_EQ(log2.size(), 3u);
  for (size_t i = 0; i < 3; ++i) {
    const bool poisoned = static_cast<int64_t>(i) == poison_step;
    EXPECT_EQ(log2[i].at("skipped").get<bool>(), poisoned) << "step " << i;
    EXPECT_EQ(log1[i].at("skipped").get<bool>(), poisoned) << "step " << i;
    if (poisoned) {
      EXPECT_EQ(log2[i].at("skip_reason").get<std::string>(), "non-finite loss") << "step " << i;
      continue;
    }
    EXPECT_EQ(log2[i].at("batch").get<int64_t>(), 4);
    EXPECT_EQ(log2[i].at("world_size").get<int64_t>(), 2);
    EXPECT_NEAR(log2[i].at("loss").get<double>(), log1[i].at("loss").get<double>(), 1e-5) << "step " << i;
    EXPECT_NEAR(log2[i].at("grad_norm").get<double>(), log1[i].at("grad_norm").get<double>(),
                1e-4 * std::max(1.0, log1[i].at("grad_norm").get<double>()))
        << "step " << i;
    if (stage == 2) {
      EXPECT_TRUE(std::isfinite(log2[i].at("d_loss").get<double>())) << "step " << i;
      EXPECT_TRUE(log2[i].at("d_terms").contains("d")) << "step " << i;
      EXPECT_EQ(log2[i].at("d_terms").contains("r1"), i % 2 == 0) << "step " << i;  // r1_every 2
    }
  }
}

TEST(Distributed, TwoGlooRanksAtBatchTwoEqualOneProcessAtBatchFour) { ExpectDataParallelEqualsSingle(1); }

TEST(Distributed, StageTwoTwoGlooRanksEqualOneProcess) { ExpectDataParallelEqualsSingle(2); }

// Rank 0's loss is not finite at step 1, rank 1's is: both skip it (the flag is reduced), and
// stay equal to the single process, which skips it too.
TEST(Distributed, NonFiniteStepOnOneRankIsSkippedByAll) { ExpectDataParallelEqualsSingle(1, 1); }

// Two ranks share one run folder (as `avatar-studio train` does): 2 steps, then a resumed run
// to step 3 equals 3 uninterrupted single-process steps; a rank that does not see the state
// (another folder) is refused, on both ranks.
TEST(Distributed, ResumeFromASharedRunFolder) {
  avatar::testing::TempDir dir;
  auto launch = [&](const std::string& steps, bool resume, const std::string& rank1_out, const std::string& tag) {
    std::vector<Child> ranks;
    for (int r = 0; r < 2; ++r) {
      std::vector<std::string> vars = {"AVATAR_DIST_MODE=train",
                                       "AVATAR_DIST_WORLD=2",
                                       "AVATAR_DIST_RANK=" + std::to_string(r),
                                       "AVATAR_DIST_BATCH=4",
                                       "AVATAR_DIST_STEPS=" + steps,
                                       "AVATAR_DIST_INIT=file://" + (dir / ("store-" + tag)).string(),
                                       "AVATAR_DIST_TIMEOUT=60",
                                       "AVATAR_DIST_OUT=" + (r == 0 ? (dir / "shared").string() : rank1_out),
                                       "AVATAR_DIST_WEIGHTS=" + (dir / (tag + std::to_string(r) + ".pt")).string()};
      if (resume) vars.push_back("AVATAR_DIST_RESUME=1");
      ranks.push_back(Spawn(vars, dir / (tag + std::to_string(r))));
    }
    WaitAll(ranks, 240.0);
    return ranks;
  };
  for (const auto& c : launch("2", false, (dir / "shared").string(), "first"))
    ASSERT_EQ(c.code, 0) << Slurp(c.out) << Slurp(c.err);
  ASSERT_TRUE(fs::exists(dir / "shared" / "state.ckpt"));
  // Rank 1 in another folder: it starts at step 0, rank 0 resumes step 2.
  for (const auto& c : launch("3", true, (dir / "elsewhere").string(), "split")) {
    EXPECT_EQ(c.code, 6) << Slurp(c.out) << Slurp(c.err);
    EXPECT_NE(Slurp(c.err).find("the ranks start at different steps"), std::string::npos) << Slurp(c.err);
  }
  for (const auto& c : launch("3", true, (dir / "shared").string(), "resumed"))
    ASSERT_EQ(c.code, 0) << Slurp(c.out) << Slurp(c.err);
  std::vector<Child> single = {
      Spawn({"AVATAR_DIST_MODE=train", "AVATAR_DIST_WORLD=1", "AVATAR_DIST_RANK=0", "AVATAR_DIST_BATCH=4",
             "AVATAR_DIST_OUT=" + (dir / "single").string(), "AVATAR_DIST_WEIGHTS=" + (dir / "single.pt").string()},
            dir / "single")};
  WaitAll(single, 240.0);
  ASSERT_EQ(single[0].code, 0) << Slurp(single[0].out) << Slurp(single[0].err);
  const auto w1 = LoadWeights(dir / "single.pt");
  const double a = MaxDifference(w1, LoadWeights(dir / "resumed0.pt"));
  const double b = MaxDifference(w1, LoadWeights(dir / "resumed1.pt"));
  std::cout << "2 + 1 resumed steps on 2 ranks vs 3 steps of 1 process: " << a << " (rank 0), " << b << " (rank 1)\n";
  EXPECT_LE(a, 1e-5);
  EXPECT_LE(b, 1e-5);
  const auto log = ReadLog(dir / "shared" / "train.jsonl");
  ASSERT_EQ(log.size(), 3u);
  for (size_t i = 0; i < 3; ++i) EXPECT_EQ(log[i].at("step").get<int64_t>(), static_cast<int64_t>(i));
}

TEST(Distributed, CancelOnOneRankStopsEveryRank) {
  avatar::testing::TempDir dir;
  std::vector<Child> ranks;
  for (int r = 0; r < 2; ++r) {
    const std::string name = "rank" + std::to_string(r);
    ranks.push_back(
        Spawn({"AVATAR_DIST_MODE=train", "AVATAR_DIST_WORLD=2", "AVATAR_DIST_RANK=" + std::to_string(r),
               "AVATAR_DIST_BATCH=4", "AVATAR_DIST_CANCEL_RANK=1",
               "AVATAR_DIST_INIT=file://" + (dir / "store").string(), "AVATAR_DIST_TIMEOUT=60",
               "AVATAR_DIST_OUT=" + (dir / name).string(), "AVATAR_DIST_WEIGHTS=" + (dir / (name + ".pt")).string()},
              dir / name));
  }
  WaitAll(ranks, 240.0);
  // Exit 7: Cancelled at step 2 on both ranks; rank 0 wrote the state of step 2, rank 1 nothing.
  for (const auto& c : ranks) EXPECT_EQ(c.code, 7) << Slurp(c.out) << Slurp(c.err);
  EXPECT_TRUE(fs::exists(dir / "rank0" / "state.ckpt"));
  EXPECT_FALSE(fs::exists(dir / "rank1"));
  EXPECT_EQ(ReadLog(dir / "rank0" / "train.jsonl").size(), 2u);
}

// A rank whose peers never come gives up once its --timeout (2 s) has passed, by itself, with a
// message that says so: exit 3 and "could not join the group within 2 s". It gave up because of
// the timeout, not earlier for another reason: the join waited at least those 2 s (measured in the
// child, around the join alone). WaitAll's 60 s is a hang limit, not a speed target: it kills a
// rank that waits for ever (exit code -1).
TEST(Distributed, RankWithoutPeersFailsWithinTheTimeout) {
  avatar::testing::TempDir dir;
  std::vector<Child> lone = {
      Spawn({"AVATAR_DIST_MODE=join", "AVATAR_DIST_TIMEOUT=2", "AVATAR_DIST_INIT=file://" + (dir / "store").string()},
            dir / "lone")};
  WaitAll(lone, 60.0);
  const std::string err = Slurp(lone[0].err);
  ASSERT_NE(lone[0].code, -1) << "the lone rank was still waiting after 60 s: the timeout was not applied\n" << err;
  EXPECT_EQ(lone[0].code, 3) << Slurp(lone[0].out) << err;
  EXPECT_NE(err.find("could not join the group within 2 s"), std::string::npos) << err;
  EXPECT_NE(err.find("rank 0 of 2"), std::string::npos) << err;
  const size_t at = err.find("gave up after ");
  ASSERT_NE(at, std::string::npos) << err;
  const double waited = std::stod(err.substr(at + 14));
  EXPECT_GE(waited, 2.0) << "gave up before its timeout";
  std::cout << "a lone rank (timeout 2 s) gave up after " << waited << " s of waiting\n";
}

TEST(Distributed, OptionValidation) {
  DistributedOptions o;
  EXPECT_NO_THROW(o.Validate());  // one process needs nothing
  o.world_size = 2;
  EXPECT_THROW(o.Validate(), InvalidOptions);  // no --init
  o.init = "file:///tmp/avatar-store";
  EXPECT_NO_THROW(o.Validate());
  o.rank = 2;
  EXPECT_THROW(o.Validate(), InvalidOptions);  // rank >= world size
  o.rank = -1;
  EXPECT_THROW(o.Validate(), InvalidOptions);
  o.rank = 1;
  for (const std::string bad : {"http://host:1234", "file://relative/path", "file:///tmp/", "tcp://host", "tcp://host:",
                                "tcp://:1234", "tcp://host:99999", "tcp://host:12a4", "tcp:/host:1", ""}) {
    o.init = bad;
    EXPECT_THROW(o.Validate(), InvalidOptions) << "'" << bad << "'";
  }
  o.init = "tcp://10.0.0.2:29500";
  EXPECT_NO_THROW(o.Validate());
  const InitMethod m = ParseInitUrl(o.init);
  EXPECT_EQ(m.scheme, "tcp");
  EXPECT_EQ(m.host, "10.0.0.2");
  EXPECT_EQ(m.port, 29500);
  EXPECT_EQ(ParseInitUrl("file:///tmp/a/store").path, "/tmp/a/store");
  o.backend = "mpi";
  EXPECT_THROW(o.Validate(), InvalidOptions);
  o.backend = "nccl";
  if (HaveNccl()) {
    EXPECT_NO_THROW(o.Validate());
  } else {
    EXPECT_THROW(o.Validate(), InvalidOptions);  // this build has no NCCL: said, not failed later
  }
  o.backend = "gloo";
  o.timeout_s = 0;
  EXPECT_THROW(o.Validate(), InvalidOptions);
  o.timeout_s = 10;
  o.world_size = 0;
  EXPECT_THROW(o.Validate(), InvalidOptions);
  // The reducer validates too (before touching any store).
  DistributedOptions bad;
  bad.world_size = 2;
  bad.rank = 5;
  bad.init = "file:///tmp/never-created-store";
  EXPECT_THROW(ProcessGroupReducer{bad}, InvalidOptions);
  EXPECT_FALSE(fs::exists("/tmp/never-created-store"));
}

TEST(Distributed, ShardsAreDisjointSlicesOfTheGlobalBatch) {
  const ModelConfig c = ModelConfig::Tiny();
  SyntheticSource whole(c, 4, true), for0(c, 4, true), for1(c, 4, true);
  ShardedBatchSource rank0(for0, 0, 2), rank1(for1, 1, 2);
  for (int step = 0; step < 2; ++step) {
    const TrainBatch all = whole.Next(), a = rank0.Next(), b = rank1.Next();
    ASSERT_EQ(a.size(), 2);
    ASSERT_EQ(b.size(), 2);
    EXPECT_TRUE(torch::equal(a.source, all.source.narrow(0, 0, 2)));
    EXPECT_TRUE(torch::equal(b.source, all.source.narrow(0, 2, 2)));
    EXPECT_TRUE(torch::equal(b.target_label, all.target_label.narrow(0, 2, 2)));
    EXPECT_TRUE(torch::equal(b.neutral_mask, all.neutral_mask.narrow(0, 2, 2)));
    EXPECT_FALSE(torch::equal(a.target, b.target));  // the synthetic pairs vary within a batch
  }
  // The cursor is the inner source's, the same on every rank.
  EXPECT_EQ(rank0.State(), whole.State());
  EXPECT_EQ(rank1.State(), whole.State());
  SyntheticSource odd(c, 3, true);
  ShardedBatchSource uneven(odd, 0, 2);
  EXPECT_THROW(uneven.Next(), InvalidInput);
  EXPECT_THROW(ShardedBatchSource(odd, 2, 2), InvalidOptions);
}

}  // namespace
}  // namespace avatar::train
