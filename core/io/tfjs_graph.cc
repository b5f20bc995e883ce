#include "core/io/tfjs_graph.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <functional>
#include <limits>
#include <set>
#include <sstream>
#include <unordered_map>

#include <nlohmann/json.hpp>

#include "core/util/error.h"

namespace avatar::io {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

const char* const kReinstall = "; reinstall the models with scripts/setup";

// The ops this runtime implements, with the graph inputs each needs at least.
const std::map<std::string, int>& OpArity() {
  static const std::map<std::string, int> kOps = {
      {"Placeholder", 0}, {"Const", 0},      {"Identity", 1},     {"Conv2D", 2},
      {"_FusedConv2D", 2}, {"DepthwiseConv2dNative", 2}, {"FusedDepthwiseConv2dNative", 2},
      {"Conv2DBackpropInput", 3}, {"MaxPool", 1}, {"AvgPool", 1}, {"Pad", 2},
      {"PadV2", 3},       {"Reshape", 2},     {"Squeeze", 1},      {"ConcatV2", 2},
      {"ResizeBilinear", 2}, {"Add", 2},      {"AddV2", 2},        {"AddN", 1},
      {"Sub", 2},         {"Mul", 2},         {"RealDiv", 2},      {"Maximum", 2},
      {"Minimum", 2},     {"Abs", 1},         {"Neg", 1},          {"Square", 1},
      {"Sqrt", 1},        {"Rsqrt", 1},       {"Exp", 1},          {"Tanh", 1},
      {"Sum", 2},         {"Mean", 2},        {"Max", 2},          {"Relu", 1},
      {"Relu6", 1},       {"Prelu", 2},       {"Sigmoid", 1},      {"BiasAdd", 2},
      {"MatMul", 2},      {"_FusedMatMul", 2}, {"Softmax", 1},
  };
  return kOps;
}

std::string Base64Decode(const std::string& in) {
  static const std::string kChars = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  uint32_t val = 0;  // unsigned: the bits shifted out on the left are simply dropped
  int bits = -8;
  for (char c : in) {
    const auto pos = kChars.find(c);
    if (pos == std::string::npos) break;  // '=' padding or junk ends the data
    val = (val << 6) + static_cast<uint32_t>(pos);
    bits += 6;
    if (bits >= 0) {
      out.push_back(static_cast<char>((val >> bits) & 0xFF));
      bits -= 8;
    }
  }
  return out;
}

// Attributes of one node, decoded from the GraphDef JSON.
struct Attrs {
  std::string padding;                 // "SAME", "VALID" or "EXPLICIT"
  std::vector<int64_t> strides;        // NHWC
  std::vector<int64_t> ksize;          // NHWC
  std::vector<int64_t> dilations;      // NHWC
  std::vector<int64_t> explicit_paddings;
  std::vector<int64_t> squeeze_dims;
  std::vector<std::string> fused_ops;
  std::string data_format = "NHWC";
  bool align_corners = false;
  bool half_pixel_centers = false;
  bool keep_dims = false;
  bool transpose_a = false;
  bool transpose_b = false;
  float leaky_alpha = 0.2f;
};

struct Node {
  std::string name;
  std::string op;
  std::vector<int> inputs;        // producer node indices (control inputs dropped)
  Attrs attrs;
  torch::Tensor value;            // Const: its tensor (float32 or int64)
  torch::Tensor weight;           // conv kinds with constant filter: torch layout
  std::vector<int64_t> shape;     // Placeholder: declared NHWC shape (-1 unknown)
};

std::vector<int64_t> IntList(const json& attr) {
  std::vector<int64_t> v;
  if (attr.contains("list") && attr["list"].contains("i")) {
    for (const auto& x : attr["list"]["i"]) v.push_back(x.is_string() ? std::stoll(x.get<std::string>()) : x.get<int64_t>());
  }
  return v;
}

int64_t Bytes(const std::string& dtype) {
  if (dtype == "float32" || dtype == "int32") return 4;
  if (dtype == "float16" || dtype == "uint16") return 2;
  if (dtype == "uint8" || dtype == "bool") return 1;
  return -1;
}

std::vector<int64_t> IntValues(const torch::Tensor& t) {
  auto c = t.to(torch::kInt64).contiguous().reshape({-1});
  return std::vector<int64_t>(c.data_ptr<int64_t>(), c.data_ptr<int64_t>() + c.numel());
}

// TF SAME padding for one spatial dimension: {before, after}; the odd pixel goes after.
std::pair<int64_t, int64_t> SamePad(int64_t in, int64_t k, int64_t stride, int64_t dilation) {
  const int64_t out = (in + stride - 1) / stride;
  const int64_t eff = (k - 1) * dilation + 1;
  const int64_t total = std::max<int64_t>((out - 1) * stride + eff - in, 0);
  return {total / 2, total - total / 2};
}

}  // namespace

struct TfjsGraph::Impl {
  fs::path path;
  std::vector<Node> nodes;
  std::unordered_map<std::string, int> index;      // node name -> index
  std::map<std::string, std::string> sig_inputs;   // signature key -> tensor name
  std::map<std::string, std::string> sig_outputs;
  std::vector<int> order;                           // topological order
  std::vector<int> placeholders;

  [[noreturn]] void Fail(const std::string& what) const {
    throw ModelLoad("model " + path.string() + ": " + what + kReinstall);
  }
  [[noreturn]] void FailNode(const Node& n, const std::string& what) const {
    throw ModelLoad("model " + path.string() + ": node '" + n.name + "' (op " + n.op + "): " + what + kReinstall);
  }

  void Load(const fs::path& model_json);
  void LoadWeights(const json& manifest);
  void Prepare(Node& n);
  int Resolve(const std::string& name) const;
  torch::Tensor Exec(const Node& n, const std::vector<torch::Tensor>& in) const;
};

void TfjsGraph::Impl::Load(const fs::path& model_json) {
  path = model_json;
  std::error_code ec;
  if (!fs::is_regular_file(model_json, ec)) Fail("file not found");
  json j;
  try {
    std::ifstream f(model_json);
    if (!f) Fail("cannot open the file");
    j = json::parse(f);
  } catch (const json::exception& e) {
    Fail(std::string("malformed JSON: ") + e.what());
  }
  try {
    if (!j.is_object() || !j.contains("modelTopology") || !j["modelTopology"].is_object() ||
        !j["modelTopology"].contains("node") || !j["modelTopology"]["node"].is_array()) {
      Fail("not a TF.js graph model (no modelTopology.node array)");
    }
    if (!j.contains("weightsManifest") || !j["weightsManifest"].is_array()) Fail("no weightsManifest array");
    // Signature: at the top level or in userDefinedMetadata.
    json sig;
    if (j.contains("signature")) sig = j["signature"];
    else if (j.contains("userDefinedMetadata") && j["userDefinedMetadata"].contains("signature")) sig = j["userDefinedMetadata"]["signature"];
    if (sig.is_object()) {
      for (const char* part : {"inputs", "outputs"}) {
        if (!sig.contains(part) || !sig[part].is_object()) continue;
        auto& dst = std::string(part) == "inputs" ? sig_inputs : sig_outputs;
        for (auto it = sig[part].begin(); it != sig[part].end(); ++it) {
          dst[it.key()] = it.value().is_object() && it.value().contains("name") ? it.value()["name"].get<std::string>() : it.key();
        }
      }
    }
    const auto& jnodes = j["modelTopology"]["node"];
    nodes.reserve(jnodes.size());
    for (const auto& jn : jnodes) {
      Node n;
      if (!jn.is_object() || !jn.contains("name") || !jn.contains("op")) Fail("a node lacks 'name' or 'op'");
      n.name = jn["name"].get<std::string>();
      n.op = jn["op"].get<std::string>();
      if (index.count(n.name)) FailNode(n, "duplicate node name");
      if (!OpArity().count(n.op)) FailNode(n, "unsupported op '" + n.op + "'");
      const json attr = jn.value("attr", json::object());
      auto str = [&](const char* k) { return attr.contains(k) && attr[k].contains("s") ? Base64Decode(attr[k]["s"].get<std::string>()) : std::string(); };
      auto boolean = [&](const char* k) { return attr.contains(k) && attr[k].contains("b") && attr[k]["b"].get<bool>(); };
      n.attrs.padding = str("padding");
      if (attr.contains("data_format")) n.attrs.data_format = str("data_format");
      if (attr.contains("strides")) n.attrs.strides = IntList(attr["strides"]);
      if (attr.contains("ksize")) n.attrs.ksize = IntList(attr["ksize"]);
      if (attr.contains("dilations")) n.attrs.dilations = IntList(attr["dilations"]);
      if (attr.contains("explicit_paddings")) n.attrs.explicit_paddings = IntList(attr["explicit_paddings"]);
      if (attr.contains("squeeze_dims")) n.attrs.squeeze_dims = IntList(attr["squeeze_dims"]);
      if (attr.contains("fused_ops") && attr["fused_ops"].contains("list") && attr["fused_ops"]["list"].contains("s")) {
        for (const auto& s : attr["fused_ops"]["list"]["s"]) n.attrs.fused_ops.push_back(Base64Decode(s.get<std::string>()));
      }
      n.attrs.align_corners = boolean("align_corners");
      n.attrs.half_pixel_centers = boolean("half_pixel_centers");
      n.attrs.keep_dims = boolean("keep_dims");
      n.attrs.transpose_a = boolean("transpose_a");
      n.attrs.transpose_b = boolean("transpose_b");
      if (attr.contains("leakyrelu_alpha") && attr["leakyrelu_alpha"].contains("f")) n.attrs.leaky_alpha = attr["leakyrelu_alpha"]["f"].get<float>();
      if (n.op == "Placeholder" && attr.contains("shape") && attr["shape"].contains("shape")) {
        const auto& sh = attr["shape"]["shape"];
        if (sh.contains("dim")) {
          for (const auto& d : sh["dim"]) {
            const auto& s = d.contains("size") ? d["size"] : json("-1");
            n.shape.push_back(s.is_string() ? std::stoll(s.get<std::string>()) : s.get<int64_t>());
          }
        }
      }
      if (!n.attrs.data_format.empty() && n.attrs.data_format != "NHWC") FailNode(n, "data_format " + n.attrs.data_format + " (only NHWC)");
      index[n.name] = static_cast<int>(nodes.size());
      nodes.push_back(std::move(n));
    }
    // Inputs (second pass: producers may come later in the file).
    for (size_t i = 0; i < jnodes.size(); ++i) {
      Node& n = nodes[i];
      for (const auto& jin : jnodes[i].value("input", json::array())) {
        std::string name = jin.get<std::string>();
        if (!name.empty() && name[0] == '^') continue;  // control dependency
        const auto colon = name.find(':');
        if (colon != std::string::npos) {
          if (name.substr(colon + 1) != "0") FailNode(n, "input '" + name + "' uses a second output (not supported)");
          name = name.substr(0, colon);
        }
        auto it = index.find(name);
        if (it == index.end()) FailNode(n, "input '" + name + "' is not a node of the graph");
        n.inputs.push_back(it->second);
      }
      if (static_cast<int>(n.inputs.size()) < OpArity().at(n.op)) {
        FailNode(n, "has " + std::to_string(n.inputs.size()) + " inputs, needs " + std::to_string(OpArity().at(n.op)));
      }
      if (n.op == "Placeholder") placeholders.push_back(static_cast<int>(i));
    }
    LoadWeights(j["weightsManifest"]);
  } catch (const json::exception& e) {
    Fail(std::string("malformed model JSON: ") + e.what());
  }
  for (const auto& n : nodes) {
    if (n.op == "Const" && !n.value.defined()) FailNode(n, "constant has no entry in weightsManifest");
  }
  // Topological order (Kahn); a cycle is a broken file.
  std::vector<int> pending(nodes.size(), 0);
  std::vector<std::vector<int>> users(nodes.size());
  for (size_t i = 0; i < nodes.size(); ++i) {
    for (int p : nodes[i].inputs) {
      users[p].push_back(static_cast<int>(i));
      ++pending[i];
    }
  }
  std::vector<int> ready;
  for (size_t i = 0; i < nodes.size(); ++i) {
    if (pending[i] == 0) ready.push_back(static_cast<int>(i));
  }
  while (!ready.empty()) {
    const int i = ready.back();
    ready.pop_back();
    order.push_back(i);
    for (int u : users[i]) {
      if (--pending[u] == 0) ready.push_back(u);
    }
  }
  if (order.size() != nodes.size()) Fail("the graph has a cycle");
  for (auto& n : nodes) Prepare(n);
}

void TfjsGraph::Impl::LoadWeights(const json& manifest) {
  for (const auto& group : manifest) {
    if (!group.contains("paths") || !group.contains("weights")) Fail("a weightsManifest group lacks 'paths' or 'weights'");
    std::string data;
    for (const auto& p : group["paths"]) {
      const fs::path shard = path.parent_path() / p.get<std::string>();
      std::ifstream f(shard, std::ios::binary);
      if (!f) Fail("weight shard " + shard.string() + " is missing or unreadable");
      std::ostringstream ss;
      ss << f.rdbuf();
      data += ss.str();
    }
    size_t offset = 0;
    for (const auto& w : group["weights"]) {
      const std::string name = w.at("name").get<std::string>();
      auto it = index.find(name);
      std::vector<int64_t> shape = w.at("shape").get<std::vector<int64_t>>();
      int64_t numel = 1;
      for (int64_t d : shape) {
        if (d < 0) Fail("weight '" + name + "' has a negative dimension");
        numel *= d;
      }
      const std::string dtype = w.at("dtype").get<std::string>();
      std::string stored = dtype;
      const json q = w.value("quantization", json());
      if (q.is_object()) stored = q.at("dtype").get<std::string>();
      const int64_t bytes = Bytes(stored);
      if (bytes < 0) Fail("weight '" + name + "' has unsupported dtype " + stored);
      const size_t size = static_cast<size_t>(numel * bytes);
      if (offset + size > data.size()) {
        Fail("weight shards are too short: weight '" + name + "' needs bytes " + std::to_string(offset) + ".." +
             std::to_string(offset + size) + " but the shards hold " + std::to_string(data.size()));
      }
      const char* ptr = data.data() + offset;
      offset += size;
      torch::Tensor t;
      auto copy = [&](torch::ScalarType st) {
        auto raw = torch::empty({numel}, torch::TensorOptions().dtype(st));
        // A weight with a zero dimension holds no bytes (and an empty tensor has no storage).
        if (size > 0) std::memcpy(raw.data_ptr(), ptr, size);
        return raw;
      };
      if (stored == "float32") t = copy(torch::kFloat32);
      else if (stored == "int32") t = copy(torch::kInt32).to(torch::kInt64);
      else if (stored == "float16") t = copy(torch::kFloat16).to(torch::kFloat32);
      else if (stored == "bool") t = copy(torch::kUInt8).to(torch::kInt64);
      else if (stored == "uint8" || stored == "uint16") {
        if (!q.is_object() || !q.contains("scale") || !q.contains("min")) Fail("weight '" + name + "' is quantized without scale/min");
        auto raw = stored == "uint8" ? copy(torch::kUInt8).to(torch::kFloat32) : copy(torch::kInt16).to(torch::kInt32).bitwise_and(0xFFFF).to(torch::kFloat32);
        t = raw * q["scale"].get<float>() + q["min"].get<float>();
        if (dtype == "int32") t = t.round().to(torch::kInt64);
      } else {
        Fail("weight '" + name + "' has unsupported dtype " + stored);
      }
      t = t.reshape(shape);
      if (it == index.end()) Fail("weight '" + name + "' matches no node");
      nodes[it->second].value = t;
    }
    if (offset != data.size()) {
      Fail("weight shards hold " + std::to_string(data.size()) + " bytes but the manifest describes " + std::to_string(offset));
    }
  }
}

// Converts constant filters to torch's layout once, and checks static attributes.
void TfjsGraph::Impl::Prepare(Node& n) {
  const bool conv = n.op == "Conv2D" || n.op == "_FusedConv2D";
  const bool depthwise = n.op == "DepthwiseConv2dNative" || n.op == "FusedDepthwiseConv2dNative";
  const bool deconv = n.op == "Conv2DBackpropInput";
  if (conv || depthwise || deconv || n.op == "MaxPool" || n.op == "AvgPool") {
    if (n.attrs.padding != "SAME" && n.attrs.padding != "VALID" && !(n.attrs.padding == "EXPLICIT" && n.attrs.explicit_paddings.size() == 8)) {
      FailNode(n, "unsupported padding '" + n.attrs.padding + "'");
    }
    if (n.attrs.strides.size() != 4) FailNode(n, "strides must have 4 entries");
    if ((n.op == "MaxPool" || n.op == "AvgPool") && n.attrs.ksize.size() != 4) FailNode(n, "ksize must have 4 entries");
    if (n.attrs.dilations.empty()) n.attrs.dilations = {1, 1, 1, 1};
    if (n.attrs.dilations.size() != 4) FailNode(n, "dilations must have 4 entries");
  }
  if (n.op == "_FusedConv2D" || n.op == "FusedDepthwiseConv2dNative" || n.op == "_FusedMatMul") {
    const auto& f = n.attrs.fused_ops;
    if (f.empty() || f.size() > 2 || f[0] != "BiasAdd") FailNode(n, "unsupported fused_ops (first must be BiasAdd)");
    if (f.size() == 2) {
      static const std::set<std::string> kAct = {"Relu", "Relu6", "Prelu", "LeakyRelu", "Elu", "Sigmoid"};
      if (!kAct.count(f[1])) FailNode(n, "unsupported fused activation '" + f[1] + "'");
      if (f[1] == "Prelu" && n.inputs.size() < 4) FailNode(n, "fused Prelu without alpha input");
    }
    if (n.inputs.size() < 3) FailNode(n, "fused BiasAdd without bias input");
  }
  if (n.op == "ResizeBilinear" && !n.attrs.half_pixel_centers && !n.attrs.align_corners) {
    FailNode(n, "ResizeBilinear without half_pixel_centers or align_corners is not supported");
  }
  const int filter_input = deconv ? 1 : 1;
  if ((conv || depthwise || deconv) && nodes[n.inputs[filter_input]].op == "Const") {
    const torch::Tensor f = nodes[n.inputs[filter_input]].value;
    if (f.dim() != 4 || !f.is_floating_point()) FailNode(n, "filter must be a 4-D float tensor");
    if (conv) n.weight = f.permute({3, 2, 0, 1}).contiguous();          // HWIO -> [O,I,H,W]
    else if (deconv) n.weight = f.permute({3, 2, 0, 1}).contiguous();   // [H,W,out,in] -> [in,out,H,W]
    else n.weight = f.reshape({f.size(0), f.size(1), f.size(2) * f.size(3)}).permute({2, 0, 1}).unsqueeze(1).contiguous();
  }
}

int TfjsGraph::Impl::Resolve(const std::string& name) const {
  std::string tensor = name;
  if (auto it = sig_outputs.find(name); it != sig_outputs.end()) tensor = it->second;
  else if (auto it2 = sig_inputs.find(name); it2 != sig_inputs.end()) tensor = it2->second;
  const auto colon = tensor.find(':');
  if (colon != std::string::npos) tensor = tensor.substr(0, colon);
  auto it = index.find(tensor);
  if (it == index.end()) throw InvalidInput("model " + path.string() + " has no input or output named '" + name + "'");
  return it->second;
}

namespace {

// x: [N,H,W,C] logical. Pads H and W for a window op; returns the NCHW view and strides.
struct Window {
  torch::Tensor x;  // NCHW view (channels-last memory), padded
  std::vector<int64_t> stride, dilation;
};

Window PadForWindow(const torch::Tensor& nhwc, const Attrs& a, int64_t kh, int64_t kw, double pad_value) {
  Window w;
  w.stride = {a.strides[1], a.strides[2]};
  w.dilation = a.dilations.size() == 4 ? std::vector<int64_t>{a.dilations[1], a.dilations[2]} : std::vector<int64_t>{1, 1};
  torch::Tensor x = nhwc.permute({0, 3, 1, 2});
  int64_t t = 0, b = 0, l = 0, r = 0;
  if (a.padding == "SAME") {
    std::tie(t, b) = SamePad(x.size(2), kh, w.stride[0], w.dilation[0]);
    std::tie(l, r) = SamePad(x.size(3), kw, w.stride[1], w.dilation[1]);
  } else if (a.padding == "EXPLICIT") {
    t = a.explicit_paddings[2]; b = a.explicit_paddings[3];
    l = a.explicit_paddings[4]; r = a.explicit_paddings[5];
  }
  if (t || b || l || r) x = torch::constant_pad_nd(x, {l, r, t, b}, pad_value);
  w.x = x;
  return w;
}

torch::Tensor Activate(const std::string& act, const torch::Tensor& x, const torch::Tensor& alpha, float leaky) {
  if (act == "Relu") return torch::relu(x);
  if (act == "Relu6") return torch::clamp(x, 0.0, 6.0);
  if (act == "Prelu") return torch::where(x < 0, x * alpha, x);
  if (act == "LeakyRelu") return torch::where(x < 0, x * leaky, x);
  if (act == "Elu") return torch::elu(x);
  if (act == "Sigmoid") return torch::sigmoid(x);
  return x;
}

}  // namespace

torch::Tensor TfjsGraph::Impl::Exec(const Node& n, const std::vector<torch::Tensor>& in) const {
  const std::string& op = n.op;
  const Attrs& a = n.attrs;
  if (op == "Identity") return in[0];
  if (op == "Conv2D" || op == "_FusedConv2D" || op == "DepthwiseConv2dNative" || op == "FusedDepthwiseConv2dNative") {
    const bool depthwise = op.find("Depthwise") != std::string::npos;
    const torch::Tensor& x = in[0];
    if (x.dim() != 4) FailNode(n, "input must be 4-D NHWC");
    const torch::Tensor& f = in[1];
    torch::Tensor w = n.weight.defined() ? n.weight
                      : depthwise ? f.reshape({f.size(0), f.size(1), f.size(2) * f.size(3)}).permute({2, 0, 1}).unsqueeze(1).contiguous()
                                  : f.permute({3, 2, 0, 1}).contiguous();
    const int64_t in_ch = depthwise ? f.size(2) : f.size(2);
    if (x.size(3) != in_ch) FailNode(n, "input has " + std::to_string(x.size(3)) + " channels, filter expects " + std::to_string(in_ch));
    Window win = PadForWindow(x, a, f.size(0), f.size(1), 0.0);
    const bool fused = op[0] == '_' || op.rfind("Fused", 0) == 0;
    torch::Tensor bias;
    if (fused) bias = in[2].reshape({-1});
    torch::Tensor y = torch::conv2d(win.x, w, bias, win.stride, torch::IntArrayRef({0, 0}), win.dilation, depthwise ? in_ch : 1);
    y = y.permute({0, 2, 3, 1});
    if (fused && a.fused_ops.size() == 2) y = Activate(a.fused_ops[1], y, in.size() > 3 ? in[3] : torch::Tensor(), a.leaky_alpha);
    return y;
  }
  if (op == "Conv2DBackpropInput") {
    const auto sizes = IntValues(in[0]);  // output NHWC
    const torch::Tensor& f = in[1];       // [kh,kw,out,in]
    const torch::Tensor& dy = in[2];      // [N,h,w,in]
    if (sizes.size() != 4 || dy.dim() != 4) FailNode(n, "bad input_sizes or input rank");
    torch::Tensor w = n.weight.defined() ? n.weight : f.permute({3, 2, 0, 1}).contiguous();
    const int64_t sh = a.strides[1], sw = a.strides[2];
    torch::Tensor full = torch::conv_transpose2d(dy.permute({0, 3, 1, 2}), w, {}, {sh, sw});
    int64_t t = 0, l = 0;
    if (a.padding == "SAME") {
      t = SamePad(sizes[1], f.size(0), sh, 1).first;
      l = SamePad(sizes[2], f.size(1), sw, 1).first;
    }
    // Negative padding crops: keep rows t..t+H-1 of the full result (zeros past its end).
    full = torch::constant_pad_nd(full, {-l, sizes[2] + l - full.size(3), -t, sizes[1] + t - full.size(2)}, 0.0);
    return full.permute({0, 2, 3, 1});
  }
  if (op == "MaxPool" || op == "AvgPool") {
    const int64_t kh = a.ksize[1], kw = a.ksize[2];
    if (op == "MaxPool") {
      Window win = PadForWindow(in[0], a, kh, kw, -std::numeric_limits<double>::infinity());
      return torch::max_pool2d(win.x, {kh, kw}, win.stride).permute({0, 2, 3, 1});
    }
    Window win = PadForWindow(in[0], a, kh, kw, 0.0);
    torch::Tensor sum = torch::avg_pool2d(win.x, {kh, kw}, win.stride);
    if (a.padding == "VALID") return sum.permute({0, 2, 3, 1});
    // TF averages only over real pixels: divide by the pooled share of valid positions.
    auto ones = torch::ones({1, in[0].size(1), in[0].size(2), 1}, in[0].options());
    Window mask = PadForWindow(ones, a, kh, kw, 0.0);
    return (sum / torch::avg_pool2d(mask.x, {kh, kw}, mask.stride)).permute({0, 2, 3, 1});
  }
  if (op == "Pad" || op == "PadV2") {
    const auto p = IntValues(in[1]);
    const int64_t rank = in[0].dim();
    if (static_cast<int64_t>(p.size()) != 2 * rank) FailNode(n, "paddings do not match the input rank");
    std::vector<int64_t> tp;
    for (int64_t d = rank - 1; d >= 0; --d) {
      tp.push_back(p[2 * d]);
      tp.push_back(p[2 * d + 1]);
    }
    const double value = op == "PadV2" ? in[2].item<double>() : 0.0;
    return torch::constant_pad_nd(in[0], tp, value);
  }
  if (op == "Reshape") {
    try {
      return in[0].reshape(IntValues(in[1]));
    } catch (const c10::Error&) {
      FailNode(n, "cannot reshape " + std::to_string(in[0].numel()) + " values");
    }
  }
  if (op == "Squeeze") {
    torch::Tensor x = in[0];
    if (a.squeeze_dims.empty()) return x.squeeze();
    std::vector<int64_t> dims = a.squeeze_dims;
    for (auto& d : dims) d = d < 0 ? d + x.dim() : d;
    std::sort(dims.rbegin(), dims.rend());
    for (int64_t d : dims) x = x.squeeze(d);
    return x;
  }
  if (op == "ConcatV2") {
    std::vector<torch::Tensor> parts(in.begin(), in.end() - 1);
    return torch::cat(parts, in.back().item<int64_t>());
  }
  if (op == "ResizeBilinear") {
    const auto size = IntValues(in[1]);
    torch::Tensor x = in[0].permute({0, 3, 1, 2});
    return torch::upsample_bilinear2d(x, std::vector<int64_t>{size[0], size[1]}, a.align_corners).permute({0, 2, 3, 1});
  }
  if (op == "Add" || op == "AddV2" || op == "BiasAdd") return in[0] + in[1];
  if (op == "AddN") {
    torch::Tensor s = in[0];
    for (size_t i = 1; i < in.size(); ++i) s = s + in[i];
    return s;
  }
  if (op == "Sub") return in[0] - in[1];
  if (op == "Mul") return in[0] * in[1];
  if (op == "RealDiv") return in[0] / in[1];
  if (op == "Maximum") return torch::maximum(in[0], in[1]);
  if (op == "Minimum") return torch::minimum(in[0], in[1]);
  if (op == "Abs") return in[0].abs();
  if (op == "Neg") return -in[0];
  if (op == "Square") return in[0] * in[0];
  if (op == "Sqrt") return in[0].sqrt();
  if (op == "Rsqrt") return in[0].rsqrt();
  if (op == "Exp") return in[0].exp();
  if (op == "Tanh") return in[0].tanh();
  if (op == "Relu" || op == "Relu6" || op == "Sigmoid") return Activate(op, in[0], {}, 0.f);
  if (op == "Prelu") return torch::where(in[0] < 0, in[0] * in[1], in[0]);
  if (op == "Sum" || op == "Mean" || op == "Max") {
    auto axes = IntValues(in[1]);
    if (axes.empty()) return in[0];
    if (op == "Sum") return in[0].sum(axes, a.keep_dims);
    if (op == "Mean") return in[0].mean(axes, a.keep_dims);
    torch::Tensor x = in[0];
    for (auto& d : axes) d = d < 0 ? d + x.dim() : d;
    std::sort(axes.rbegin(), axes.rend());
    for (int64_t d : axes) x = std::get<0>(x.max(d, a.keep_dims));
    return x;
  }
  if (op == "MatMul" || op == "_FusedMatMul") {
    torch::Tensor x = a.transpose_a ? in[0].t() : in[0];
    torch::Tensor y = a.transpose_b ? in[1].t() : in[1];
    torch::Tensor r = torch::matmul(x, y);
    if (op == "_FusedMatMul") {
      r = r + in[2];
      if (a.fused_ops.size() == 2) r = Activate(a.fused_ops[1], r, in.size() > 3 ? in[3] : torch::Tensor(), a.leaky_alpha);
    }
    return r;
  }
  if (op == "Softmax") return torch::softmax(in[0], -1);
  FailNode(n, "op has no implementation");
}

TfjsGraph::TfjsGraph(const fs::path& model_json) : impl_(std::make_unique<Impl>()) {
  try {
    impl_->Load(model_json);
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw ModelLoad("model " + model_json.string() + ": " + e.what() + kReinstall);
  }
}
TfjsGraph::~TfjsGraph() = default;
TfjsGraph::TfjsGraph(TfjsGraph&&) noexcept = default;
TfjsGraph& TfjsGraph::operator=(TfjsGraph&&) noexcept = default;

std::vector<torch::Tensor> TfjsGraph::Run(const std::map<std::string, torch::Tensor>& inputs,
                                          const std::vector<std::string>& outputs) const {
  const Impl& g = *impl_;
  torch::InferenceMode guard;
  std::vector<torch::Tensor> values(g.nodes.size());
  std::vector<char> needed(g.nodes.size(), 0);
  std::vector<int> wanted;
  for (const auto& name : outputs) wanted.push_back(g.Resolve(name));
  std::vector<int> stack = wanted;
  while (!stack.empty()) {
    const int i = stack.back();
    stack.pop_back();
    if (needed[i]) continue;
    needed[i] = 1;
    for (int p : g.nodes[i].inputs) stack.push_back(p);
  }
  for (const auto& [name, tensor] : inputs) {
    const int i = g.Resolve(name);
    const Node& n = g.nodes[i];
    if (n.op != "Placeholder") throw InvalidInput("model " + g.path.string() + ": '" + name + "' is not an input");
    if (!n.shape.empty()) {
      bool ok = tensor.dim() == static_cast<int64_t>(n.shape.size());
      for (size_t d = 0; ok && d < n.shape.size(); ++d) ok = n.shape[d] < 0 || n.shape[d] == tensor.size(d);
      if (!ok) {
        std::ostringstream msg;
        msg << "model " << g.path.string() << ": input '" << name << "' has shape " << tensor.sizes() << ", expected [";
        for (size_t d = 0; d < n.shape.size(); ++d) msg << (d ? "," : "") << n.shape[d];
        msg << "]";
        throw InvalidInput(msg.str());
      }
    }
    values[i] = tensor.to(torch::kFloat32);
  }
  // Last use of each value, to free activations early.
  std::vector<int> remaining(g.nodes.size(), 0);
  for (int i : g.order) {
    if (!needed[i]) continue;
    for (int p : g.nodes[i].inputs) ++remaining[p];
  }
  for (int i : wanted) ++remaining[i];
  for (int i : g.order) {
    if (!needed[i]) continue;
    const Node& n = g.nodes[i];
    if (n.op == "Placeholder") {
      if (!values[i].defined()) throw InvalidInput("model " + g.path.string() + ": input '" + n.name + "' was not given");
      continue;
    }
    if (n.op == "Const") {
      values[i] = n.value;
      continue;
    }
    std::vector<torch::Tensor> in;
    in.reserve(n.inputs.size());
    for (int p : n.inputs) in.push_back(values[p]);
    try {
      values[i] = g.Exec(n, in);
    } catch (const Error&) {
      throw;
    } catch (const std::exception& e) {
      g.FailNode(n, std::string("execution failed: ") + e.what());
    }
    for (int p : n.inputs) {
      if (--remaining[p] == 0 && g.nodes[p].op != "Const") values[p] = torch::Tensor();
    }
  }
  std::vector<torch::Tensor> out;
  for (int i : wanted) out.push_back(values[i].contiguous());
  return out;
}

std::vector<torch::Tensor> TfjsGraph::Run(const torch::Tensor& input, const std::vector<std::string>& outputs) const {
  AVATAR_CHECK_AS(ModelLoad, !impl_->placeholders.empty()) << "model " << impl_->path.string() << " has no input";
  return Run({{impl_->nodes[impl_->placeholders.front()].name, input}}, outputs);
}

const fs::path& TfjsGraph::Path() const { return impl_->path; }

std::vector<std::string> TfjsGraph::InputNames() const {
  std::vector<std::string> names;
  for (int i : impl_->placeholders) names.push_back(impl_->nodes[i].name);
  return names;
}

std::vector<int64_t> TfjsGraph::InputShape(const std::string& name) const { return impl_->nodes[impl_->Resolve(name)].shape; }

std::vector<std::string> TfjsGraph::SignatureOutputs() const {
  std::vector<std::string> keys;
  for (const auto& [k, v] : impl_->sig_outputs) keys.push_back(k);
  return keys;
}

std::vector<std::string> TfjsGraph::Ops() const {
  std::set<std::string> ops;
  for (const auto& n : impl_->nodes) ops.insert(n.op);
  return {ops.begin(), ops.end()};
}

std::vector<std::string> TfjsGraph::SupportedOps() {
  std::vector<std::string> ops;
  for (const auto& [k, v] : OpArity()) ops.push_back(k);
  return ops;
}

}  // namespace avatar::io
