#pragma once
// A look at a built training dataset (`avatar-studio dataset inspect DIR`): its counts and
// identity split from dataset.json, the pose and expression values of every frame and pair (for
// histograms), the shards' sizes, a histogram sheet (histograms.png) and a contact sheet of
// random pairs (source | target | I_exp | M_neu).

#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/util/run_context.h"

namespace avatar {

struct DatasetInspectOptions {
  // Dataset folder written by `dataset build`.
  std::string dir;
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
  // Only pairs of this identity (a name from split.json's identities) on the contact sheet; "" = all.
  // A sheet of one public-domain identity (grace_hopper) is one that may be published.
  std::string identity;

  template <typename V>
  void Visit(V&& v) {
    v("contact", contact, "Contact sheet PNG (default DIR/contact.png)");
    v("pairs", pairs, "Random pairs on the contact sheet");
    v("seed", seed, "Seed of the pair choice");
    v("kind", kind, "Pairs on the contact sheet: real (training split) or synthetic");
    v("histograms", histograms, "Histogram PNG of clip and synthetic pairs (default DIR/histograms.png)");
    v("identity", identity, "Only pairs of this identity (a name in split.json) on the contact sheet");
  }
  // Throws InvalidOptions (pairs, kind; not the folder).
  void Validate() const;
};

// One shard's size.
struct DatasetShardSummary {
  int64_t pairs = 0, photo_pairs = 0, clip_pairs = 0, frames = 0, identities = 0;
  int64_t validation_identities = 0;  // synthetic shard: validation identities among its heads (should be 0)
};

struct DatasetInspection {
  int size = 0;                                             // image side (dataset.json)
  std::vector<std::pair<std::string, std::string>> counts;  // dataset.json "counts": name, value as JSON text
  int64_t split_seed = 0;
  int64_t train_identities = 0;
  std::vector<std::string> val_identities;                  // their names
  bool has_synthetic = false;                               // dataset.json names synthetic frames
  // Per frame (records.json): yaw, pitch (degrees), |beta|.
  std::vector<double> yaw, pitch, expression;
  // Per clip pair: |d yaw|, |d pitch|, |beta_s - beta_t|; the same for synthetic pairs.
  std::vector<double> clip_d_yaw, clip_d_pitch, clip_d_expression;
  std::vector<double> synthetic_d_yaw, synthetic_d_pitch, synthetic_d_expression;
  // Per synthetic frame (has_synthetic): camera yaw and pitch.
  std::vector<double> synthetic_yaw, synthetic_pitch;
  std::string histograms_path;                              // the PNG written
  DatasetShardSummary train, val;
  std::optional<DatasetShardSummary> synthetic;             // shards/synthetic.pt when present
  std::string contact_path;                                 // "" when the sheet's split is empty
};

// Reads the dataset (the shards are opened and checked before anything is written into DIR) and
// writes the histogram and contact sheets. Throws InvalidOptions (also --kind synthetic on a
// dataset without synthetic pairs, after the histograms are written); Io; InvalidInput naming a
// JSON file of the wrong content or a corrupt shard; Cancelled.
DatasetInspection InspectDataset(const DatasetInspectOptions& options, RunContext& ctx);

// The upper end of a histogram of non-negative values: just above their maximum (1 when empty).
double HistogramTop(const std::vector<double>& values);

}  // namespace avatar
