// Fuzz target "tfjs_graph": TF.js graph models (model.json + weight shards), loaded by
// core/io/tfjs_graph (TfjsGraph's constructor validates the whole graph and its weights).
// Input: a MultiFile (fuzz_common.h): model.json first, then the shards under their names.
#include <nlohmann/json.hpp>

#include "core/io/tfjs_graph.h"
#include "core/util/error.h"
#include "fuzz_common.h"

namespace avatar::fuzz {
namespace {

std::string RunTfjsGraph(std::string_view input) {
  const std::filesystem::path model = WriteParts(FreshInputDir(), SplitParts(input, "model.json"));
  return AcceptAvatarErrors([&] {
    const io::TfjsGraph graph(model);
    for (const std::string& name : graph.InputNames()) (void)graph.InputShape(name);
    (void)graph.SignatureOutputs();
    (void)graph.Ops();
  });
}

// A graph made here: input [1,4,4,2] -> Conv2D (3x3, 2->3, SAME) -> BiasAdd -> Relu.
std::vector<std::pair<std::string, std::string>> TinyGraph() {
  using nlohmann::json;
  auto shape = [](std::vector<int> dims) {
    json d = json::array();
    for (int v : dims) d.push_back({{"size", std::to_string(v)}});
    return json{{"dim", d}};
  };
  json nodes = json::array();
  nodes.push_back({{"name", "input"}, {"op", "Placeholder"},
                   {"attr", {{"dtype", {{"type", "DT_FLOAT"}}}, {"shape", {{"shape", shape({1, 4, 4, 2})}}}}}});
  nodes.push_back({{"name", "w"}, {"op", "Const"}, {"attr", {{"dtype", {{"type", "DT_FLOAT"}}}}}});
  nodes.push_back({{"name", "b"}, {"op", "Const"}, {"attr", {{"dtype", {{"type", "DT_FLOAT"}}}}}});
  nodes.push_back({{"name", "conv"},
                   {"op", "Conv2D"},
                   {"input", {"input", "w"}},
                   {"attr",
                    {{"padding", {{"s", "U0FNRQ=="}}},
                     {"strides", {{"list", {{"i", {"1", "1", "1", "1"}}}}}},
                     {"dilations", {{"list", {{"i", {"1", "1", "1", "1"}}}}}},
                     {"data_format", {{"s", "TkhXQw=="}}}}}});
  nodes.push_back({{"name", "bias"}, {"op", "BiasAdd"}, {"input", {"conv", "b"}}});
  nodes.push_back({{"name", "out"}, {"op", "Relu"}, {"input", {"bias"}}});
  const json manifest = json::array({{{"paths", {"tiny.bin"}},
                                      {"weights",
                                       {{{"name", "w"}, {"shape", {3, 3, 2, 3}}, {"dtype", "float32"}},
                                        {{"name", "b"}, {"shape", {3}}, {"dtype", "float32"}}}}}});
  const json model = {{"format", "graph-model"},
                      {"modelTopology", {{"node", nodes}, {"versions", {{"producer", 1}}}}},
                      {"weightsManifest", manifest}};
  std::string weights;
  for (int k = 0; k < 3 * 3 * 2 * 3 + 3; ++k) {
    const float v = 0.05f * static_cast<float>(k % 7) - 0.1f;
    weights.append(reinterpret_cast<const char*>(&v), sizeof v);
  }
  return {{"model.json", model.dump()}, {"tiny.bin", weights}};
}

int TfjsGraphSeeds(const std::filesystem::path& dir) {
  int n = 0;
  WriteFile(dir / "tiny-conv", JoinParts(TinyGraph()));
  ++n;
  // The small face models of the data folder (scripts/setup), each with its shards.
  const std::filesystem::path models = DataDir() / "models";
  for (const char* name : {"blazeface-front", "selfie"}) {
    const std::filesystem::path json_file = models / (std::string(name) + ".json");
    std::error_code ec;
    if (DataDir().empty() || !std::filesystem::is_regular_file(json_file, ec)) continue;
    std::vector<std::pair<std::string, std::string>> parts = {{"model.json", ReadFile(json_file)}};
    const nlohmann::json j = nlohmann::json::parse(parts.front().second);
    for (const auto& group : j.at("weightsManifest")) {
      for (const auto& p : group.at("paths")) {
        parts.emplace_back(p.get<std::string>(), ReadFile(models / p.get<std::string>()));
      }
    }
    WriteFile(dir / name, JoinParts(parts));
    ++n;
  }
  return n;
}

AVATAR_FUZZ_TARGET("tfjs_graph", RunTfjsGraph, TfjsGraphSeeds);

}  // namespace
}  // namespace avatar::fuzz
