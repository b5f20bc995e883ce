#include "core/tools/accuracy_benchmark.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "core/tools/face_metrics.h"
#include "core/io/atomic_file.h"
#include "core/io/image_io.h"
#include "core/tools/benchmarks.h"
#include "core/tools/evaluate.h"
#include "core/io/image_tensor.h"
#include "core/pipeline/detail_source.h"
#include "core/pipeline/probe.h"
#include "core/pipeline/refine.h"
#include "core/pipeline/session.h"
#include "core/pipeline/session_source.h"
#include "core/pipeline/source_analysis.h"
#include "core/tools/dataset_records.h"
#include "core/render/view_pose.h"
#include "core/train/dataset.h"
#include "core/train/losses.h"
#include "core/train/perceptual.h"
#include "core/util/error.h"
#include "core/util/text.h"
#include "core/util/measure.h"
#include "core/util/threads.h"
#include "core/util/timer.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// One validation portrait as the session and the refinement take it.
struct Portrait {
  int64_t pair = 0;      // index into the val split
  int64_t identity = 0;  // dataset identity id
  face::AlignedPortrait aligned;
  SourceFit fit;
  RefineTarget target;
  torch::Tensor source;  // [1,3,S,S] matted source in [-1,1]
  torch::Tensor matte;   // [1,1,S,S]
  cv::Mat source_bgr;    // dataset-size matted source (the CSIM reference)
};


Portrait MakePortrait(const train::TrainSample& s, int64_t index) {
  Portrait p;
  p.pair = index;
  p.identity = s.identity;
  p.source = s.source.unsqueeze(0).to(torch::kFloat32);
  p.matte = s.source_matte.unsqueeze(0).to(torch::kFloat32);
  p.source_bgr = TensorToBgr(p.source);
  p.aligned = PortraitFromAlignedImage(p.source_bgr);
  cv::resize(TensorToFloatMat(s.source_matte), p.aligned.matte, cv::Size(512, 512), 0, 0, cv::INTER_LINEAR);
  cv::Mat eye_mouth;
  TensorToFloatMat(s.source_eye_mouth).convertTo(eye_mouth, CV_8UC1, 255.0);
  cv::resize(eye_mouth, p.aligned.eye_mouth_mask, cv::Size(512, 512), 0, 0, cv::INTER_NEAREST);
  const torch::Tensor label = s.source_label.to(torch::kCPU, torch::kFloat32).contiguous();
  std::copy(label.data_ptr<float>(), label.data_ptr<float>() + 25, p.fit.camera.begin());
  std::vector<float> beta;
  if (s.target_expression.defined()) {
    const torch::Tensor t = s.target_expression.to(torch::kCPU, torch::kFloat32).contiguous();
    beta.assign(t.data_ptr<float>(), t.data_ptr<float>() + t.numel());
  }
  // I_exp of a validation photo: its own expression image (photo pairs: target = source), the
  // only expression the benchmark renders, with the shard's morphable coefficients.
  p.fit.expressions =
      std::make_shared<FixedExpressionSource>(TensorToBgr(s.expression_image.unsqueeze(0)), std::move(beta),
                                              "bench-fixed", /*own_expression_only=*/true);
  p.target.image = p.aligned.image;
  p.target.matte = p.aligned.matte;
  if (s.neutral_image.defined() && s.neutral_mask.defined()) {
    p.target.neutral_image = TensorToBgr(s.neutral_image.unsqueeze(0));
    p.target.neutral_mask = TensorToFloatMat(s.neutral_mask);
  }
  return p;
}

// Up to `n` photo pairs of the split, one per identity, spread over the split.
std::vector<int64_t> ChoosePortraits(const train::TrainDataset& dataset, int n) {
  std::vector<int64_t> photos;
  std::set<int64_t> seen;
  for (int64_t i = 0; i < dataset.size(); ++i) {
    const train::TrainSample s = dataset.Get(i);
    if (s.kind != train::PairKind::kPhoto || !seen.insert(s.identity).second) continue;
    photos.push_back(i);
  }
  if (static_cast<int>(photos.size()) <= n) return photos;
  std::vector<int64_t> chosen;
  for (int k = 0; k < n; ++k) chosen.push_back(photos[static_cast<size_t>(k) * photos.size() / n]);
  return chosen;
}

// Row::kind of a quality level's row (the value accuracy.json stores keeps its first word), and of
// its detail-path twin.
constexpr const char* kLevelRow = "preset";
constexpr const char* kDetailRow = "detail";

// One row of the table: render settings + refinement steps.
struct Row {
  std::string name;
  std::string kind;  // kLevelRow or "sweep"
  RenderSettings settings;
  std::string describe;
  int steps = 0;
  bool detail = false;  // rendered through the photo's detail path
  // Per portrait.
  std::vector<double> reconstruct_s, frame_s, psnr, psnr_matte, ssim, perceptual;
  std::vector<face::PairFaceMetrics> turned_plus, turned_minus;
};


json JsonNum(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

// "0.912 (4/4)" or "no face (0/4)".
std::string CsimCell(const face::FaceMetricsSummary& s) {
  if (s.pairs == 0) return "-";
  const std::string count = " (" + std::to_string(s.valid) + "/" + std::to_string(s.pairs) + ")";
  return (s.valid > 0 ? Fixed(s.csim, 3) : std::string("no face")) + count;
}

// ----------------------------------------------------------------------------- plot

// "Nice" tick step for a span (1, 2 or 5 x 10^k, about `count` ticks).
double TickStep(double span, int count) {
  const double raw = span / std::max(1, count);
  const double p = std::pow(10.0, std::floor(std::log10(std::max(raw, 1e-12))));
  for (double m : {1.0, 2.0, 5.0, 10.0}) {
    if (m * p >= raw) return m * p;
  }
  return 10.0 * p;
}

std::string TickLabel(double v, double step) {
  const int digits = step >= 1.0 ? 0 : static_cast<int>(std::ceil(-std::log10(step)));
  return Fixed(v, digits);
}

struct Series {
  std::string label;
  cv::Scalar colour;
  bool line = false;
  std::vector<cv::Point2d> points;
  std::vector<std::string> names;  // per point
};

// One panel: `series` of (seconds, value) with axes, ticks, labels and a legend.
void DrawPanel(cv::Mat& canvas, const cv::Rect& area, const std::string& title, const std::string& x_label,
               const std::string& y_label, const std::vector<Series>& series) {
  const cv::Scalar ink(30, 30, 30), grid(225, 225, 225);
  const int font = cv::FONT_HERSHEY_SIMPLEX;
  const int left = 72, right = 18, top = 40, bottom = 56;
  const cv::Rect plot(area.x + left, area.y + top, area.width - left - right, area.height - top - bottom);
  double x0 = 0.0, x1 = 0.0, y0 = 0.0, y1 = 0.0;
  bool any = false;
  for (const auto& s : series) {
    for (const auto& p : s.points) {
      if (!std::isfinite(p.x) || !std::isfinite(p.y)) continue;
      if (!any) {
        x0 = x1 = p.x;
        y0 = y1 = p.y;
        any = true;
      }
      x0 = std::min(x0, p.x);
      x1 = std::max(x1, p.x);
      y0 = std::min(y0, p.y);
      y1 = std::max(y1, p.y);
    }
  }
  cv::putText(canvas, title, cv::Point(area.x + left, area.y + 24), font, 0.55, ink, 1, cv::LINE_AA);
  cv::rectangle(canvas, plot, ink, 1);
  if (!any) {
    cv::putText(canvas, "no values", cv::Point(plot.x + plot.width / 2 - 40, plot.y + plot.height / 2), font, 0.5, ink,
                1, cv::LINE_AA);
    return;
  }
  x0 = std::min(x0, 0.0);
  const double ypad = std::max(1e-3, 0.08 * (y1 - y0));
  y0 -= ypad;
  y1 += ypad;
  x1 = x1 + std::max(1e-3, 0.05 * (x1 - x0));
  const double xs = TickStep(x1 - x0, 6), ys = TickStep(y1 - y0, 6);
  x0 = std::floor(x0 / xs) * xs;
  x1 = std::ceil(x1 / xs) * xs;
  y0 = std::floor(y0 / ys) * ys;
  y1 = std::ceil(y1 / ys) * ys;
  auto to_px = [&](const cv::Point2d& p) {
    return cv::Point(plot.x + static_cast<int>(std::lround((p.x - x0) / (x1 - x0) * plot.width)),
                     plot.y + plot.height - static_cast<int>(std::lround((p.y - y0) / (y1 - y0) * plot.height)));
  };
  for (double x = x0; x <= x1 + 1e-9; x += xs) {
    const cv::Point a = to_px({x, y0}), b = to_px({x, y1});
    cv::line(canvas, a, b, grid, 1);
    const std::string t = TickLabel(x, xs);
    cv::putText(canvas, t, cv::Point(a.x - 4 * static_cast<int>(t.size()), a.y + 18), font, 0.4, ink, 1, cv::LINE_AA);
  }
  for (double y = y0; y <= y1 + 1e-9; y += ys) {
    const cv::Point a = to_px({x0, y}), b = to_px({x1, y});
    cv::line(canvas, a, b, grid, 1);
    const std::string t = TickLabel(y, ys);
    cv::putText(canvas, t, cv::Point(a.x - 8 - 8 * static_cast<int>(t.size()), a.y + 4), font, 0.4, ink, 1,
                cv::LINE_AA);
  }
  cv::rectangle(canvas, plot, ink, 1);
  // Axis labels (the y label rotated).
  int base = 0;
  const cv::Size xs_size = cv::getTextSize(x_label, font, 0.5, 1, &base);
  cv::putText(canvas, x_label, cv::Point(plot.x + (plot.width - xs_size.width) / 2, plot.y + plot.height + 42), font,
              0.5, ink, 1, cv::LINE_AA);
  const cv::Size ys_size = cv::getTextSize(y_label, font, 0.5, 1, &base);
  cv::Mat label(ys_size.height + 8, ys_size.width + 4, CV_8UC3, cv::Scalar(255, 255, 255));
  cv::putText(label, y_label, cv::Point(2, ys_size.height + 2), font, 0.5, ink, 1, cv::LINE_AA);
  cv::Mat rotated;
  cv::rotate(label, rotated, cv::ROTATE_90_COUNTERCLOCKWISE);
  const int ly = std::max(area.y, plot.y + (plot.height - rotated.rows) / 2);
  const cv::Rect dst(area.x + 4, ly, rotated.cols, std::min(rotated.rows, area.y + area.height - ly));
  rotated(cv::Rect(0, 0, dst.width, dst.height)).copyTo(canvas(dst));
  // Data.
  int legend_y = plot.y + 16;
  for (const auto& s : series) {
    std::vector<cv::Point> px;
    for (const auto& p : s.points) {
      if (std::isfinite(p.x) && std::isfinite(p.y)) px.push_back(to_px(p));
    }
    if (s.line && px.size() > 1) cv::polylines(canvas, px, false, s.colour, 2, cv::LINE_AA);
    size_t k = 0;
    for (size_t i = 0; i < s.points.size(); ++i) {
      if (!std::isfinite(s.points[i].x) || !std::isfinite(s.points[i].y)) continue;
      const cv::Point c = px[k++];
      cv::circle(canvas, c, 5, s.colour, cv::FILLED, cv::LINE_AA);
      if (i < s.names.size()) {
        cv::putText(canvas, s.names[i], c + cv::Point(7, -6), font, 0.38, s.colour * 0.7, 1, cv::LINE_AA);
      }
    }
    cv::circle(canvas, cv::Point(plot.x + plot.width - 190, legend_y - 4), 5, s.colour, cv::FILLED, cv::LINE_AA);
    cv::putText(canvas, s.label, cv::Point(plot.x + plot.width - 180, legend_y), font, 0.42, ink, 1, cv::LINE_AA);
    legend_y += 18;
  }
}

}  // namespace

std::vector<int> AccuracyBenchmarkOptions::Steps() const {
  std::vector<int> steps;
  for (const auto& s : SplitList(refine_steps)) {
    char* end = nullptr;
    const long v = std::strtol(s.c_str(), &end, 10);
    AVATAR_CHECK_OPTION(end != nullptr && *end == '\0' && v >= 0 && v <= 100000)
        << "--refine-steps: '" << s << "' is not a step count (0..100000)";
    steps.push_back(static_cast<int>(v));
  }
  return steps;
}
std::vector<const QualityLevel*> AccuracyBenchmarkOptions::Levels() const {
  std::vector<const QualityLevel*> out;
  for (const auto& name : SplitList(quality)) {
    if (name == "all") {
      out.clear();
      for (const auto& p : QualityLadder()) out.push_back(&p);
      return out;
    }
    out.push_back(&QualityLevelByName(name));
  }
  return out;
}
void AccuracyBenchmarkOptions::Validate() const {
  AVATAR_CHECK_OPTION(!data.empty()) << "--data must name a dataset folder (built by 'avatar-studio dataset build')";
  AVATAR_CHECK_OPTION(portraits >= 1 && portraits <= 1000) << "--portraits must be 1..1000, got " << portraits;
  AVATAR_CHECK_OPTION(!out.empty()) << "--out must name the output folder";
  AVATAR_CHECK_OPTION(std::isfinite(yaw) && yaw > 0.0 && yaw <= 90.0) << "--yaw must be within (0, 90], got " << yaw;
  Steps();
  AVATAR_CHECK_OPTION(!Levels().empty() || !Steps().empty()) << "nothing to measure: give --quality or --refine-steps";
  ValidateDetailMode(detail);
}

AccuracyBenchmarkReport RunAccuracyBenchmark(const AccuracyBenchmarkOptions& options, RunContext& ctx,
                                             const std::function<void(const std::string&)>& notes) {
  options.Validate();
  Timer total;
  const fs::path data(options.data);
  if (!fs::is_directory(data) || !fs::exists(data / "dataset.json")) {
    throw Io("'" + options.data + "' is not a dataset folder (" + (data / "dataset.json").string() +
             " is missing); build one with 'avatar-studio dataset build --out DIR'");
  }
  std::error_code ec;
  fs::create_directories(options.out, ec);
  if (!fs::is_directory(options.out)) {
    throw Io("cannot create the output folder '" + options.out + "'" + (ec ? ": " + ec.message() : std::string()));
  }
  const int threads = ConfiguredThreads() > 0 ? ConfiguredThreads() : ConfigureThreads(options.threads);
  SessionOptions so;
  so.checkpoint = options.checkpoint;
  so.data_dir = options.data_dir;
  const auto shared_session = std::make_shared<const Session>(so);
  const Session& session = *shared_session;
  const ModelInfo info = session.Info();
  const int compare = std::max(info.sr_size, info.render_size);  // every row is compared at this size

  const train::TrainDataset dataset = train::TrainDataset::Open(options.data, "val");
  const std::vector<int64_t> chosen = ChoosePortraits(dataset, options.portraits);
  AVATAR_CHECK_INPUT(!chosen.empty()) << options.data
                                      << ": the val split has no photo pairs (portraits); build the dataset with "
                                         "--val-identities >= 1";
  std::unique_ptr<PerceptualLoss> perceptual;
  if (options.perceptual) {
    PerceptualOptions po;
    po.data_dir = options.data_dir;
    perceptual = std::make_unique<PerceptualLoss>(po);
  }
  std::unique_ptr<face::FaceMetrics> faces;
  if (options.face_metrics) {
    face::FaceMetricsOptions fo;
    fo.data_dir = options.data_dir;
    fo.expression = false;  // CSIM only
    faces = std::make_unique<face::FaceMetrics>(fo);
  }

  // Rows: the quality levels, then the sweep at the model's own render settings.
  std::vector<Row> rows;
  for (const QualityLevel* p : options.Levels()) {
    Row r;
    r.name = p->name;
    r.kind = kLevelRow;
    r.settings = p->Render(info);
    r.describe = p->Describe(info);
    r.steps = p->refine_steps;
    rows.push_back(r);
    if (options.detail != "off") {
      r.name += " + detail";
      r.kind = kDetailRow;
      r.describe += ", detail " + options.detail;
      r.detail = true;
      rows.push_back(r);
    }
  }
  const QualityLevel& standard = QualityLevelByName("standard");
  for (int steps : options.Steps()) {
    Row r;
    r.name = "refine " + std::to_string(steps);
    r.kind = "sweep";
    r.settings = standard.Render(info);
    QualityLevel p = standard;
    p.refine_steps = steps;
    r.describe = p.Describe(info);
    r.steps = steps;
    rows.push_back(r);
  }
  // The detail rows need each portrait's crop and morphable fit: the dataset's records of the pairs.
  std::string detail_left_out;
  SplitPairRecords records;
  if (options.detail != "off") {
    records = LoadSplitPairRecords(data, "val", dataset.size());
    if (!records.ok) {
      detail_left_out = "the detail rows are left out: " + records.why;
      rows.erase(std::remove_if(rows.begin(), rows.end(), [](const Row& r) { return r.detail; }), rows.end());
      if (notes) notes("bench accuracy: " + detail_left_out + "\n");
    }
  }
  std::set<int> step_counts;
  for (const auto& r : rows) step_counts.insert(r.steps);

  const double gemm_before = MeasureGemmGflops();
  {
    std::ostringstream line;
    line << "bench accuracy: " << chosen.size() << " portraits, " << rows.size() << " rows, refinement steps {";
    for (int s : step_counts) line << " " << s;
    line << " }, " << threads << " threads, " << DescribeModel(info) << "\n";
    if (notes) notes(line.str());
  }

  RefineOptions refine_base;
  refine_base.data_dir = options.data_dir;
  json per_portrait = json::array();
  for (size_t k = 0; k < chosen.size(); ++k) {
    ctx.ThrowIfCancelled();
    RunContext::ProgressRange range(ctx, static_cast<double>(k) / chosen.size(),
                                    static_cast<double>(k + 1) / chosen.size());
    const Portrait portrait = MakePortrait(dataset.Get(chosen[k]), chosen[k]);
    RunContext quiet;
    if (k == 0) {
      // Warm-up: first forward passes and the perceptual network's load are not the portrait's cost.
      const Avatar warm = session.ReconstructFromAnalysis(portrait.aligned, portrait.fit, quiet);
      RefineOptions one = refine_base;
      one.steps = 1;
      RefineAvatar(session, warm, portrait.target, one, ctx);
    }
    Timer one_shot_timer;
    const Avatar one_shot = session.ReconstructFromAnalysis(portrait.aligned, portrait.fit, quiet);
    const double one_shot_s = one_shot_timer.Seconds();
    std::map<int, Avatar> avatars;
    std::map<int, double> refine_s;
    avatars[0] = one_shot;
    refine_s[0] = 0.0;
    for (int steps : step_counts) {
      if (steps == 0) continue;
      RefineOptions o = refine_base;
      o.steps = steps;
      Timer t;
      avatars[steps] = RefineAvatar(session, one_shot, portrait.target, o, ctx).avatar;
      refine_s[steps] = t.Seconds();
    }
    const face::FaceMeasurement reference = faces ? faces->Measure(portrait.source_bgr) : face::FaceMeasurement{};
    const torch::Tensor target = train::ResizeTo(portrait.source, compare);
    const torch::Tensor matte = train::ResizeTo(portrait.matte, compare);
    const render::ViewPose source_pose = render::PoseOfCamera(portrait.fit.camera);
    render::ViewPose plus = source_pose, minus = source_pose;
    plus.yaw += options.yaw;
    minus.yaw -= options.yaw;
    const std::array<float, 25> cam_plus = render::CameraForView(plus, portrait.fit.camera);
    const std::array<float, 25> cam_minus = render::CameraForView(minus, portrait.fit.camera);
    json pj = {{"pair", portrait.pair}, {"identity", portrait.identity}, {"one_shot_seconds", one_shot_s}};
    for (auto& [steps, avatar] : avatars) {
      // The expression planes of this avatar, once (frames then time a new view only).
      session.Animate(avatar, Expression{}, portrait.fit.camera, RenderSettings{});
    }
    SourceAnalysis analysis;
    if (records.ok) {
      const json& record = records.records.at(records.pairs.at(static_cast<size_t>(chosen[k])).first);
      face::AlignedPortrait crop = RecordPortrait(data, record);
      morphable::FitResult record_fit = RecordFit(record, crop.image_unmatted.size());
      analysis = AnalysisFromFit(std::move(crop), std::move(record_fit), options.data_dir);
    }
    for (auto& row : rows) {
      ctx.ThrowIfCancelled();
      const Avatar& avatar = avatars.at(row.steps);
      std::vector<double> frame_times;
      double bake_s = 0.0;
      std::unique_ptr<DetailFrameSource> detail;
      if (row.detail) {
        auto network = std::make_shared<SessionFrameSource>(shared_session, avatar, false, analysis.overlay);
        network->SetRenderSettings(row.settings);
        DetailOptions d;
        d.mode = options.detail;
        Timer bake;
        detail = std::make_unique<DetailFrameSource>(std::move(network), analysis, d);
        bake_s = bake.Seconds();
      }
      // The network's frame at `camera`, or the detail path's at `pose` (the same camera: the
      // avatar's source camera is the portrait's).
      auto render = [&](const std::array<float, 25>& camera, const render::ViewPose& pose) {
        Timer t;
        Frame f;
        if (detail) {
          FrameRequest q;
          q.view = pose;
          q.width = q.height = compare;
          f.bgr = detail->Render(q, quiet).bgr;
        } else {
          f = session.Animate(avatar, Expression{}, camera, row.settings);
        }
        frame_times.push_back(t.Seconds());
        return f;
      };
      const Frame source_view = render(portrait.fit.camera, source_pose);
      const Frame turned_plus = render(cam_plus, plus);
      const Frame turned_minus = render(cam_minus, minus);
      cv::Mat shown;
      cv::resize(source_view.bgr, shown, cv::Size(compare, compare), 0, 0,
                 source_view.bgr.cols < compare ? cv::INTER_CUBIC : cv::INTER_AREA);
      const torch::Tensor rendered = ImageToTensor(shown, compare, "source-view render");
      const train::ImageMetrics full = EvaluationImageMetrics(rendered, target, {}, perceptual.get());
      const train::ImageMetrics weighted = EvaluationImageMetrics(rendered, target, matte, nullptr);
      row.reconstruct_s.push_back(one_shot_s + refine_s.at(row.steps) + bake_s);
      row.frame_s.push_back(Median(frame_times));
      row.psnr.push_back(full.psnr[0].item<double>());
      row.ssim.push_back(full.ssim[0].item<double>());
      if (full.perceptual.defined()) row.perceptual.push_back(full.perceptual[0].item<double>());
      row.psnr_matte.push_back(weighted.psnr[0].item<double>());
      json rj = {{"reconstruct_seconds", row.reconstruct_s.back()},
                 {"frame_seconds", row.frame_s.back()},
                 {"psnr", JsonNum(row.psnr.back())},
                 {"psnr_matte", JsonNum(row.psnr_matte.back())},
                 {"ssim", JsonNum(row.ssim.back())}};
      if (full.perceptual.defined()) rj["perceptual"] = JsonNum(row.perceptual.back());
      if (faces) {
        row.turned_plus.push_back(faces->Compare(faces->Measure(turned_plus.bgr), reference));
        row.turned_minus.push_back(faces->Compare(faces->Measure(turned_minus.bgr), reference));
        if (row.turned_plus.back().valid()) rj["csim_plus"] = JsonNum(row.turned_plus.back().csim);
        if (row.turned_minus.back().valid()) rj["csim_minus"] = JsonNum(row.turned_minus.back().csim);
      }
      pj["rows"][row.name] = rj;
    }
    per_portrait.push_back(pj);
    ctx.Report("bench accuracy", 1.0, std::to_string(k + 1) + "/" + std::to_string(chosen.size()) + " portraits");
    if (notes) {
      notes("  portrait " + std::to_string(k + 1) + "/" + std::to_string(chosen.size()) + " (pair " +
            std::to_string(portrait.pair) + "): one-shot " + Fixed(one_shot_s, 2) + " s, refinement " +
            Fixed(refine_s.rbegin()->second, 1) + " s for " + std::to_string(refine_s.rbegin()->first) +
            " steps; elapsed " + Fixed(total.Seconds(), 0) + " s\n");
    }
  }
  const double gemm_after = MeasureGemmGflops();

  // Table.
  std::ostringstream md;
  md << "# Accuracy against time\n\n"
     << "- model: " << DescribeModel(info) << "\n"
     << "- data: `" << options.data << "`, val split, " << chosen.size()
     << " portraits (photo pairs, one per identity)\n"
     << "- machine: " << threads << " threads; fp32 GEMM " << Fixed(gemm_before, 1) << " GFLOP/s before, "
     << Fixed(gemm_after, 1) << " after (a large change means the machine was busy)\n"
     << "- wall time: " << Fixed(total.Seconds(), 0) << " s\n\n"
     << "| row | settings | reconstruct s | frame s | PSNR | PSNR (matte) | SSIM | perceptual | CSIM +" << options.yaw
     << " | CSIM -" << options.yaw << " |\n"
     << "|---|---|---|---|---|---|---|---|---|---|\n";
  json jrows = json::array();
  std::vector<face::FaceMetricsSummary> plus_summary, minus_summary;
  for (const auto& r : rows) {
    const face::FaceMetricsSummary sp = face::FaceMetrics::Summarise(r.turned_plus);
    const face::FaceMetricsSummary sm = face::FaceMetrics::Summarise(r.turned_minus);
    plus_summary.push_back(sp);
    minus_summary.push_back(sm);
    md << "| " << r.name << " | " << r.describe << " | " << FixedOrDash(MeanOrNan(r.reconstruct_s), 2) << " | "
       << FixedOrDash(MeanOrNan(r.frame_s), 3) << " | " << FixedOrDash(MeanOrNan(r.psnr), 2) << " | " << FixedOrDash(MeanOrNan(r.psnr_matte), 2) << " | "
       << FixedOrDash(MeanOrNan(r.ssim), 3) << " | " << FixedOrDash(MeanOrNan(r.perceptual), 3) << " | " << CsimCell(sp) << " | "
       << CsimCell(sm) << " |\n";
    json jr = {{"name", r.name},
               {"kind", r.kind},
               {"settings", r.describe},
               {"refine_steps", r.steps},
               {"detail", r.detail ? options.detail : std::string("off")},
               {"render_size", r.settings.resolution},
               {"num_coarse", r.settings.num_coarse},
               {"num_importance", r.settings.num_importance},
               {"super_resolution", r.settings.super_resolution},
               {"reconstruct_seconds", JsonNum(MeanOrNan(r.reconstruct_s))},
               {"frame_seconds", JsonNum(MeanOrNan(r.frame_s))},
               {"psnr", JsonNum(MeanOrNan(r.psnr))},
               {"psnr_matte", JsonNum(MeanOrNan(r.psnr_matte))},
               {"ssim", JsonNum(MeanOrNan(r.ssim))},
               {"perceptual", JsonNum(MeanOrNan(r.perceptual))}};
    jr["csim_plus"] = {{"valid", sp.valid}, {"pairs", sp.pairs}, {"mean", sp.valid > 0 ? JsonNum(sp.csim) : json()}};
    jr["csim_minus"] = {{"valid", sm.valid}, {"pairs", sm.pairs}, {"mean", sm.valid > 0 ? JsonNum(sm.csim) : json()}};
    jrows.push_back(jr);
  }
  md << "\nReconstruct s = one-shot forward + refinement (face analysis not included; the portraits come aligned "
        "from the dataset); frame s = median of the source-view and the two turned renders. PSNR (dB, peak = the "
        "[-1,1] range), SSIM and perceptual (MobileNetV2 features, not LPIPS) compare the source-view render with the "
        "matted source photo at "
     << compare << " px (renders resized bicubically), as `eval` does; PSNR (matte) weights by the person matte. "
     << "CSIM = fr_feature cosine similarity of the renders at yaw +-" << options.yaw
     << " degrees (about the source camera) with the source photo, over the renders with a face (count in brackets). "
        "Rows 'refine N' are the model's render settings after N refinement steps. Rows 'LEVEL + detail' render the "
        "same avatar through the photo's detail path (its bake, the source-view depth, is in reconstruct s).\n";
  if (!detail_left_out.empty()) md << "\nNote: " << detail_left_out << ".\n";

  // Plot: PSNR and CSIM against reconstruct seconds.
  std::vector<Series> psnr_series(3), csim_series(3);
  psnr_series[0] = {"quality levels", cv::Scalar(200, 90, 30), false, {}, {}};
  psnr_series[1] = {"refinement sweep", cv::Scalar(40, 140, 40), true, {}, {}};
  psnr_series[2] = {"levels + detail", cv::Scalar(40, 60, 210), false, {}, {}};
  csim_series[0] = {"levels, mean of +-yaw", cv::Scalar(200, 90, 30), false, {}, {}};
  csim_series[1] = {"refinement sweep", cv::Scalar(40, 140, 40), true, {}, {}};
  csim_series[2] = {"levels + detail", cv::Scalar(40, 60, 210), false, {}, {}};
  for (size_t i = 0; i < rows.size(); ++i) {
    const Row& r = rows[i];
    const size_t s = r.detail ? 2 : r.kind == kLevelRow ? 0 : 1;
    const double x = MeanOrNan(r.reconstruct_s);
    const std::string label = r.kind == "sweep" ? std::to_string(r.steps) : r.name;
    psnr_series[s].points.push_back({x, MeanOrNan(r.psnr)});
    psnr_series[s].names.push_back(label);
    std::vector<double> csims;
    if (plus_summary[i].valid > 0) csims.push_back(plus_summary[i].csim);
    if (minus_summary[i].valid > 0) csims.push_back(minus_summary[i].csim);
    csim_series[s].points.push_back({x, MeanOrNan(csims)});
    csim_series[s].names.push_back(label);
  }
  cv::Mat plot(520, 1200, CV_8UC3, cv::Scalar(255, 255, 255));
  DrawPanel(plot, cv::Rect(0, 0, 600, 520), "Source-view PSNR vs reconstruct time", "reconstruct seconds",
            "PSNR at the source view (dB)", psnr_series);
  DrawPanel(plot, cv::Rect(600, 0, 600, 520), "Identity at yaw +-" + Fixed(options.yaw, 0) + " vs reconstruct time",
            "reconstruct seconds", "CSIM (fr_feature)", csim_series);

  json j;
  j["model"] = {{"description", DescribeModel(info)},
                {"model_id", info.model_id},
                {"config", info.config_name},
                {"checkpoint", info.checkpoint_path},
                {"sr_trained", info.sr_trained}};
  j["data"] = options.data;
  j["portraits"] = chosen.size();
  j["threads"] = threads;
  j["gemm_gflops"] = {{"before", gemm_before}, {"after", gemm_after}};
  j["compare_size"] = compare;
  j["yaw"] = options.yaw;
  j["seconds"] = total.Seconds();
  j["rows"] = jrows;
  j["per_portrait"] = per_portrait;
  const fs::path out(options.out);
  SaveImage(out / "accuracy.png", plot);
  WriteBytesAtomically(out / "accuracy.md", md.str());
  WriteBytesAtomically(out / "accuracy.json", j.dump(1) + "\n");
  AccuracyBenchmarkReport report;
  report.markdown = md.str();
  report.markdown_path = (out / "accuracy.md").string();
  report.json_path = (out / "accuracy.json").string();
  report.plot_path = (out / "accuracy.png").string();
  return report;
}

}  // namespace avatar
