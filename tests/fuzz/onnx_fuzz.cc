// Fuzz target "onnx": our loading path of the faceplugin ONNX models (core/face/identity_net.cc
// and head_pose_net.cc): the pre-check of LoadOnnxNet, cv::dnn's importer behind it, the trial
// run of each network, and IdentityTorch, which reads the weights out of cv::dnn's layers.
#include "core/face/head_pose_net.h"
#include "core/face/identity_net.h"
#include "core/util/error.h"
#include "fuzz_common.h"

namespace avatar::fuzz {
namespace {

// Accepted when one of the three loaders accepts the file (each model fits only its own loader).
std::string RunOnnx(std::string_view input) {
  const std::filesystem::path file = FreshInputDir() / "model.onnx";
  WriteFile(file, input);
  const std::string identity = AcceptAvatarErrors([&] { (void)face::IdentityNet::FromFile(file); });
  const std::string pose = AcceptAvatarErrors([&] { (void)face::HeadPoseNet::FromFile(file); });
  const std::string torch = AcceptAvatarErrors([&] { (void)face::IdentityTorch::FromFile(file).NumLayers(); });
  if (identity.empty() || pose.empty() || torch.empty()) return {};
  return identity + " | " + pose + " | " + torch;
}

int OnnxSeeds(const std::filesystem::path& dir) {
  int n = 0;
  const std::filesystem::path models = DataDir() / "models";
  for (const char* name : {"fr_feature.onnx", "fr_pose.onnx"}) {
    std::error_code ec;
    if (DataDir().empty() || !std::filesystem::is_regular_file(models / name, ec)) continue;
    std::filesystem::copy_file(models / name, dir / name, std::filesystem::copy_options::overwrite_existing);
    ++n;
  }
  // Without the data folder: the smallest protobuf that passes the pre-check (ir_version 7).
  WriteFile(dir / "edge-ir-version-only.onnx", std::string("\x08\x07", 2));
  ++n;
  return n;
}

AVATAR_FUZZ_TARGET("onnx", RunOnnx, OnnxSeeds);

}  // namespace
}  // namespace avatar::fuzz
