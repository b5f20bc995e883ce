// The avatar-studio command line: argument handling, help texts and exit codes are checked
// in this process through the command library (app/commands.h: RunCommandLine, RunXImpl); the
// things only the real executable does (the version banner's OpenMP re-exec, the GUI entry
// without a display) run the binary.
#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include <sstream>

#include "app/cmd_view.h"
#include "cli/in_process.h"
#include "common/run_process.h"
#include "common/temp_dir.h"
#include "core/io/image_io.h"
#include "core/io/resources.h"
#include "core/model/fusion_net.h"

namespace avatar {
namespace {

using avatar::testing::CoutTo;
using avatar::testing::InProcess;
using avatar::testing::ProcessResult;
using avatar::testing::ScopedEnv;
using avatar::testing::TempDir;

ProcessResult Studio(const std::string& args, const std::string& env = "") {
  // No display: the CLI must never need one.
  return avatar::testing::RunProcess(std::string("'") + AVATAR_STUDIO_EXE + "' " + args,
                                     "env -u DISPLAY -u WAYLAND_DISPLAY -u QT_QPA_PLATFORM " + env);
}

TEST(Cli, HelpListsTheCommands) {
  const auto r = InProcess({"--help"});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  for (const char* name : {"view", "analyze", "fit", "build-morphable", "inspect", "reconstruct", "render", "animate",
                           "bench", "train", "eval"}) {
    EXPECT_NE(r.out.find(std::string("  ") + name + " "), std::string::npos) << name << "\n" << r.out;
  }
  EXPECT_NE(r.out.find("130 cancelled"), std::string::npos);
}

TEST(Cli, VersionPrintsTheVersion) {
  const auto r = Studio("--version");
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_EQ(r.out.rfind("avatar-studio 0.", 0), 0u) << r.out;
  EXPECT_NE(r.out.find("LibTorch"), std::string::npos);
  // Which fusion net finishes the detail frames by default: the bundled one of the source tree.
  EXPECT_NE(r.out.find("detail finish: "), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("fusion-default.ckpt (bundled)"), std::string::npos) << r.out;
}

TEST(Cli, StartsWithPassiveOpenMpWaitUnlessTheUserChoseAPolicy) {
  // Spinning OpenMP threads make renders many times slower when the cores are shared
  // (core/util/threads.h); the executable re-executes itself with passive waiting.
  const auto unset = Studio("--version", "env -u OMP_WAIT_POLICY");
  EXPECT_EQ(unset.exit_code, 0) << unset.err;
  EXPECT_NE(unset.out.find("OpenMP wait policy PASSIVE"), std::string::npos) << unset.out;
  const auto chosen = Studio("--version", "OMP_WAIT_POLICY=ACTIVE");
  EXPECT_EQ(chosen.exit_code, 0) << chosen.err;
  EXPECT_NE(chosen.out.find("OpenMP wait policy ACTIVE"), std::string::npos) << chosen.out;
}

TEST(Cli, CommandHelpShowsTheDefaultsNotTheFlagsGiven) {
  const auto r = InProcess({"view", "--help", "--verbose", "--threads", "3"});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("Show this help [default: false]"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("Print debug log lines [default: false]"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("[default: 3]"), std::string::npos) << r.out;
}

TEST(Cli, UnknownCommandIsAUsageError) {
  const auto r = InProcess({"frobnicate"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("unknown command 'frobnicate'"), std::string::npos) << r.err;
  // The executable's main() dispatches to the same library: same code, same message.
  const auto exe = Studio("frobnicate");
  EXPECT_EQ(exe.exit_code, r.exit_code);
  EXPECT_NE(exe.err.find(r.err), std::string::npos) << exe.err;
  EXPECT_EQ(InProcess({}).exit_code, 2) << "no command word: the GUI's job, not RunCommandLine's";
}

TEST(Cli, UnknownFlagIsAUsageError) {
  const auto r = InProcess({"view", "x.jpg", "--bogus", "3"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--bogus"), std::string::npos) << r.err;
}

TEST(Cli, EvalWithoutCheckpointIsAUsageError) {
  // eval was the last reserved command; it is implemented now (tests/pipeline/eval_test.cc).
  const auto r = InProcess({"eval"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--checkpoint"), std::string::npos) << r.err;
}

TEST(Cli, MissingInputFileIsAnErrorNamingTheFile) {
  TempDir dir;
  const auto r = InProcess({"view", (dir / "no_such_portrait.jpg").string(), "-o", (dir / "o.png").string()});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("no_such_portrait.jpg"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("check the path"), std::string::npos) << r.err;
  EXPECT_TRUE(dir.List().empty());
}

// `fusion export` writes the shipped form of trained weights with the inference setting asked
// for; bad settings and missing files are errors that name them, and nothing is written.
TEST(Cli, FusionExportWritesTheShippedFormAndRefusesBadSettings) {
  TempDir dir;
  const std::string bundled = ResourcePath(kBundledFusionFile).string();
  const std::string out = (dir / "shipped.ckpt").string();
  const auto r = InProcess({"fusion", "export", "--weights", bundled, "--out", out, "--turn-open", "0.5"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("turn_open 0.5"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(", float16"), std::string::npos) << r.out;
  FusionNetInfo info;
  LoadFusionNet(out, &info);
  EXPECT_EQ(info.options.turn_open, 0.5);
  const auto bad = InProcess({"fusion", "export", "--weights", bundled, "--out", (dir / "x.ckpt").string(),
                              "--turn-open", "3"});
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("--turn-open"), std::string::npos) << bad.err;
  const auto no_out = InProcess({"fusion", "export", "--weights", bundled});
  EXPECT_EQ(no_out.exit_code, 2);
  EXPECT_NE(no_out.err.find("--out"), std::string::npos) << no_out.err;
  const auto missing = InProcess({"fusion", "export", "--weights", (dir / "none.ckpt").string(), "--out",
                                  (dir / "x.ckpt").string()});
  EXPECT_EQ(missing.exit_code, 1);
  EXPECT_NE(missing.err.find("none.ckpt"), std::string::npos) << missing.err;
  EXPECT_FALSE(std::filesystem::exists(dir / "x.ckpt"));
}

TEST(Cli, ViewWritesTheViewportImage) {
  TempDir dir;
  cv::Mat portrait(60, 40, CV_8UC3, cv::Scalar(0, 0, 255));
  cv::imwrite((dir / "p.png").string(), portrait);
  // The command's own function, called with its options struct.
  app::ViewOptions options;
  options.input = (dir / "p.png").string();
  options.output = (dir / "v.png").string();
  options.preview.width = 100;
  options.preview.height = 120;
  RunContext ctx;
  std::ostringstream out;
  int code = -1;
  {
    CoutTo capture(out);
    code = app::RunViewImpl(options, ctx);
  }
  ASSERT_EQ(code, 0);
  EXPECT_NE(out.str().find("100x120"), std::string::npos) << out.str();
  const cv::Mat v = LoadImageBgr(dir / "v.png");
  EXPECT_EQ(v.size(), cv::Size(100, 120));
  EXPECT_EQ(v.at<cv::Vec3b>(60, 50), cv::Vec3b(0, 0, 255));  // Portrait in the centre.
  EXPECT_EQ(v.at<cv::Vec3b>(60, 2), cv::Vec3b(0, 0, 0));     // Black margin.
}

TEST(Cli, BadOptionValuesAreUsageErrors) {
  const auto r = InProcess({"view", "x.png", "--width", "3"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--width"), std::string::npos) << r.err;
  ScopedEnv threads("AVATAR_THREADS", "lots");
  const auto t = InProcess({"view", "x.png"});
  EXPECT_EQ(t.exit_code, 2);
  EXPECT_NE(t.err.find("AVATAR_THREADS"), std::string::npos) << t.err;
}

TEST(Cli, WithoutADisplayTheGuiRunsTheHeadlessEquivalent) {
  TempDir dir;
  cv::Mat portrait(30, 30, CV_8UC3, cv::Scalar(255, 0, 0));
  cv::imwrite((dir / "p.png").string(), portrait);
  const auto r = Studio("--open '" + (dir / "p.png").string() + "' --headless-output '" + (dir / "h.png").string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("No display found"), std::string::npos) << r.out;
  EXPECT_EQ(LoadImageBgr(dir / "h.png").at<cv::Vec3b>(400, 400), cv::Vec3b(255, 0, 0));
  const auto bare = Studio("");
  EXPECT_EQ(bare.exit_code, 2);
  EXPECT_NE(bare.err.find("no display"), std::string::npos) << bare.err;
}

}  // namespace
}  // namespace avatar
