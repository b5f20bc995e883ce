#include "core/tools/upscale_benchmark.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <memory>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "core/compose/upscaler.h"
#include "core/io/atomic_file.h"
#include "core/io/image_io.h"
#include "core/io/image_tensor.h"
#include "core/io/json_file.h"
#include "core/pipeline/source_analysis.h"
#include "core/pipeline/studio_backend.h"
#include "core/render/view_pose.h"
#include "core/tools/dataset_records.h"
#include "core/tools/evaluate.h"
#include "core/train/perceptual.h"
#include "core/util/error.h"
#include "core/util/measure.h"
#include "core/util/text.h"
#include "core/util/threads.h"
#include "core/util/timer.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// A record's frame matted onto black, at its stored size, and its matte (CV_32FC1).
std::pair<cv::Mat, cv::Mat> MattedFrame(const fs::path& dir, const json& record) {
  const face::AlignedPortrait p = RecordPortrait(dir, record);
  cv::Mat f, m3, out;
  p.image_unmatted.convertTo(f, CV_32FC3);
  cv::Mat matte;
  p.matte.convertTo(matte, CV_32FC1);
  cv::cvtColor(matte, m3, cv::COLOR_GRAY2BGR);
  f = f.mul(m3);
  f.convertTo(out, CV_8UC3);
  return {out, matte};
}

// Running means of one way of making a full-size frame.
struct Way {
  std::string name;
  std::vector<double> psnr, psnr_matte, ssim, perceptual, seconds;
};


class Scorer {
 public:
  explicit Scorer(const PerceptualLoss* perceptual) : perceptual_(perceptual) {}
  // Adds the metrics of `image` against `target` (both BGR8 of one size; matte CV_32FC1).
  void Score(Way& way, const cv::Mat& image, const cv::Mat& target, const cv::Mat& matte) const {
    const int s = target.cols;
    const torch::Tensor a = ImageToTensor(image, s, "upscaled frame");
    const torch::Tensor b = ImageToTensor(target, s, "target frame");
    const train::ImageMetrics full = EvaluationImageMetrics(a, b, {}, perceptual_);
    const train::ImageMetrics inside = EvaluationImageMetrics(a, b, MaskToTensor(matte, s, 1.0f, "matte"), nullptr);
    way.psnr.push_back(full.psnr[0].item<double>());
    way.ssim.push_back(full.ssim[0].item<double>());
    if (full.perceptual.defined()) way.perceptual.push_back(full.perceptual[0].item<double>());
    way.psnr_matte.push_back(inside.psnr[0].item<double>());
  }

 private:
  const PerceptualLoss* perceptual_;
};

void Table(std::ostringstream& md, const std::vector<Way>& ways) {
  md << "| way | frames | PSNR | PSNR (matte) | SSIM | perceptual | seconds / frame |\n|---|---|---|---|---|---|---|\n";
  for (const Way& w : ways) {
    md << "| " << w.name << " | " << w.psnr.size() << " | " << FixedOrDash(MeanOrNan(w.psnr), 2) << " | "
       << FixedOrDash(MeanOrNan(w.psnr_matte), 2) << " | " << FixedOrDash(MeanOrNan(w.ssim), 4) << " | " << FixedOrDash(MeanOrNan(w.perceptual), 4) << " | "
       << (w.seconds.empty() ? std::string("-") : Fixed(Median(w.seconds), 3)) << " |\n";
  }
}

json WaysJson(const std::vector<Way>& ways) {
  json out = json::array();
  for (const Way& w : ways) {
    auto num = [](double v) { return std::isfinite(v) ? json(v) : json(nullptr); };
    out.push_back({{"name", w.name},
                   {"frames", w.psnr.size()},
                   {"psnr", num(MeanOrNan(w.psnr))},
                   {"psnr_matte", num(MeanOrNan(w.psnr_matte))},
                   {"ssim", num(MeanOrNan(w.ssim))},
                   {"perceptual", num(MeanOrNan(w.perceptual))},
                   {"seconds", w.seconds.empty() ? json(nullptr) : json(Median(w.seconds))}});
  }
  return out;
}

// A crop around the frame's centre (the face), labelled, for the contact sheet.
cv::Mat Crop(const cv::Mat& image, const std::string& label) {
  const int side = image.cols / 3;
  const cv::Rect r((image.cols - side) / 2, image.rows / 3 - side / 4, side, side);
  cv::Mat c;
  cv::resize(image(r & cv::Rect(0, 0, image.cols, image.rows)), c, cv::Size(256, 256), 0, 0, cv::INTER_NEAREST);
  cv::rectangle(c, cv::Rect(0, 0, 256, 20), cv::Scalar(255, 255, 255), cv::FILLED);
  cv::putText(c, label, cv::Point(4, 15), cv::FONT_HERSHEY_SIMPLEX, 0.45, cv::Scalar(20, 20, 20), 1, cv::LINE_AA);
  return c;
}

}  // namespace

void UpscaleBenchmarkOptions::Validate() const {
  AVATAR_CHECK_OPTION(!data.empty()) << "--data must name a dataset folder (built by 'avatar-studio dataset build')";
  AVATAR_CHECK_OPTION(!out.empty()) << "--out must name the output folder";
  AVATAR_CHECK_OPTION(frames >= 1 && frames <= 10000) << "--frames must be 1..10000, got " << frames;
  AVATAR_CHECK_OPTION(detail_pairs >= 0 && detail_pairs <= 1000) << "--detail-pairs must be 0..1000, got " << detail_pairs;
  const auto names = SplitList(upscalers);
  AVATAR_CHECK_OPTION(!names.empty()) << "--upscalers must name at least one upscaler";
  for (const auto& n : names) {
    const auto& known = compose::UpscalerNames();
    AVATAR_CHECK_OPTION(std::find(known.begin(), known.end(), n) != known.end())
        << "--upscalers: unknown upscaler '" << n << "' (bicubic, esrgan-slim)";
  }
}

UpscaleBenchmarkReport RunUpscaleBenchmark(const UpscaleBenchmarkOptions& options, RunContext& ctx,
                                           const std::function<void(const std::string&)>& notes) {
  options.Validate();
  Timer total;
  const fs::path data(options.data);
  const fs::path records_path = data / "records.json", pairs_path = data / "pairs.json";
  if (!fs::exists(records_path) || !fs::exists(pairs_path)) {
    throw Io("'" + options.data + "' is not a dataset folder with records (" + records_path.string() +
             " or pairs.json is missing); build one with 'avatar-studio dataset build --out DIR'");
  }
  std::error_code ec;
  fs::create_directories(options.out, ec);
  if (!fs::is_directory(options.out)) throw Io("cannot create the output folder '" + options.out + "'");
  const int threads = ConfiguredThreads() > 0 ? ConfiguredThreads() : ConfigureThreads(options.threads);

  const json records = ReadJsonFile(records_path, "rebuild the dataset");
  const json pairs = ReadJsonFile(pairs_path, "rebuild the dataset");
  AVATAR_CHECK_INPUT(records.is_array() && pairs.is_array()) << records_path.string() << " / pairs.json must hold JSON arrays";
  std::map<std::string, size_t> val;
  for (size_t i = 0; i < records.size(); ++i) {
    if (records[i].is_object() && records[i].value("split", "") == "val") val[records[i].value("id", "")] = i;
  }
  std::vector<std::pair<size_t, size_t>> clip_pairs;
  std::vector<size_t> targets;
  std::set<size_t> seen;
  for (const json& p : pairs) {
    const std::string kind = p.value("kind", "");
    if (kind != "clip" && kind != "photo") continue;
    const auto s = val.find(p.value("source", "")), t = val.find(p.value("target", ""));
    if (s == val.end() || t == val.end()) continue;
    if (seen.insert(t->second).second) targets.push_back(t->second);
    if (kind == "clip" && s->second != t->second) clip_pairs.emplace_back(s->second, t->second);
  }
  AVATAR_CHECK_INPUT(!targets.empty()) << options.data << ": the val split has no photos or clip frames to measure on";
  auto spread = [](size_t have, int want) {
    std::vector<size_t> k;
    const size_t n = std::min<size_t>(have, static_cast<size_t>(want));
    for (size_t i = 0; i < n; ++i) k.push_back(i * have / n);
    return k;
  };

  std::vector<compose::ImageUpscaler> upscalers;
  for (const auto& n : SplitList(options.upscalers)) upscalers.emplace_back(n, options.data_dir);
  std::unique_ptr<PerceptualLoss> perceptual;
  if (options.perceptual) {
    PerceptualOptions po;
    po.data_dir = options.data_dir;
    perceptual = std::make_unique<PerceptualLoss>(po);
  }
  const Scorer scorer(perceptual.get());
  const double gemm_before = MeasureGemmGflops();

  // Real frames.
  std::vector<Way> real;
  for (const auto& u : upscalers) real.push_back({u.name() + " x2 of the half-size frame", {}, {}, {}, {}, {}});
  int photos = 0;
  std::vector<cv::Mat> sheet_rows;
  double mult_adds = 0.0;
  int full_size = 0;
  const std::vector<size_t> chosen = spread(targets.size(), options.frames);
  for (size_t k = 0; k < chosen.size(); ++k) {
    ctx.ThrowIfCancelled();
    ctx.Report("bench upscale", 0.5 * static_cast<double>(k) / chosen.size(), "real frames");
    const json& record = records[targets[chosen[k]]];
    const auto [target, matte] = MattedFrame(data, record);
    photos += record.value("kind", "") == "photo" ? 1 : 0;
    full_size = target.cols;
    cv::Mat half;
    cv::resize(target, half, cv::Size(target.cols / 2, target.rows / 2), 0, 0, cv::INTER_AREA);
    std::vector<cv::Mat> row = {Crop(target, "target")};
    for (size_t u = 0; u < upscalers.size(); ++u) {
      Timer t;
      const cv::Mat up = upscalers[u].Upscale(half, target.size());
      real[u].seconds.push_back(t.Seconds());
      scorer.Score(real[u], up, target, matte);
      if (upscalers[u].MultiplyAdds(half.cols, half.rows) > 0) mult_adds = upscalers[u].MultiplyAdds(half.cols, half.rows);
      row.push_back(Crop(up, upscalers[u].name()));
    }
    if (sheet_rows.size() < 3 && k % std::max<size_t>(1, chosen.size() / 3) == 0) {
      cv::Mat r;
      cv::hconcat(row, r);
      sheet_rows.push_back(r);
    }
  }
  if (notes) notes("bench upscale: " + std::to_string(chosen.size()) + " real frames done\n");

  // Detail frames: half size + each upscaler, or the full size directly.
  std::vector<Way> detail;
  int detail_done = 0;
  if (options.detail_pairs > 0 && !clip_pairs.empty()) {
    detail.push_back({"detail path at full size", {}, {}, {}, {}, {}});
    for (const auto& u : upscalers) detail.push_back({"detail path at half size + " + u.name(), {}, {}, {}, {}, {}});
    BackendOptions backend;
    backend.checkpoint = options.checkpoint;
    backend.data_dir = options.data_dir;
    backend.detail = "geometric";  // the composite is what this measures: no fusion net per source
    const std::vector<size_t> picked = spread(clip_pairs.size(), options.detail_pairs);
    for (size_t k = 0; k < picked.size(); ++k) {
      ctx.ThrowIfCancelled();
      ctx.Report("bench upscale", 0.5 + 0.5 * static_cast<double>(k) / picked.size(), "detail frames");
      const json& src = records[clip_pairs[picked[k]].first];
      const json& tgt = records[clip_pairs[picked[k]].second];
      face::AlignedPortrait portrait = RecordPortrait(data, src);
      morphable::FitResult fit = RecordFit(src, portrait.image_unmatted.size());
      SourceAnalysis analysis = AnalysisFromFit(std::move(portrait), std::move(fit), options.data_dir);
      RunContext quiet;
      const PortraitPaths paths = CreatePortraitPaths(std::move(analysis), backend, quiet);
      const auto [target, matte] = MattedFrame(data, tgt);
      FrameRequest request;
      request.view = render::PoseOfCamera(RecordLabel(tgt.at("label"), tgt.value("id", "")));
      request.expression.coefficients = tgt.at("beta").get<std::vector<float>>();
      request.expression.coefficients_absolute = true;
      request.width = request.height = target.cols;
      paths.detail->Render(request, quiet);  // warm-up (expression planes of this target)
      Timer t_full;
      const cv::Mat full = paths.detail->Render(request, quiet).bgr;
      detail[0].seconds.push_back(t_full.Seconds());
      scorer.Score(detail[0], full, target, matte);
      request.width = request.height = target.cols / 2;
      Timer t_half;
      const cv::Mat half = paths.detail->Render(request, quiet).bgr;
      const double half_s = t_half.Seconds();
      for (size_t u = 0; u < upscalers.size(); ++u) {
        Timer t;
        const cv::Mat up = upscalers[u].Upscale(half, target.size());
        detail[u + 1].seconds.push_back(half_s + t.Seconds());
        scorer.Score(detail[u + 1], up, target, matte);
      }
      ++detail_done;
      if (notes) notes("  detail pair " + std::to_string(k + 1) + "/" + std::to_string(picked.size()) + "\n");
    }
  }
  const double gemm_after = MeasureGemmGflops();

  std::ostringstream md;
  md << "# The 256 -> 512 step of exports\n\n"
     << "- data: `" << options.data << "`, val split: " << chosen.size() << " real frames (" << photos
     << " photos, the rest clip frames), "
     << detail_done << " clip pairs through the detail path; frames " << full_size << " px\n"
     << "- machine: " << threads << " threads; fp32 GEMM " << Fixed(gemm_before, 1) << " GFLOP/s before, "
     << Fixed(gemm_after, 1) << " after\n";
  for (size_t u = 0; u < upscalers.size(); ++u) {
    const double ma = upscalers[u].MultiplyAdds(full_size / 2, full_size / 2);
    if (ma <= 0 || real[u].seconds.empty()) continue;
    const double gflops = 2.0 * ma / Median(real[u].seconds) / 1e9;
    md << "- " << upscalers[u].name() << ": " << Fixed(ma / 1e9, 2) << " G multiply-adds per " << full_size / 2
       << " px frame, " << Fixed(gflops, 1) << " GFLOP/s = " << Fixed(100.0 * gflops / std::max(1e-9, gemm_before), 0)
       << "% of the GEMM peak\n";
  }
  md << "- wall time: " << Fixed(total.Seconds(), 0) << " s\n\n## Real frames: half size, upscaled, against the frame\n\n";
  Table(md, real);
  if (!detail.empty()) {
    md << "\n## Detail frames against the real target frame\n\n";
    Table(md, detail);
    md << "\nSeconds of the half-size rows include rendering the half-size frame.\n";
  }
  md << "\nPSNR (dB, peak = the [-1,1] range), SSIM and perceptual (MobileNetV2 features, not LPIPS) over the whole "
        "frame as `eval` computes them; PSNR (matte) inside the person matte.\n";
  (void)mult_adds;

  json j;
  j["data"] = options.data;
  j["threads"] = threads;
  j["gemm_gflops"] = {{"before", gemm_before}, {"after", gemm_after}};
  j["frame_size"] = full_size;
  j["real_frames"] = WaysJson(real);
  j["detail_frames"] = WaysJson(detail);
  j["seconds"] = total.Seconds();
  const fs::path out(options.out);
  UpscaleBenchmarkReport report;
  report.markdown = md.str();
  report.markdown_path = (out / "upscale.md").string();
  report.json_path = (out / "upscale.json").string();
  report.image_path = (out / "upscale.png").string();
  if (!sheet_rows.empty()) {
    cv::Mat sheet;
    cv::vconcat(sheet_rows, sheet);
    SaveImage(out / "upscale.png", sheet);
  }
  WriteBytesAtomically(out / "upscale.md", md.str());
  WriteBytesAtomically(out / "upscale.json", j.dump(1) + "\n");
  return report;
}

}  // namespace avatar
