#pragma once
// Private to core/tools (not for other layers): the last stage of RunEvaluation (evaluate.h), kept
// in evaluate_report.cc: the row averages, eval.json, eval.md and contact.png. evaluate.cc fills
// the per-pair values below batch by batch.

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/model/checkpoint.h"
#include "core/model/model_config.h"
#include "core/tools/evaluate.h"
#include "core/tools/face_metrics.h"

namespace avatar::evaluation {

// Per-pair values of one row.
struct RowPair {
  std::string kind;  // pair kind (photo, clip, ...)
  std::map<std::string, double> full, masked;
  face::PairFaceMetrics face;
  bool has_face = false;
};

struct RowState {
  EvalRow row;
  std::vector<RowPair> pairs;
};

// The pairs shown on contact.png: one row of cells per pair, and its caption.
struct ContactRows {
  std::vector<std::vector<cv::Mat>> cells;
  std::vector<std::string> captions;
};

// What the outputs say about the run besides the rows.
struct RunDescription {
  std::string fingerprint;             // of the checkpoint file
  const ModelConfig* config = nullptr;  // the network's
  CheckpointInfo info;                 // the checkpoint's
  bool sr = false;                     // the SR row was evaluated (sr_trained)
  int64_t split_pairs = 0;             // pairs in the evaluated split
  int64_t render_size = 0;             // the network's render size
  int64_t dataset_size = 0;            // side of the dataset's images
};

// A value for eval.json: null when not finite (JSON has no NaN).
nlohmann::json Num(double v);

// report->rows and report->rows_by_kind: the averages of `rows` over all pairs, then per pair kind.
void SummariseRows(const std::vector<RowState>& rows, EvaluateReport* report);

// Writes contact.png (when `contact` has rows), eval.md and eval.json (last) into options.out and
// sets report->markdown and the paths.
void WriteEvaluationOutputs(const EvaluateOptions& options, const RunDescription& run, const nlohmann::json& per_pair,
                            const ContactRows& contact, EvaluateReport* report);

}  // namespace avatar::evaluation
