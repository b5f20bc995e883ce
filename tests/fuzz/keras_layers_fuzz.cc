// Fuzz target "keras_layers": TF.js Keras layers models as the nsfwjs npm package ships them
// (a JavaScript module or model.json, plus raw or base64-in-JavaScript weight shards), read by
// core/io/keras_layers LoadKerasLayersModel. Input: a MultiFile (fuzz_common.h), the model
// file first (named model.min.js), then the shards under their names.
#include <nlohmann/json.hpp>

#include "core/io/keras_layers.h"
#include "core/util/error.h"
#include "fuzz_common.h"

namespace avatar::fuzz {
namespace {

std::string RunKerasLayers(std::string_view input) {
  const std::filesystem::path model = WriteParts(FreshInputDir(), SplitParts(input, "model.min.js"));
  return AcceptAvatarErrors([&] {
    const io::KerasLayersModel m = io::LoadKerasLayersModel(model);
    for (const auto& [name, tensor] : m.weights) (void)tensor.sum().item<float>();
    if (!m.layers.empty()) (void)m.Find(m.layers.front().name);
  });
}

std::string Base64(const std::string& bytes) {
  static const char* kAlphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const uint32_t v = (static_cast<uint8_t>(bytes[i]) << 16) | (static_cast<uint8_t>(bytes[i + 1]) << 8) |
                       static_cast<uint8_t>(bytes[i + 2]);
    for (int s : {18, 12, 6, 0}) out += kAlphabet[(v >> s) & 63];
  }
  if (i + 1 == bytes.size()) {
    const uint32_t v = static_cast<uint8_t>(bytes[i]) << 16;
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += "==";
  } else if (i + 2 == bytes.size()) {
    const uint32_t v = (static_cast<uint8_t>(bytes[i]) << 16) | (static_cast<uint8_t>(bytes[i + 1]) << 8);
    for (int s : {18, 12, 6}) out += kAlphabet[(v >> s) & 63];
    out += "=";
  }
  return out;
}

int KerasLayersSeeds(const std::filesystem::path& dir) {
  using nlohmann::json;
  int n = 0;
  // A two-layer model made here: float32 kernel, uint8- and uint16-quantized biases.
  const json layers = json::array(
      {{{"name", "input_1"}, {"class_name", "InputLayer"}, {"config", {{"batch_input_shape", {nullptr, 4}}}},
        {"inbound_nodes", json::array()}},
       {{"name", "dense"}, {"class_name", "Dense"}, {"config", {{"units", 2}, {"activation", "relu"}}},
        {"inbound_nodes", {{{"input_1", 0, 0, json::object()}}}}}});
  const json manifest = json::array(
      {{{"paths", {"group1-shard1of1"}},
        {"weights",
         {{{"name", "dense/kernel"}, {"shape", {4, 2}}, {"dtype", "float32"}},
          {{"name", "dense/bias"}, {"shape", {2}}, {"dtype", "float32"},
           {"quantization", {{"dtype", "uint8"}, {"min", -1.0}, {"scale", 0.01}}}},
          {{"name", "dense/extra"}, {"shape", {1, 2}}, {"dtype", "float32"},
           {"quantization", {{"dtype", "uint16"}, {"min", 0.5}, {"scale", 0.001}}}}}}}});
  const json model = {{"modelTopology", {{"class_name", "Model"}, {"config", {{"name", "tiny"}, {"layers", layers}}}}},
                      {"weightsManifest", manifest}};
  std::string shard;
  for (int k = 0; k < 8; ++k) {
    const float v = 0.25f * static_cast<float>(k) - 1.0f;
    shard.append(reinterpret_cast<const char*>(&v), sizeof v);
  }
  shard += std::string("\x10\xf0", 2);
  shard += std::string("\x01\x02\x03\x04", 4);
  WriteFile(dir / "tiny-json-raw", JoinParts({{"model.min.js", model.dump()}, {"group1-shard1of1", shard}}));
  ++n;
  // The same as minified JavaScript modules (the nsfwjs form): the loader strips the wrapper.
  std::string js = "module.exports=" + model.dump() + ";";
  WriteFile(dir / "tiny-js-base64",
            JoinParts({{"model.min.js", js},
                       {"group1-shard1of1.min.js", "module.exports=\"" + Base64(shard) + "\";"}}));
  ++n;
  // The nsfwjs model of the data folder (scripts/setup).
  const std::filesystem::path nsfw = DataDir() / "models" / "nsfwjs";
  std::error_code ec;
  if (!DataDir().empty() && std::filesystem::is_regular_file(nsfw / "model.min.js", ec)) {
    WriteFile(dir / "nsfwjs", JoinParts({{"model.min.js", ReadFile(nsfw / "model.min.js")},
                                         {"group1-shard1of1.min.js", ReadFile(nsfw / "group1-shard1of1.min.js")}}));
    ++n;
  }
  return n;
}

AVATAR_FUZZ_TARGET("keras_layers", RunKerasLayers, KerasLayersSeeds);

}  // namespace
}  // namespace avatar::fuzz
