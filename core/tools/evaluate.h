#pragma once
// Evaluation of a trained network on a dataset split (GOHA, Li et al. 2023, section 4), the
// back end of `avatar-studio eval`.
//
// For each evaluated pair (source I_s, target I_t with camera C_t and expression beta_t) it
// renders, deterministically, at the target camera:
//   I_c       R(T_c, C_t)                  canonical planes only
//   I_c+e     R(T_c + T_e, C_t)            + expression planes
//   I_c+e+p   R(T_c + T_e + T_p, C_t)      + appearance planes (the network's output)
//   SR        SR(I_c+e+p)                  only when the checkpoint's SR module was trained
//   baseline  the morphable preview: the source's fitted morphable face (identity, scale and
//             texture sampled from the source crop) rendered at C_t with beta_t (records.json)
// and compares each with the target, matted onto the black background and resized to the
// row's resolution (render_size; sr_size for SR; the baseline is rendered at the dataset size
// and box-averaged to render_size, so that every neural row and the baseline are compared at
// one resolution):
//   image metrics (core/train/metrics.h) twice: on the full image, and weighted by the target
//   matte (the person only): PSNR (peak = the [-1,1] range), SSIM, L1 (on [-1,1]) and the
//   perceptual distance on MobileNetV2 features (never LPIPS);
//   face metrics (core/tools/face_metrics.h) against the matted target at the dataset size:
//   CSIM, AED (our morphable coefficients), APD (fr_pose, degrees), with no-face counts.
// Averages are over pairs (face metrics over the pairs with a face in both images).
// Outputs, written atomically into OUT: eval.json (options, checkpoint, averages per row,
// per-pair values), eval.md (a Markdown table) and contact.png (a few pairs; columns source,
// target, baseline, I_c, I_c+e, I_c+e+p[, SR]).
//
// Ablation checkpoints (issue 14): with expression bases T_e comes from the target's morphable
// coefficients beta_t (the shard's target_expression) instead of I_exp; without an appearance
// branch T_p = 0, so the I_c+e+p row (key "full", renamed "I_c+e+p = I_c+e (no appearance
// branch)", with a note in eval.json) repeats the I_c+e numbers: it is still the network's output,
// which the ablation table compares. eval.md names the ablation under the checkpoint line.

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "core/tools/face_metrics.h"
#include "core/train/dataset.h"
#include "core/train/metrics.h"
#include "core/util/run_context.h"

namespace avatar {

struct EvaluateOptions {
  // Model checkpoint (.ckpt written by `train` or SaveModelCheckpoint).
  std::string checkpoint;
  // Dataset folder written by `avatar-studio dataset build`.
  std::string data;
  // Split to evaluate: val or train.
  std::string split = "val";
  // Output folder (created).
  std::string out = "eval";
  // Pairs to evaluate (0 = all): equal shares per pair kind, evenly spaced within each kind.
  int max_pairs = 64;
  // Pairs per forward pass.
  int batch_size = 4;
  // Pairs shown in contact.png.
  int contact_rows = 4;
  // Device of the network: cpu or cuda[:N].
  std::string device = "cpu";
  // Compute CSIM / AED / APD.
  bool face_metrics = true;
  // Compute the perceptual distance (MobileNetV2 features).
  bool perceptual = true;
  // Render the morphable-preview baseline.
  bool baseline = true;
  // Progress line with ETA on stderr.
  bool print_progress = true;
  // Folder with the installed models ("" = AVATAR_DATA_DIR, then ~/.cache/avatar-studio).
  std::string data_dir;
  // Face metrics settings (data_dir is taken from above).
  face::FaceMetricsOptions face;

  template <typename V>
  void Visit(V&& v) {
    v("checkpoint", checkpoint, "Model checkpoint to evaluate (.ckpt)");
    v("data", data, "Dataset folder written by 'avatar-studio dataset build'", 'd');
    v("split", split, "Split to evaluate: val or train");
    v("out", out, "Output folder (eval.md, eval.json, contact.png)", 'o');
    v("max_pairs", max_pairs, "Pairs to evaluate (0 = all), equal shares per pair kind");
    v("batch_size", batch_size, "Pairs per forward pass");
    v("contact_rows", contact_rows, "Pairs shown in contact.png");
    v("device", device, "Device of the network: cpu or cuda[:N]");
    v("face_metrics", face_metrics, "Compute CSIM, AED and APD");
    v("perceptual", perceptual, "Compute the perceptual distance (MobileNetV2 features)");
    v("baseline", baseline, "Render the morphable-preview baseline");
    v("progress", print_progress, "Progress line with ETA on stderr");
    face.Visit(v);
  }
  // Throws InvalidOptions.
  void Validate() const;
};

// Averages of one row of the table.
struct EvalRow {
  std::string key;         // baseline, canonical, expression, full, sr
  std::string name;        // as printed in the table
  bool available = true;   // false: no numbers (note says why)
  std::string note;
  int resolution = 0;      // side of the compared images
  // Means over pairs of psnr, ssim, l1, perceptual (absent when not computed): on the full image
  // and within the target matte.
  std::map<std::string, double> full, masked;
  face::FaceMetricsSummary face;  // face.pairs == 0 when face metrics are off
};

struct EvaluateReport {
  int pairs = 0;                          // pairs evaluated
  std::map<std::string, int> pairs_by_kind;
  std::vector<int64_t> pair_indices;      // indices into the split
  std::vector<EvalRow> rows;              // baseline, canonical, expression, full, sr, upsampled (bicubic full)
  std::map<std::string, std::vector<EvalRow>> rows_by_kind;  // the same rows per pair kind
  double seconds = 0.0;
  std::string json_path, markdown_path, contact_path;
  std::string markdown;                   // the table file's text
};

// The pair indices evaluated out of `dataset`: all when max_pairs is 0 or at least the size;
// else equal shares per pair kind (a kind with fewer pairs gives its leftover share to the
// others), evenly spaced within each kind; sorted.
std::vector<int64_t> ChooseEvaluationPairs(const train::TrainDataset& dataset, int max_pairs);

class PerceptualLoss;  // core/train/perceptual.h

// The image metrics of one comparison as the evaluation computes them (core/train/metrics.h):
// PSNR, SSIM, L1 and, with `perceptual` (may be null), the perceptual distance; images under
// 32 px are upsampled bilinearly for the perceptual term only. a, b [B,3,H,W] in [-1,1]; mask
// undefined (the full image) or [B,1,H,W] in [0,1]. Also used by `bench accuracy`.
train::ImageMetrics EvaluationImageMetrics(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask,
                                           const PerceptualLoss* perceptual);

// Runs the evaluation and writes the outputs. Throws InvalidOptions; Io naming a missing
// checkpoint, data folder or unwritable output folder; ModelLoad for a bad checkpoint (naming
// it); InvalidInput for a corrupt dataset; MissingData for missing face / perceptual models;
// Cancelled (nothing is written then).
EvaluateReport RunEvaluation(const EvaluateOptions& options, RunContext& ctx);

}  // namespace avatar
