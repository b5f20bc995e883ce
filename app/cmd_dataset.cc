// `avatar-studio dataset build --out DIR [...]` builds (or resumes) the training dataset from the
// whitelisted real photos and clips; `avatar-studio dataset inspect DIR` prints its counts, split
// and histograms and writes a contact sheet of random pairs.

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <random>

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
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("contact", contact, "Contact sheet PNG (default DIR/contact.png)");
    v("pairs", pairs, "Random pairs on the contact sheet");
    v("seed", seed, "Seed of the pair choice");
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
  return kExitOk;
}

int RunInspect(const std::vector<std::string>& args) {
  DatasetInspectOptions o;
  std::vector<std::string> positionals;
  if (!ParseCommand(o, args, "avatar-studio dataset inspect DIR [--contact FILE] [--pairs N]",
                    "Prints the counts, split and yaw/pitch/expression histograms of a built dataset and writes\n"
                    "a contact sheet of random training pairs (source | target | I_exp | M_neu).",
                    &positionals)) {
    return kExitOk;
  }
  AVATAR_CHECK_OPTION(positionals.size() == 1) << "expected one DIR, got " << positionals.size() << " arguments";
  AVATAR_CHECK_OPTION(o.pairs >= 1 && o.pairs <= 64) << "--pairs must be in 1..64";
  const fs::path dir = positionals[0];
  const json ds = LoadJson(dir / "dataset.json");
  const json records = LoadJson(dir / ds.value("records", std::string("records.json")));
  const json pairs = LoadJson(dir / ds.value("pairs", std::string("pairs.json")));
  std::cout << "dataset " << dir.string() << " (size " << ds.value("size", 0) << ")\n";
  for (auto it = ds["counts"].begin(); it != ds["counts"].end(); ++it)
    std::cout << "  " << std::left << std::setw(12) << it.key() << std::right << " " << it.value() << "\n";
  std::cout << "split (seed " << ds["split"].value("seed", 0) << "): " << ds["split"]["train"].size()
            << " train identities, " << ds["split"]["val"].size() << " val identities:\n  val:";
  for (const auto& n : ds["split"]["val"]) std::cout << " " << n.get<std::string>();
  std::cout << "\n";
  std::vector<double> yaw, pitch, expr, d_yaw, d_pitch, d_expr;
  for (const auto& r : records) {
    yaw.push_back(r["pose"]["yaw"].get<double>());
    pitch.push_back(r["pose"]["pitch"].get<double>());
    double s = 0.0;
    for (const auto& b : r["beta"]) s += b.get<double>() * b.get<double>();
    expr.push_back(std::sqrt(s));
  }
  for (const auto& p : pairs) {
    if (p["kind"] != "clip") continue;
    d_yaw.push_back(p["d_yaw"].get<double>());
    d_pitch.push_back(p["d_pitch"].get<double>());
    d_expr.push_back(p["d_expression"].get<double>());
  }
  auto top = [](const std::vector<double>& v) { return v.empty() ? 1.0 : std::max(1e-3, *std::max_element(v.begin(), v.end()) * 1.0001); };
  PrintHistogram("yaw of all frames (degrees)", yaw, -45.0, 45.0, 9);
  PrintHistogram("pitch of all frames (degrees)", pitch, -45.0, 45.0, 9);
  PrintHistogram("expression magnitude |beta| of all frames", expr, 0.0, top(expr), 8);
  PrintHistogram("clip pairs: |yaw difference| (degrees)", d_yaw, 0.0, top(d_yaw), 8);
  PrintHistogram("clip pairs: |pitch difference| (degrees)", d_pitch, 0.0, top(d_pitch), 8);
  PrintHistogram("clip pairs: expression difference |beta_s - beta_t|", d_expr, 0.0, top(d_expr), 8);

  const train::TrainDataset train_set = train::TrainDataset::Open(dir.string(), "train");
  const train::TrainDataset val_set = train::TrainDataset::Open(dir.string(), "val");
  std::cout << "shards: train " << train_set.size() << " pairs (" << train_set.CountKind(train::PairKind::kPhoto)
            << " photo, " << train_set.CountKind(train::PairKind::kClip) << " clip) over " << train_set.frames()
            << " frames, " << train_set.Identities().size() << " identities; val " << val_set.size() << " pairs over "
            << val_set.frames() << " frames, " << val_set.Identities().size() << " identities\n";
  if (train_set.size() == 0) return kExitOk;
  std::mt19937_64 rng(static_cast<uint64_t>(o.seed));
  std::uniform_int_distribution<int64_t> pick(0, train_set.size() - 1);
  std::vector<cv::Mat> rows;
  for (int k = 0; k < o.pairs; ++k) {
    const train::TrainSample s = train_set.Get(pick(rng));
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
  std::cout << "contact sheet (source | target | I_exp | M_neu, " << o.pairs << " random train pairs): "
            << contact.string() << "\n";
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
