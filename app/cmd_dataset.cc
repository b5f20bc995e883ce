// `avatar-studio dataset build --out DIR [...]` builds (or resumes) the training dataset from the
// whitelisted real photos and clips; `avatar-studio dataset inspect DIR` prints its counts, split
// and histograms and writes a contact sheet of random pairs.

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <optional>
#include <random>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "app/commands.h"
#include "core/io/atomic_file.h"
#include "core/io/image_io.h"
#include "core/pipeline/dataset_build.h"
#include "core/train/dataset.h"
#include "core/util/error.h"

namespace avatar::app {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

struct DatasetBuildCommandOptions {
  // What to build.
  DatasetBuildOptions build;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    build.Visit(v);
    common.Visit(v);
  }
};

struct DatasetInspectOptions {
  // Contact sheet path ("" = DIR/contact.png).
  std::string contact;
  // Random pairs on the contact sheet.
  int pairs = 8;
  // Seed of the pair choice.
  int64_t seed = 1;
  // Pairs on the contact sheet: real (training split) or synthetic.
  std::string kind = "real";
  // Histogram PNG path ("" = DIR/histograms.png).
  std::string histograms;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("contact", contact, "Contact sheet PNG (default DIR/contact.png)");
    v("pairs", pairs, "Random pairs on the contact sheet");
    v("seed", seed, "Seed of the pair choice");
    v("kind", kind, "Pairs on the contact sheet: real (training split) or synthetic");
    v("histograms", histograms, "Histogram PNG of clip and synthetic pairs (default DIR/histograms.png)");
    common.Visit(v);
  }
};

json LoadJson(const fs::path& path) {
  try {
    return json::parse(ReadFileBytes(path));
  } catch (const json::exception& e) {
    throw InvalidInput(path.string() + " is not valid JSON (" + e.what() + "): rebuild the dataset");
  }
}

// A text histogram of `values` over [lo,hi] in `bins` bins.
void PrintHistogram(const std::string& title, const std::vector<double>& values, double lo, double hi, int bins) {
  std::cout << title << " (" << values.size() << " values)\n";
  if (values.empty()) return;
  std::vector<int> count(bins, 0);
  for (double v : values) {
    const int b = std::clamp(static_cast<int>(std::floor((v - lo) / (hi - lo) * bins)), 0, bins - 1);
    ++count[b];
  }
  const int peak = *std::max_element(count.begin(), count.end());
  for (int b = 0; b < bins; ++b) {
    const double a = lo + (hi - lo) * b / bins;
    const double z = lo + (hi - lo) * (b + 1) / bins;
    std::cout << "  [" << std::setw(7) << std::fixed << std::setprecision(2) << a << "," << std::setw(7) << z << ") "
              << std::setw(6) << count[b] << " " << std::string(peak > 0 ? count[b] * 40 / peak : 0, '#') << "\n";
  }
}

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

// [C,S,S] float in [-1,1] (signed) or [0,1] -> BGR8.
cv::Mat TileImage(const torch::Tensor& t, bool is_signed) {
  torch::Tensor x = is_signed ? t.add(1.0).mul(127.5) : t.mul(255.0);
  x = x.clamp(0, 255).to(torch::kUInt8).permute({1, 2, 0}).contiguous();
  if (x.size(2) == 1) x = x.repeat({1, 1, 3});
  cv::Mat rgb(static_cast<int>(x.size(0)), static_cast<int>(x.size(1)), CV_8UC3, x.data_ptr<uint8_t>());
  cv::Mat bgr;
  cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
  return bgr;
}

int RunBuild(const std::vector<std::string>& args) {
  DatasetBuildCommandOptions o;
  std::vector<std::string> positionals;
  if (!ParseCommand(o, args,
                    "avatar-studio dataset build --out DIR [--size 128|256|512] [--synthetic N] [--seed S] "
                    "[--val-identities K]",
                    "Builds the training dataset from the whitelisted real photos and clips (every face through the\n"
                    "inference preprocessing; clip frame pairs; identity split). A rerun resumes; Ctrl+C stops\n"
                    "cleanly.",
                    &positionals)) {
    return kExitOk;
  }
  AVATAR_CHECK_OPTION(positionals.empty()) << "dataset build takes no positional arguments";
  o.build.data_dir = o.common.data_dir;
  o.build.Validate();
  std::vector<DatasetPhoto> photos;
  std::vector<DatasetClip> clips;
  WhitelistInputs(o.build.data_dir, &photos, &clips);
  const DatasetBuildReport r = BuildDataset(o.build, photos, clips, ProcessContext());
  std::cout << "dataset " << o.build.out_dir << ": " << r.faces << " real faces from " << r.photos << " photos, "
            << r.clip_frames << " clip frames, " << r.clip_pairs << " clip pairs, " << r.identities
            << " identities (" << r.val_identities << " for validation), " << r.train_pairs << " train / "
            << r.val_pairs << " val pairs, " << r.skipped << " skipped (see build.log), " << std::fixed
            << std::setprecision(1) << r.seconds << " s\n";
  if (o.build.synthetic > 0) {
    std::cout << "synthetic: " << r.synthetic_pairs << " pairs over " << r.synthetic_frames << " frames of "
              << r.synthetic_heads << " training heads (" << std::setprecision(1) << r.synthetic_seconds
              << " s rendering in this run)\n";
  }
  return kExitOk;
}

int RunInspect(const std::vector<std::string>& args) {
  DatasetInspectOptions o;
  std::vector<std::string> positionals;
  if (!ParseCommand(o, args, "avatar-studio dataset inspect DIR [--contact FILE] [--pairs N] [--kind real|synthetic]",
                    "Prints the counts, split and yaw/pitch/expression histograms of a built dataset and writes\n"
                    "a contact sheet of random training pairs (source | target | I_exp | M_neu).",
                    &positionals)) {
    return kExitOk;
  }
  AVATAR_CHECK_OPTION(positionals.size() == 1) << "expected one DIR, got " << positionals.size() << " arguments";
  AVATAR_CHECK_OPTION(o.pairs >= 1 && o.pairs <= 64) << "--pairs must be in 1..64";
  AVATAR_CHECK_OPTION(o.kind == "real" || o.kind == "synthetic") << "--kind must be real or synthetic";
  const fs::path dir = positionals[0];
  // The shards are opened (and checked) before anything is written into DIR.
  const train::TrainDataset train_set = train::TrainDataset::Open(dir.string(), "train");
  const train::TrainDataset val_set = train::TrainDataset::Open(dir.string(), "val");
  const json ds = LoadJson(dir / "dataset.json");
  std::vector<double> yaw, pitch, expr, d_yaw, d_pitch, d_expr, s_yaw, s_pitch, s_expr;
  std::vector<double> f_yaw, f_pitch;
  const bool has_synthetic = ds.contains("synthetic");
  // Fields of the wrong type or missing name the file instead of failing inside the JSON library.
  fs::path reading = dir / "dataset.json";
  try {
    const json records = LoadJson(reading = dir / ds.value("records", std::string("records.json")));
    const json pairs = LoadJson(reading = dir / ds.value("pairs", std::string("pairs.json")));
    reading = dir / "dataset.json";
    std::cout << "dataset " << dir.string() << " (size " << ds.value("size", 0) << ")\n";
    for (auto it = ds.at("counts").begin(); it != ds.at("counts").end(); ++it)
      std::cout << "  " << std::left << std::setw(12) << it.key() << std::right << " " << it.value() << "\n";
    const json& split = ds.at("split");
    std::cout << "split (seed " << split.value("seed", 0) << "): " << split.at("train").size() << " train identities, "
              << split.at("val").size() << " val identities:\n  val:";
    for (const auto& n : split.at("val")) std::cout << " " << n.get<std::string>();
    std::cout << "\n";
    reading = dir / ds.value("records", std::string("records.json"));
    for (const auto& r : records) {
      yaw.push_back(r.at("pose").at("yaw").get<double>());
      pitch.push_back(r.at("pose").at("pitch").get<double>());
      double s = 0.0;
      for (const auto& b : r.at("beta")) s += b.get<double>() * b.get<double>();
      expr.push_back(std::sqrt(s));
    }
    reading = dir / ds.value("pairs", std::string("pairs.json"));
    for (const auto& p : pairs) {
      if (p.at("kind") == "clip") {
        d_yaw.push_back(p.at("d_yaw").get<double>());
        d_pitch.push_back(p.at("d_pitch").get<double>());
        d_expr.push_back(p.at("d_expression").get<double>());
      } else if (p.at("kind") == "synthetic") {
        s_yaw.push_back(p.at("d_yaw").get<double>());
        s_pitch.push_back(p.at("d_pitch").get<double>());
        s_expr.push_back(p.at("d_expression").get<double>());
      }
    }
    if (has_synthetic) {
      reading = dir / ds.at("synthetic").get<std::string>();
      for (const auto& r : LoadJson(reading)) {
        f_yaw.push_back(r.at("pose").at("yaw").get<double>());
        f_pitch.push_back(r.at("pose").at("pitch").get<double>());
      }
    }
  } catch (const json::exception& e) {
    throw InvalidInput(reading.string() + " does not have the expected content (" + e.what() +
                       "): rebuild the dataset");
  }
  auto top = [](const std::vector<double>& v) { return v.empty() ? 1.0 : std::max(1e-3, *std::max_element(v.begin(), v.end()) * 1.0001); };
  PrintHistogram("yaw of all frames (degrees)", yaw, -45.0, 45.0, 9);
  PrintHistogram("pitch of all frames (degrees)", pitch, -45.0, 45.0, 9);
  PrintHistogram("expression magnitude |beta| of all frames", expr, 0.0, top(expr), 8);
  PrintHistogram("clip pairs: |yaw difference| (degrees)", d_yaw, 0.0, top(d_yaw), 8);
  PrintHistogram("clip pairs: |pitch difference| (degrees)", d_pitch, 0.0, top(d_pitch), 8);
  PrintHistogram("clip pairs: expression difference |beta_s - beta_t|", d_expr, 0.0, top(d_expr), 8);
  if (has_synthetic) {
    PrintHistogram("synthetic frames: camera yaw (degrees)", f_yaw, -45.0, 45.0, 9);
    PrintHistogram("synthetic frames: camera pitch (degrees)", f_pitch, -45.0, 45.0, 9);
    PrintHistogram("synthetic pairs: |yaw difference| (degrees)", s_yaw, 0.0, top(s_yaw), 8);
    PrintHistogram("synthetic pairs: |pitch difference| (degrees)", s_pitch, 0.0, top(s_pitch), 8);
    PrintHistogram("synthetic pairs: expression difference |beta_s - beta_t|", s_expr, 0.0, top(s_expr), 8);
  }
  {
    // PNG: one row per pair kind, one column per quantity, shared ranges per column.
    const double yaw_hi = std::max(top(d_yaw), top(s_yaw)), pitch_hi = std::max(top(d_pitch), top(s_pitch));
    const double expr_hi = std::max(top(d_expr), top(s_expr));
    const int pw = 320, ph = 200;
    cv::Mat sheet(2 * ph, 3 * pw, CV_8UC3, cv::Scalar(255, 255, 255));
    const std::vector<double>* rows_values[2][3] = {{&d_yaw, &d_pitch, &d_expr},
                                                   {&s_yaw, &s_pitch, &s_expr}};
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
    std::cout << "histograms (clip and synthetic pairs: |d yaw|, |d pitch|, |d beta|): " << hist.string() << "\n";
  }

  std::cout << "shards: train " << train_set.size() << " pairs (" << train_set.CountKind(train::PairKind::kPhoto)
            << " photo, " << train_set.CountKind(train::PairKind::kClip) << " clip) over " << train_set.frames()
            << " frames, " << train_set.Identities().size() << " identities; val " << val_set.size() << " pairs over "
            << val_set.frames() << " frames, " << val_set.Identities().size() << " identities\n";
  std::optional<train::TrainDataset> synthetic_set;
  if (train::TrainDataset::HasSynthetic(dir.string())) {
    synthetic_set = train::TrainDataset::Open(dir.string(), "synthetic");
    const std::vector<int64_t> ids = synthetic_set->Identities(), val_ids = val_set.Identities();
    int64_t leaked = 0;
    for (int64_t id : ids) leaked += std::count(val_ids.begin(), val_ids.end(), id);
    std::cout << "synthetic: " << synthetic_set->size() << " pairs over " << synthetic_set->frames() << " frames of "
              << ids.size() << " training identities (" << leaked << " validation identities among them)\n";
  } else {
    std::cout << "synthetic: none (build with --synthetic N)\n";
  }
  AVATAR_CHECK_OPTION(o.kind == "real" || o.kind == "synthetic") << "--kind must be real or synthetic";
  AVATAR_CHECK_OPTION(o.kind == "real" || synthetic_set) << "--kind synthetic: the dataset has no synthetic pairs";
  const train::TrainDataset& sheet_set = o.kind == "synthetic" ? *synthetic_set : train_set;
  if (sheet_set.size() == 0) return kExitOk;
  std::mt19937_64 rng(static_cast<uint64_t>(o.seed));
  std::uniform_int_distribution<int64_t> pick(0, sheet_set.size() - 1);
  std::vector<cv::Mat> rows;
  for (int k = 0; k < o.pairs; ++k) {
    const train::TrainSample s = sheet_set.Get(pick(rng));
    std::vector<cv::Mat> tiles = {TileImage(s.source, true), TileImage(s.target, true),
                                  TileImage(s.expression_image, true), TileImage(s.neutral_mask, false)};
    cv::Mat row;
    cv::hconcat(tiles, row);
    rows.push_back(row);
  }
  cv::Mat sheet;
  cv::vconcat(rows, sheet);
  const fs::path contact = o.contact.empty() ? dir / "contact.png" : fs::path(o.contact);
  SaveImage(contact, sheet);
  std::cout << "contact sheet (source | target | I_exp | M_neu, " << o.pairs << " random "
            << (o.kind == "synthetic" ? "synthetic" : "train") << " pairs): " << contact.string() << "\n";
  return kExitOk;
}

int RunDataset(const std::vector<std::string>& args) {
  return GuardedRun("dataset", [&] {
    const std::string usage =
        "Usage: avatar-studio dataset build --out DIR [options] | avatar-studio dataset inspect DIR\n";
    if (args.empty() || args[0] == "--help" || args[0] == "-h") {
      std::cout << usage;
      return args.empty() ? kExitUsage : kExitOk;
    }
    const std::vector<std::string> rest(args.begin() + 1, args.end());
    if (args[0] == "build") return RunBuild(rest);
    if (args[0] == "inspect") return RunInspect(rest);
    throw InvalidOptions("unknown dataset subcommand '" + args[0] + "': use build or inspect");
  });
}

}  // namespace

AVATAR_REGISTER_COMMAND("dataset", "build or inspect the training dataset", RunDataset);

}  // namespace avatar::app
