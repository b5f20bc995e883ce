// Fuzz target "keyframes": keyframe JSON (`animate --driver keys.json`), parsed by
// core/pipeline/driving KeyframeDriver, then read the way an export reads it: its controls are
// checked, the first frames sampled in order and a few times sampled directly.
#include "core/pipeline/driving.h"
#include "core/util/error.h"
#include "core/util/run_context.h"
#include "fuzz_common.h"

namespace avatar::fuzz {
namespace {

std::string RunKeyframes(std::string_view input) {
  const std::filesystem::path file = FreshInputDir() / "keys.json";
  WriteFile(file, input);
  return AcceptAvatarErrors([&] {
    KeyframeDriver driver(file);
    (void)driver.Fps();
    const int64_t frames = driver.FrameCount();
    RunContext ctx;
    DrivingSample sample;
    for (int i = 0; i < 64 && driver.Next(sample, ctx); ++i) {
    }
    for (const double t : {0.0, 0.5, 1e-3, 1e6}) (void)driver.At(t);
    (void)frames;
    driver.CheckControls({"smile", "jaw_open", "brow_raise", "blink"});
  });
}

int KeyframesSeeds(const std::filesystem::path& dir) {
  WriteFile(dir / "orbit.json",
            R"({"fps": 25, "duration": 2.0, "keys": [{"time": 0, "yaw": -20, "zoom": 1},)"
            R"( {"time": 1, "yaw": 20, "pitch": 5, "roll": -3, "zoom": 1.2, "expression": {"smile": 0.8}},)"
            R"( {"time": 2, "yaw": 0, "expression": {"smile": 0, "jaw_open": 0.5}}]})");
  WriteFile(dir / "one-key.json", R"({"keys": [{"time": 0.5, "expression": {"blink": 1}}]})");
  WriteFile(dir / "unsorted.json",
            R"({"fps": 10, "keys": [{"time": 3, "pitch": 10}, {"time": 1, "pitch": -10}, {"time": 1, "zoom": 0.5}]})");
  return 3;
}

AVATAR_FUZZ_TARGET("keyframes", RunKeyframes, KeyframesSeeds);

}  // namespace
}  // namespace avatar::fuzz
