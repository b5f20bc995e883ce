#include "core/tools/dataset_records.h"

#include <algorithm>

#include "core/io/image_io.h"
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

}  // namespace avatar
