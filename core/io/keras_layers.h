#pragma once
// A reader for TF.js Keras "layers-model" files as npm packages ship them (nsfwjs): the model
// file is a JavaScript module exporting the object literal {modelTopology, weightsManifest},
// and each weight shard is either raw bytes or a JavaScript module exporting the bytes as one
// base64 string. The reader strips the JavaScript wrapper, turns the object literal into JSON,
// decodes the shards and dequantizes every weight (per-tensor affine uint8/uint16:
// value = q * scale + min) to float32. It builds no network: core/model does that.

#include <filesystem>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include <torch/torch.h>
#include <nlohmann/json.hpp>

namespace avatar::io {

// One layer of the functional Keras model, in topology order.
struct KerasLayer {
  std::string name;                  // e.g. "block_3_depthwise"
  std::string class_name;            // e.g. "DepthwiseConv2D"
  nlohmann::json config;             // the layer's Keras config object
  std::vector<std::string> inbound;  // names of the layers feeding it (first inbound node)
};

struct KerasLayersModel {
  std::filesystem::path path;      // the model file (for messages)
  std::vector<KerasLayer> layers;  // topology order
  // Weights by manifest name ("Conv1/kernel", "bn_Conv1/gamma"...), float32 in Keras layout
  // (Conv2D kernels HWIO, depthwise kernels [kh,kw,in,multiplier]).
  std::map<std::string, torch::Tensor> weights;

  // The layer called `name`, or nullptr.
  const KerasLayer* Find(const std::string& name) const;
  // The weight called `name`; throws ModelLoad naming the file when absent.
  const torch::Tensor& Weight(const std::string& name) const;
};

// Loads a layers model. `model_file` is model.json or a JavaScript module (model.min.js);
// shards are looked up next to it under their manifest path, then with ".min.js" / ".js"
// appended. Throws ModelLoad naming the file (missing, truncated, not a layers model, shard
// size not matching the manifest, unsupported dtype) and pointing at scripts/setup.
KerasLayersModel LoadKerasLayersModel(const std::filesystem::path& model_file);

namespace internal {
// The JSON text of the first object literal (`{` ... matching `}`) or string literal assigned by
// `exports=` in a JavaScript module, or `text` unchanged when it already starts with `{`.
// Handles what minifiers emit: unquoted keys, !0/!1, numbers such as .5 or 5.; throws
// ModelLoad (mentioning `file`) on anything else or when the literal is cut short.
std::string JsLiteralToJson(std::string_view text, const std::string& file);
// Standard base64 (with or without '=' padding); throws ModelLoad mentioning `file` on bad input.
std::vector<uint8_t> DecodeBase64(std::string_view text, const std::string& file);
}  // namespace internal

}  // namespace avatar::io
