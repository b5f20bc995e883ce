// One word per idea (issue 31): the network size is --config, the render mode of one frame
// --mode, bench render's cases --cases and the quality ladder --quality; "preset" is left to
// expression presets. The new flags work; each old flag (app/cli_util.h RenamedFlags) still works
// for one release, means the same (byte-identical frames) and prints a deprecation warning; the
// help texts no longer say "preset" except for expression presets.
#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <filesystem>
#include <iostream>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "app/cli_util.h"
#include "app/cmd_bench.h"
#include "app/commands.h"
#include "cli/in_process.h"
#include "common/run_process.h"
#include "common/temp_dir.h"
#include "core/io/data_paths.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using avatar::testing::InProcess;
using avatar::testing::ProcessResult;
using avatar::testing::TempDir;

std::string Warning(const std::string& command, const std::string& old_flag, const std::string& new_flag) {
  return "warning: `" + command + " " + old_flag + "` is deprecated and will be removed after 0.2; use " + new_flag +
         "\n";
}

size_t Count(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

std::vector<std::string> Words(const std::string& line) {
  std::istringstream in(line);
  return {std::istream_iterator<std::string>(in), std::istream_iterator<std::string>()};
}

std::string Bytes(const fs::path& path) {
  std::ifstream f(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

std::string Portrait() {
  return DataPaths::Resolve().Require(DataPaths::kDefaultPortrait, "the sample portrait (run scripts/setup)").string();
}

TEST(RenamedFlags, TheTableCoversEveryRenamedFlag) {
  struct Entry {
    std::string command, old_flag, new_flag;
  };
  const std::vector<Entry> expected = {{"animate", "--preset", "--config"},
                                       {"render", "--preset", "--mode"},
                                       {"bench render", "--presets", "--cases"},
                                       {"bench accuracy", "--presets", "--quality"}};
  ASSERT_EQ(app::RenamedFlags().size(), expected.size());
  for (size_t i = 0; i < expected.size(); ++i) {
    EXPECT_EQ(app::RenamedFlags()[i].command, expected[i].command);
    EXPECT_EQ(app::RenamedFlags()[i].old_flag, expected[i].old_flag);
    EXPECT_EQ(app::RenamedFlags()[i].new_flag, expected[i].new_flag);
  }
}

TEST(RenamedFlags, RewritesBothFormsOfItsCommandOnlyBeforeTheEndOfOptions) {
  for (const app::RenamedFlag& r : app::RenamedFlags()) {
    SCOPED_TRACE(std::string(r.command) + " " + r.old_flag);
    const std::string old_flag = r.old_flag, new_flag = r.new_flag;
    std::vector<std::string> args = Words(r.command);
    const size_t n = args.size();
    for (const std::string& a : {std::string("input"), old_flag, std::string("v"), old_flag + "=w",
                                 new_flag, std::string("x"), std::string("--"), old_flag}) {
      args.push_back(a);
    }
    std::ostringstream warnings;
    const std::vector<std::string> out = app::RewriteRenamedFlags(args, warnings);
    std::vector<std::string> want(args.begin(), args.begin() + static_cast<std::ptrdiff_t>(n));
    for (const std::string& a : {std::string("input"), new_flag, std::string("v"), new_flag + "=w", new_flag,
                                 std::string("x"), std::string("--"), old_flag}) {
      want.push_back(a);
    }
    EXPECT_EQ(out, want);
    const std::string line = Warning(r.command, old_flag, new_flag);
    EXPECT_EQ(warnings.str(), line + line);
  }
  // Other commands, the new names and flags that only start like an old one are left alone.
  for (const std::vector<std::string>& args :
       std::vector<std::vector<std::string>>{{"reconstruct", "p.jpg", "--preset", "lite"},
                                             {"bench", "model", "--presets", "x"},
                                             {"bench", "--presets", "x"},
                                             {"view", "render", "--preset", "x"},
                                             {"animate", "--config", "lite", "--presetting", "x"},
                                             {"render", "a.avatar", "--mode", "final"},
                                             {"bench", "render", "--cases", "tiny"},
                                             {"bench", "accuracy", "--quality", "fine"}}) {
    std::ostringstream warnings;
    EXPECT_EQ(app::RewriteRenamedFlags(args, warnings), args);
    EXPECT_EQ(warnings.str(), "");
  }
}

// Old and new flags of `render` and `animate` give the same files, byte for byte; only the old
// flags warn. One tiny random-weight avatar of the sample portrait.
class RenamedFlagsRender : public ::testing::Test {
 protected:
  void SetUp() override {
    const ProcessResult r =
        InProcess({"reconstruct", Portrait(), "--random-weights", "--config", "tiny", "-o", Avatar(), "--threads", "2"});
    ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  }
  std::string Avatar() const { return (dir_ / "a.avatar").string(); }
  ProcessResult Render(std::vector<std::string> flags, const std::string& output) const {
    std::vector<std::string> args = {"render", Avatar(), "--random-weights", "--yaw", "20", "--threads", "2"};
    args.insert(args.end(), flags.begin(), flags.end());
    args.push_back("-o");
    args.push_back((dir_ / output).string());
    return InProcess(args);
  }
  TempDir dir_;
};

TEST_F(RenamedFlagsRender, ModeAndTheOldPresetFlagRenderTheSameBytes) {
  const std::string warning = Warning("render", "--preset", "--mode");
  for (const char* name : {"preview", "standard", "final"}) {
    const std::string mode = name;
    SCOPED_TRACE(mode);
    const ProcessResult now = Render({"--mode", mode}, mode + "_mode.png");
    ASSERT_EQ(now.exit_code, 0) << now.err;
    EXPECT_NE(now.out.find(", mode " + mode), std::string::npos) << now.out;
    EXPECT_EQ(now.err.find("deprecated"), std::string::npos) << now.err;
    const ProcessResult old = Render({"--preset", mode}, mode + "_preset.png");
    ASSERT_EQ(old.exit_code, 0) << old.err;
    EXPECT_EQ(Count(old.err, warning), 1u) << old.err;
    const ProcessResult old_eq = Render({"--preset=" + mode}, mode + "_preset_eq.png");
    ASSERT_EQ(old_eq.exit_code, 0) << old_eq.err;
    EXPECT_EQ(Count(old_eq.err, warning), 1u) << old_eq.err;
    const std::string bytes = Bytes(dir_ / (mode + "_mode.png"));
    ASSERT_FALSE(bytes.empty());
    EXPECT_EQ(Bytes(dir_ / (mode + "_preset.png")), bytes);
    EXPECT_EQ(Bytes(dir_ / (mode + "_preset_eq.png")), bytes);
  }
  // The default mode is final.
  ASSERT_EQ(Render({}, "default.png").exit_code, 0);
  EXPECT_EQ(Bytes(dir_ / "default.png"), Bytes(dir_ / "final_mode.png"));
  // A bad value names the render mode under either name.
  for (const char* flag : {"--mode", "--preset"}) {
    const ProcessResult bad = Render({flag, "ultra"}, "bad.png");
    EXPECT_EQ(bad.exit_code, 2) << flag;
    EXPECT_NE(bad.err.find("unknown render mode 'ultra' (preview, standard or final)"), std::string::npos) << bad.err;
    EXPECT_EQ(Count(bad.err, warning), std::string(flag) == "--preset" ? 1u : 0u) << bad.err;
  }
  EXPECT_FALSE(fs::exists(dir_ / "bad.png"));
}

// `render FILE.avatar` draws the photo's detail over the network render by default (the avatar
// file keeps the portrait's analysis), at --size; --detail off renders the network alone.
using RenderDetail = RenamedFlagsRender;
TEST_F(RenderDetail, SavedAvatarsRenderWithThePhotosDetail) {
  const ProcessResult detail = Render({"--size", "128", "--alpha"}, "detail.png");
  ASSERT_EQ(detail.exit_code, 0) << detail.out << detail.err;
  EXPECT_NE(detail.out.find("the photo's detail on the head"), std::string::npos) << detail.out;
  EXPECT_EQ(detail.err.find("warning: This avatar"), std::string::npos) << detail.err;
  const cv::Mat image = cv::imread((dir_ / "detail.png").string(), cv::IMREAD_UNCHANGED);
  EXPECT_EQ(image.size(), cv::Size(128, 128));
  EXPECT_EQ(image.channels(), 4);
  const ProcessResult plain = Render({"--detail", "off"}, "plain.png");
  ASSERT_EQ(plain.exit_code, 0) << plain.err;
  EXPECT_EQ(plain.out.find("photo's detail"), std::string::npos) << plain.out;
  const ProcessResult bad = Render({"--detail", "sharp"}, "bad.png");
  EXPECT_EQ(bad.exit_code, 2) << bad.out << bad.err;
  EXPECT_NE(bad.err.find("sharp"), std::string::npos) << bad.err;
}

// export-mesh (issue 32): a .glb the Khronos glTF validator accepts without errors, holding the
// face mesh (468 vertices) with its texture; an .obj with its .mtl and textures; bad output
// names and old avatar files are refused with a message.
using ExportMesh = RenamedFlagsRender;
TEST_F(ExportMesh, WritesGltfTheKhronosValidatorAcceptsAndObj) {
  const std::string glb = (dir_ / "head.glb").string();
  const ProcessResult r = InProcess({"export-mesh", Avatar(), "--random-weights", "--depth-size", "64", "-o", glb,
                                     "--threads", "2"});
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("face 468 vertices"), std::string::npos) << r.out;
  const std::string bytes = Bytes(glb);
  ASSERT_GT(bytes.size(), 28u);
  auto u32 = [&](size_t at) {
    uint32_t v = 0;
    for (int i = 3; i >= 0; --i) v = (v << 8) | static_cast<unsigned char>(bytes[at + i]);
    return v;
  };
  EXPECT_EQ(bytes.substr(0, 4), "glTF");
  EXPECT_EQ(u32(4), 2u);
  EXPECT_EQ(u32(8), bytes.size());
  const uint32_t json_length = u32(12);
  EXPECT_EQ(u32(16), 0x4E4F534Au);
  const nlohmann::json j = nlohmann::json::parse(bytes.substr(20, json_length));
  const size_t bin_at = 20 + json_length + 8;
  ASSERT_EQ(u32(20 + json_length + 4), 0x004E4942u);
  ASSERT_GE(j.at("meshes").size(), 1u);
  EXPECT_EQ(j["meshes"][0]["name"], "face");
  const int position = j["meshes"][0]["primitives"][0]["attributes"]["POSITION"];
  EXPECT_EQ(j["accessors"][position]["count"], 468);
  // Every texture is a PNG inside the binary chunk.
  ASSERT_EQ(j.at("images").size(), j["meshes"].size());
  for (const auto& image : j["images"]) {
    const auto& view = j["bufferViews"][image["bufferView"].get<int>()];
    const std::string png = bytes.substr(bin_at + view["byteOffset"].get<size_t>(), view["byteLength"].get<size_t>());
    const cv::Mat decoded = cv::imdecode(std::vector<uchar>(png.begin(), png.end()), cv::IMREAD_COLOR);
    EXPECT_FALSE(decoded.empty());
  }
  // The Khronos validator (npm gltf-validator, installed on first use by the script).
  const ProcessResult v = avatar::testing::RunProcess("'" AVATAR_SOURCE_DIR "/scripts/validate-gltf' '" + glb + "'");
  std::cout << v.out;
  EXPECT_EQ(v.exit_code, 0) << v.out << v.err;
  EXPECT_NE(v.out.find(": 0 errors"), std::string::npos) << v.out << v.err;

  const ProcessResult obj =
      InProcess({"export-mesh", Avatar(), "--random-weights", "--depth-size", "64", "-o", (dir_ / "head.obj").string()});
  ASSERT_EQ(obj.exit_code, 0) << obj.out << obj.err;
  EXPECT_TRUE(fs::exists(dir_ / "head.mtl"));
  EXPECT_FALSE(cv::imread((dir_ / "head_face.png").string()).empty());
  std::istringstream lines(Bytes(dir_ / "head.obj"));
  int vertices = 0;
  for (std::string line; std::getline(lines, line);) vertices += line.rfind("v ", 0) == 0 ? 1 : 0;
  EXPECT_GE(vertices, 468);

  const ProcessResult stl = InProcess({"export-mesh", Avatar(), "--random-weights", "-o", (dir_ / "head.stl").string()});
  EXPECT_EQ(stl.exit_code, 2) << stl.err;
  EXPECT_NE(stl.err.find(".glb"), std::string::npos) << stl.err;
  EXPECT_FALSE(fs::exists(dir_ / "head.stl"));
  const ProcessResult missing = InProcess({"export-mesh", (dir_ / "none.avatar").string(), "-o", glb});
  EXPECT_NE(missing.exit_code, 0);
  EXPECT_NE(missing.err.find("none.avatar"), std::string::npos) << missing.err;
}

// live (issue 34): without a camera it says so and exits 1; a sample clip played as a camera
// drives a saved avatar, and the recording holds the frames in real time.
using Live = RenamedFlagsRender;
TEST_F(Live, WithoutACameraSaysSoAndAClipPlayedAsACameraDrivesTheAvatar) {
  const ProcessResult none = InProcess({"live", Avatar(), "--random-weights", "--camera", "61"});
  EXPECT_EQ(none.exit_code, 1) << none.out << none.err;
  EXPECT_NE(none.err.find("no camera /dev/video61"), std::string::npos) << none.err;
  const std::string clip =
      DataPaths::Resolve().Require("samples/cap13_edit2.mp4", "a sample driving clip (run scripts/setup)").string();
  const ProcessResult missing = InProcess({"live", (dir_ / "none.avatar").string(), "--camera", clip});
  EXPECT_EQ(missing.exit_code, 1) << missing.err;
  EXPECT_NE(missing.err.find("none.avatar"), std::string::npos) << missing.err;
  const std::string out = (dir_ / "live.mp4").string();
  const ProcessResult live = InProcess({"live", Avatar(), "--random-weights", "--camera", clip, "--seconds", "1.5",
                                        "--size", "64", "--detail", "off", "-o", out, "--threads", "2"});
  ASSERT_EQ(live.exit_code, 0) << live.out << live.err;
  EXPECT_NE(live.out.find("fps delivered"), std::string::npos) << live.out;
  EXPECT_NE(live.out.find("recorded to"), std::string::npos) << live.out;
  EXPECT_NE(live.err.find("Neutral reference"), std::string::npos) << live.err;
  cv::VideoCapture recorded(out);
  ASSERT_TRUE(recorded.isOpened());
  EXPECT_GE(recorded.get(cv::CAP_PROP_FRAME_COUNT), 10.0);
}

TEST_F(RenamedFlagsRender, AnimateConfigAndTheOldPresetFlagExportTheSameFrames) {
  const std::string warning = Warning("animate", "--preset", "--config");
  auto animate = [&](const std::vector<std::string>& flags, const std::string& folder) {
    std::vector<std::string> args = {"animate", Portrait(), "--random-weights", "--view", "orbit", "--seconds", "0.2",
                                     "--fps",   "5",        "--width",          "32",     "--height", "32",
                                     "--threads", "2"};
    args.insert(args.end(), flags.begin(), flags.end());
    args.push_back("-o");
    args.push_back((dir_ / folder).string() + "/");
    return InProcess(args);
  };
  const ProcessResult now = animate({"--config", "lite"}, "config");
  ASSERT_EQ(now.exit_code, 0) << now.out << now.err;
  EXPECT_EQ(now.err.find("deprecated"), std::string::npos) << now.err;
  const ProcessResult old = animate({"--preset", "lite"}, "preset");
  ASSERT_EQ(old.exit_code, 0) << old.out << old.err;
  EXPECT_EQ(Count(old.err, warning), 1u) << old.err;
  std::vector<std::string> frames;
  for (const auto& e : fs::directory_iterator(dir_ / "config")) frames.push_back(e.path().filename().string());
  ASSERT_FALSE(frames.empty());
  for (const std::string& f : frames) {
    SCOPED_TRACE(f);
    ASSERT_TRUE(fs::exists(dir_ / "preset" / f));
    EXPECT_EQ(Bytes(dir_ / "preset" / f), Bytes(dir_ / "config" / f));
  }
  // The value reaches the network size under either name: a bad one is refused as --config.
  for (const char* flag : {"--config", "--preset"}) {
    const ProcessResult bad = animate({flag, "huge"}, "bad");
    EXPECT_EQ(bad.exit_code, 2) << flag << "\n" << bad.err;
    EXPECT_NE(bad.err.find("--config must be lite or paper, got 'huge'"), std::string::npos) << bad.err;
    EXPECT_EQ(Count(bad.err, warning), std::string(flag) == "--preset" ? 1u : 0u) << bad.err;
  }
  EXPECT_FALSE(fs::exists(dir_ / "bad"));
}

TEST(RenamedFlags, BenchRenderCasesAndTheOldPresetsFlagMeasureTheSameCases) {
  const std::string warning = Warning("bench render", "--presets", "--cases");
  for (const char* flag : {"--cases", "--presets", "--presets="}) {
    SCOPED_TRACE(flag);
    std::vector<std::string> args = {"bench", "render", "--repeats", "1", "--threads", "2"};
    if (std::string(flag).back() == '=') {
      args.push_back(std::string(flag) + "tiny");
    } else {
      args.push_back(flag);
      args.push_back("tiny");
    }
    const ProcessResult r = InProcess(args);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    EXPECT_NE(r.out.find("| case | rays |"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("| tiny | 1x32^2 |"), std::string::npos) << r.out;
    EXPECT_EQ(r.out.find("| small |"), std::string::npos) << r.out;
    EXPECT_EQ(Count(r.err, warning), std::string(flag) == "--cases" ? 0u : 1u) << r.err;
  }
  for (const char* flag : {"--cases", "--presets"}) {
    const ProcessResult bad = InProcess({"bench", "render", flag, "tiny,huge"});
    EXPECT_EQ(bad.exit_code, 2) << flag;
    EXPECT_NE(bad.err.find("unknown case 'huge' (paper, medium, small, tiny, all)"), std::string::npos) << bad.err;
  }
}

TEST(RenamedFlags, BenchAccuracyQualityAndTheOldPresetsFlagNameQualityLevels) {
  const std::string warning = Warning("bench accuracy", "--presets", "--quality");
  TempDir dir;
  for (const char* flag : {"--quality", "--presets"}) {
    SCOPED_TRACE(flag);
    // An unknown level is refused before anything is read, naming the ladder.
    const ProcessResult bad = InProcess({"bench", "accuracy", "--data", (dir / "none").string(), flag, "fine,ultra",
                                         "--out", (dir / "out").string()});
    EXPECT_EQ(bad.exit_code, 2) << bad.err;
    EXPECT_NE(bad.err.find("unknown quality level 'ultra' (instant, preview, standard, fine, best, paper)"),
              std::string::npos)
        << bad.err;
    EXPECT_EQ(Count(bad.err, warning), std::string(flag) == "--presets" ? 1u : 0u) << bad.err;
    // Known levels pass the options; the missing dataset is what fails.
    const ProcessResult good = InProcess({"bench", "accuracy", "--data", (dir / "none").string(), flag, "fine",
                                          "--refine-steps", "", "--out", (dir / "out").string()});
    EXPECT_EQ(good.exit_code, 1) << good.err;
    EXPECT_NE(good.err.find("none"), std::string::npos) << good.err;
    EXPECT_EQ(good.err.find("unknown"), std::string::npos) << good.err;
  }
  // Nothing to measure names the new flag.
  const ProcessResult nothing = InProcess({"bench", "accuracy", "--data", (dir / "none").string(), "--quality", "",
                                           "--refine-steps", "", "--out", (dir / "out").string()});
  EXPECT_EQ(nothing.exit_code, 2);
  EXPECT_NE(nothing.err.find("give --quality or --refine-steps"), std::string::npos) << nothing.err;
}

// Every help text: "preset" only in "expression preset(s)".
TEST(RenamedFlags, HelpTextsSayPresetOnlyForExpressionPresets) {
  std::vector<std::vector<std::string>> lines = {{"--help"}, {"bench", "--help"}, {"dataset", "--help"},
                                                 {"dataset", "build", "--help"}, {"dataset", "inspect", "--help"}};
  for (const app::Command& c : app::CommandTable()) {
    if (c.run != nullptr) lines.push_back({c.name, "--help"});
  }
  for (const app::BenchSubject& s : app::BenchSubjects()) lines.push_back({"bench", s.name, "--help"});
  for (const auto& line : lines) {
    std::string shown;
    for (const auto& w : line) shown += w + " ";
    SCOPED_TRACE(shown);
    const ProcessResult r = InProcess(line);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    std::string text = r.out + r.err;
    std::transform(text.begin(), text.end(), text.begin(), [](unsigned char ch) { return std::tolower(ch); });
    for (size_t at = text.find("expression preset"); at != std::string::npos; at = text.find("expression preset")) {
      text.erase(at, std::string("expression preset").size());
    }
    EXPECT_EQ(text.find("preset"), std::string::npos) << r.out;
  }
  // The new names are the documented ones.
  const struct {
    std::vector<std::string> line;
    const char* flag;
  } flags[] = {{{"render", "--help"}, "--mode VALUE"},           {{"animate", "--help"}, "--config VALUE"},
               {{"bench", "render", "--help"}, "--cases VALUE"}, {{"bench", "accuracy", "--help"}, "--quality VALUE"},
               {{"reconstruct", "--help"}, "--quality VALUE"}};
  for (const auto& f : flags) {
    const ProcessResult r = InProcess(f.line);
    EXPECT_NE(r.out.find(f.flag), std::string::npos) << f.flag << "\n" << r.out;
  }
  EXPECT_NE(InProcess({"render", "--help"}).out.find("[--mode preview|standard|final]"), std::string::npos);
}

}  // namespace
}  // namespace avatar
