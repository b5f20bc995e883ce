#include "core/io/keras_layers.h"

#include <array>
#include <cctype>
#include <cstring>
#include <fstream>
#include <sstream>

#include "core/util/error.h"

namespace avatar::io {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

const char* const kReinstall = "; reinstall the models with scripts/setup";

[[noreturn]] void Fail(const std::string& file, const std::string& what) {
  throw ModelLoad("model " + file + ": " + what + kReinstall);
}

std::string ReadAll(const fs::path& file) {
  std::error_code ec;
  if (!fs::is_regular_file(file, ec)) Fail(file.string(), "file not found");
  std::ifstream in(file, std::ios::binary);
  if (!in) Fail(file.string(), "cannot be opened");
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

bool IsIdentStart(char c) { return std::isalpha(static_cast<unsigned char>(c)) || c == '_' || c == '$'; }
bool IsIdentChar(char c) { return IsIdentStart(c) || std::isdigit(static_cast<unsigned char>(c)); }

// Where the exported literal starts: after "exports=" followed by `first` ('{' or '"').
size_t ExportedLiteral(std::string_view text, char first) {
  static const std::string_view kExports = "exports=";
  for (size_t at = text.find(kExports); at != std::string_view::npos; at = text.find(kExports, at + 1)) {
    const size_t p = at + kExports.size();
    if (p < text.size() && text[p] == first) return p;
  }
  return std::string_view::npos;
}

// Copies a JS string literal starting at text[i] (quote ' or ") as a JSON string; returns the
// index after the closing quote.
size_t CopyString(std::string_view text, size_t i, std::string& out, const std::string& file) {
  const char quote = text[i++];
  out += '"';
  while (true) {
    if (i >= text.size()) Fail(file, "truncated (a string literal is not closed)");
    const char c = text[i];
    if (c == quote) break;
    if (c == '\\') {
      if (i + 1 >= text.size()) Fail(file, "truncated (a string literal is not closed)");
      const char e = text[i + 1];
      if (e == '\'') {
        out += '\'';
      } else {
        out += c;
        out += e;
      }
      i += 2;
      continue;
    }
    if (c == '"') {
      out += "\\\"";
    } else {
      out += c;
    }
    ++i;
  }
  out += '"';
  return i + 1;
}

}  // namespace

namespace internal {

std::string JsLiteralToJson(std::string_view text, const std::string& file) {
  size_t i = 0;
  while (i < text.size() && std::isspace(static_cast<unsigned char>(text[i]))) ++i;
  if (i >= text.size() || (text[i] != '{')) {
    i = ExportedLiteral(text, '{');
    if (i == std::string_view::npos) Fail(file, "not a TF.js layers model (no exported object literal)");
  }
  std::string out;
  out.reserve(text.size() - i);
  int depth = 0;
  while (true) {
    if (i >= text.size()) Fail(file, "truncated (the model literal is not closed)");
    const char c = text[i];
    if (c == '"' || c == '\'') {
      i = CopyString(text, i, out, file);
    } else if (c == '{' || c == '[') {
      ++depth;
      out += c;
      ++i;
    } else if (c == '}' || c == ']') {
      --depth;
      out += c;
      ++i;
      if (depth == 0) break;
    } else if (c == ',' || c == ':') {
      out += c;
      ++i;
    } else if (std::isspace(static_cast<unsigned char>(c))) {
      ++i;
    } else if (c == '!' && i + 1 < text.size() && (text[i + 1] == '0' || text[i + 1] == '1')) {
      out += text[i + 1] == '0' ? "true" : "false";
      i += 2;
    } else if (IsIdentStart(c)) {
      size_t j = i;
      while (j < text.size() && IsIdentChar(text[j])) ++j;
      const std::string_view word = text.substr(i, j - i);
      if (word == "null" || word == "true" || word == "false") {
        out += word;
      } else if (word == "void" && text.substr(j, 2) == " 0") {
        out += "null";
        j += 2;
      } else {
        size_t k = j;
        while (k < text.size() && std::isspace(static_cast<unsigned char>(text[k]))) ++k;
        if (k >= text.size() || text[k] != ':') {
          Fail(file, "not a plain data literal (unexpected '" + std::string(word) + "')");
        }
        out += '"';
        out += word;
        out += '"';
      }
      i = j;
    } else if (c == '-' || c == '+' || c == '.' || std::isdigit(static_cast<unsigned char>(c))) {
      // A JS number; JSON wants a digit on both sides of the point and no leading '+'.
      size_t j = i;
      if (text[j] == '-') {
        out += '-';
        ++j;
      } else if (text[j] == '+') {
        ++j;
      }
      size_t digits = 0;
      while (j < text.size() && std::isdigit(static_cast<unsigned char>(text[j]))) {
        out += text[j++];
        ++digits;
      }
      if (digits == 0) out += '0';
      if (j < text.size() && text[j] == '.') {
        out += '.';
        ++j;
        size_t frac = 0;
        while (j < text.size() && std::isdigit(static_cast<unsigned char>(text[j]))) {
          out += text[j++];
          ++frac;
        }
        if (frac == 0) out += '0';
        if (digits == 0 && frac == 0) Fail(file, "not a plain data literal (bad number)");
      } else if (digits == 0) {
        Fail(file, "not a plain data literal (bad number)");
      }
      if (j < text.size() && (text[j] == 'e' || text[j] == 'E')) {
        out += 'e';
        ++j;
        if (j < text.size() && (text[j] == '-' || text[j] == '+')) out += text[j++];
        size_t exp = 0;
        while (j < text.size() && std::isdigit(static_cast<unsigned char>(text[j]))) {
          out += text[j++];
          ++exp;
        }
        if (exp == 0) Fail(file, "not a plain data literal (bad number)");
      }
      i = j;
    } else {
      Fail(file, std::string("not a plain data literal (unexpected '") + c + "')");
    }
  }
  return out;
}

std::vector<uint8_t> DecodeBase64(std::string_view text, const std::string& file) {
  static const auto kTable = [] {
    std::array<int8_t, 256> t{};
    t.fill(-1);
    const char* alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    for (int k = 0; k < 64; ++k) t[static_cast<unsigned char>(alphabet[k])] = static_cast<int8_t>(k);
    return t;
  }();
  while (!text.empty() && text.back() == '=') text.remove_suffix(1);
  if (text.size() % 4 == 1) Fail(file, "weight data is not valid base64 (bad length)");
  std::vector<uint8_t> out;
  out.reserve(text.size() * 3 / 4);
  uint32_t acc = 0;
  int bits = 0;
  for (const char c : text) {
    const int v = kTable[static_cast<unsigned char>(c)];
    if (v < 0) Fail(file, "weight data is not valid base64");
    acc = (acc << 6) | static_cast<uint32_t>(v);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out.push_back(static_cast<uint8_t>((acc >> bits) & 0xff));
    }
  }
  return out;
}

}  // namespace internal

const KerasLayer* KerasLayersModel::Find(const std::string& name) const {
  for (const auto& l : layers) {
    if (l.name == name) return &l;
  }
  return nullptr;
}

const torch::Tensor& KerasLayersModel::Weight(const std::string& name) const {
  const auto it = weights.find(name);
  if (it == weights.end()) Fail(path.string(), "weight '" + name + "' missing from the manifest");
  return it->second;
}

namespace {

// The bytes of one shard: raw, or a JS module exporting a base64 string.
std::vector<uint8_t> ReadShard(const fs::path& dir, const std::string& name, const std::string& model_file) {
  fs::path file;
  for (const char* suffix : {"", ".min.js", ".js"}) {
    const fs::path candidate = dir / (name + suffix);
    std::error_code ec;
    if (fs::is_regular_file(candidate, ec)) {
      file = candidate;
      break;
    }
  }
  if (file.empty()) Fail((dir / name).string(), "weight shard not found (model " + model_file + ")");
  const std::string bytes = ReadAll(file);
  const size_t start = ExportedLiteral(bytes, '"');
  if (start == std::string::npos) {
    if (file.extension() == ".js") Fail(file.string(), "not a weight shard (no exported base64 string)");
    return {bytes.begin(), bytes.end()};
  }
  const size_t end = bytes.find('"', start + 1);
  if (end == std::string::npos) Fail(file.string(), "truncated (the base64 string is not closed)");
  return internal::DecodeBase64(std::string_view(bytes).substr(start + 1, end - start - 1), file.string());
}

}  // namespace

KerasLayersModel LoadKerasLayersModel(const fs::path& model_file) {
  const std::string file = model_file.string();
  const std::string text = ReadAll(model_file);
  json root;
  try {
    root = json::parse(internal::JsLiteralToJson(text, file));
  } catch (const json::exception& e) {
    Fail(file, std::string("the model literal is not valid JSON (") + e.what() + ")");
  }
  KerasLayersModel model;
  model.path = model_file;
  try {
    if (!root.is_object() || !root.contains("modelTopology") || !root.contains("weightsManifest")) {
      Fail(file, "not a TF.js layers model (no modelTopology / weightsManifest)");
    }
    const json& topology = root["modelTopology"];
    const json* config = nullptr;
    if (topology.is_object() && topology.contains("model_config") && topology["model_config"].is_object() &&
        topology["model_config"].contains("config")) {
      config = &topology["model_config"]["config"];
    } else if (topology.is_object() && topology.contains("config")) {
      config = &topology["config"];
    }
    if (config == nullptr || !config->is_object() || !config->contains("layers") || !(*config)["layers"].is_array()) {
      Fail(file, "not a Keras layers model (no layer list in modelTopology)");
    }
    for (const json& l : (*config)["layers"]) {
      KerasLayer layer;
      layer.name = l.at("name").get<std::string>();
      layer.class_name = l.at("class_name").get<std::string>();
      layer.config = l.at("config");
      const json nodes = l.value("inbound_nodes", json::array());
      if (!nodes.empty() && nodes[0].is_array()) {
        for (const json& in : nodes[0]) layer.inbound.push_back(in.at(0).get<std::string>());
      }
      model.layers.push_back(std::move(layer));
    }
    // All shards of all groups, in manifest order, form one buffer that the weights fill in
    // order (as TF.js reads them).
    std::vector<uint8_t> data;
    std::vector<json> specs;
    std::string shard_names;
    for (const json& group : root["weightsManifest"]) {
      for (const json& p : group.at("paths")) {
        const auto shard = ReadShard(model_file.parent_path(), p.get<std::string>(), file);
        shard_names += " " + (model_file.parent_path() / p.get<std::string>()).string();
        data.insert(data.end(), shard.begin(), shard.end());
      }
      for (const json& w : group.at("weights")) specs.push_back(w);
    }
    size_t offset = 0;
    for (const json& w : specs) {
      const std::string name = w.at("name").get<std::string>();
      const auto shape = w.at("shape").get<std::vector<int64_t>>();
      int64_t count = 1;
      for (const int64_t d : shape) count *= d;
      const std::string dtype = w.at("dtype").get<std::string>();
      if (dtype != "float32") Fail(file, "weight '" + name + "' has unsupported dtype " + dtype);
      torch::Tensor t = torch::empty(shape, torch::kFloat32);
      float* dst = t.data_ptr<float>();
      if (w.contains("quantization")) {
        const json& q = w["quantization"];
        const std::string qtype = q.at("dtype").get<std::string>();
        const size_t width = qtype == "uint8" ? 1 : qtype == "uint16" ? 2 : 0;
        if (width == 0 || !q.contains("min") || !q.contains("scale")) {
          Fail(file, "weight '" + name + "' has unsupported quantization " + q.dump());
        }
        if (offset + count * width > data.size()) {
          Fail(file, "weight data truncated at weight '" + name + "' (shards" + shard_names + ")");
        }
        const float lo = q["min"].get<float>();
        const float scale = q["scale"].get<float>();
        for (int64_t k = 0; k < count; ++k) {
          const uint8_t* b = data.data() + offset + k * width;
          const uint32_t v = width == 1 ? b[0] : static_cast<uint32_t>(b[0] | (b[1] << 8));
          dst[k] = static_cast<float>(v) * scale + lo;
        }
        offset += count * width;
      } else {
        if (offset + count * 4 > data.size()) {
          Fail(file, "weight data truncated at weight '" + name + "' (shards" + shard_names + ")");
        }
        std::memcpy(dst, data.data() + offset, count * 4);
        offset += count * 4;
      }
      model.weights[name] = t;
    }
    if (offset != data.size()) {
      Fail(file, "weight data (shards" + shard_names + ") has " + std::to_string(data.size()) +
                     " bytes but the manifest describes " + std::to_string(offset));
    }
  } catch (const json::exception& e) {
    Fail(file, std::string("malformed layers model (") + e.what() + ")");
  }
  return model;
}

}  // namespace avatar::io
