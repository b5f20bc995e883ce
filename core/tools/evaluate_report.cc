// The report stage of the evaluation (evaluate_impl.h): the row averages over pairs and per pair
// kind, eval.json, eval.md and the contact sheet.
#include "core/tools/evaluate_impl.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "core/io/atomic_file.h"
#include "core/io/image_io.h"
#include "core/util/text.h"

namespace avatar::evaluation {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// Averages of a row over its pairs (of one kind when `kind` is not empty).
EvalRow Average(const RowState& s, const std::string& kind = {}) {
  EvalRow row = s.row;
  if (!row.available) return row;
  std::map<std::string, double> full, masked;
  std::vector<face::PairFaceMetrics> faces;
  int n = 0;
  for (const auto& p : s.pairs) {
    if (!kind.empty() && p.kind != kind) continue;
    ++n;
    for (const auto& [k, v] : p.full) full[k] += v;
    for (const auto& [k, v] : p.masked) masked[k] += v;
    if (p.has_face) faces.push_back(p.face);
  }
  if (n == 0) return row;
  for (const auto& [k, v] : full) row.full[k] = v / n;
  for (const auto& [k, v] : masked) row.masked[k] = v / n;
  if (!faces.empty()) row.face = face::FaceMetrics::Summarise(faces);
  return row;
}

// One Markdown table of rows.
std::string Table(const std::vector<EvalRow>& rows) {
  std::ostringstream md;
  md << "| row | px | PSNR | SSIM | L1 | perceptual | PSNR (matte) | SSIM (matte) | L1 (matte) | perceptual (matte) | CSIM "
        "| AED | APD | faces |\n";
  md << "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  auto get = [](const std::map<std::string, double>& m, const char* k, int digits) {
    const auto it = m.find(k);
    return it == m.end() ? std::string("-") : Fixed(it->second, digits);
  };
  for (const auto& r : rows) {
    md << "| " << r.name << " | " << r.resolution << " | ";
    if (!r.available) {
      md << r.note << " | | | | | | | | | | | |\n";
      continue;
    }
    md << get(r.full, "psnr", 2) << " | " << get(r.full, "ssim", 3) << " | " << get(r.full, "l1", 3) << " | "
       << get(r.full, "perceptual", 3) << " | " << get(r.masked, "psnr", 2) << " | " << get(r.masked, "ssim", 3)
       << " | " << get(r.masked, "l1", 3) << " | " << get(r.masked, "perceptual", 3) << " | ";
    if (r.face.pairs == 0) {
      md << "- | - | - | - |\n";
      continue;
    }
    const bool any = r.face.valid > 0;
    md << (any ? Fixed(r.face.csim, 3) : "no face") << " | " << (any && r.face.has_aed ? Fixed(r.face.aed, 3) : "-")
       << " | " << (any ? Fixed(r.face.apd, 2) : "-") << " | " << r.face.valid << "/" << r.face.pairs;
    if (r.face.no_face_render > 0 || r.face.no_face_reference > 0)
      md << " (no face: " << r.face.no_face_render << " render, " << r.face.no_face_reference << " target)";
    md << " |\n";
  }
  return md.str();
}

// The Markdown report.
std::string Markdown(const EvaluateReport& report, const json& header) {
  std::ostringstream md;
  md << "# Evaluation\n\n";
  md << "- checkpoint: `" << header["checkpoint"]["path"].get<std::string>() << "` (config "
     << header["checkpoint"]["config"].get<std::string>() << ", step " << header["checkpoint"]["step"].get<int64_t>()
     << ", SR trained: " << (header["checkpoint"]["sr_trained"].get<bool>() ? "yes" : "no") << ", fingerprint "
     << header["checkpoint"]["fingerprint"].get<std::string>() << ")\n";
  const bool appearance = header["checkpoint"]["appearance_branch"].get<bool>();
  const bool bases = header["checkpoint"]["expression_model"].get<std::string>() == "bases";
  if (!appearance || bases) {
    md << "- ablation:";
    if (!appearance) md << " no appearance branch (T_p = 0: the I_c+e+p row is the network's output I_c+e);";
    if (bases)
      md << " linear expression bases (T_e mixed from " << header["checkpoint"]["expression_coefficients"].get<int>()
         << " morphable expression coefficients instead of E_e over I_exp);";
    md << "\n";
  }
  md << "- data: `" << header["data"].get<std::string>() << "`, split " << header["split"].get<std::string>() << ", "
     << report.pairs << " of " << header["split_pairs"].get<int64_t>() << " pairs (";
  bool first = true;
  for (const auto& [k, n] : report.pairs_by_kind) {
    md << (first ? "" : ", ") << n << " " << k;
    first = false;
  }
  md << ")\n- wall time: " << Fixed(report.seconds, 1) << " s\n\n";
  md << Table(report.rows);
  if (report.rows_by_kind.size() > 1) {
    for (const auto& [kind, rows] : report.rows_by_kind) {
      md << "\n## " << kind << " pairs (" << report.pairs_by_kind.at(kind) << ")";
      if (kind == "photo") md << ": source = target (one-shot reconstruction at the source camera)";
      if (kind == "clip") md << ": another frame of the source's clip (self-reenactment: new pose and expression)";
      md << "\n\n" << Table(rows);
    }
  }
  md << "\nColumns: PSNR, SSIM, L1 and perceptual compare each row with the target matted onto the black "
        "background at the row's resolution px (the target box-averaged/bilinear-resized to it), on the full "
        "image and, in the (matte) columns, weighted by the target's person matte. PSNR in dB with the peak = "
        "the full [-1,1] range (as 8-bit PSNR); L1 on [-1,1]; perceptual = perceptual (MobileNetV2), an "
        "LPIPS-style distance on ImageNet MobileNetV2 features without learned weights (not LPIPS). "
        "CSIM = cosine similarity of fr_feature identity embeddings (render vs target); AED = mean |difference| "
        "of our morphable model's expression coefficients fitted on render and target (not Deng et al.'s 3DMM); "
        "APD = mean |difference| of fr_pose yaw/pitch/roll in degrees. Face metrics average the pairs with a face "
        "in both images (renders are upsampled to "
     << header["face_analysis_size"].get<int>()
     << " px before face analysis); 'faces' = such pairs / pairs. Baseline = the morphable preview (source's "
        "fitted morphable face textured from the source, at the target camera with the target expression).\n";
  return md.str();
}

// Contact sheet: one row per pair, columns source, target, baseline, I_c, I_c+e, I_c+e+p[, SR].
cv::Mat ContactSheet(const std::vector<std::vector<cv::Mat>>& rows, const std::vector<std::string>& columns,
                     const std::vector<std::string>& captions, int cell) {
  const int header = 22;
  const int cols = static_cast<int>(columns.size());
  cv::Mat sheet(header + cell * static_cast<int>(rows.size()), cell * cols, CV_8UC3, cv::Scalar(40, 40, 40));
  for (int c = 0; c < cols; ++c)
    cv::putText(sheet, columns[c], cv::Point(c * cell + 4, 16), cv::FONT_HERSHEY_SIMPLEX, 0.42,
                cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  for (size_t r = 0; r < rows.size(); ++r) {
    for (int c = 0; c < cols && c < static_cast<int>(rows[r].size()); ++c) {
      const cv::Mat& img = rows[r][c];
      cv::Mat cellimg;
      if (img.empty()) {
        cellimg = cv::Mat(cell, cell, CV_8UC3, cv::Scalar(60, 60, 60));
        cv::putText(cellimg, "n/a", cv::Point(cell / 2 - 12, cell / 2), cv::FONT_HERSHEY_SIMPLEX, 0.45,
                    cv::Scalar(200, 200, 200), 1, cv::LINE_AA);
      } else {
        // Small renders are shown with nearest-neighbour upsampling (their real pixels).
        cv::resize(img, cellimg, cv::Size(cell, cell), 0, 0, img.cols < cell ? cv::INTER_NEAREST : cv::INTER_AREA);
      }
      cellimg.copyTo(sheet(cv::Rect(c * cell, header + static_cast<int>(r) * cell, cell, cell)));
    }
    cv::putText(sheet, captions[r], cv::Point(3, header + static_cast<int>(r) * cell + cell - 5),
                cv::FONT_HERSHEY_SIMPLEX, 0.35, cv::Scalar(0, 255, 255), 1, cv::LINE_AA);
  }
  return sheet;
}

}  // namespace

json Num(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

void SummariseRows(const std::vector<RowState>& rows, EvaluateReport* report) {
  for (const auto& r : rows) report->rows.push_back(Average(r));
  for (const auto& [kind, n] : report->pairs_by_kind)
    for (const auto& r : rows) report->rows_by_kind[kind].push_back(Average(r, kind));
}

void WriteEvaluationOutputs(const EvaluateOptions& options, const RunDescription& run, const json& per_pair,
                            const ContactRows& contact, EvaluateReport* report) {
  const ModelConfig& config = *run.config;
  // What was evaluated: eval.json's head, and eval.md's.
  json header;
  header["checkpoint"] = {{"path", options.checkpoint}, {"fingerprint", run.fingerprint},
                          {"config", config.name},      {"step", run.info.step},
                          {"sr_trained", run.sr},       {"data_provenance", run.info.data_provenance},
                          {"appearance_branch", config.appearance_branch},
                          {"expression_model", config.expression_model}};
  if (config.expression_bases()) header["checkpoint"]["expression_coefficients"] = config.expression_coefficients;
  header["data"] = options.data;
  header["split"] = options.split;
  header["split_pairs"] = run.split_pairs;
  header["face_analysis_size"] = options.face.analysis_size;
  json j = header;
  j["pairs"] = report->pairs;
  j["pairs_by_kind"] = report->pairs_by_kind;
  j["seconds"] = report->seconds;
  j["device"] = options.device;
  j["render_size"] = run.render_size;
  j["dataset_size"] = run.dataset_size;
  j["metrics"] = {
      {"image", "PSNR (dB, peak = [-1,1] range), SSIM, L1 (on [-1,1]) and perceptual (MobileNetV2) against the "
                "target matted onto black at the row's resolution; *_matte: weighted by the target matte"},
      {"csim", "cosine similarity of fr_feature embeddings, render vs target"},
      {"aed", "mean |difference| of our morphable expression coefficients, render vs target"},
      {"apd", "mean |difference| of fr_pose yaw, pitch, roll in degrees, render vs target"}};
  auto row_json = [](const EvalRow& r) {
    json jr;
    jr["key"] = r.key;
    jr["name"] = r.name;
    jr["available"] = r.available;
    if (!r.note.empty()) jr["note"] = r.note;
    jr["resolution"] = r.resolution;
    if (r.available) {
      for (const auto& [k, v] : r.full) jr["full"][k] = Num(v);
      for (const auto& [k, v] : r.masked) jr["matte"][k] = Num(v);
      if (r.face.pairs > 0) {
        jr["face"] = {{"pairs", r.face.pairs},
                      {"valid", r.face.valid},
                      {"no_face_render", r.face.no_face_render},
                      {"no_face_target", r.face.no_face_reference}};
        if (r.face.valid > 0) {
          jr["face"]["csim"] = Num(r.face.csim);
          jr["face"]["apd"] = Num(r.face.apd);
          if (r.face.has_aed) jr["face"]["aed"] = Num(r.face.aed);
        }
      }
    }
    return jr;
  };
  json jrows = json::array();
  for (const auto& r : report->rows) jrows.push_back(row_json(r));
  json by_kind = json::object();
  for (const auto& [kind, rs] : report->rows_by_kind) {
    by_kind[kind] = json::array();
    for (const auto& r : rs) by_kind[kind].push_back(row_json(r));
  }
  j["rows_by_kind"] = by_kind;
  j["rows"] = jrows;
  j["per_pair"] = per_pair;
  report->markdown = Markdown(*report, header);

  const fs::path out(options.out);
  report->json_path = (out / "eval.json").string();
  report->markdown_path = (out / "eval.md").string();
  report->contact_path = (out / "contact.png").string();
  std::vector<std::string> columns = {"source", "target", "baseline", "I_c", "I_c+e",
                                      config.appearance_branch ? "I_c+e+p" : "I_c+e (no T_p)"};
  if (run.sr) columns.push_back("SR");
  if (!contact.cells.empty()) {
    SaveImage(report->contact_path, ContactSheet(contact.cells, columns, contact.captions,
                                                 std::max<int>(128, static_cast<int>(run.dataset_size))));
  } else {
    report->contact_path.clear();
  }
  WriteBytesAtomically(report->markdown_path, report->markdown);
  WriteBytesAtomically(report->json_path, j.dump(1) + "\n");
}

}  // namespace avatar::evaluation
