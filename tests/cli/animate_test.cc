// `avatar-studio animate`: the real executable on the bundled sample portrait and short
// driving clips made here with ffmpeg (with and without a sound track). Outputs are checked
// with ffprobe and by reading them back.
#include <unistd.h>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "common/run_process.h"
#include "common/temp_dir.h"
#include "core/io/data_paths.h"
#include "core/io/video_io.h"
#include "core/pipeline/animate.h"
#include "core/pipeline/export.h"
#include "core/pipeline/studio_backend.h"
#include "core/util/error.h"
#include "morphable/morphable_test_util.h"

namespace avatar {
namespace {

using avatar::testing::ProcessResult;
using avatar::testing::TempDir;
namespace fs = std::filesystem;

// The morphable model these tests render with: a synthetic one written once per process
// (smooth random bases on the installed facemesh topology), so the tests exercise the whole
// animate path - real face analysis of the sample portrait, fit, texture, rendering, export -
// without depending on the committed model's contents.
const std::string& SyntheticModelFile() {
  static const std::string path = [] {
    const fs::path file = fs::temp_directory_path() / ("avatar_cli_model_" + std::to_string(::getpid()) + ".avmm");
    morphable::testing::SyntheticModel(morphable::testing::InstalledTopology(), 6, 12).Save(file);
    ::setenv("AVATAR_MORPHABLE_MODEL", file.c_str(), 1);
    return file.string();
  }();
  return path;
}

ProcessResult Studio(const std::string& args) {
  return avatar::testing::RunProcess(
      std::string("'") + AVATAR_STUDIO_EXE + "' " + args,
      "env -u DISPLAY -u WAYLAND_DISPLAY -u QT_QPA_PLATFORM AVATAR_THREADS=2 AVATAR_MORPHABLE_MODEL='" +
          SyntheticModelFile() + "'");
}

// Runs the studio with `folder` as the working directory (for relative output paths).
ProcessResult StudioIn(const fs::path& folder, const std::string& args) {
  return avatar::testing::RunProcess(
      std::string("'") + AVATAR_STUDIO_EXE + "' " + args,
      "cd '" + folder.string() + "' && env -u DISPLAY -u WAYLAND_DISPLAY -u QT_QPA_PLATFORM AVATAR_THREADS=2 " +
          "AVATAR_MORPHABLE_MODEL='" + SyntheticModelFile() + "'");
}

// The PNG frames in `folder`, sorted.
std::vector<std::string> PngFrames(const fs::path& folder) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(folder)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

std::vector<std::string> FrameNames(int n) {
  std::vector<std::string> names;
  for (int i = 0; i < n; ++i) {
    char name[32];
    std::snprintf(name, sizeof(name), "frame_%06d.png", i);
    names.push_back(name);
  }
  return names;
}

std::string Portrait() {
  SyntheticModelFile();  // In-process calls (RunAnimation, CreateFrameSource) use it too.
  return DataPaths::Resolve().Require(DataPaths::kDefaultPortrait, "the sample portrait (run scripts/setup)").string();
}

// A driving clip cut from the bundled face video (so it shows a real face), re-timed to
// `fps`, optionally with a sine sound track exactly as long as the video.
fs::path MakeClip(const TempDir& dir, const std::string& name, int frames, int fps, bool audio) {
  const std::string source =
      DataPaths::Resolve().Require("samples/cap13_edit2.mp4", "a sample driving clip (run scripts/setup)").string();
  const double seconds = static_cast<double>(frames) / fps;
  std::vector<std::string> args = {"-nostdin", "-y", "-v", "error", "-i", source};
  if (audio) {
    args.insert(args.end(), {"-f", "lavfi", "-i", "sine=frequency=440:duration=" + std::to_string(seconds)});
  }
  args.insert(args.end(), {"-map", "0:v:0"});
  if (audio) args.insert(args.end(), {"-map", "1:a:0", "-c:a", "aac"});
  args.insert(args.end(), {"-vf", "fps=" + std::to_string(fps), "-t", std::to_string(seconds), "-c:v", "libx264",
                           "-pix_fmt", "yuv420p", (dir / name).string()});
  EXPECT_EQ(RunProgram("ffmpeg", args), 0) << "ffmpeg could not make the test clip";
  return dir / name;
}

// ffprobe's view of a media file: "codec_type,nb_read_frames,r_frame_rate" per stream.
std::string Probe(const fs::path& file) {
  const ProcessResult r = avatar::testing::RunProcess(
      "ffprobe -v error -count_frames -show_entries stream=codec_type,nb_read_frames,r_frame_rate -of csv=p=0 '" +
      file.string() + "'");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  return r.out;
}

TEST(Animate, Mp4MatchesTheDriversFramesAndRateAndKeepsItsAudio) {
  TempDir dir;
  const fs::path clip = MakeClip(dir, "talk.mp4", 30, 15, true);
  ASSERT_TRUE(ProbeHasAudio(clip));
  const fs::path out = dir / "out.mp4";
  const auto r =
      Studio("animate '" + Portrait() + "' '" + clip.string() + "' -o '" + out.string() + "' --width 96 --height 96");
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("Wrote 30 frames at 15 fps"), std::string::npos) << r.out;
  // The bundled neural model renders by default, and the output says which model it was.
  EXPECT_NE(r.out.find("Renderer: the bundled neural avatar model"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("Frames rendered by: Neural avatar: bundled neural model ckpt:"), std::string::npos) << r.out;
  // ... under the photo's detail path finished by the bundled fusion net (the default; --detail
  // geometric leaves the net out, --detail off shows the network alone).
  EXPECT_NE(r.out.find(" + the photo's detail on the head, finished by the fusion net (step "), std::string::npos)
      << r.out;
  EXPECT_EQ(r.out.find("timing and audio only"), std::string::npos) << "the driver was not measured\n" << r.out;
  const std::string probe = Probe(out);
  EXPECT_NE(probe.find("video,15/1,30"), std::string::npos) << probe;
  EXPECT_NE(probe.find("audio"), std::string::npos) << "the driver's audio is missing:\n" << probe;
  std::vector<std::string> names = dir.List();
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"out.mp4", "talk.mp4"}));
}

TEST(Animate, SilentDriverGivesASilentClipWithItsFrameCount) {
  TempDir dir;
  const fs::path clip = MakeClip(dir, "silent.mp4", 12, 24, false);
  const fs::path out = dir / "out.mp4";
  const auto r =
      Studio("animate '" + Portrait() + "' '" + clip.string() + "' -o '" + out.string() + "' --width 64 --height 64");
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  const std::string probe = Probe(out);
  EXPECT_NE(probe.find("video,24/1,12"), std::string::npos) << probe;
  EXPECT_EQ(probe.find("audio"), std::string::npos) << probe;
}

TEST(Animate, OrbitWithoutDriverLastsTheRequestedTime) {
  TempDir dir;
  const fs::path out = dir / "turntable.mp4";
  const auto r = Studio("animate '" + Portrait() + "' --view orbit --seconds 1 --fps 10 -o '" + out.string() +
                        "' --width 64 --height 64");
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  EXPECT_NE(Probe(out).find("video,10/1,10"), std::string::npos) << Probe(out);
}

TEST(Animate, KeyframesDriveThePngSequence) {
  TempDir dir;
  std::ofstream(dir / "keys.json") << R"({"fps": 5, "duration": 1.0,
      "keys": [{"time": 0, "expression": {"smile": 0}}, {"time": 1, "yaw": 20, "expression": {"smile": 1}}]})";
  const fs::path out = dir / "frames";
  // The morphable preview: its mesh gives exact opaque/transparent regions to check the alpha
  // channel against (the neural frames' alpha is checked in pipeline/StudioBackend).
  const auto r = Studio("animate '" + Portrait() + "' '" + (dir / "keys.json").string() + "' -o '" + out.string() +
                        "' --width 128 --height 96 --renderer morphable");
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  int count = 0;
  for (const auto& e : fs::directory_iterator(out)) count += e.path().extension() == ".png" ? 1 : 0;
  EXPECT_EQ(count, 6);  // t = 0, 0.2, ..., 1.0.
  const cv::Mat png = cv::imread((out / "frame_000000.png").string(), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(png.type(), CV_8UC4);
  EXPECT_EQ(png.cols, 128);
  EXPECT_EQ(png.rows, 96);
  std::vector<cv::Mat> channels;
  cv::split(png, channels);
  const cv::Mat& alpha = channels[3];
  const int partial = cv::countNonZero((alpha > 0) & (alpha < 255));
  EXPECT_GT(partial, 20) << "the head's edge must have partial opacity";
  EXPECT_GT(cv::countNonZero(alpha == 255), 500) << "the head is missing";
  EXPECT_EQ(alpha.at<uchar>(0, 0), 0) << "the background must be transparent";
  // The last frame (yaw 20, full smile) differs from the first.
  const cv::Mat last = cv::imread((out / "frame_000005.png").string(), cv::IMREAD_UNCHANGED);
  EXPECT_GT(cv::norm(png, last, cv::NORM_L1) / (128.0 * 96.0), 1.0);
}

TEST(Animate, CancelLeavesNoFileAndNoTemporaries) {
  TempDir dir;
  const fs::path clip = MakeClip(dir, "talk.mp4", 40, 20, true);
  for (const char* target : {"out.mp4", "frames"}) {
    AnimateOptions o;
    o.source = Portrait();
    o.driver = clip.string();
    o.output = (dir / target).string();
    o.width = o.height = 64;
    int reports = 0;
    RunContext ctx([&](const Progress& p) {
      if (p.stage == "export" && ++reports == 10) ctx.RequestCancel();
    });
    EXPECT_THROW(RunAnimation(o, ctx), Cancelled);
    EXPECT_EQ(dir.List(), std::vector<std::string>{"talk.mp4"}) << target;
  }
}

TEST(Animate, ReconstructionStopsAtTheNextStageWhenCancelled) {
  const cv::Mat portrait = cv::imread(Portrait());
  ASSERT_FALSE(portrait.empty());
  std::vector<std::string> stages;
  std::chrono::steady_clock::time_point asked;
  RunContext ctx([&](const Progress& p) {
    stages.push_back(p.stage);
    if (stages.size() == 2) {
      asked = std::chrono::steady_clock::now();
      ctx.RequestCancel();
    }
  });
  EXPECT_THROW(CreateFrameSource(portrait, BackendOptions{}, ctx), Cancelled);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - asked).count();
  std::printf("reconstruction stopped %.1f ms after the cancel request (stages seen: %zu)\n", ms, stages.size());
  EXPECT_EQ(stages.size(), 2u) << "work went on after the cancel request";
}

TEST(Animate, ExportFailureLeavesNoFile) {
  TempDir dir;
  AnimateOptions o;
  o.source = Portrait();
  o.output = (dir / "out.mp4").string();
  o.width = 63;  // H.264 needs even sizes: refused as an option, before the portrait's analysis.
  o.height = 64;
  o.view = "orbit";
  RunContext ctx;
  EXPECT_THROW(RunAnimation(o, ctx), InvalidOptions);
  EXPECT_TRUE(dir.List().empty());
  // The MP4 sink refuses it too, before writing, for callers that skip AnimateOptions.
  ExportOptions e;
  e.output = o.output;
  const FrameProducer never = [](int64_t, ExportFrame&) -> bool {
    ADD_FAILURE() << "no frame should be asked for";
    return false;
  };
  EXPECT_THROW(ExportFrames(never, 10, 63, 64, e, ctx), InvalidInput);
  EXPECT_TRUE(dir.List().empty());
}

TEST(Animate, BadInputsGiveClearMessagesAndExitCodes) {
  TempDir dir;
  const std::string out = " -o '" + (dir / "o.mp4").string() + "'";
  auto r = Studio("animate");
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("PORTRAIT"), std::string::npos) << r.err;
  r = Studio("animate '" + Portrait() + "' '" + (dir / "missing.mp4").string() + "'" + out);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("missing.mp4"), std::string::npos) << r.err;
  r = Studio("animate '" + Portrait() + "' --view sideways" + out);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--view"), std::string::npos) << r.err;
  std::ofstream(dir / "bad.json") << "{\"keys\": [{\"time\": \"soon\"}]}";
  r = Studio("animate '" + Portrait() + "' '" + (dir / "bad.json").string() + "'" + out);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("time"), std::string::npos) << r.err;
  r = Studio("animate '" + Portrait() + "' '" + (dir / "notes.txt").string() + "'" + out);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("notes.txt"), std::string::npos) << r.err;
  // A photo without a face: a clear error naming the photo, nothing written.
  cv::Mat sky(240, 320, CV_8UC3, cv::Scalar(230, 180, 120));
  cv::imwrite((dir / "sky.png").string(), sky);
  r = Studio("animate '" + (dir / "sky.png").string() + "' --view orbit" + out);
  EXPECT_EQ(r.exit_code, 1) << r.out;
  EXPECT_NE(r.err.find("sky.png"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("face"), std::string::npos) << r.err;
  std::vector<std::string> names = dir.List();
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"bad.json", "sky.png"}));
}

TEST(Animate, RandomWeightsOnRequestBundledModelByDefaultAllLabelled) {
  TempDir dir;
  const fs::path out = dir / "random.mp4";
  const auto r = Studio("animate '" + Portrait() + "' --random-weights --view orbit --seconds 0.4 --fps 5 -o '" +
                        out.string() + "' --width 64 --height 64");
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("RANDOM weights"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("not a result"), std::string::npos) << r.out;
  EXPECT_NE(Probe(out).find("video,5/1,2"), std::string::npos) << Probe(out);
  // Without the flag the trained model renders; the morphable preview only when asked for.
  const auto neural = Studio("animate '" + Portrait() + "' --view orbit --seconds 0.2 --fps 5 -o '" +
                             (dir / "n.mp4").string() + "' --width 64 --height 64");
  ASSERT_EQ(neural.exit_code, 0) << neural.err;
  EXPECT_EQ(neural.out.find("RANDOM"), std::string::npos) << neural.out;
  EXPECT_NE(neural.out.find("Neural avatar: bundled neural model"), std::string::npos) << neural.out;
  const auto preview = Studio("animate '" + Portrait() + "' --renderer morphable --view orbit --seconds 0.2 --fps 5 -o '" +
                              (dir / "p.mp4").string() + "' --width 64 --height 64");
  ASSERT_EQ(preview.exit_code, 0) << preview.err;
  EXPECT_EQ(preview.out.find("RANDOM"), std::string::npos) << preview.out;
  EXPECT_NE(preview.out.find("Preview: morphable model (chosen"), std::string::npos) << preview.out;
  // A named checkpoint that does not exist is an error naming it, never a silent preview.
  const auto missing = Studio("animate '" + Portrait() + "' --checkpoint '" + (dir / "nope.ckpt").string() +
                              "' --view orbit --seconds 0.2 --fps 5 -o '" + (dir / "m.mp4").string() + "'");
  EXPECT_NE(missing.exit_code, 0);
  EXPECT_NE((missing.out + missing.err).find("file not found: '" + (dir / "nope.ckpt").string() + "'"),
            std::string::npos)
      << missing.out << missing.err;
  EXPECT_FALSE(fs::exists(dir / "m.mp4"));
}

TEST(Animate, HelpDescribesTheOptions) {
  const auto r = Studio("animate --help");
  EXPECT_EQ(r.exit_code, 0);
  for (const char* flag : {"--view", "--neutral-frame", "--smoothing", "--no-audio", "--random-weights", "--config"}) {
    EXPECT_NE(r.out.find(flag), std::string::npos) << flag << "\n" << r.out;
  }
}

TEST(Animate, PngSequenceToAFolderWithOrWithoutTheSlashMissingOrExisting) {
  TempDir dir;
  // Two frames (0.4 s at 5 fps) of the turntable; the morphable preview for exact alpha.
  const std::string clip = "animate '" + Portrait() + "' --renderer morphable --view orbit --fps 5 --width 64 --height 64";
  struct Case {
    std::string output;   // As typed, relative to the working folder.
    std::string folder;   // The folder it names.
    std::string before;   // "missing", "empty" or "export" (an earlier export of ours, 3 frames).
  };
  const std::vector<Case> cases = {{"frames/", "frames", "missing"}, {"frames", "frames", "export"},
                                   {"plain", "plain", "missing"},    {"slash/", "slash", "export"},
                                   {"empty/", "empty", "empty"},     {"empty2", "empty2", "empty"}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.output + " (" + c.before + ")");
    const fs::path folder = dir / c.folder;
    if (c.before == "empty") fs::create_directories(folder);
    if (c.before == "export") {
      fs::remove_all(folder);
      const auto first = StudioIn(dir.path(), clip + " --seconds 0.6 -o '" + c.folder + "'");
      ASSERT_EQ(first.exit_code, 0) << first.out << first.err;
      ASSERT_EQ(PngFrames(folder), FrameNames(3));
    }
    const auto r = StudioIn(dir.path(), clip + " --seconds 0.4 -o '" + c.output + "'");
    ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
    EXPECT_NE(r.out.find("Wrote 2 frames"), std::string::npos) << r.out;
    // Exactly the new export: an earlier one is replaced, not merged.
    EXPECT_EQ(PngFrames(folder), FrameNames(2));
    const cv::Mat png = cv::imread((folder / "frame_000001.png").string(), cv::IMREAD_UNCHANGED);
    ASSERT_EQ(png.type(), CV_8UC4);
    EXPECT_EQ(png.size(), cv::Size(64, 64));
    std::vector<cv::Mat> channels;
    cv::split(png, channels);
    EXPECT_EQ(channels[3].at<uchar>(0, 0), 0) << "the background must be transparent";
    EXPECT_GT(cv::countNonZero(channels[3] == 255), 100) << "the head is missing";
  }
  // No temporary folders are left next to the targets.
  std::vector<std::string> names = dir.List();
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"empty", "empty2", "frames", "plain", "slash"}));
  // A folder holding something that is not ours is never replaced.
  std::ofstream(dir / "plain" / "notes.txt") << "mine";
  const auto refused = StudioIn(dir.path(), clip + " --seconds 0.4 -o plain/");
  EXPECT_EQ(refused.exit_code, 1) << refused.out << refused.err;
  EXPECT_NE(refused.err.find("notes.txt"), std::string::npos) << refused.err;
  EXPECT_TRUE(fs::exists(dir / "plain" / "notes.txt"));
  EXPECT_EQ(PngFrames(dir / "plain").size(), 3u);  // Two frames and the user's file.
}

TEST(Animate, Mp4ToARelativePathInTheWorkingFolder) {
  TempDir dir;
  const auto r = StudioIn(dir.path(), "animate '" + Portrait() +
                                          "' --renderer morphable --view orbit --seconds 0.6 --fps 5 -o clip.mp4 "
                                          "--width 64 --height 64");
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  EXPECT_NE(Probe(dir / "clip.mp4").find("video,5/1,3"), std::string::npos) << Probe(dir / "clip.mp4");
  EXPECT_EQ(dir.List(), std::vector<std::string>{"clip.mp4"});
}

TEST(Animate, ADriverWhoseFirstTwoSecondsShowNoFaceAnimatesEndToEnd) {
  TempDir dir;
  // 2 s of black frames, then the face clip: 28 frames at 10 fps (the default neural renderer).
  const std::string source =
      DataPaths::Resolve().Require("samples/cap13_edit2.mp4", "a sample driving clip (run scripts/setup)").string();
  const fs::path clip = dir / "late.mp4";
  ASSERT_EQ(RunProgram("ffmpeg", {"-nostdin", "-y", "-v", "error", "-f", "lavfi", "-i",
                                  "color=c=black:s=400x300:r=10:d=2", "-i", source, "-filter_complex",
                                  "[1:v]fps=10,trim=end_frame=8,setpts=PTS-STARTPTS,setsar=1[face];"
                                  "[0:v]setsar=1[blank];[blank][face]concat=n=2:v=1:a=0[v]",
                                  "-map", "[v]", "-c:v", "libx264", "-pix_fmt", "yuv420p", clip.string()}),
            0);
  const fs::path out = dir / "out.mp4";
  const auto r = Studio("animate '" + Portrait() + "' '" + clip.string() + "' -o '" + out.string() +
                        "' --width 64 --height 64");
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("Wrote 28 frames at 10 fps"), std::string::npos) << r.out;
  // The choice is reported: frame 0 had no face, the first frame with one (20 or a little later) is used.
  const std::string note = "Note: the neutral frame 0 of 'late.mp4' shows no face; using frame ";
  const size_t at = r.out.find(note);
  ASSERT_NE(at, std::string::npos) << r.out;
  const int used = std::atoi(r.out.c_str() + at + note.size());
  std::printf("neutral frame used: %d\n", used);
  EXPECT_GE(used, 20);
  EXPECT_LT(used, 28);
  EXPECT_NE(Probe(out).find("video,10/1,28"), std::string::npos) << Probe(out);
  // In-process, the same choice reaches the result.
  AnimateOptions o;
  o.source = Portrait();
  o.driver = clip.string();
  o.output = (dir / "again.mp4").string();
  o.width = o.height = 32;
  o.max_frames = 2;
  o.backend.renderer = "morphable";
  RunContext ctx;
  const AnimateResult result = RunAnimation(o, ctx);
  EXPECT_EQ(result.neutral_frame, used);
  EXPECT_NE(result.driver_note.find("first frame with a face"), std::string::npos) << result.driver_note;
}

TEST(Animate, AnOutOfRangeNeutralFrameIsAnOptionError) {
  TempDir dir;
  const fs::path clip = MakeClip(dir, "short.mp4", 6, 10, false);
  const auto r = Studio("animate '" + Portrait() + "' '" + clip.string() + "' --neutral-frame 6 -o '" +
                        (dir / "o.mp4").string() + "' --renderer morphable --width 64 --height 64");
  EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
  EXPECT_NE(r.err.find("--neutral-frame 6 is past the end"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "o.mp4"));
}

}  // namespace
}  // namespace avatar
