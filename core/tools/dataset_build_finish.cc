// Stage 2 of the dataset build (dataset_build_impl.h): the records of every kept item, identities
// (person keys merged by embedding), the split by identity, the pairs, and the output files:
// split.json, records.json, pairs.json, the shards and dataset.json last.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <map>
#include <numeric>
#include <random>
#include <set>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <torch/serialize.h>

#include "core/face/face_analyzer.h"
#include "core/io/atomic_file.h"
#include "core/io/json_file.h"
#include "core/tools/dataset_build_impl.h"
#include "core/util/error.h"

namespace avatar::dataset {
namespace {

// `quota` distinct ordered pairs of distinct frames, drawn round-robin from 8 equal-width bins of
// the combined difference (yaw and pitch in units of 10 degrees, expression in units of its
// median over all pairs).
std::vector<json> ClipPairs(const std::vector<json>& records, const std::map<std::string, size_t>& index,
                            const std::vector<std::string>& ids, int quota, std::mt19937_64& rng) {
  struct Candidate {
    size_t s, t;
    double yaw, pitch, expr, d;
  };
  std::vector<Candidate> all;
  for (size_t s = 0; s < ids.size(); ++s) {
    for (size_t t = 0; t < ids.size(); ++t) {
      if (s == t) continue;
      const json& a = records[index.at(ids[s])];
      const json& b = records[index.at(ids[t])];
      all.push_back({s, t, std::abs(a["pose"]["yaw"].get<double>() - b["pose"]["yaw"].get<double>()),
                     std::abs(a["pose"]["pitch"].get<double>() - b["pose"]["pitch"].get<double>()),
                     ExpressionDistance(a, b), 0.0});
    }
  }
  std::vector<double> exprs;
  for (const auto& c : all) exprs.push_back(c.expr);
  std::nth_element(exprs.begin(), exprs.begin() + exprs.size() / 2, exprs.end());
  const double expr_unit = std::max(exprs[exprs.size() / 2], 1e-6);
  double max_d = 0.0;
  for (auto& c : all) {
    c.d = std::hypot(c.yaw / 10.0, c.pitch / 10.0, c.expr / expr_unit);
    max_d = std::max(max_d, c.d);
  }
  constexpr int kBins = 8;
  std::vector<std::vector<size_t>> bins(kBins);
  for (size_t i = 0; i < all.size(); ++i) {
    const int b = std::min(kBins - 1, static_cast<int>(all[i].d / std::max(max_d, 1e-9) * kBins));
    bins[b].push_back(i);
  }
  for (auto& b : bins) std::shuffle(b.begin(), b.end(), rng);
  std::vector<json> out;
  std::vector<size_t> next(kBins, 0);
  const size_t want = std::min<size_t>(quota, all.size());
  while (out.size() < want) {
    for (int b = 0; b < kBins && out.size() < want; ++b) {
      if (next[b] >= bins[b].size()) continue;
      const Candidate& c = all[bins[b][next[b]++]];
      out.push_back({{"source", ids[c.s]}, {"target", ids[c.t]}, {"kind", "clip"}, {"d_yaw", c.yaw},
                     {"d_pitch", c.pitch}, {"d_expression", c.expr}});
    }
  }
  return out;
}

}  // namespace

double ExpressionDistance(const json& a, const json& b) {
  const auto ba = a["beta"].get<std::vector<float>>();
  const auto bb = b["beta"].get<std::vector<float>>();
  double s = 0.0;
  for (size_t k = 0; k < std::min(ba.size(), bb.size()); ++k) s += (ba[k] - bb[k]) * (ba[k] - bb[k]);
  return std::sqrt(s);
}

DatasetBuildReport Builder::Finish(int photos) {
  DatasetBuildReport rep;
  rep.photos = photos;
  rep.faces = static_cast<int>(photo_faces_.size());
  rep.skipped = skipped_;
  // Records, in a fixed order.
  std::vector<json> records;
  std::map<std::string, size_t> index;
  auto add = [&](const std::string& id) {
    index[id] = records.size();
    records.push_back(ReadJsonFile(dir_ / "items" / (id + ".json"), "delete it and rerun the build"));
  };
  for (const auto& id : photo_faces_) add(id);
  for (const auto& [clip, ids] : clip_frames_) {
    for (const auto& id : ids) {
      add(id);
      records.back()["person"] = clip_person_.at(clip);  // the current input's key, also on resume
    }
    rep.clip_frames += static_cast<int>(ids.size());
  }
  // Identities: one per person key, merged across photos by embedding similarity.
  std::vector<size_t> parent(records.size());
  std::iota(parent.begin(), parent.end(), 0);
  std::function<size_t(size_t)> root = [&](size_t i) { return parent[i] == i ? i : parent[i] = root(parent[i]); };
  auto unite = [&](size_t a, size_t b) { parent[root(a)] = root(b); };
  std::map<std::string, size_t> by_person;
  for (size_t i = 0; i < records.size(); ++i) {
    const std::string person = records[i].value("person", "");
    if (person.empty()) continue;
    auto it = by_person.find(person);
    if (it == by_person.end()) by_person[person] = i;
    else unite(i, it->second);
  }
  for (size_t i = 0; i < records.size(); ++i) {
    const auto& ei = records[i].value("embedding", std::vector<float>{});
    if (ei.empty()) continue;
    for (size_t j = 0; j < i; ++j) {
      const auto& ej = records[j].value("embedding", std::vector<float>{});
      if (ej.size() == ei.size() && face::IdentitySimilarity(ei, ej) >= o_.merge_similarity) unite(i, j);
    }
  }
  std::map<size_t, std::string> names;  // root -> identity name (a person key if any, else the first id)
  for (size_t i = 0; i < records.size(); ++i) {
    const size_t r = root(i);
    const std::string person = records[i].value("person", "");
    auto it = names.find(r);
    if (it == names.end()) names[r] = person.empty() ? records[i]["id"].get<std::string>() : person;
    else if (!person.empty() && person < it->second) it->second = person;
  }
  std::set<std::string> sorted_names;
  for (const auto& [r, n] : names) sorted_names.insert(n);
  const std::vector<std::string> identity_names(sorted_names.begin(), sorted_names.end());
  std::map<std::string, int> identity_of_name;
  for (size_t k = 0; k < identity_names.size(); ++k) identity_of_name[identity_names[k]] = static_cast<int>(k);
  for (size_t i = 0; i < records.size(); ++i) records[i]["identity"] = identity_of_name.at(names.at(root(i)));
  rep.identities = static_cast<int>(identity_names.size());

  // Split by identity: one clip person first, then random others.
  std::mt19937_64 rng(static_cast<uint64_t>(o_.seed));
  std::set<int> val;
  const int want_val = std::min<int>(o_.val_identities, std::max(0, rep.identities - 1));
  std::vector<int> clip_ids, other_ids;
  for (int k = 0; k < rep.identities; ++k) {
    bool clip = false;
    for (const auto& r : records) clip |= r["identity"] == k && r["kind"] == "clip";
    (clip ? clip_ids : other_ids).push_back(k);
  }
  if (want_val > 0 && !clip_ids.empty()) {
    // The clip person with the fewest frames validates, so training keeps the most clip pairs.
    std::shuffle(clip_ids.begin(), clip_ids.end(), rng);
    std::map<int, int> frames_of;
    for (const auto& r : records) {
      if (r["kind"] == "clip") ++frames_of[r["identity"].get<int>()];
    }
    std::stable_sort(clip_ids.begin(), clip_ids.end(), [&](int a, int b) { return frames_of[a] < frames_of[b]; });
    val.insert(clip_ids.front());
    other_ids.insert(other_ids.end(), clip_ids.begin() + 1, clip_ids.end());
  }
  std::shuffle(other_ids.begin(), other_ids.end(), rng);
  for (int k : other_ids) {
    if (static_cast<int>(val.size()) >= want_val) break;
    val.insert(k);
  }
  rep.val_identities = static_cast<int>(val.size());
  for (auto& r : records) r["split"] = val.count(r["identity"].get<int>()) ? "val" : "train";

  // Pairs: photos pair with themselves; clip frames pair with other frames of the clip,
  // drawn evenly over bins of pose + expression difference so that differences are spread.
  json pairs = json::array();
  for (const auto& id : photo_faces_) pairs.push_back({{"source", id}, {"target", id}, {"kind", "photo"}});
  const int clips_with_frames = static_cast<int>(
      std::count_if(clip_frames_.begin(), clip_frames_.end(), [](const auto& kv) { return kv.second.size() >= 2; }));
  int clip_index = 0;
  for (const auto& [clip, ids] : clip_frames_) {
    if (ids.size() < 2) continue;
    const int quota = o_.clip_pairs / clips_with_frames + (clip_index++ < o_.clip_pairs % clips_with_frames ? 1 : 0);
    for (const auto& p : ClipPairs(records, index, ids, quota, rng)) pairs.push_back(p);
  }
  for (const auto& p : pairs) {
    if (p["kind"] == "clip") ++rep.clip_pairs;
  }
  // Synthetic heads of the training photos only (after the split, with their own random
  // streams, so the real pairs are the same with or without them).
  std::vector<json> synthetic;
  if (o_.synthetic > 0) Synthetic(records, &synthetic, &pairs, &rep);

  // Outputs; dataset.json last (its presence means the dataset is complete).
  json split;
  split["seed"] = o_.seed;
  split["identities"] = identity_names;
  std::vector<std::string> val_names, train_names;
  for (int k = 0; k < rep.identities; ++k) (val.count(k) ? val_names : train_names).push_back(identity_names[k]);
  split["val"] = val_names;
  split["train"] = train_names;
  WriteJson(dir_ / "split.json", split);
  WriteJson(dir_ / "records.json", records);
  WriteJson(dir_ / "pairs.json", pairs);
  json shards;
  for (const char* name : {"train", "val"}) {
    const int n = WriteShard(name, records, pairs);
    (std::string(name) == "train" ? rep.train_pairs : rep.val_pairs) = n;
    shards[name] = std::string("shards/") + name + ".pt";
  }
  if (o_.synthetic > 0) {
    WriteJson(dir_ / "synthetic.json", synthetic);
    rep.synthetic_pairs = WriteShard("train", synthetic, pairs, "synthetic");
    shards["synthetic"] = "shards/synthetic.pt";
  }
  json labels = json::array();
  for (const auto& r : records) labels.push_back({r["files"]["image"], r["label"]});
  for (const auto& r : synthetic) labels.push_back({r["files"]["image"], r["label"]});
  json ds;
  ds["labels"] = labels;
  ds["size"] = o_.size;
  ds["version"] = 1;
  ds["shards"] = shards;
  ds["records"] = "records.json";
  ds["pairs"] = "pairs.json";
  ds["split"] = split;
  ds["counts"] = {{"photos", rep.photos}, {"faces", rep.faces}, {"skipped", rep.skipped},
                  {"identities", rep.identities}, {"clip_frames", rep.clip_frames}, {"clip_pairs", rep.clip_pairs},
                  {"train_pairs", rep.train_pairs}, {"val_pairs", rep.val_pairs}};
  if (o_.synthetic > 0) {
    ds["synthetic"] = "synthetic.json";
    ds["counts"]["synthetic_heads"] = rep.synthetic_heads;
    ds["counts"]["synthetic_frames"] = rep.synthetic_frames;
    ds["counts"]["synthetic_pairs"] = rep.synthetic_pairs;
  }
  ds["label_convention"] = "row-major cam2world 4x4 (OpenCV camera axes, radius 2.7) + normalised intrinsics 3x3";
  WriteJson(dir_ / "dataset.json", ds);
  Log("done: " + ds["counts"].dump());
  return rep;
}

torch::Tensor Builder::LoadU8(const std::string& rel, int channels) const {
  cv::Mat m = cv::imread((dir_ / rel).string(), channels == 1 ? cv::IMREAD_GRAYSCALE : cv::IMREAD_COLOR);
  AVATAR_CHECK_AS(Io, !m.empty()) << "cannot read " << (dir_ / rel).string() << ": delete DIR/items and rebuild";
  if (channels == 3) cv::cvtColor(m, m, cv::COLOR_BGR2RGB);
  AVATAR_CHECK_AS(Io, m.rows == o_.size && m.cols == o_.size)
      << (dir_ / rel).string() << " is " << m.cols << "x" << m.rows << ", not " << o_.size
      << ": the folder was built with another --size; use a new --out";
  return torch::from_blob(m.data, {m.rows, m.cols, channels}, torch::kUInt8).permute({2, 0, 1}).clone();
}

int Builder::WriteShard(const std::string& split, const std::vector<json>& records, const json& pairs,
                        const std::string& file) {
  std::vector<const json*> frames;
  std::map<std::string, int64_t> local;
  for (const auto& r : records) {
    if (r["split"] != split) continue;
    local[r["id"].get<std::string>()] = static_cast<int64_t>(frames.size());
    frames.push_back(&r);
  }
  std::vector<torch::Tensor> image, matte, eye_mouth, exp, neu, neu_mask, label, expression;
  std::vector<int64_t> identity;
  for (const json* r : frames) {
    const json& f = (*r)["files"];
    image.push_back(LoadU8(f["image"], 3));
    matte.push_back(LoadU8(f["matte"], 1));
    eye_mouth.push_back(LoadU8(f["eye_mouth"], 1));
    exp.push_back(LoadU8(f["expression_image"], 3));
    neu.push_back(LoadU8(f["neutral_image"], 3));
    neu_mask.push_back(LoadU8(f["neutral_mask"], 1));
    label.push_back(torch::tensor((*r)["label"].get<std::vector<float>>()));
    expression.push_back(torch::tensor((*r)["beta"].get<std::vector<float>>()));
    identity.push_back((*r)["identity"].get<int64_t>());
  }
  std::vector<int64_t> pair_index, pair_kind;
  for (const auto& p : pairs) {
    auto s = local.find(p["source"].get<std::string>());
    auto t = local.find(p["target"].get<std::string>());
    if (s == local.end() || t == local.end()) continue;
    pair_index.push_back(s->second);
    pair_index.push_back(t->second);
    pair_kind.push_back(p["kind"] == "clip" ? 1 : p["kind"] == "synthetic" ? 2 : 0);
  }
  const int64_t n = static_cast<int64_t>(frames.size());
  const int64_t s = o_.size;
  const int64_t k = model_.num_expression();
  auto stack = [&](const std::vector<torch::Tensor>& v, std::vector<int64_t> empty_shape) {
    return v.empty() ? torch::zeros(empty_shape, v.empty() ? torch::kUInt8 : v[0].scalar_type()) : torch::stack(v);
  };
  c10::Dict<std::string, torch::Tensor> d;
  d.insert("image", stack(image, {0, 3, s, s}));
  d.insert("matte", stack(matte, {0, 1, s, s}));
  d.insert("eye_mouth", stack(eye_mouth, {0, 1, s, s}));
  d.insert("expression_image", stack(exp, {0, 3, s, s}));
  d.insert("neutral_image", stack(neu, {0, 3, s, s}));
  d.insert("neutral_mask", stack(neu_mask, {0, 1, s, s}));
  d.insert("label", label.empty() ? torch::zeros({0, 25}) : torch::stack(label));
  d.insert("expression", expression.empty() ? torch::zeros({0, k}) : torch::stack(expression));
  d.insert("identity", torch::tensor(identity, torch::kInt64).reshape({n}));
  d.insert("pairs", torch::tensor(pair_index, torch::kInt64).reshape({-1, 2}));
  d.insert("pair_kind", torch::tensor(pair_kind, torch::kInt64).reshape({-1}));
  const std::vector<char> bytes = torch::pickle_save(c10::IValue(d));
  WriteBytesAtomically(dir_ / "shards" / ((file.empty() ? split : file) + ".pt"), std::string(bytes.begin(), bytes.end()));
  return static_cast<int>(pair_kind.size());
}

}  // namespace avatar::dataset
