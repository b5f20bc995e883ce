#include "core/tools/dataset_inspect.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <numeric>
#include <random>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "core/io/atomic_file.h"
#include "core/io/image_io.h"
#include "core/io/image_tensor.h"
#include "core/io/json_file.h"
#include "core/train/dataset.h"
#include "core/util/error.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;


// One histogram panel (bars over [lo,hi]) drawn into `panel` (BGR8).
void DrawHistogram(cv::Mat& panel, const std::string& title, const std::vector<double>& values, double lo,
                   double hi, int bins) {
  panel.setTo(cv::Scalar(255, 255, 255));
  const int left = 40, right = 10, top = 28, bottom = 30;
  const cv::Rect plot(left, top, panel.cols - left - right, panel.rows - top - bottom);
  cv::putText(panel, title + " (" + std::to_string(values.size()) + ")", cv::Point(6, 18), cv::FONT_HERSHEY_SIMPLEX,
              0.45, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  cv::rectangle(panel, plot, cv::Scalar(160, 160, 160), 1);
  std::vector<int> count(bins, 0);
  for (double v : values) ++count[std::clamp(static_cast<int>(std::floor((v - lo) / (hi - lo) * bins)), 0, bins - 1)];
  const int peak = std::max(1, *std::max_element(count.begin(), count.end()));
  for (int b = 0; b < bins; ++b) {
    const int x0 = plot.x + plot.width * b / bins, x1 = plot.x + plot.width * (b + 1) / bins - 1;
    const int h = plot.height * count[b] / peak;
    if (h > 0) cv::rectangle(panel, cv::Point(x0, plot.y + plot.height - h), cv::Point(x1, plot.y + plot.height - 1),
                             cv::Scalar(180, 110, 40), cv::FILLED);
  }
  auto fmt = [](double v) {
    std::ostringstream s;
    s << std::fixed << std::setprecision(v >= 10 || v <= -10 ? 0 : 2) << v;
    return s.str();
  };
  cv::putText(panel, fmt(lo), cv::Point(plot.x, panel.rows - 10), cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0),
              1, cv::LINE_AA);
  cv::putText(panel, fmt(hi), cv::Point(plot.x + plot.width - 30, panel.rows - 10), cv::FONT_HERSHEY_SIMPLEX, 0.4,
              cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  cv::putText(panel, std::to_string(peak), cv::Point(4, plot.y + 10), cv::FONT_HERSHEY_SIMPLEX, 0.35,
              cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
}


DatasetShardSummary Summarise(const train::TrainDataset& set) {
  DatasetShardSummary s;
  s.pairs = set.size();
  s.photo_pairs = set.CountKind(train::PairKind::kPhoto);
  s.clip_pairs = set.CountKind(train::PairKind::kClip);
  s.frames = set.frames();
  s.identities = static_cast<int64_t>(set.Identities().size());
  return s;
}

}  // namespace

double HistogramTop(const std::vector<double>& v) {
  return v.empty() ? 1.0 : std::max(1e-3, *std::max_element(v.begin(), v.end()) * 1.0001);
}

void DatasetInspectOptions::Validate() const {
  AVATAR_CHECK_OPTION(pairs >= 1 && pairs <= 64) << "--pairs must be in 1..64";
  AVATAR_CHECK_OPTION(kind == "real" || kind == "synthetic") << "--kind must be real or synthetic";
}

DatasetInspection InspectDataset(const DatasetInspectOptions& o, RunContext& ctx) {
  o.Validate();
  const fs::path dir = o.dir;
  // The shards are opened (and checked) before anything is written into DIR.
  const train::TrainDataset train_set = train::TrainDataset::Open(dir.string(), "train");
  const train::TrainDataset val_set = train::TrainDataset::Open(dir.string(), "val");
  const json ds = ReadJsonFile(dir / "dataset.json", "rebuild the dataset");
  DatasetInspection out;
  out.has_synthetic = ds.contains("synthetic");
  // Fields of the wrong type or missing name the file instead of failing inside the JSON library.
  fs::path reading = dir / "dataset.json";
  try {
    const json records = ReadJsonFile(reading = dir / ds.value("records", std::string("records.json")), "rebuild the dataset");
    const json pairs = ReadJsonFile(reading = dir / ds.value("pairs", std::string("pairs.json")), "rebuild the dataset");
    reading = dir / "dataset.json";
    out.size = ds.value("size", 0);
    for (auto it = ds.at("counts").begin(); it != ds.at("counts").end(); ++it)
      out.counts.emplace_back(it.key(), it.value().dump());
    const json& split = ds.at("split");
    out.split_seed = split.value("seed", 0);
    out.train_identities = static_cast<int64_t>(split.at("train").size());
    for (const auto& n : split.at("val")) out.val_identities.push_back(n.get<std::string>());
    reading = dir / ds.value("records", std::string("records.json"));
    for (const auto& r : records) {
      out.yaw.push_back(r.at("pose").at("yaw").get<double>());
      out.pitch.push_back(r.at("pose").at("pitch").get<double>());
      double s = 0.0;
      for (const auto& b : r.at("beta")) s += b.get<double>() * b.get<double>();
      out.expression.push_back(std::sqrt(s));
    }
    reading = dir / ds.value("pairs", std::string("pairs.json"));
    for (const auto& p : pairs) {
      if (p.at("kind") == "clip") {
        out.clip_d_yaw.push_back(p.at("d_yaw").get<double>());
        out.clip_d_pitch.push_back(p.at("d_pitch").get<double>());
        out.clip_d_expression.push_back(p.at("d_expression").get<double>());
      } else if (p.at("kind") == "synthetic") {
        out.synthetic_d_yaw.push_back(p.at("d_yaw").get<double>());
        out.synthetic_d_pitch.push_back(p.at("d_pitch").get<double>());
        out.synthetic_d_expression.push_back(p.at("d_expression").get<double>());
      }
    }
    if (out.has_synthetic) {
      reading = dir / ds.at("synthetic").get<std::string>();
      for (const auto& r : ReadJsonFile(reading, "rebuild the dataset")) {
        out.synthetic_yaw.push_back(r.at("pose").at("yaw").get<double>());
        out.synthetic_pitch.push_back(r.at("pose").at("pitch").get<double>());
      }
    }
  } catch (const json::exception& e) {
    throw InvalidInput(reading.string() + " does not have the expected content (" + e.what() +
                       "): rebuild the dataset");
  }
  ctx.ThrowIfCancelled();
  {
    // PNG: one row per pair kind, one column per quantity, shared ranges per column.
    const double yaw_hi = std::max(HistogramTop(out.clip_d_yaw), HistogramTop(out.synthetic_d_yaw));
    const double pitch_hi = std::max(HistogramTop(out.clip_d_pitch), HistogramTop(out.synthetic_d_pitch));
    const double expr_hi = std::max(HistogramTop(out.clip_d_expression), HistogramTop(out.synthetic_d_expression));
    const int pw = 320, ph = 200;
    cv::Mat sheet(2 * ph, 3 * pw, CV_8UC3, cv::Scalar(255, 255, 255));
    const std::vector<double>* rows_values[2][3] = {{&out.clip_d_yaw, &out.clip_d_pitch, &out.clip_d_expression},
                                                   {&out.synthetic_d_yaw, &out.synthetic_d_pitch,
                                                    &out.synthetic_d_expression}};
    const char* row_names[2] = {"clip pairs", "synthetic pairs"};
    const char* col_names[3] = {"|d yaw| deg", "|d pitch| deg", "|d beta|"};
    const double his[3] = {yaw_hi, pitch_hi, expr_hi};
    for (int r = 0; r < 2; ++r) {
      for (int c = 0; c < 3; ++c) {
        cv::Mat panel = sheet(cv::Rect(c * pw, r * ph, pw, ph));
        DrawHistogram(panel, std::string(row_names[r]) + ": " + col_names[c], *rows_values[r][c], 0.0, his[c], 16);
      }
    }
    const fs::path hist = o.histograms.empty() ? dir / "histograms.png" : fs::path(o.histograms);
    SaveImage(hist, sheet);
    out.histograms_path = hist.string();
  }

  out.train = Summarise(train_set);
  out.val = Summarise(val_set);
  std::optional<train::TrainDataset> synthetic_set;
  if (train::TrainDataset::HasSynthetic(dir.string())) {
    synthetic_set = train::TrainDataset::Open(dir.string(), "synthetic");
    DatasetShardSummary s = Summarise(*synthetic_set);
    const std::vector<int64_t> ids = synthetic_set->Identities(), val_ids = val_set.Identities();
    for (int64_t id : ids) s.validation_identities += std::count(val_ids.begin(), val_ids.end(), id);
    out.synthetic = s;
  }
  AVATAR_CHECK_OPTION(o.kind == "real" || synthetic_set) << "--kind synthetic: the dataset has no synthetic pairs";
  const train::TrainDataset& sheet_set = o.kind == "synthetic" ? *synthetic_set : train_set;
  std::vector<int64_t> candidates;
  if (o.identity.empty()) {
    candidates.resize(static_cast<size_t>(sheet_set.size()));
    std::iota(candidates.begin(), candidates.end(), int64_t{0});
  } else {
    // Identity ids are positions in split.json's list of names.
    const fs::path split_path = dir / "split.json";
    int64_t id = -1;
    try {
      const json names = ReadJsonFile(split_path, "rebuild the dataset").at("identities");
      for (size_t i = 0; i < names.size(); ++i)
        if (names[i].get<std::string>() == o.identity) id = static_cast<int64_t>(i);
    } catch (const json::exception& e) {
      throw InvalidInput(split_path.string() + " does not have the expected content (" + e.what() +
                         "): rebuild the dataset");
    }
    AVATAR_CHECK_OPTION(id >= 0) << "--identity: '" << o.identity << "' is not an identity of " << split_path.string();
    for (int64_t i = 0; i < sheet_set.size(); ++i)
      if (sheet_set.PairIdentity(i) == id) candidates.push_back(i);
    AVATAR_CHECK_OPTION(!candidates.empty())
        << "--identity: '" << o.identity << "' has no " << o.kind << " training pairs (a validation identity?)";
  }
  if (candidates.empty()) return out;
  std::mt19937_64 rng(static_cast<uint64_t>(o.seed));
  std::uniform_int_distribution<size_t> pick(0, candidates.size() - 1);
  std::vector<cv::Mat> rows;
  for (int k = 0; k < o.pairs; ++k) {
    ctx.ThrowIfCancelled();
    const train::TrainSample s = sheet_set.Get(candidates[pick(rng)]);
    std::vector<cv::Mat> tiles = {TensorToBgr(s.source), TensorToBgr(s.target),
                                  TensorToBgr(s.expression_image), TensorToBgr(s.neutral_mask, /*unit_range=*/true)};
    cv::Mat row;
    cv::hconcat(tiles, row);
    rows.push_back(row);
  }
  cv::Mat sheet;
  cv::vconcat(rows, sheet);
  const fs::path contact = o.contact.empty() ? dir / "contact.png" : fs::path(o.contact);
  SaveImage(contact, sheet);
  out.contact_path = contact.string();
  return out;
}

}  // namespace avatar
