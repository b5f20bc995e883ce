// `avatar-studio dataset build --out DIR [...]` builds (or resumes) the training dataset from the
// whitelisted real photos and clips; `avatar-studio dataset inspect DIR` prints its counts, split
// and histograms and writes a contact sheet of random pairs.

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <iostream>

#include "app/commands.h"
#include "core/tools/dataset_build.h"
#include "core/tools/dataset_inspect.h"
#include "core/util/error.h"

namespace avatar::app {
namespace {

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

struct DatasetInspectCommandOptions {
  // Sheets, pairs, seed, kind.
  DatasetInspectOptions inspect;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    inspect.Visit(v);
    common.Visit(v);
  }
};

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
  DatasetInspectCommandOptions o;
  std::vector<std::string> positionals;
  if (!ParseCommand(o, args, "avatar-studio dataset inspect DIR [--contact FILE] [--pairs N] [--kind real|synthetic] [--identity NAME]",
                    "Prints the counts, split and yaw/pitch/expression histograms of a built dataset and writes\n"
                    "a contact sheet of random training pairs (source | target | I_exp | M_neu).",
                    &positionals)) {
    return kExitOk;
  }
  AVATAR_CHECK_OPTION(positionals.size() == 1) << "expected one DIR, got " << positionals.size() << " arguments";
  o.inspect.dir = positionals[0];
  const DatasetInspection d = InspectDataset(o.inspect, ProcessContext());
  std::cout << "dataset " << o.inspect.dir << " (size " << d.size << ")\n";
  for (const auto& [name, value] : d.counts)
    std::cout << "  " << std::left << std::setw(12) << name << std::right << " " << value << "\n";
  std::cout << "split (seed " << d.split_seed << "): " << d.train_identities << " train identities, "
            << d.val_identities.size() << " val identities:\n  val:";
  for (const auto& n : d.val_identities) std::cout << " " << n;
  std::cout << "\n";
  const auto top = HistogramTop;
  PrintHistogram("yaw of all frames (degrees)", d.yaw, -45.0, 45.0, 9);
  PrintHistogram("pitch of all frames (degrees)", d.pitch, -45.0, 45.0, 9);
  PrintHistogram("expression magnitude |beta| of all frames", d.expression, 0.0, top(d.expression), 8);
  PrintHistogram("clip pairs: |yaw difference| (degrees)", d.clip_d_yaw, 0.0, top(d.clip_d_yaw), 8);
  PrintHistogram("clip pairs: |pitch difference| (degrees)", d.clip_d_pitch, 0.0, top(d.clip_d_pitch), 8);
  PrintHistogram("clip pairs: expression difference |beta_s - beta_t|", d.clip_d_expression, 0.0,
                 top(d.clip_d_expression), 8);
  if (d.has_synthetic) {
    PrintHistogram("synthetic frames: camera yaw (degrees)", d.synthetic_yaw, -45.0, 45.0, 9);
    PrintHistogram("synthetic frames: camera pitch (degrees)", d.synthetic_pitch, -45.0, 45.0, 9);
    PrintHistogram("synthetic pairs: |yaw difference| (degrees)", d.synthetic_d_yaw, 0.0, top(d.synthetic_d_yaw), 8);
    PrintHistogram("synthetic pairs: |pitch difference| (degrees)", d.synthetic_d_pitch, 0.0,
                   top(d.synthetic_d_pitch), 8);
    PrintHistogram("synthetic pairs: expression difference |beta_s - beta_t|", d.synthetic_d_expression, 0.0,
                   top(d.synthetic_d_expression), 8);
  }
  std::cout << "histograms (clip and synthetic pairs: |d yaw|, |d pitch|, |d beta|): " << d.histograms_path << "\n";
  std::cout << "shards: train " << d.train.pairs << " pairs (" << d.train.photo_pairs << " photo, "
            << d.train.clip_pairs << " clip) over " << d.train.frames << " frames, " << d.train.identities
            << " identities; val " << d.val.pairs << " pairs over " << d.val.frames << " frames, " << d.val.identities
            << " identities\n";
  if (d.synthetic) {
    std::cout << "synthetic: " << d.synthetic->pairs << " pairs over " << d.synthetic->frames << " frames of "
              << d.synthetic->identities << " training identities (" << d.synthetic->validation_identities
              << " validation identities among them)\n";
  } else {
    std::cout << "synthetic: none (build with --synthetic N)\n";
  }
  if (d.contact_path.empty()) return kExitOk;
  std::cout << "contact sheet (source | target | I_exp | M_neu, " << o.inspect.pairs << " random "
            << (o.inspect.kind == "synthetic" ? "synthetic" : "train") << " pairs): " << d.contact_path << "\n";
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
