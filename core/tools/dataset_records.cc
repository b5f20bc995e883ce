#include "core/tools/dataset_records.h"

#include <algorithm>
#include <map>

#include "core/io/image_io.h"
#include "core/io/json_file.h"
#include "core/tools/synthetic_head.h"
#include "core/util/error.h"

namespace avatar {

morphable::CameraLabel RecordLabel(const nlohmann::json& values, const std::string& what) {
  AVATAR_CHECK_INPUT(values.is_array()) << what << ": the camera label is not an array";
  const auto v = values.get<std::vector<float>>();
  AVATAR_CHECK_INPUT(v.size() == morphable::CameraLabel{}.size()) << what << ": camera label has " << v.size() << " values";
  morphable::CameraLabel l{};
  std::copy(v.begin(), v.end(), l.begin());
  return l;
}

morphable::FitResult RecordFit(const nlohmann::json& record, cv::Size image_size) {
  const std::string id = record.value("id", std::string("a record"));
  AVATAR_CHECK_INPUT(record.contains("alpha") && record.contains("beta") && record.contains("scale") &&
                     record.contains("label"))
      << id << ": the record lacks its morphable fit (alpha, beta, scale, label): rebuild the dataset";
  try {
    return morphable::FitFromLabel(record.at("alpha").get<morphable::Alpha>(), record.at("beta").get<morphable::Beta>(),
                         record.at("scale").get<float>(), RecordLabel(record.at("label"), id), image_size);
  } catch (const nlohmann::json::exception& e) {
    throw InvalidInput(id + ": malformed morphable fit in the record (" + e.what() + "): rebuild the dataset");
  }
}

face::AlignedPortrait RecordPortrait(const std::filesystem::path& dir, const nlohmann::json& record) {
  const std::string id = record.value("id", std::string("a record"));
  AVATAR_CHECK_INPUT(record.contains("files") && record.at("files").is_object())
      << id << ": the record lists no files: rebuild the dataset";
  const nlohmann::json& files = record.at("files");
  auto file = [&](const char* key) {
    AVATAR_CHECK_INPUT(files.contains(key) && files.at(key).is_string()) << id << ": the record lists no " << key;
    return dir / files.at(key).get<std::string>();
  };
  face::AlignedPortrait p;
  p.image_unmatted = LoadImageBgr(file("image"));
  const cv::Mat matte = LoadImageBgr(file("matte"));
  cv::Mat grey;
  cv::extractChannel(matte, grey, 0);
  grey.convertTo(p.matte, CV_32FC1, 1.0 / 255.0);
  cv::extractChannel(LoadImageBgr(file("eye_mouth")), p.eye_mouth_mask, 0);
  AVATAR_CHECK_INPUT(p.matte.size() == p.image_unmatted.size() && p.eye_mouth_mask.size() == p.image_unmatted.size())
      << id << ": the stored crop, matte and eye/mouth mask differ in size: rebuild the dataset";
  return p;
}

SplitPairRecords LoadSplitPairRecords(const std::filesystem::path& dir, const std::string& split,
                                      int64_t expected_pairs) {
  SplitPairRecords b;
  const std::filesystem::path records = dir / "records.json", pairs = dir / "pairs.json";
  if (!std::filesystem::exists(records) || !std::filesystem::exists(pairs)) {
    b.why = "the dataset has no records.json / pairs.json (the morphable fits)";
    return b;
  }
  b.records = ReadJsonFile(records, "rebuild the dataset");
  const nlohmann::json p = ReadJsonFile(pairs, "rebuild the dataset");
  AVATAR_CHECK_INPUT(b.records.is_array() && p.is_array()) << records.string() << " / " << pairs.string()
                                                           << " must hold JSON arrays";
  std::map<std::string, size_t> by_id;
  for (size_t i = 0; i < b.records.size(); ++i) {
    const nlohmann::json& r = b.records[i];
    if (r.is_object() && r.value("split", "") == split) by_id[r.value("id", "")] = i;
  }
  for (const auto& e : p) {
    const auto s = by_id.find(e.value("source", "")), t = by_id.find(e.value("target", ""));
    if (s == by_id.end() || t == by_id.end()) continue;
    b.pairs.emplace_back(s->second, t->second);
  }
  if (static_cast<int64_t>(b.pairs.size()) != expected_pairs) {
    b.why = "records.json / pairs.json list " + std::to_string(b.pairs.size()) + " pairs of split '" + split +
            "' but the shard has " + std::to_string(expected_pairs);
    b.pairs.clear();
    return b;
  }
  b.ok = true;
  return b;
}

}  // namespace avatar
