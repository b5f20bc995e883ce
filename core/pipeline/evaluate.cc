#include "core/pipeline/evaluate.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/model/goha_model.h"
#include "core/model/super_resolution.h"
#include "core/morphable/mesh_renderer.h"
#include "core/morphable/morphable_model.h"
#include "core/morphable/texture.h"
#include "core/render/camera.h"
#include "core/train/losses.h"
#include "core/train/metrics.h"
#include "core/train/perceptual.h"
#include "core/util/error.h"
#include "core/util/progress_line.h"
#include "core/util/timer.h"

namespace avatar {

namespace fs = std::filesystem;
using nlohmann::json;

void EvaluateOptions::Validate() const {
  AVATAR_CHECK_OPTION(!checkpoint.empty()) << "--checkpoint must name the model checkpoint to evaluate";
  AVATAR_CHECK_OPTION(!data.empty()) << "--data must name the dataset folder";
  AVATAR_CHECK_OPTION(split == "val" || split == "train") << "--split must be val or train, got '" << split << "'";
  AVATAR_CHECK_OPTION(!out.empty()) << "--out must name the output folder";
  AVATAR_CHECK_OPTION(max_pairs >= 0) << "--max-pairs must be >= 0 (0 = all), got " << max_pairs;
  AVATAR_CHECK_OPTION(batch_size >= 1 && batch_size <= 256) << "--batch-size must be within 1..256, got " << batch_size;
  AVATAR_CHECK_OPTION(contact_rows >= 0 && contact_rows <= 64)
      << "--contact-rows must be within 0..64, got " << contact_rows;
  AVATAR_CHECK_OPTION(device == "cpu" || device.rfind("cuda", 0) == 0)
      << "--device must be cpu or cuda[:N], got '" << device << "'";
  face.Validate();
}

namespace {

const char* KindName(int64_t kind) {
  switch (static_cast<train::PairKind>(kind)) {
    case train::PairKind::kPhoto: return "photo";
    case train::PairKind::kClip: return "clip";
    case train::PairKind::kSynthetic: return "synthetic";
  }
  return "other";
}

json Num(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

std::string Fixed(double v, int digits) {
  if (!std::isfinite(v)) return v > 0 ? "inf" : "n/a";
  std::ostringstream s;
  s << std::fixed << std::setprecision(digits) << v;
  return s.str();
}

std::string Duration(double seconds) {
  const int64_t s = static_cast<int64_t>(std::max(0.0, seconds) + 0.5);
  std::ostringstream out;
  if (s >= 3600) out << s / 3600 << "h";
  out << std::setw(s >= 3600 ? 2 : 1) << std::setfill('0') << (s % 3600) / 60 << "m" << std::setw(2) << s % 60 << "s";
  return out.str();
}

// [3,H,W] RGB in [-1,1] (any device) -> CV_8UC3 BGR.
cv::Mat ToBgr8(const torch::Tensor& rgb) {
  const torch::Tensor u8 = rgb.detach()
                               .to(torch::kCPU, torch::kFloat32)
                               .clamp(-1.0, 1.0)
                               .add(1.0)
                               .mul(127.5)
                               .round()
                               .to(torch::kUInt8)
                               .permute({1, 2, 0})
                               .contiguous();
  cv::Mat rgb_mat(static_cast<int>(u8.size(0)), static_cast<int>(u8.size(1)), CV_8UC3, u8.data_ptr<uint8_t>());
  cv::Mat bgr;
  cv::cvtColor(rgb_mat, bgr, cv::COLOR_RGB2BGR);
  return bgr;
}

// CV_32FC3 BGR in [0,1] -> [3,H,W] RGB in [-1,1].
torch::Tensor FromBgrFloat(const cv::Mat& bgr) {
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  const torch::Tensor t = torch::from_blob(rgb.data, {rgb.rows, rgb.cols, 3}, torch::kFloat32).clone();
  return t.permute({2, 0, 1}).mul(2.0).sub(1.0).contiguous();
}

json ReadJsonFile(const fs::path& path) {
  try {
    return json::parse(ReadFileBytes(path));
  } catch (const json::exception& e) {
    throw InvalidInput(path.string() + " is not valid JSON: " + e.what());
  }
}

// The dataset's records of one split's pairs, for the morphable baseline: the shard's pairs are
// the pairs.json entries whose two frames are in the split, in file order (dataset_build.cc).
struct BaselineData {
  bool ok = false;
  std::string why;  // when !ok
  std::vector<std::pair<size_t, size_t>> pairs;  // (source, target) indices into records
  json records;
};

BaselineData LoadBaselineData(const fs::path& dir, const std::string& split, int64_t expected_pairs) {
  BaselineData b;
  const fs::path records = dir / "records.json", pairs = dir / "pairs.json";
  if (!fs::exists(records) || !fs::exists(pairs)) {
    b.why = "the dataset has no records.json / pairs.json (the morphable fits)";
    return b;
  }
  b.records = ReadJsonFile(records);
  const json p = ReadJsonFile(pairs);
  AVATAR_CHECK_INPUT(b.records.is_array() && p.is_array()) << records.string() << " / " << pairs.string()
                                                           << " must hold JSON arrays";
  std::map<std::string, size_t> by_id;
  for (size_t i = 0; i < b.records.size(); ++i) {
    const json& r = b.records[i];
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

morphable::CameraLabel LabelOf(const json& values, const std::string& what) {
  const auto v = values.get<std::vector<float>>();
  AVATAR_CHECK_INPUT(v.size() == morphable::CameraLabel{}.size()) << what << ": camera label has " << v.size() << " values";
  morphable::CameraLabel l{};
  std::copy(v.begin(), v.end(), l.begin());
  return l;
}

// The morphable preview of the source at the target camera with the target expression.
class MorphableBaseline {
 public:
  MorphableBaseline(const morphable::MorphableModel& model, fs::path dir, int size)
      : model_(model), dir_(std::move(dir)), size_(size) {}

  // [3,S,S] RGB in [-1,1]. Checks that the records are the shard's frames (labels match).
  torch::Tensor Render(const json& source, const json& target, const torch::Tensor& source_label,
                       const torch::Tensor& target_label) {
    const std::string sid = source.at("id").get<std::string>();
    const morphable::CameraLabel src_cam = LabelOf(source.at("label"), sid);
    const morphable::CameraLabel tgt_cam = LabelOf(target.at("label"), target.at("id").get<std::string>());
    const torch::Tensor shard_src = source_label.to(torch::kCPU, torch::kFloat32);
    const torch::Tensor shard_tgt = target_label.to(torch::kCPU, torch::kFloat32);
    AVATAR_CHECK_INPUT(torch::allclose(shard_src, morphable::LabelTensor(src_cam), 1e-4, 1e-5) &&
                       torch::allclose(shard_tgt, morphable::LabelTensor(tgt_cam), 1e-4, 1e-5))
        << (dir_ / "records.json").string() << " does not match the shard (camera labels of " << sid
        << " differ): rebuild the dataset";
    auto it = cache_.find(sid);
    if (it == cache_.end()) {
      morphable::FitResult fit;
      fit.alpha = source.at("alpha").get<std::vector<float>>();
      fit.beta = source.at("beta").get<std::vector<float>>();
      fit.scale = source.at("scale").get<float>();
      fit.camera = src_cam;
      const cv::Mat image = LoadImageBgr(dir_ / source.at("files").at("image").get<std::string>());
      fit.image_size = image.size();
      AVATAR_CHECK_INPUT(static_cast<int>(fit.alpha.size()) == model_.num_identity() &&
                         static_cast<int>(fit.beta.size()) == model_.num_expression())
          << sid << ": the record's coefficients do not fit the installed morphable model";
      morphable::TextureOptions to;
      to.size = 256;
      Entry e{fit, morphable::SampleTexture(model_, fit, image, to)};
      it = cache_.emplace(sid, std::move(e)).first;
      if (cache_.size() > 64) {  // sources repeat in runs (clip pairs); keep the cache small
        const std::string keep = sid;
        Entry kept = it->second;
        cache_.clear();
        it = cache_.emplace(keep, std::move(kept)).first;
      }
    }
    const Entry& e = it->second;
    const morphable::Beta beta = target.at("beta").get<std::vector<float>>();
    morphable::RenderOptions ro;
    ro.supersample = 2;
    const morphable::RenderResult r =
        morphable::Render(model_, e.fit.alpha, beta, e.fit.scale, e.texture, tgt_cam, cv::Size(size_, size_), ro);
    return FromBgrFloat(r.image);
  }

 private:
  struct Entry {
    morphable::FitResult fit;
    morphable::Texture texture;
  };
  const morphable::MorphableModel& model_;
  fs::path dir_;
  int size_;
  std::map<std::string, Entry> cache_;
};

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

train::ImageMetrics EvaluationImageMetrics(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask,
                                           const PerceptualLoss* perceptual) {
  if (perceptual == nullptr) return train::ComputeImageMetrics(a, b, mask);
  // MobileNetV2 needs >= 32 px: smaller images (and masks) are upsampled for that term only.
  auto distance = [perceptual](const torch::Tensor& x, const torch::Tensor& y, const torch::Tensor& m) {
    if (x.size(2) >= 32) return perceptual->Distance(x, y, m);
    return perceptual->Distance(ResizeBilinear(x, 32, 32), ResizeBilinear(y, 32, 32),
                                m.defined() ? ResizeBilinear(m, 32, 32) : m);
  };
  return train::ComputeImageMetrics(a, b, mask, distance);
}

std::vector<int64_t> ChooseEvaluationPairs(const train::TrainDataset& dataset, int max_pairs) {
  const int64_t n = dataset.size();
  std::vector<int64_t> all(n);
  for (int64_t i = 0; i < n; ++i) all[i] = i;
  if (max_pairs <= 0 || max_pairs >= n) return all;
  std::map<int64_t, std::vector<int64_t>> by_kind;
  for (int64_t i = 0; i < n; ++i) by_kind[static_cast<int64_t>(dataset.Get(i).kind)].push_back(i);
  // Equal shares; a kind with fewer pairs than its share passes the rest on.
  std::map<int64_t, int64_t> quota;
  int64_t left = max_pairs;
  std::vector<int64_t> open;
  for (const auto& [k, v] : by_kind) open.push_back(k);
  while (left > 0 && !open.empty()) {
    const int64_t share = std::max<int64_t>(1, left / static_cast<int64_t>(open.size()));
    std::vector<int64_t> still;
    for (int64_t k : open) {
      const int64_t take = std::min({share, static_cast<int64_t>(by_kind[k].size()) - quota[k], left});
      quota[k] += take;
      left -= take;
      if (quota[k] < static_cast<int64_t>(by_kind[k].size())) still.push_back(k);
    }
    open = still;
  }
  std::vector<int64_t> out;
  for (const auto& [k, v] : by_kind) {
    const int64_t q = quota[k], m = static_cast<int64_t>(v.size());
    for (int64_t j = 0; j < q; ++j) out.push_back(v[(j * m) / q]);
  }
  std::sort(out.begin(), out.end());
  return out;
}

EvaluateReport RunEvaluation(const EvaluateOptions& options, RunContext& ctx) {
  options.Validate();
  Timer timer;
  const fs::path data_dir(options.data);
  if (!fs::exists(options.checkpoint))
    throw Io("checkpoint '" + options.checkpoint + "' does not exist; check the path (train writes RUN/model.ckpt)");
  if (!fs::is_directory(data_dir))
    throw Io("dataset folder '" + options.data +
             "' does not exist; check the path or build one with 'avatar-studio dataset build --out DIR'");
  if (!fs::exists(data_dir / "dataset.json"))
    throw Io("'" + options.data + "' is not a dataset folder: " + (data_dir / "dataset.json").string() +
             " is missing (build one with 'avatar-studio dataset build --out DIR')");

  std::string fingerprint;
  LoadedModel loaded = LoadModelCheckpoint(options.checkpoint, &fingerprint);
  GohaModel model = loaded.model;
  const ModelConfig& config = model->config();
  const torch::Device device(options.device);
  model->to(device);
  model->eval();
  torch::NoGradGuard no_grad;

  const train::TrainDataset dataset = train::TrainDataset::Open(options.data, options.split);
  AVATAR_CHECK_INPUT(dataset.size() > 0) << options.data << ": split '" << options.split << "' has no pairs";
  const int64_t size = dataset.image_size();
  const int64_t res = config.render_size;
  const std::vector<int64_t> chosen = ChooseEvaluationPairs(dataset, options.max_pairs);
  ctx.ThrowIfCancelled();

  // Output folder (checked before the long part).
  std::error_code ec;
  fs::create_directories(options.out, ec);
  if (!fs::is_directory(options.out))
    throw Io("cannot create the output folder '" + options.out + "'" + (ec ? ": " + ec.message() : std::string()));

  std::unique_ptr<PerceptualLoss> perceptual;
  if (options.perceptual) {
    PerceptualOptions po;
    po.data_dir = options.data_dir;
    perceptual = std::make_unique<PerceptualLoss>(po);
    perceptual->To(device);
  }
  std::unique_ptr<face::FaceMetrics> face_metrics;
  if (options.face_metrics) {
    face::FaceMetricsOptions fo = options.face;
    fo.data_dir = options.data_dir;
    face_metrics = std::make_unique<face::FaceMetrics>(fo);
  }

  // Rows.
  constexpr int kRows = 6;
  std::vector<RowState> rows(kRows);
  rows[0].row = {"baseline", "morphable baseline", true, "", static_cast<int>(res), {}, {}, {}};
  rows[1].row = {"canonical", "I_c", true, "", static_cast<int>(res), {}, {}, {}};
  rows[2].row = {"expression", "I_c+e", true, "", static_cast<int>(res), {}, {}, {}};
  rows[3].row = {"full", "I_c+e+p", true, "", static_cast<int>(res), {}, {}, {}};
  if (!config.appearance_branch) {
    // The w/o-appearance ablation: T_p = 0, so the network's output (this row, and SR / bicubic
    // of it) is I_c+e; the row keeps its key and repeats the I_c+e numbers under its own name.
    rows[3].row.name = "I_c+e+p = I_c+e (no appearance branch)";
    rows[3].row.note = "the checkpoint has no appearance branch (appearance_branch false): T_p = 0 and the "
                       "network's output is I_c+e; this row repeats the I_c+e row";
  }
  rows[4].row = {"sr", "SR(I_c+e+p)", true, "", config.sr_size, {}, {}, {}};
  const bool sr = loaded.info.sr_trained;
  if (!sr) {
    rows[4].row.available = false;
    rows[4].row.note = "not trained (checkpoint has sr_trained = false: stage-I weights)";
  }
  // What the app shows at sr_size when the SR is untrained, and the yardstick a trained SR must beat.
  rows[5].row = {"upsampled", "I_c+e+p bicubic", true, "", config.sr_size, {}, {}, {}};
  std::unique_ptr<MorphableBaseline> baseline;
  BaselineData records;
  if (!options.baseline) {
    rows[0].row.available = false;
    rows[0].row.note = "off (--no-baseline)";
  } else {
    records = LoadBaselineData(data_dir, options.split, dataset.size());
    if (!records.ok) {
      rows[0].row.available = false;
      rows[0].row.note = "not available: " + records.why;
    } else {
      const morphable::MorphableModel& mm = morphable::LoadDefaultModel(DataPaths::Resolve(options.data_dir));
      baseline = std::make_unique<MorphableBaseline>(mm, data_dir, static_cast<int>(size));
    }
  }

  // Contact sheet rows: evenly spaced over the evaluated pairs.
  std::vector<size_t> contact_at;
  const size_t n_contact = std::min<size_t>(options.contact_rows, chosen.size());
  for (size_t r = 0; r < n_contact; ++r) contact_at.push_back(r * chosen.size() / n_contact);
  std::vector<std::vector<cv::Mat>> contact_rows;
  std::vector<std::string> contact_captions;

  EvaluateReport report;
  report.pairs = static_cast<int>(chosen.size());
  report.pair_indices = chosen;
  json per_pair = json::array();

  const Timer loop_timer;
  ProgressLine progress_line = ProgressLine::ForStderr();
  size_t done = 0;
  for (size_t begin = 0; begin < chosen.size(); begin += options.batch_size) {
    ctx.ThrowIfCancelled();
    const size_t end = std::min(chosen.size(), begin + static_cast<size_t>(options.batch_size));
    std::vector<train::TrainSample> samples;
    for (size_t i = begin; i < end; ++i) samples.push_back(dataset.Get(chosen[i]));
    const train::TrainBatch b = train::Collate(samples).To(device);
    const int64_t bn = b.size();
    auto input = [&](const torch::Tensor& x) { return train::ResizeTo(x, config.image_size); };
    const torch::Tensor source = input(b.source), eye_mouth = input(b.source_eye_mouth);
    const torch::Tensor source_matte = input(b.source_matte), expression_image = input(b.expression_image);
    const render::Cameras source_cam = render::CamerasFromLabels(b.source_label);
    const render::Cameras target_cam = render::CamerasFromLabels(b.target_label);
    const torch::Tensor target_full = train::Matte(b.target, b.target_matte);  // [B,3,S,S]
    const torch::Tensor target_r = train::ResizeTo(target_full, res);
    const torch::Tensor matte_r = train::ResizeTo(b.target_matte, res);

    // Neural renders at the target camera (deterministic).
    std::vector<torch::Tensor> renders(kRows);
    const torch::Tensor tc = model->CanonicalPlanes(source);
    // T_e from I_exp (encoder) or from the target's morphable coefficients (expression bases).
    const torch::Tensor tce = tc + model->ExpressionPlanesFor(expression_image, b.target_expression);
    renders[1] = model->Render(tc, target_cam, 0, true).rgb;
    renders[2] = model->Render(tce, target_cam, 0, true).rgb;
    if (config.appearance_branch) {
      const torch::Tensor tp = model->AppearancePlanes(source, eye_mouth, source_matte, tc, source_cam).planes;
      renders[3] = model->Render(tce + tp, target_cam, 0, true).rgb;
    } else {
      renders[3] = renders[2];  // no appearance branch: the output is I_c+e
    }
    if (sr) renders[4] = model->SuperResolve(renders[3]);
    renders[5] = torch::nn::functional::interpolate(
                     renders[3], torch::nn::functional::InterpolateFuncOptions()
                                     .size(std::vector<int64_t>{config.sr_size, config.sr_size})
                                     .mode(torch::kBicubic)
                                     .align_corners(false))
                     .clamp(-1.0, 1.0);
    torch::Tensor baseline_full;  // [B,3,S,S]
    if (baseline) {
      std::vector<torch::Tensor> imgs;
      for (size_t i = begin; i < end; ++i) {
        const auto& [src, tgt] = records.pairs[chosen[i]];
        imgs.push_back(baseline->Render(records.records[src], records.records[tgt], samples[i - begin].source_label, samples[i - begin].target_label));
      }
      baseline_full = torch::stack(imgs).to(device);
      renders[0] = train::ResizeTo(baseline_full, res);
    }

    // Image metrics per row.
    std::vector<train::ImageMetrics> full_m(kRows), masked_m(kRows);
    for (int r = 0; r < kRows; ++r) {
      if (!rows[r].row.available) continue;
      const bool is_sr = r == 4 || r == 5;
      const torch::Tensor tgt = is_sr ? train::ResizeTo(target_full, config.sr_size) : target_r;
      const torch::Tensor mask = is_sr ? train::ResizeTo(b.target_matte, config.sr_size) : matte_r;
      full_m[r] = EvaluationImageMetrics(renders[r], tgt, {}, perceptual.get());
      masked_m[r] = EvaluationImageMetrics(renders[r], tgt, mask, perceptual.get());
    }

    for (int64_t j = 0; j < bn; ++j) {
      ctx.ThrowIfCancelled();
      const size_t i = begin + static_cast<size_t>(j);
      const cv::Mat target_bgr = ToBgr8(target_full[j]);
      face::FaceMeasurement target_face;
      if (face_metrics) target_face = face_metrics->Measure(target_bgr);
      json pj;
      pj["index"] = chosen[i];
      pj["kind"] = KindName(b.kind[j].item<int64_t>());
      pj["identity"] = b.identity[j].item<int64_t>();
      if (face_metrics) pj["target_face"] = target_face.found;
      for (int r = 0; r < kRows; ++r) {
        if (!rows[r].row.available) continue;
        RowPair rp;
        rp.kind = pj["kind"].get<std::string>();
        auto put = [](std::map<std::string, double>& m, const train::ImageMetrics& im, int64_t k) {
          m["psnr"] = im.psnr[k].item<double>();
          m["ssim"] = im.ssim[k].item<double>();
          m["l1"] = im.l1[k].item<double>();
          if (im.perceptual.defined()) m["perceptual"] = im.perceptual[k].item<double>();
        };
        put(rp.full, full_m[r], j);
        put(rp.masked, masked_m[r], j);
        json rj;
        for (const auto& [k, v] : rp.full) rj[k] = Num(v);
        for (const auto& [k, v] : rp.masked) rj[k + "_matte"] = Num(v);
        if (face_metrics) {
          const face::FaceMeasurement m = face_metrics->Measure(ToBgr8(renders[r][j]));
          rp.face = face_metrics->Compare(m, target_face);
          rp.has_face = true;
          rj["face_found"] = m.found;
          if (rp.face.valid()) {
            rj["csim"] = Num(rp.face.csim);
            rj["apd"] = Num(rp.face.apd);
            if (rp.face.has_aed) rj["aed"] = Num(rp.face.aed);
          }
        }
        pj["rows"][rows[r].row.key] = rj;
        rows[r].pairs.push_back(std::move(rp));
      }
      per_pair.push_back(pj);
      report.pairs_by_kind[pj["kind"].get<std::string>()]++;
      if (std::find(contact_at.begin(), contact_at.end(), i) != contact_at.end()) {
        std::vector<cv::Mat> cells = {ToBgr8(b.source[j]), target_bgr,
                                      baseline_full.defined() ? ToBgr8(baseline_full[j]) : cv::Mat(),
                                      ToBgr8(renders[1][j]), ToBgr8(renders[2][j]), ToBgr8(renders[3][j])};
        if (sr) cells.push_back(ToBgr8(renders[4][j]));
        contact_rows.push_back(std::move(cells));
        contact_captions.push_back(std::string(KindName(b.kind[j].item<int64_t>())) + " #" + std::to_string(chosen[i]));
      }
      ++done;
    }
    const double elapsed = loop_timer.Seconds();
    const double eta = elapsed / static_cast<double>(done) * static_cast<double>(chosen.size() - done);
    const double fraction = static_cast<double>(done) / static_cast<double>(chosen.size());
    ctx.Report("evaluate", fraction, std::to_string(done) + "/" + std::to_string(chosen.size()) + " pairs");
    if (options.print_progress) {
      std::ostringstream text;
      text << "eval: " << done << "/" << chosen.size() << " pairs (" << std::fixed << std::setprecision(0)
           << 100.0 * fraction << "%), " << Fixed(elapsed / static_cast<double>(done), 2) << " s/pair, elapsed "
           << Duration(elapsed) << ", ETA " << Duration(eta);
      progress_line.Update(text.str());
    }
  }
  if (options.print_progress) progress_line.Finish();
  ctx.ThrowIfCancelled();

  for (const auto& r : rows) report.rows.push_back(Average(r));
  for (const auto& [kind, n] : report.pairs_by_kind)
    for (const auto& r : rows) report.rows_by_kind[kind].push_back(Average(r, kind));
  report.seconds = timer.Seconds();

  // Outputs.
  json header;
  header["checkpoint"] = {{"path", options.checkpoint}, {"fingerprint", fingerprint},
                          {"config", config.name},      {"step", loaded.info.step},
                          {"sr_trained", sr},           {"data_provenance", loaded.info.data_provenance},
                          {"appearance_branch", config.appearance_branch},
                          {"expression_model", config.expression_model}};
  if (config.expression_bases()) header["checkpoint"]["expression_coefficients"] = config.expression_coefficients;
  header["data"] = options.data;
  header["split"] = options.split;
  header["split_pairs"] = dataset.size();
  header["face_analysis_size"] = options.face.analysis_size;
  json j = header;
  j["pairs"] = report.pairs;
  j["pairs_by_kind"] = report.pairs_by_kind;
  j["seconds"] = report.seconds;
  j["device"] = options.device;
  j["render_size"] = res;
  j["dataset_size"] = size;
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
  for (const auto& r : report.rows) jrows.push_back(row_json(r));
  json by_kind = json::object();
  for (const auto& [kind, rs] : report.rows_by_kind) {
    by_kind[kind] = json::array();
    for (const auto& r : rs) by_kind[kind].push_back(row_json(r));
  }
  j["rows_by_kind"] = by_kind;
  j["rows"] = jrows;
  j["per_pair"] = per_pair;
  report.markdown = Markdown(report, header);

  const fs::path out(options.out);
  report.json_path = (out / "eval.json").string();
  report.markdown_path = (out / "eval.md").string();
  report.contact_path = (out / "contact.png").string();
  std::vector<std::string> columns = {"source", "target", "baseline", "I_c", "I_c+e",
                                      config.appearance_branch ? "I_c+e+p" : "I_c+e (no T_p)"};
  if (sr) columns.push_back("SR");
  if (!contact_rows.empty()) {
    SaveImage(report.contact_path,
              ContactSheet(contact_rows, columns, contact_captions, std::max<int>(128, static_cast<int>(size))));
  } else {
    report.contact_path.clear();
  }
  WriteBytesAtomically(report.markdown_path, report.markdown);
  WriteBytesAtomically(report.json_path, j.dump(1) + "\n");
  return report;
}

}  // namespace avatar
