// MobileNetV2 from nsfwjs's Keras layers model: the loader (JS wrapper, base64, quantization,
// bad files) and the network against TensorFlow.js goldens (scripts/goldens, fixture face/goldens).
// The generic Keras graph runner (core/model/keras_net.h): a tiny graph against the same sums in
// LibTorch, its refusals, and the esrgan-slim x2 upscaler against TensorFlow.js.

#include "core/model/mobilenet_v2.h"

#include <chrono>
#include <fstream>
#include <iostream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "common/temp_dir.h"
#include "core/io/data_paths.h"
#include "core/io/keras_layers.h"
#include "core/model/keras_net.h"
#include "core/util/error.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

fs::path NsfwjsModel() {
  const fs::path p = NsfwjsMobileNetV2Path();
  EXPECT_TRUE(fs::exists(p)) << p << " is missing: run scripts/setup (it installs nsfwjs@4.4.0)";
  return p;
}

std::string ReadText(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void WriteText(const fs::path& p, const std::string& s) {
  std::ofstream out(p, std::ios::binary);
  out << s;
}

// A tensor of the TF.js goldens (raw float32, NHWC as TF.js writes it) as NCHW.
torch::Tensor ReadGolden(const fs::path& dir, const json& t) {
  const auto shape = t["shape"].get<std::vector<int64_t>>();
  auto out = torch::zeros(shape, torch::kFloat32);
  std::ifstream f(dir / t["file"].get<std::string>(), std::ios::binary);
  f.read(reinterpret_cast<char*>(out.data_ptr<float>()), out.numel() * 4);
  EXPECT_EQ(f.gcount(), out.numel() * 4) << t["file"];
  return out.permute({0, 3, 1, 2}).contiguous();
}

// Expects ModelLoad whose message names `file` and scripts/setup.
template <typename F>
void ExpectModelLoad(F&& f, const fs::path& file) {
  try {
    f();
    ADD_FAILURE() << "no ModelLoad for " << file;
  } catch (const ModelLoad& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(file.string()), std::string::npos) << what;
    EXPECT_NE(what.find("scripts/setup"), std::string::npos) << what;
  }
}

TEST(KerasLayers, JsLiteralBecomesJson) {
  const std::string js =
      R"(!function(e){module.exports=e()}(function(){return function(a){a.exports={k:"x",n:[.5,-.25,3.,1e-3,2],)"
      R"(t:!0,f:!1,z:null,s:'q"uote'}}}))";
  const json j = json::parse(io::internal::JsLiteralToJson(js, "x.js"));
  EXPECT_EQ(j["k"], "x");
  EXPECT_DOUBLE_EQ(j["n"][0].get<double>(), 0.5);
  EXPECT_DOUBLE_EQ(j["n"][1].get<double>(), -0.25);
  EXPECT_DOUBLE_EQ(j["n"][2].get<double>(), 3.0);
  EXPECT_DOUBLE_EQ(j["n"][3].get<double>(), 1e-3);
  EXPECT_EQ(j["t"], true);
  EXPECT_EQ(j["f"], false);
  EXPECT_TRUE(j["z"].is_null());
  EXPECT_EQ(j["s"], "q\"uote");
  EXPECT_THROW(io::internal::JsLiteralToJson("a.exports={k:1", "x.js"), ModelLoad);
  EXPECT_THROW(io::internal::JsLiteralToJson("a.exports={k:f()}", "x.js"), ModelLoad);
}

TEST(KerasLayers, Base64) {
  const auto b = io::internal::DecodeBase64("AP8Qw2Fi", "x");
  EXPECT_EQ(b, (std::vector<uint8_t>{0x00, 0xff, 0x10, 0xc3, 0x61, 0x62}));
  EXPECT_EQ(io::internal::DecodeBase64("YQ==", "x"), (std::vector<uint8_t>{'a'}));
  EXPECT_THROW(io::internal::DecodeBase64("YQ*=", "x"), ModelLoad);
}

TEST(KerasLayers, LoadsNsfwjs) {
  const auto model = io::LoadKerasLayersModel(NsfwjsModel());
  EXPECT_EQ(model.layers.size(), 162u);
  EXPECT_EQ(model.layers.front().class_name, "InputLayer");
  int64_t count = 0;
  for (const auto& [name, t] : model.weights) count += t.numel();
  EXPECT_EQ(count, 2619461);  // one uint8 per weight in the shard
  const auto& k = model.Weight("Conv1/kernel");
  EXPECT_EQ(k.sizes().vec(), (std::vector<int64_t>{3, 3, 3, 32}));
  // Dequantized values lie on the manifest's grid: min + q * scale with q in 0..255.
  EXPECT_NEAR(k.min().item<double>(), -0.87334511607301, 1e-6);
  EXPECT_LE(k.max().item<double>(), -0.87334511607301 + 255 * 0.006666756611244351 + 1e-5);
  const auto* block10 = model.Find("block_10_project_BN");
  ASSERT_NE(block10, nullptr);
  EXPECT_EQ(block10->inbound, std::vector<std::string>{"block_10_project"});
  EXPECT_FALSE(block10->config.at("trainable").get<bool>());  // ImageNet part, frozen by nsfwjs
  EXPECT_TRUE(model.Find("block_11_expand")->config.at("trainable").get<bool>());
}

TEST(KerasLayers, BadFilesGiveModelLoad) {
  const fs::path src = NsfwjsModel();
  testing::TempDir dir;
  // Missing model, through the loader and through the network's data-folder entry point.
  ExpectModelLoad([&] { io::LoadKerasLayersModel(dir / "model.min.js"); }, dir / "model.min.js");
  ExpectModelLoad([&] { LoadNsfwjsMobileNetV2(dir.path().string()); }, dir / "models" / "nsfwjs" / "model.min.js");
  const std::string model_text = ReadText(src);
  const std::string shard_text = ReadText(src.parent_path() / "group1-shard1of1.min.js");
  // Truncated model file.
  WriteText(dir / "model.min.js", model_text.substr(0, model_text.size() / 2));
  WriteText(dir / "group1-shard1of1.min.js", shard_text);
  ExpectModelLoad([&] { io::LoadKerasLayersModel(dir / "model.min.js"); }, dir / "model.min.js");
  // Whole model, missing shard.
  WriteText(dir / "model.min.js", model_text);
  fs::remove(dir / "group1-shard1of1.min.js");
  ExpectModelLoad([&] { io::LoadKerasLayersModel(dir / "model.min.js"); }, dir / "group1-shard1of1");
  // Truncated shard (string cut; and string closed early).
  WriteText(dir / "group1-shard1of1.min.js", shard_text.substr(0, shard_text.size() / 2));
  ExpectModelLoad([&] { io::LoadKerasLayersModel(dir / "model.min.js"); }, dir / "group1-shard1of1.min.js");
  const size_t cut = (shard_text.size() / 2) & ~size_t{3};
  WriteText(dir / "group1-shard1of1.min.js", shard_text.substr(0, cut) + "\"}");
  ExpectModelLoad([&] { io::LoadKerasLayersModel(dir / "model.min.js"); }, dir / "group1-shard1of1");
  // Foreign files: random text; a TF.js graph model (facemesh) renamed.
  WriteText(dir / "model.min.js", "console.log('hello');\n");
  ExpectModelLoad([&] { io::LoadKerasLayersModel(dir / "model.min.js"); }, dir / "model.min.js");
  const fs::path facemesh = DataPaths::Resolve().Require("models/facemesh.json", "face mesh model");
  WriteText(dir / "model.min.js", ReadText(facemesh));
  ExpectModelLoad([&] { io::LoadKerasLayersModel(dir / "model.min.js"); }, dir / "model.min.js");
}

TEST(KerasLayers, ForeignTopologyRejectedByNetwork) {
  // A valid layers model whose layers are not MobileNetV2's: drop every block_3 layer.
  auto model = io::LoadKerasLayersModel(NsfwjsModel());
  std::vector<io::KerasLayer> kept;
  for (auto& l : model.layers) {
    if (l.name.rfind("block_3_", 0) != 0) kept.push_back(l);
  }
  model.layers = kept;
  MobileNetV2 net;
  ExpectModelLoad([&] { net->LoadKeras(model); }, model.path);
}

// Outputs of the tapped layers against TensorFlow.js (tfjs-layers 4.22.0, pure-JS CPU backend).
TEST(MobileNetV2, MatchesTensorFlowJsGoldens) {
  const fs::path dir = fs::path(AVATAR_BINARY_DIR) / "goldens";
  const fs::path manifest_file = dir / "manifest.json";
  ASSERT_TRUE(fs::exists(manifest_file)) << "no goldens at " << manifest_file
                                         << ": the face/goldens fixture runs scripts/goldens/make_goldens.sh";
  std::ifstream in(manifest_file);
  const json manifest = json::parse(in);
  ASSERT_TRUE(manifest.contains("layers_models"))
      << "goldens lack nsfwjs (model not installed when they were made?): run scripts/setup, then ctest -R goldens";
  const json& entry = manifest["layers_models"][0];
  ASSERT_EQ(entry["name"], "nsfwjs");
  auto read = [&](const json& t) { return ReadGolden(dir, t); };
  const torch::Tensor x = read(entry["inputs"][0]);
  std::vector<std::string> taps;
  for (const auto& o : entry["outputs"]) taps.push_back(o["name"]);
  const MobileNetV2 net = LoadNsfwjsMobileNetV2();
  torch::NoGradGuard no_grad;
  const auto outs = net->Features(x, taps);
  ASSERT_EQ(outs.size(), taps.size());
  double worst = 0.0;
  for (size_t i = 0; i < taps.size(); ++i) {
    const torch::Tensor ref = read(entry["outputs"][i]);
    ASSERT_EQ(outs[i].sizes(), ref.sizes()) << taps[i];
    EXPECT_EQ(net->TapChannels(taps[i]), ref.size(1)) << taps[i];
    EXPECT_EQ(net->TapStride(taps[i]), 224 / ref.size(2)) << taps[i];
    const double err = (outs[i] - ref).abs().max().item<double>();
    const double scale = ref.abs().max().item<double>();
    const double rel = err / std::max(scale, 1e-12);
    std::cout << "[golden] nsfwjs " << taps[i] << " " << ref.sizes() << ": max abs error " << err << " (max |ref| "
              << scale << ", relative " << rel << ")\n";
    EXPECT_LT(rel, 1e-3) << taps[i];
    EXPECT_GT(scale, 1e-3) << taps[i] << " is all zeros";
    worst = std::max(worst, rel);
  }
  std::cout << "[golden] nsfwjs worst relative error " << worst << "\n";
}

// A hand-made graph of every supported layer: in(3) -> c1 conv3x3 relu (4) -> c2 conv1x1 (3) ->
// add(c2, in) -> concat(add, in) (6) -> up x2 -> c3 conv3x3 'same' (3) -> act tanh; the runner's
// output against the same operations written out in LibTorch, with Keras' HWIO kernels.
io::KerasLayersModel TinyKerasGraph() {
  io::KerasLayersModel m;
  m.path = "tiny-graph.json";
  auto layer = [&](const std::string& name, const std::string& kind, json config, std::vector<std::string> in) {
    m.layers.push_back({name, kind, std::move(config), std::move(in)});
  };
  layer("in", "InputLayer", {{"batch_input_shape", {nullptr, nullptr, nullptr, 3}}}, {});
  layer("c1", "Conv2D", {{"kernel_size", {3, 3}}, {"strides", {1, 1}}, {"padding", "same"}, {"activation", "relu"}},
        {"in"});
  layer("c2", "Conv2D", {{"kernel_size", {1, 1}}, {"padding", "valid"}, {"activation", "linear"}, {"use_bias", false}},
        {"c1"});
  layer("sum", "Add", json::object(), {"c2", "in"});
  layer("cat", "Concatenate", {{"axis", -1}}, {"sum", "in"});
  layer("up", "UpSampling2D", {{"size", {2, 2}}, {"interpolation", "nearest"}}, {"cat"});
  layer("c3", "Conv2D", {{"kernel_size", {3, 3}}, {"padding", "same"}, {"activation", "linear"}}, {"up"});
  layer("out", "Activation", {{"activation", "tanh"}}, {"c3"});
  torch::manual_seed(21);
  m.weights["c1/kernel"] = torch::randn({3, 3, 3, 4});
  m.weights["c1/bias"] = torch::randn({4});
  m.weights["c2/kernel"] = torch::randn({1, 1, 4, 3});
  m.weights["c3/kernel"] = torch::randn({3, 3, 6, 3}) * 0.2;
  m.weights["c3/bias"] = torch::randn({3});
  return m;
}

TEST(KerasNet, RunsEverySupportedLayerAsLibTorchDoes) {
  const io::KerasLayersModel m = TinyKerasGraph();
  const KerasNet net(m);
  EXPECT_EQ(net.InputChannels(), 3);
  EXPECT_EQ(net.Scale(), 2);
  EXPECT_EQ(net.ParameterCount(), 3 * 3 * 3 * 4 + 4 + 4 * 3 + 3 * 3 * 6 * 3 + 3);
  // Multiply-adds at 5 x 7: c1 and c2 at 5 x 7, c3 at 10 x 14.
  EXPECT_DOUBLE_EQ(net.MultiplyAdds(5, 7), 35.0 * (3 * 3 * 3 * 4) + 35.0 * (4 * 3) + 140.0 * (3 * 3 * 6 * 3));
  const torch::Tensor x = torch::rand({2, 3, 5, 7});
  torch::NoGradGuard no_grad;
  auto oihw = [&](const char* name) { return m.weights.at(name).permute({3, 2, 0, 1}); };
  namespace F = torch::nn::functional;
  const torch::Tensor c1 =
      torch::relu(F::conv2d(x, oihw("c1/kernel"), F::Conv2dFuncOptions().bias(m.weights.at("c1/bias")).padding(1)));
  const torch::Tensor sum = F::conv2d(c1, oihw("c2/kernel")) + x;
  const torch::Tensor up = F::interpolate(torch::cat({sum, x}, 1), F::InterpolateFuncOptions()
                                                                       .scale_factor(std::vector<double>{2.0, 2.0})
                                                                       .mode(torch::kNearest));
  const torch::Tensor want =
      torch::tanh(F::conv2d(up, oihw("c3/kernel"), F::Conv2dFuncOptions().bias(m.weights.at("c3/bias")).padding(1)));
  const torch::Tensor got = net.Forward(x);
  ASSERT_EQ(got.sizes(), want.sizes());
  EXPECT_LT((got - want).abs().max().item<double>(), 1e-5);
  EXPECT_THROW(net.Forward(torch::rand({1, 4, 5, 7})), InvalidInput);
  EXPECT_THROW(net.Forward(torch::rand({3, 5, 7})), InvalidInput);
}

TEST(KerasNet, RefusesWhatItCannotRunWhenBuilt) {
  auto refused = [](io::KerasLayersModel m, const std::string& mention) {
    try {
      KerasNet net(m);
      ADD_FAILURE() << "no ModelLoad; expected one mentioning " << mention;
    } catch (const ModelLoad& e) {
      EXPECT_NE(std::string(e.what()).find(mention), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("tiny-graph.json"), std::string::npos) << e.what();
    }
  };
  io::KerasLayersModel m = TinyKerasGraph();
  m.layers[2].class_name = "Dense";
  refused(m, "'c2' (Dense)");
  m = TinyKerasGraph();
  m.layers[1].config["strides"] = {2, 2};
  refused(m, "strides");
  m = TinyKerasGraph();
  m.layers[1].config["activation"] = "swish";
  refused(m, "swish");
  m = TinyKerasGraph();
  m.layers[5].config["interpolation"] = "bilinear";
  refused(m, "nearest");
  m = TinyKerasGraph();
  m.weights.erase("c3/bias");
  EXPECT_THROW(KerasNet{m}, ModelLoad);
  m = TinyKerasGraph();
  m.weights["c1/kernel"] = torch::randn({5, 5, 3, 4});
  refused(m, "kernel of the wrong shape");
  m = TinyKerasGraph();
  m.layers[3].inbound = {"c2", "later"};
  refused(m, "'later'");
  m = TinyKerasGraph();
  m.layers.push_back({"dangling", "Activation", {{"activation", "relu"}}, {"c1"}});
  m.layers.push_back({"tail", "Activation", {{"activation", "relu"}}, {"out"}});
  EXPECT_THROW(KerasNet{m}, ModelLoad);  // 'dangling' is a second output
}

// The esrgan-slim x2 upscaler (installed by scripts/setup) against TensorFlow.js on the golden
// input (0..255): the whole SR output.
TEST(KerasNet, EsrganSlimMatchesTensorFlowJsGoldens) {
  const fs::path dir = fs::path(AVATAR_BINARY_DIR) / "goldens";
  const fs::path manifest_file = dir / "manifest.json";
  ASSERT_TRUE(fs::exists(manifest_file)) << "no goldens at " << manifest_file
                                         << ": the face/goldens fixture runs scripts/goldens/make_goldens.sh";
  std::ifstream in(manifest_file);
  const json manifest = json::parse(in);
  const json* entry = nullptr;
  if (manifest.contains("layers_models")) {
    for (const json& e : manifest["layers_models"])
      if (e["name"] == "esrgan-slim-x2") entry = &e;
  }
  ASSERT_NE(entry, nullptr) << "goldens lack esrgan-slim-x2 (not installed when they were made?): run scripts/setup, "
                               "then ctest -R goldens";
  auto read = [&](const json& t) { return ReadGolden(dir, t); };
  const fs::path model = DataPaths::Resolve().Path("models/esrgan-slim-x2/model.json");
  ASSERT_TRUE(fs::exists(model)) << model << " is missing: run scripts/setup (data version 3)";
  const KerasNet net(io::LoadKerasLayersModel(model));
  EXPECT_EQ(net.Scale(), 2);
  EXPECT_EQ(net.InputChannels(), 3);
  const torch::Tensor x = read((*entry)["inputs"][0]);
  const torch::Tensor ref = read((*entry)["outputs"][0]);
  torch::NoGradGuard no_grad;
  const torch::Tensor got = net.Forward(x);
  ASSERT_EQ(got.sizes(), ref.sizes());
  const double err = (got - ref).abs().max().item<double>();
  const double scale = ref.abs().max().item<double>();
  std::cout << "[golden] esrgan-slim x2 " << ref.sizes() << ": max abs error " << err << " (max |ref| " << scale
            << ")\n";
  EXPECT_GT(scale, 10.0) << "the reference is nearly all zeros";
  EXPECT_LT(err / scale, 1e-4);
}

TEST(MobileNetV2, ShapesFrozenAndTiming) {
  const MobileNetV2 net = LoadNsfwjsMobileNetV2();
  for (const auto& p : net->parameters()) EXPECT_FALSE(p.requires_grad());
  torch::NoGradGuard no_grad;
  const auto x = torch::rand({1, 3, 224, 224}) * 2 - 1;
  EXPECT_EQ(net->forward(x).sizes().vec(), (std::vector<int64_t>{1, 96, 14, 14}));
  // Other sizes work (no fixed input shape), odd ones too (the topology's fixed pads, not TF's dynamic SAME).
  EXPECT_EQ(net->forward(torch::zeros({2, 3, 128, 96})).sizes().vec(), (std::vector<int64_t>{2, 96, 8, 6}));
  EXPECT_EQ(net->forward(torch::zeros({1, 3, 33, 47})).sizes().vec(),
            (std::vector<int64_t>{1, 96, 2, 2}));  // explicit (0,1) pads: 33->16->8->4->2
  EXPECT_THROW(net->forward(torch::zeros({1, 1, 64, 64})), InvalidInput);
  EXPECT_THROW(net->Features(x, {"block_12_add"}), InvalidInput);
  net->forward(x);  // warm-up
  const int runs = 5;
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < runs; ++i) net->forward(x);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / runs;
  std::cout << "[timing] MobileNetV2 Conv1..block_10, 1x3x224x224 float32 CPU forward: " << ms << " ms (mean of "
            << runs << ", threads " << torch::get_num_threads() << ")\n";
  RecordProperty("forward_224_ms", std::to_string(ms));
}

TEST(MobileNetV2Encoder, ShapesPretrainedSixChannelsAndGradients) {
  const auto model = io::LoadKerasLayersModel(NsfwjsModel());
  MobileNetV2Encoder enc(6, 256);
  enc->LoadKeras(model);
  const auto rgb = torch::rand({2, 3, 128, 128}) * 2 - 1;
  const auto x = torch::cat({rgb, rgb}, 1);
  const auto stages = enc->Stages(x);
  ASSERT_EQ(stages.size(), 4u);
  const std::vector<int64_t> channels = {24, 32, 96, 320};
  for (size_t s = 0; s < 4; ++s) {
    EXPECT_EQ(stages[s].sizes().vec(), (std::vector<int64_t>{2, channels[s], 128 >> (s + 2), 128 >> (s + 2)}));
  }
  // Two copies of one RGB image through the 6-channel Conv1 = the pretrained RGB network.
  const MobileNetV2 rgb_net = LoadNsfwjsMobileNetV2();
  {
    torch::NoGradGuard no_grad;
    const auto ref = rgb_net->Features(rgb, {"block_2_add"})[0];
    const double err = (stages[0] - ref).abs().max().item<double>() / ref.abs().max().item<double>();
    EXPECT_LT(err, 1e-5) << "6-channel Conv1 reuse";
  }
  const auto y = enc->forward(x);
  EXPECT_EQ(y.sizes().vec(), (std::vector<int64_t>{2, 256, 32, 32}));
  y.pow(2).mean().backward();
  int with_grad = 0;
  for (const auto& p : enc->parameters()) {
    if (p.grad().defined() && p.grad().abs().sum().item<double>() > 0) ++with_grad;
  }
  EXPECT_EQ(with_grad, static_cast<int>(enc->parameters().size())) << "every parameter should receive a gradient";
  EXPECT_THROW(enc->forward(torch::zeros({1, 6, 100, 100})), InvalidInput);
  EXPECT_THROW(enc->forward(torch::zeros({1, 3, 128, 128})), InvalidInput);
}

}  // namespace
}  // namespace avatar
