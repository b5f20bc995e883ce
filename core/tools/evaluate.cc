// Evaluation of a network on a dataset split (evaluate.h): RunEvaluation's loading, rendering and
// per-pair measuring steps; the averages and output files are in evaluate_report.cc.
#include "core/tools/evaluate.h"
#include "core/tools/dataset_records.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/io/image_tensor.h"
#include "core/io/json_file.h"
#include "core/model/goha_model.h"
#include "core/model/super_resolution.h"
#include "core/morphable/mesh_renderer.h"
#include "core/morphable/morphable_model.h"
#include "core/morphable/texture.h"
#include "core/render/camera.h"
#include "core/tools/evaluate_impl.h"
#include "core/train/losses.h"
#include "core/train/metrics.h"
#include "core/train/perceptual.h"
#include "core/util/error.h"
#include "core/util/text.h"
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

std::string Duration(double seconds) {
  const int64_t s = static_cast<int64_t>(std::max(0.0, seconds) + 0.5);
  std::ostringstream out;
  if (s >= 3600) out << s / 3600 << "h";
  out << std::setw(s >= 3600 ? 2 : 1) << std::setfill('0') << (s % 3600) / 60 << "m" << std::setw(2) << s % 60 << "s";
  return out.str();
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
    const morphable::CameraLabel src_cam = RecordLabel(source.at("label"), sid);
    const morphable::CameraLabel tgt_cam = RecordLabel(target.at("label"), target.at("id").get<std::string>());
    const torch::Tensor shard_src = source_label.to(torch::kCPU, torch::kFloat32);
    const torch::Tensor shard_tgt = target_label.to(torch::kCPU, torch::kFloat32);
    AVATAR_CHECK_INPUT(torch::allclose(shard_src, morphable::LabelTensor(src_cam), 1e-4, 1e-5) &&
                       torch::allclose(shard_tgt, morphable::LabelTensor(tgt_cam), 1e-4, 1e-5))
        << (dir_ / "records.json").string() << " does not match the shard (camera labels of " << sid
        << " differ): rebuild the dataset";
    auto it = cache_.find(sid);
    if (it == cache_.end()) {
      const cv::Mat image = LoadImageBgr(dir_ / source.at("files").at("image").get<std::string>());
      const morphable::FitResult fit = RecordFit(source, image.size());
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
    return FloatBgrToTensor(r.image);
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


using evaluation::ContactRows;
using evaluation::RowPair;
using evaluation::RowState;

// The table's rows, in order: baseline, canonical, expression, full, sr, upsampled.
constexpr int kEvalRows = 6;

// Io naming the checkpoint or the dataset folder when either is missing, before anything loads.
void CheckEvaluationInputs(const EvaluateOptions& options) {
  const fs::path data_dir(options.data);
  if (!fs::exists(options.checkpoint))
    throw Io("checkpoint '" + options.checkpoint + "' does not exist; check the path (train writes RUN/model.ckpt)");
  if (!fs::is_directory(data_dir))
    throw Io("dataset folder '" + options.data +
             "' does not exist; check the path or build one with 'avatar-studio dataset build --out DIR'");
  if (!fs::exists(data_dir / "dataset.json"))
    throw Io("'" + options.data + "' is not a dataset folder: " + (data_dir / "dataset.json").string() +
             " is missing (build one with 'avatar-studio dataset build --out DIR')");
}

// The output folder, checked before the long part.
void CreateEvaluationFolder(const std::string& out) {
  std::error_code ec;
  fs::create_directories(out, ec);
  if (!fs::is_directory(out))
    throw Io("cannot create the output folder '" + out + "'" + (ec ? ": " + ec.message() : std::string()));
}

// The optional scorers besides PSNR, SSIM and L1 (null when switched off).
struct EvalScorers {
  std::unique_ptr<PerceptualLoss> perceptual;
  std::unique_ptr<face::FaceMetrics> face_metrics;
};

EvalScorers LoadEvalScorers(const EvaluateOptions& options, const torch::Device& device) {
  EvalScorers scorers;
  if (options.perceptual) {
    PerceptualOptions po;
    po.data_dir = options.data_dir;
    scorers.perceptual = std::make_unique<PerceptualLoss>(po);
    scorers.perceptual->To(device);
  }
  if (options.face_metrics) {
    face::FaceMetricsOptions fo = options.face;
    fo.data_dir = options.data_dir;
    scorers.face_metrics = std::make_unique<face::FaceMetrics>(fo);
  }
  return scorers;
}

// The table's rows (names, resolutions, which are available and why not) and, when the baseline
// row is on, the dataset's records of the split's pairs and the baseline's renderer.
struct EvalRows {
  std::vector<RowState> rows;
  std::unique_ptr<MorphableBaseline> baseline;
  SplitPairRecords records;
};

EvalRows SetUpEvalRows(const EvaluateOptions& options, const ModelConfig& config, bool sr, int64_t split_pairs,
                       int64_t size) {
  const fs::path data_dir(options.data);
  const int64_t res = config.render_size;
  EvalRows table;
  std::vector<RowState>& rows = table.rows;
  rows.resize(kEvalRows);
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
  if (!sr) {
    rows[4].row.available = false;
    rows[4].row.note = "not trained (checkpoint has sr_trained = false: stage-I weights)";
  }
  // What the app shows at sr_size when the SR is untrained, and the yardstick a trained SR must beat.
  rows[5].row = {"upsampled", "I_c+e+p bicubic", true, "", config.sr_size, {}, {}, {}};
  if (!options.baseline) {
    rows[0].row.available = false;
    rows[0].row.note = "off (--no-baseline)";
  } else {
    table.records = LoadSplitPairRecords(data_dir, options.split, split_pairs);
    if (!table.records.ok) {
      rows[0].row.available = false;
      rows[0].row.note = "not available: " + table.records.why;
    } else {
      const morphable::MorphableModel& mm = morphable::LoadDefaultModel(DataPaths::Resolve(options.data_dir));
      table.baseline = std::make_unique<MorphableBaseline>(mm, data_dir, static_cast<int>(size));
    }
  }
  return table;
}

// The positions (into the evaluated pairs) of the contact sheet's rows: evenly spaced.
std::vector<size_t> ContactPairPositions(int contact_rows, size_t pairs) {
  std::vector<size_t> contact_at;
  const size_t n_contact = std::min<size_t>(contact_rows, pairs);
  for (size_t r = 0; r < n_contact; ++r) contact_at.push_back(r * pairs / n_contact);
  return contact_at;
}

// What every batch reads (the network, the split, the scorers) and what the batches fill (the
// rows' per-pair values, eval.json's per-pair entries, the contact sheet, the pair counts).
struct EvalLoop {
  const EvaluateOptions& options;
  GohaModel model;
  const ModelConfig& config;
  const torch::Device device;
  const train::TrainDataset& dataset;
  const std::vector<int64_t>& chosen;  // indices into the split of the evaluated pairs
  const bool sr;                       // the SR row is evaluated
  EvalScorers scorers;
  EvalRows table;
  std::vector<size_t> contact_at;  // ContactPairPositions
  ContactRows contact;
  json per_pair;
  EvaluateReport& report;  // pairs_by_kind
};

// One batch's images per row: [B,3,res,res], SR and bicubic at sr_size; undefined where the row
// is not available.
struct BatchRenders {
  std::vector<torch::Tensor> rows;
  torch::Tensor baseline_full;  // [B,3,S,S], the baseline at the dataset size (contact sheet)
};

// The neural renders at the target camera (deterministic) and the morphable baseline of the
// batch of pairs [begin, end).
BatchRenders RenderBatch(EvalLoop& loop, const std::vector<train::TrainSample>& samples, const train::TrainBatch& b,
                         size_t begin, size_t end) {
  const ModelConfig& config = loop.config;
  GohaModel& model = loop.model;
  const int64_t res = config.render_size;
  auto input = [&](const torch::Tensor& x) { return train::ResizeTo(x, config.image_size); };
  const torch::Tensor source = input(b.source), eye_mouth = input(b.source_eye_mouth);
  const torch::Tensor source_matte = input(b.source_matte), expression_image = input(b.expression_image);
  const render::Cameras source_cam = render::CamerasFromLabels(b.source_label);
  const render::Cameras target_cam = render::CamerasFromLabels(b.target_label);

  BatchRenders out;
  std::vector<torch::Tensor>& renders = out.rows;
  renders.resize(kEvalRows);
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
  if (loop.sr) renders[4] = model->SuperResolve(renders[3]);
  renders[5] = torch::nn::functional::interpolate(
                   renders[3], torch::nn::functional::InterpolateFuncOptions()
                                   .size(std::vector<int64_t>{config.sr_size, config.sr_size})
                                   .mode(torch::kBicubic)
                                   .align_corners(false))
                   .clamp(-1.0, 1.0);
  if (loop.table.baseline) {
    const SplitPairRecords& records = loop.table.records;
    std::vector<torch::Tensor> imgs;
    for (size_t i = begin; i < end; ++i) {
      const auto& [src, tgt] = records.pairs[loop.chosen[i]];
      imgs.push_back(loop.table.baseline->Render(records.records[src], records.records[tgt],
                                                 samples[i - begin].source_label, samples[i - begin].target_label));
    }
    out.baseline_full = torch::stack(imgs).to(loop.device);
    renders[0] = train::ResizeTo(out.baseline_full, res);
  }
  return out;
}

// Image metrics per available row against the matted target at the row's resolution: on the full
// image, and weighted by the target matte.
struct BatchMetrics {
  std::vector<train::ImageMetrics> full, masked;  // by row
};

BatchMetrics RowImageMetrics(const EvalLoop& loop, const train::TrainBatch& b, const torch::Tensor& target_full,
                             const std::vector<torch::Tensor>& renders) {
  const ModelConfig& config = loop.config;
  const torch::Tensor target_r = train::ResizeTo(target_full, config.render_size);
  const torch::Tensor matte_r = train::ResizeTo(b.target_matte, config.render_size);
  BatchMetrics m{std::vector<train::ImageMetrics>(kEvalRows), std::vector<train::ImageMetrics>(kEvalRows)};
  for (int r = 0; r < kEvalRows; ++r) {
    if (!loop.table.rows[r].row.available) continue;
    const bool is_sr = r == 4 || r == 5;
    const torch::Tensor tgt = is_sr ? train::ResizeTo(target_full, config.sr_size) : target_r;
    const torch::Tensor mask = is_sr ? train::ResizeTo(b.target_matte, config.sr_size) : matte_r;
    m.full[r] = EvaluationImageMetrics(renders[r], tgt, {}, loop.scorers.perceptual.get());
    m.masked[r] = EvaluationImageMetrics(renders[r], tgt, mask, loop.scorers.perceptual.get());
  }
  return m;
}

// Pair j of the batch (i of the evaluated pairs): the face metrics of every available row against
// the target's, its values in the rows and in eval.json, and its contact sheet row when shown.
void ScorePair(EvalLoop& loop, const train::TrainBatch& b, const torch::Tensor& target_full,
               const BatchRenders& batch, const BatchMetrics& metrics, size_t i, int64_t j) {
  const std::vector<torch::Tensor>& renders = batch.rows;
  const std::unique_ptr<face::FaceMetrics>& face_metrics = loop.scorers.face_metrics;
  std::vector<RowState>& rows = loop.table.rows;
  const cv::Mat target_bgr = TensorToBgr(target_full[j]);
  face::FaceMeasurement target_face;
  if (face_metrics) target_face = face_metrics->Measure(target_bgr);
  json pj;
  pj["index"] = loop.chosen[i];
  pj["kind"] = KindName(b.kind[j].item<int64_t>());
  pj["identity"] = b.identity[j].item<int64_t>();
  if (face_metrics) pj["target_face"] = target_face.found;
  for (int r = 0; r < kEvalRows; ++r) {
    if (!rows[r].row.available) continue;
    RowPair rp;
    rp.kind = pj["kind"].get<std::string>();
    auto put = [](std::map<std::string, double>& m, const train::ImageMetrics& im, int64_t k) {
      m["psnr"] = im.psnr[k].item<double>();
      m["ssim"] = im.ssim[k].item<double>();
      m["l1"] = im.l1[k].item<double>();
      if (im.perceptual.defined()) m["perceptual"] = im.perceptual[k].item<double>();
    };
    put(rp.full, metrics.full[r], j);
    put(rp.masked, metrics.masked[r], j);
    json rj;
    for (const auto& [k, v] : rp.full) rj[k] = evaluation::Num(v);
    for (const auto& [k, v] : rp.masked) rj[k + "_matte"] = evaluation::Num(v);
    if (face_metrics) {
      const face::FaceMeasurement m = face_metrics->Measure(TensorToBgr(renders[r][j]));
      rp.face = face_metrics->Compare(m, target_face);
      rp.has_face = true;
      rj["face_found"] = m.found;
      if (rp.face.valid()) {
        rj["csim"] = evaluation::Num(rp.face.csim);
        rj["apd"] = evaluation::Num(rp.face.apd);
        if (rp.face.has_aed) rj["aed"] = evaluation::Num(rp.face.aed);
      }
    }
    pj["rows"][rows[r].row.key] = rj;
    rows[r].pairs.push_back(std::move(rp));
  }
  loop.per_pair.push_back(pj);
  loop.report.pairs_by_kind[pj["kind"].get<std::string>()]++;
  if (std::find(loop.contact_at.begin(), loop.contact_at.end(), i) != loop.contact_at.end()) {
    std::vector<cv::Mat> cells = {TensorToBgr(b.source[j]), target_bgr,
                                  batch.baseline_full.defined() ? TensorToBgr(batch.baseline_full[j]) : cv::Mat(),
                                  TensorToBgr(renders[1][j]), TensorToBgr(renders[2][j]), TensorToBgr(renders[3][j])};
    if (loop.sr) cells.push_back(TensorToBgr(renders[4][j]));
    loop.contact.cells.push_back(std::move(cells));
    loop.contact.captions.push_back(std::string(KindName(b.kind[j].item<int64_t>())) + " #" +
                                    std::to_string(loop.chosen[i]));
  }
}

// The evaluated pairs [begin, end): renders, image metrics, then pair by pair.
void EvaluateBatch(EvalLoop& loop, size_t begin, size_t end, RunContext& ctx) {
  std::vector<train::TrainSample> samples;
  for (size_t i = begin; i < end; ++i) samples.push_back(loop.dataset.Get(loop.chosen[i]));
  const train::TrainBatch b = train::Collate(samples).To(loop.device);
  const int64_t bn = b.size();
  const torch::Tensor target_full = train::Matte(b.target, b.target_matte);  // [B,3,S,S]
  const BatchRenders renders = RenderBatch(loop, samples, b, begin, end);
  const BatchMetrics metrics = RowImageMetrics(loop, b, target_full, renders.rows);
  for (int64_t j = 0; j < bn; ++j) {
    ctx.ThrowIfCancelled();
    ScorePair(loop, b, target_full, renders, metrics, begin + static_cast<size_t>(j), j);
  }
}

// ctx's progress reports and, with `print`, the progress line with ETA on stderr; once per batch.
class EvalProgress {
 public:
  EvalProgress(bool print, size_t total) : print_(print), total_(total) {}

  void Update(size_t done, RunContext& ctx) {
    const double elapsed = timer_.Seconds();
    const double eta = elapsed / static_cast<double>(done) * static_cast<double>(total_ - done);
    const double fraction = static_cast<double>(done) / static_cast<double>(total_);
    ctx.Report("evaluate", fraction, std::to_string(done) + "/" + std::to_string(total_) + " pairs");
    if (print_) {
      std::ostringstream text;
      text << "eval: " << done << "/" << total_ << " pairs (" << std::fixed << std::setprecision(0)
           << 100.0 * fraction << "%), " << Fixed(elapsed / static_cast<double>(done), 2) << " s/pair, elapsed "
           << Duration(elapsed) << ", ETA " << Duration(eta);
      line_.Update(text.str());
    }
  }
  void Finish() {
    if (print_) line_.Finish();
  }

 private:
  const Timer timer_;
  ProgressLine line_ = ProgressLine::ForStderr();
  bool print_;
  size_t total_;
};

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
  CheckEvaluationInputs(options);

  // The network, in evaluation mode on the device; no gradients from here on.
  std::string fingerprint;
  LoadedModel loaded = LoadModelCheckpoint(options.checkpoint, &fingerprint);
  GohaModel model = loaded.model;
  const ModelConfig& config = model->config();
  const torch::Device device(options.device);
  model->to(device);
  model->eval();
  torch::NoGradGuard no_grad;

  // The split and its evaluated pairs.
  const train::TrainDataset dataset = train::TrainDataset::Open(options.data, options.split);
  AVATAR_CHECK_INPUT(dataset.size() > 0) << options.data << ": split '" << options.split << "' has no pairs";
  const std::vector<int64_t> chosen = ChooseEvaluationPairs(dataset, options.max_pairs);
  ctx.ThrowIfCancelled();
  CreateEvaluationFolder(options.out);

  // Scorers, rows and contact sheet pairs (in this order: each may throw MissingData or Io).
  EvaluateReport report;
  report.pairs = static_cast<int>(chosen.size());
  report.pair_indices = chosen;
  const bool sr = loaded.info.sr_trained;
  EvalLoop loop{options, model, config, device, dataset, chosen, sr, LoadEvalScorers(options, device),
                SetUpEvalRows(options, config, sr, dataset.size(), dataset.image_size()),
                ContactPairPositions(options.contact_rows, chosen.size()), {}, json::array(), report};

  EvalProgress progress(options.print_progress, chosen.size());
  for (size_t begin = 0; begin < chosen.size(); begin += options.batch_size) {
    ctx.ThrowIfCancelled();
    const size_t end = std::min(chosen.size(), begin + static_cast<size_t>(options.batch_size));
    EvaluateBatch(loop, begin, end, ctx);
    progress.Update(end, ctx);  // every pair up to `end` is done
  }
  progress.Finish();
  ctx.ThrowIfCancelled();

  evaluation::SummariseRows(loop.table.rows, &report);
  report.seconds = timer.Seconds();
  const evaluation::RunDescription run{fingerprint, &config, loaded.info, sr, dataset.size(), config.render_size,
                                       dataset.image_size()};
  evaluation::WriteEvaluationOutputs(options, run, loop.per_pair, loop.contact, &report);
  return report;
}

}  // namespace avatar
