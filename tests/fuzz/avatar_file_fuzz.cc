// Fuzz target "avatar_file": .avatar files (core/pipeline/avatar_file), read as `render` and the
// Studio read them: ReadAvatarFileInfo, then ReadAvatarFile for a session whose model matches
// the file (config and model id taken from the file itself, so that every later check runs).
#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include "core/model/checkpoint.h"
#include "core/pipeline/avatar_file.h"
#include "core/pipeline/avatar_state.h"
#include "core/pipeline/session.h"
#include "core/util/error.h"
#include "fuzz_common.h"

namespace avatar::fuzz {
namespace {

// The expression-source loader of this target: keeps the bytes (the morphable loader is not
// part of the fuzz build; its kind is refused there as unknown).
class BytesSource : public ExpressionImageSource {
 public:
  explicit BytesSource(std::string bytes) : bytes_(std::move(bytes)) {}
  cv::Mat Render(const Expression&, int size) const override { return cv::Mat(size, size, CV_8UC3, cv::Scalar(0)); }
  std::string Kind() const override { return "fuzz-bytes"; }
  std::string Serialize() const override { return bytes_; }
  std::vector<std::string> ControlNames() const override { return {}; }

 private:
  std::string bytes_;
};

std::shared_ptr<const ExpressionImageSource> LoadBytesSource(const std::string& bytes) {
  if (bytes.empty()) throw InvalidInput("empty expression source");
  return std::make_shared<BytesSource>(bytes);
}

const bool kLoader = RegisterExpressionSourceLoader("fuzz-bytes", &LoadBytesSource);

std::string RunAvatarFile(std::string_view input) {
  (void)kLoader;
  const std::filesystem::path file = FreshInputDir() / "portrait.avatar";
  WriteFile(file, WithArchiveChecksum(input));
  const std::string info = AcceptAvatarErrors([&] { (void)ReadAvatarFileInfo(file); });
  const std::string full = AcceptAvatarErrors([&] {
    ModelConfig config = ModelConfig::Tiny();
    std::string model_id = "fuzz";
    const TensorArchive archive = ReadTensorArchive(file, "goha-avatar");
    try {
      config = ModelConfigFromJson(archive.meta.at("config").dump());
      model_id = archive.meta.at("model_id").get<std::string>();
    } catch (const nlohmann::json::exception&) {
      // ReadAvatarFile reports these; keep the defaults.
    } catch (const InvalidOptions&) {
    }
    const auto state = ReadAvatarFile(file, config, model_id);
    if (state->expressions) (void)state->expressions->Serialize();
  });
  return info.empty() ? full : info;
}

int AvatarFileSeeds(const std::filesystem::path& dir) {
  int n = 0;
  for (const bool with_source : {false, true}) {
    AvatarState s;
    s.config = ModelConfig::Tiny();
    s.model_id = "fuzz-seed";
    const int c = s.config.plane_channels;
    const int p = s.config.plane_size();
    s.canonical = torch::linspace(-1, 1, 3 * c * p * p).reshape({1, 3, c, p, p});
    s.appearance = torch::full({1, 3, c, p, p}, 0.25f);
    for (int k = 0; k < 25; ++k) s.camera[k] = 0.1f * static_cast<float>(k);
    s.source = cv::Mat(16, 16, CV_8UC3, cv::Scalar(10, 120, 230));
    if (with_source) {
      s.expressions = std::make_shared<BytesSource>("expression source bytes");
      s.refinement = R"({"steps": 4, "loss": 0.5})";
    }
    const std::string name = with_source ? "tiny-with-source.avatar" : "tiny.avatar";
    WriteAvatarFile(s, dir / name);
    ++n;
  }
  return n;
}

AVATAR_FUZZ_TARGET("avatar_file", RunAvatarFile, AvatarFileSeeds);

}  // namespace
}  // namespace avatar::fuzz
