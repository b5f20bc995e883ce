// TF.js graph runtime: outputs against TensorFlow.js goldens (scripts/goldens), op semantics
// against hand-computed values, and clean ModelLoad errors for broken model files.
#include "core/io/tfjs_graph.h"

#include <algorithm>
#include <cstdint>
#include <fstream>
#include <iostream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "common/temp_dir.h"
#include "core/io/data_paths.h"
#include "core/util/error.h"

namespace avatar::io {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

fs::path GoldenDir() { return fs::path(AVATAR_BINARY_DIR) / "goldens"; }

fs::path ModelsDir() {
  return DataPaths::Resolve().Require("models/facemesh.json", "TF.js face models").parent_path();
}

torch::Tensor ReadF32(const fs::path& file, const std::vector<int64_t>& shape) {
  std::ifstream in(file, std::ios::binary);
  EXPECT_TRUE(in.good()) << "missing golden file " << file << "; the face/goldens fixture regenerates it";
  auto t = torch::zeros(shape, torch::kFloat32);
  in.read(reinterpret_cast<char*>(t.data_ptr<float>()), t.numel() * 4);
  EXPECT_EQ(in.gcount(), t.numel() * 4) << file;
  return t;
}

json Manifest() {
  const fs::path m = GoldenDir() / "manifest.json";
  if (!fs::exists(m)) {
    ADD_FAILURE() << "no goldens at " << m << ": run `ctest -L io` (its fixture face/goldens runs "
                  << "scripts/goldens/make_goldens.sh; it needs node from scripts/setup)";
    return json();
  }
  std::ifstream in(m);
  return json::parse(in);
}

class TfjsGolden : public ::testing::TestWithParam<std::string> {};

TEST_P(TfjsGolden, MatchesTensorFlowJs) {
  const json manifest = Manifest();
  ASSERT_TRUE(manifest.is_object());
  const json* entry = nullptr;
  for (const auto& m : manifest["models"]) {
    if (m["name"] == GetParam()) entry = &m;
  }
  ASSERT_NE(entry, nullptr) << "golden manifest lacks model " << GetParam();
  TfjsGraph graph(ModelsDir() / (*entry)["model"].get<std::string>());
  std::map<std::string, torch::Tensor> inputs;
  for (const auto& in : (*entry)["inputs"]) {
    inputs[in["name"]] = ReadF32(GoldenDir() / in["file"].get<std::string>(), in["shape"].get<std::vector<int64_t>>());
  }
  std::vector<std::string> names;
  for (const auto& out : (*entry)["outputs"]) names.push_back(out["name"]);
  const auto outputs = graph.Run(inputs, names);
  ASSERT_EQ(outputs.size(), names.size());
  double worst = 0.0;
  for (size_t i = 0; i < names.size(); ++i) {
    const auto& o = (*entry)["outputs"][i];
    const auto shape = o["shape"].get<std::vector<int64_t>>();
    const auto ref = ReadF32(GoldenDir() / o["file"].get<std::string>(), shape);
    ASSERT_EQ(outputs[i].sizes().vec(), shape) << names[i];
    ASSERT_TRUE(torch::isfinite(outputs[i]).all().item<bool>()) << names[i];
    const double err = (outputs[i] - ref).abs().max().item<double>();
    const double scale = ref.abs().max().item<double>();
    std::cout << "[golden] " << GetParam() << " " << names[i] << ": max abs error " << err << " (max |ref| " << scale
              << ")\n";
    RecordProperty(names[i] + "_max_abs_error", std::to_string(err));
    // 1e-3 absolute, or float32 rounding of outputs that reach the thousands (box regressors
    // of up to ~1200 px): the sum order differs between TF.js and LibTorch and with the thread count.
    const double tolerance = std::max(1e-3, 5e-6 * scale);
    EXPECT_LT(err, tolerance) << GetParam() << " output " << names[i] << " (max |ref| " << scale << ")";
    worst = std::max(worst, err);
  }
  std::cout << "[golden] " << GetParam() << ": worst max abs error " << worst << "\n";
}

INSTANTIATE_TEST_SUITE_P(Models, TfjsGolden,
                         ::testing::Values("blazeface-front", "blazeface-back", "facemesh", "selfie", "mobilefacenet"),
                         [](const auto& info) {
                           std::string s = info.param;
                           for (auto& c : s) c = std::isalnum(static_cast<unsigned char>(c)) ? c : '_';
                           return s;
                         });

// ---- Small hand-written graphs: op semantics and error paths. ----

std::string B64(const std::string& s) {
  static const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  uint32_t val = 0;  // kept to its low 24 bits (the most ever read): unsigned, so no shift overflows
  int bits = -6;
  for (unsigned char c : s) {
    val = ((val << 8) | c) & 0xFFFFFFu;
    bits += 8;
    while (bits >= 0) {
      out.push_back(k[(val >> bits) & 0x3F]);
      bits -= 6;
    }
  }
  if (bits > -6) out.push_back(k[((val << 8) >> (bits + 8)) & 0x3F]);
  while (out.size() % 4) out.push_back('=');
  return out;
}

json Ints(std::vector<int> v) {
  json l = json::array();
  for (int x : v) l.push_back(std::to_string(x));
  return {{"list", {{"i", l}}}};
}

// A graph: input [1,H,W,C] -> op with a constant filter -> output "out".
struct Builder {
  json nodes = json::array();
  json weights = json::array();
  std::string bin;

  void Input(const std::string& name, std::vector<int> shape) {
    json dims = json::array();
    for (int d : shape) dims.push_back({{"size", std::to_string(d)}});
    nodes.push_back({{"name", name}, {"op", "Placeholder"}, {"attr", {{"shape", {{"shape", {{"dim", dims}}}}}}}});
  }
  void Const(const std::string& name, const std::vector<float>& values, std::vector<int> shape) {
    nodes.push_back({{"name", name}, {"op", "Const"}});
    weights.push_back({{"name", name}, {"shape", shape}, {"dtype", "float32"}});
    bin.append(reinterpret_cast<const char*>(values.data()), values.size() * 4);
  }
  void ConstInt(const std::string& name, const std::vector<int32_t>& values, std::vector<int> shape) {
    nodes.push_back({{"name", name}, {"op", "Const"}});
    weights.push_back({{"name", name}, {"shape", shape}, {"dtype", "int32"}});
    bin.append(reinterpret_cast<const char*>(values.data()), values.size() * 4);
  }
  void Op(const std::string& name, const std::string& op, std::vector<std::string> inputs, json attr = json::object()) {
    nodes.push_back({{"name", name}, {"op", op}, {"input", inputs}, {"attr", attr}});
  }
  fs::path Write(const fs::path& dir, const std::string& stem = "m") const {
    json model = {{"format", "graph-model"},
                  {"modelTopology", {{"node", nodes}}},
                  {"weightsManifest", json::array({{{"paths", {stem + ".bin"}}, {"weights", weights}}})}};
    std::ofstream(dir / (stem + ".json")) << model.dump();
    std::ofstream(dir / (stem + ".bin"), std::ios::binary) << bin;
    return dir / (stem + ".json");
  }
};

TEST(TfjsGraphOps, SamePaddingIsAsymmetricLikeTensorFlow) {
  // 1x4x4x1 input, 2x2 all-ones filter, stride 2, SAME: TF pads 0 before and 0 after (4 = 2*2),
  // for a 3x3 filter with stride 2: total pad 1, all of it after (bottom/right).
  testing::TempDir dir;
  Builder b;
  b.Input("x", {1, 4, 4, 1});
  b.Const("w", std::vector<float>(9, 1.0f), {3, 3, 1, 1});
  b.Op("out", "Conv2D", {"x", "w"}, {{"padding", {{"s", B64("SAME")}}}, {"strides", Ints({1, 2, 2, 1})}});
  TfjsGraph g(b.Write(dir.path()));
  auto x = torch::arange(16, torch::kFloat32).reshape({1, 4, 4, 1});
  auto y = g.Run(x, {"out"})[0];
  ASSERT_EQ(y.sizes().vec(), (std::vector<int64_t>{1, 2, 2, 1}));
  // Output (0,0): window rows 0..2, cols 0..2 (no padding before).
  float expect00 = 0;
  for (int r = 0; r < 3; ++r) for (int c = 0; c < 3; ++c) expect00 += r * 4 + c;
  // Output (1,1): rows 2..3, cols 2..3 (row/col 4 is padding).
  float expect11 = 10 + 11 + 14 + 15;
  EXPECT_FLOAT_EQ(y[0][0][0][0].item<float>(), expect00);
  EXPECT_FLOAT_EQ(y[0][1][1][0].item<float>(), expect11);
}

TEST(TfjsGraphOps, DepthwiseMultiplierLayout) {
  // Depthwise filter [1,1,2,2]: output channel c*2+m = x[c] * f[c][m].
  testing::TempDir dir;
  Builder b;
  b.Input("x", {1, 1, 1, 2});
  b.Const("w", {1, 2, 3, 4}, {1, 1, 2, 2});
  b.Op("out", "DepthwiseConv2dNative", {"x", "w"}, {{"padding", {{"s", B64("VALID")}}}, {"strides", Ints({1, 1, 1, 1})}});
  TfjsGraph g(b.Write(dir.path()));
  auto y = g.Run(torch::tensor({10.0f, 100.0f}).reshape({1, 1, 1, 2}), {"out"})[0].reshape({-1});
  EXPECT_FLOAT_EQ(y[0].item<float>(), 10);
  EXPECT_FLOAT_EQ(y[1].item<float>(), 20);
  EXPECT_FLOAT_EQ(y[2].item<float>(), 300);
  EXPECT_FLOAT_EQ(y[3].item<float>(), 400);
}

TEST(TfjsGraphOps, ResizeHalfPixelAndChannelPad) {
  // Upsampling [0, 4] to width 4 with half-pixel centres: 0, 1, 3, 4.
  testing::TempDir dir;
  Builder b;
  b.Input("x", {1, 1, 2, 1});
  b.ConstInt("size", {1, 4}, {2});
  b.ConstInt("pads", {0, 0, 0, 0, 0, 0, 1, 2}, {4, 2});
  b.Op("r", "ResizeBilinear", {"x", "size"}, {{"half_pixel_centers", {{"b", true}}}});
  b.Op("out", "Pad", {"r", "pads"});
  TfjsGraph g(b.Write(dir.path()));
  auto y = g.Run(torch::tensor({0.0f, 4.0f}).reshape({1, 1, 2, 1}), {"out"})[0];
  ASSERT_EQ(y.sizes().vec(), (std::vector<int64_t>{1, 1, 4, 4}));
  const float expect[] = {0, 1, 3, 4};
  for (int i = 0; i < 4; ++i) {
    EXPECT_FLOAT_EQ(y[0][0][i][1].item<float>(), expect[i]);
    EXPECT_FLOAT_EQ(y[0][0][i][0].item<float>(), 0.0f);
    EXPECT_FLOAT_EQ(y[0][0][i][3].item<float>(), 0.0f);
  }
}

TEST(TfjsGraphOps, QuantizedWeightsDecode) {
  // uint8 affine (value = q * scale + min) and float16 weights, added to the input.
  testing::TempDir dir;
  Builder b;
  b.Input("x", {1, 1, 1, 3});
  b.nodes.push_back({{"name", "q8"}, {"op", "Const"}});
  b.weights.push_back({{"name", "q8"}, {"shape", {3}}, {"dtype", "float32"},
                       {"quantization", {{"dtype", "uint8"}, {"scale", 0.5}, {"min", -1.0}}}});
  b.bin += std::string("\x00\x02\xff", 3);  // -> -1, 0, 126.5
  b.nodes.push_back({{"name", "h16"}, {"op", "Const"}});
  b.weights.push_back({{"name", "h16"}, {"shape", {3}}, {"dtype", "float32"}, {"quantization", {{"dtype", "float16"}}}});
  const torch::Tensor half = torch::tensor({0.25f, -2.0f, 1000.0f}).to(torch::kHalf);
  b.bin.append(reinterpret_cast<const char*>(half.data_ptr()), 6);
  b.Op("a", "AddV2", {"x", "q8"});
  b.Op("out", "AddV2", {"a", "h16"});
  TfjsGraph g(b.Write(dir.path()));
  auto y = g.Run(torch::zeros({1, 1, 1, 3}), {"out"})[0].reshape({-1});
  EXPECT_FLOAT_EQ(y[0].item<float>(), -1.0f + 0.25f);
  EXPECT_FLOAT_EQ(y[1].item<float>(), 0.0f - 2.0f);
  EXPECT_FLOAT_EQ(y[2].item<float>(), 126.5f + 1000.0f);
}

// Expects ModelLoad whose message contains every one of `parts`.
void ExpectModelLoad(const fs::path& file, const std::vector<std::string>& parts) {
  try {
    TfjsGraph g(file);
    ADD_FAILURE() << "no error for " << file;
  } catch (const ModelLoad& e) {
    const std::string msg = e.what();
    for (const auto& p : parts) EXPECT_NE(msg.find(p), std::string::npos) << "'" << p << "' not in: " << msg;
  }
}

Builder SimpleConv() {
  Builder b;
  b.Input("x", {1, 4, 4, 1});
  b.Const("w", std::vector<float>(4, 1.0f), {2, 2, 1, 1});
  b.Op("out", "Conv2D", {"x", "w"}, {{"padding", {{"s", B64("SAME")}}}, {"strides", Ints({1, 1, 1, 1})}});
  return b;
}

TEST(TfjsGraphErrors, UnsupportedOpNamesModelNodeAndOp) {
  testing::TempDir dir;
  Builder b = SimpleConv();
  b.Op("weird", "FFT2D", {"out"});
  ExpectModelLoad(b.Write(dir.path()), {"m.json", "weird", "FFT2D", "scripts/setup"});
}

TEST(TfjsGraphErrors, MissingShard) {
  testing::TempDir dir;
  const auto file = SimpleConv().Write(dir.path());
  fs::remove(dir / "m.bin");
  ExpectModelLoad(file, {"m.json", "m.bin", "missing"});
}

TEST(TfjsGraphErrors, ShortAndLongShards) {
  testing::TempDir dir;
  Builder b = SimpleConv();
  b.bin.resize(b.bin.size() - 3);
  ExpectModelLoad(b.Write(dir.path()), {"too short", "'w'"});
  Builder c = SimpleConv();
  c.bin += "extra";
  ExpectModelLoad(c.Write(dir.path(), "n"), {"n.json", "bytes"});
}

TEST(TfjsGraphErrors, MalformedJsonAndMissingFile) {
  testing::TempDir dir;
  std::ofstream(dir / "bad.json") << "{\"modelTopology\": {\"node\": [";
  ExpectModelLoad(dir / "bad.json", {"bad.json", "malformed JSON"});
  std::ofstream(dir / "empty.json") << "";
  ExpectModelLoad(dir / "empty.json", {"empty.json"});
  std::ofstream(dir / "array.json") << "[1,2]";
  ExpectModelLoad(dir / "array.json", {"array.json", "modelTopology"});
  ExpectModelLoad(dir / "nope.json", {"nope.json", "not found"});
}

TEST(TfjsGraphErrors, DanglingInputAndBadFusedOps) {
  testing::TempDir dir;
  Builder b = SimpleConv();
  b.Op("add", "AddV2", {"out", "ghost"});
  ExpectModelLoad(b.Write(dir.path()), {"add", "AddV2", "ghost"});
  Builder c;
  c.Input("x", {1, 4, 4, 1});
  c.Const("w", std::vector<float>(4, 1.0f), {2, 2, 1, 1});
  c.Const("bias", {0.5f}, {1});
  c.Op("f", "_FusedConv2D", {"x", "w", "bias"},
       {{"padding", {{"s", B64("SAME")}}}, {"strides", Ints({1, 1, 1, 1})},
        {"fused_ops", {{"list", {{"s", {B64("BiasAdd"), B64("Gelu")}}}}}}});
  ExpectModelLoad(c.Write(dir.path(), "f"), {"f.json", "'f'", "_FusedConv2D", "Gelu"});
}

TEST(TfjsGraphErrors, WrongInputShapeIsInvalidInput) {
  testing::TempDir dir;
  TfjsGraph g(SimpleConv().Write(dir.path()));
  EXPECT_THROW(g.Run(torch::zeros({1, 5, 4, 1}), {"out"}), InvalidInput);
  EXPECT_THROW(g.Run(torch::zeros({1, 4, 4, 1}), {"no_such_output"}), InvalidInput);
  EXPECT_EQ(g.Run(torch::ones({1, 4, 4, 1}), {"out"})[0][0][0][0][0].item<float>(), 4.0f);
}

TEST(TfjsGraphErrors, CorruptedRealModelFile) {
  // Truncating the real facemesh shard must be caught at load time, naming the weight.
  testing::TempDir dir;
  const fs::path models = ModelsDir();
  fs::copy_file(models / "facemesh.json", dir / "facemesh.json");
  {
    std::ifstream in(models / "facemesh.bin", std::ios::binary);
    std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    std::ofstream(dir / "facemesh.bin", std::ios::binary) << data.substr(0, data.size() / 2);
  }
  ExpectModelLoad(dir / "facemesh.json", {"facemesh.json", "too short"});
}

}  // namespace
}  // namespace avatar::io
