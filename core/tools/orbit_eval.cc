#include "core/tools/orbit_eval.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "core/io/atomic_file.h"
#include "core/io/image_io.h"
#include "core/pipeline/driving.h"
#include "core/pipeline/studio_backend.h"
#include "core/util/error.h"
#include "core/util/text.h"

namespace avatar {
namespace fs = std::filesystem;
namespace {

constexpr int kBorderErode = 3;

// The opaque pixels outside the face: `opaque` eroded, minus the landmarks' convex hull dilated
// by the same margin (the face's outline is an edge of its own).
cv::Mat OutsideFaceMask(const cv::Mat& opaque, const std::vector<cv::Point2f>& landmarks) {
  cv::Mat mask;
  const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * kBorderErode + 1, 2 * kBorderErode + 1));
  cv::erode(opaque, mask, kernel);
  if (!landmarks.empty()) {
    std::vector<cv::Point> points;
    for (const auto& p : landmarks) points.emplace_back(cvRound(p.x), cvRound(p.y));
    std::vector<cv::Point> hull;
    cv::convexHull(points, hull);
    cv::Mat face = cv::Mat::zeros(mask.size(), CV_8UC1);
    cv::fillConvexPoly(face, hull, cv::Scalar(255));
    cv::dilate(face, face, kernel);
    mask.setTo(0, face);
  }
  return mask;
}

// Mean |Laplacian| of the grey image over `mask` (0 when the mask is empty).
double MeanAbsLaplacian(const cv::Mat& bgr, const cv::Mat& mask) {
  if (cv::countNonZero(mask) == 0) return 0.0;
  cv::Mat grey, lap;
  cv::cvtColor(bgr, grey, cv::COLOR_BGR2GRAY);
  cv::Laplacian(grey, lap, CV_32F);
  return cv::mean(cv::abs(lap), mask)[0];
}

cv::Mat Opaque(const cv::Mat& alpha) {
  cv::Mat m;
  cv::threshold(alpha, m, 127, 255, cv::THRESH_BINARY);
  return m;
}

// The preview's face over the network render by the preview's alpha.
RenderedFrame Paste(const RenderedFrame& network, const RenderedFrame& preview) {
  RenderedFrame out = network;
  cv::Mat a, net, pre;
  preview.alpha.convertTo(a, CV_32F, 1.0 / 255.0);
  cv::cvtColor(a, a, cv::COLOR_GRAY2BGR);
  network.bgr.convertTo(net, CV_32FC3);
  preview.bgr.convertTo(pre, CV_32FC3);
  cv::Mat mixed = pre.mul(a) + net.mul(cv::Scalar::all(1.0) - a);
  out.bgr = cv::Mat();  // a new buffer: `out` shares the network frame's pixels
  mixed.convertTo(out.bgr, CV_8UC3);
  out.alpha = cv::max(network.alpha, preview.alpha);
  return out;
}

struct Accumulator {
  std::vector<double> identity, detail;
  std::vector<int> found;
  double mouth = 0.0, psnr = 0.0;
  int mouth_found = 0, psnr_count = 0;
};

std::string Fmt(double v, int digits) { return std::isfinite(v) ? Fixed(v, digits) : std::string("n/a"); }

}  // namespace

std::vector<double> OrbitEvalOptions::YawList() const {
  std::vector<double> out;
  for (const std::string& item : SplitList(yaws)) {
    double y = 0.0;
    try {
      size_t used = 0;
      y = std::stod(item, &used);
      AVATAR_CHECK_OPTION(used == item.size()) << "--yaws: '" << item << "' is not a number";
    } catch (const std::logic_error&) {
      throw InvalidOptions("--yaws: '" + item + "' is not a number");
    }
    AVATAR_CHECK_OPTION(std::isfinite(y) && std::abs(y) <= 90.0) << "--yaws: " << item << " is outside -90..90";
    out.push_back(y);
  }
  return out;
}

void OrbitEvalOptions::Validate() const {
  AVATAR_CHECK_OPTION(!photos.empty()) << "eval orbit needs at least one PHOTO";
  AVATAR_CHECK_OPTION(!out.empty()) << "--out must name a folder";
  AVATAR_CHECK_OPTION(!YawList().empty()) << "--yaws must list at least one yaw";
  AVATAR_CHECK_OPTION(size >= 64 && size <= 1024) << "--size must be within 64..1024, got " << size;
  AVATAR_CHECK_OPTION(!jaw_control.empty()) << "--jaw-control must name an expression control";
  AVATAR_CHECK_OPTION(std::isfinite(jaw_value) && jaw_value >= -2.0 && jaw_value <= 2.0)
      << "--jaw-value must be within -2..2, got " << jaw_value;
  AVATAR_CHECK_OPTION(contact_photos >= 0) << "--contact-photos must be >= 0";
  face.Validate();
}

OrbitEvalReport RunOrbitEvaluation(const OrbitEvalOptions& options, RunContext& ctx) {
  options.Validate();
  const auto start = std::chrono::steady_clock::now();
  OrbitEvalReport report;
  report.yaws = options.YawList();
  const size_t n_yaw = report.yaws.size();
  BackendOptions backend;
  backend.checkpoint = options.checkpoint;
  backend.data_dir = options.data_dir;
  backend.fusion = options.fusion;
  backend.align_depth = options.align_depth;
  backend.Validate();
  std::vector<std::string> keys = {"network", "preview", "paste", "face", "detail"};
  if (!FusionWeightsOf(backend).empty()) keys.push_back("learned");  // CreatePortraitPaths's learned path
  std::vector<Accumulator> acc(keys.size());
  for (auto& a : acc) {
    a.identity.assign(n_yaw, 0.0);
    a.detail.assign(n_yaw, 0.0);
    a.found.assign(n_yaw, 0);
  }
  std::vector<std::string> names(keys.size());
  nlohmann::json per_photo = nlohmann::json::array();

  face::FaceMetricsOptions fo = options.face;
  fo.data_dir = options.data_dir;
  fo.expression = false;  // identity, landmarks and pose only
  const face::FaceMetrics metrics(fo);

  const int size = options.size;
  const int shown = std::min<int>(options.contact_photos, static_cast<int>(options.photos.size()));
  std::vector<cv::Mat> sheet_rows;
  const size_t photo_count = options.photos.size();
  for (size_t p = 0; p < photo_count; ++p) {
    const std::string& file = options.photos[p];
    RunContext::ProgressRange range(ctx, static_cast<double>(p) / photo_count, static_cast<double>(p + 1) / photo_count);
    ctx.Report("orbit " + fs::path(file).filename().string(), 0.0);
    const cv::Mat photo = LoadImageBgr(file);
    PortraitPaths paths;
    try {
      paths = CreatePortraitPaths(photo, backend, ctx);
    } catch (const InvalidInput& e) {
      throw InvalidInput(file + ": " + e.what());
    }
    const face::FaceMeasurement reference = metrics.Measure(photo);
    AVATAR_CHECK_INPUT(reference.found) << file << ": the identity network finds no face in the photo ("
                                        << reference.reason << ")";
    // The photo's own detail: its aligned crop at the output size, within its matte.
    cv::Mat crop, crop_matted, matte8;
    cv::resize(paths.portrait.image_unmatted, crop, cv::Size(size, size), 0, 0, cv::INTER_AREA);
    cv::resize(paths.portrait.image, crop_matted, cv::Size(size, size), 0, 0, cv::INTER_AREA);
    cv::Mat matte;
    cv::resize(paths.portrait.matte, matte, cv::Size(size, size), 0, 0, cv::INTER_AREA);
    matte.convertTo(matte8, CV_8U, 255.0);
    const face::FaceMeasurement crop_face = metrics.Measure(crop);
    const double photo_detail = MeanAbsLaplacian(crop, OutsideFaceMask(Opaque(matte8), crop_face.landmarks));
    AVATAR_CHECK_INPUT(photo_detail > 0.0) << file << ": the photo shows no person outside the face to compare with";

    const std::vector<const FrameSource*> sources = {paths.network.get(), paths.preview.get(), nullptr,
                                                     paths.face.get(), paths.detail.get(), paths.learned.get()};
    if (paths.learned) names[5] = paths.learned->Label();
    names[0] = paths.network->Label();
    names[1] = paths.preview->Label();
    names[2] = "the preview's face pasted over the network render (by the preview's alpha)";
    names[3] = paths.face->Label();
    names[4] = paths.detail->Label();
    nlohmann::json photo_json = {{"photo", file}, {"photo_detail", photo_detail}};
    std::vector<std::vector<cv::Mat>> tiles(keys.size());
    auto render_all = [&](double yaw, const Expression& expression) {
      ViewPose user;
      user.yaw = yaw;
      const FrameRequest request =
          ComposeFrame(paths.network->SourcePose(), user, expression, nullptr, false, size, size);
      std::vector<RenderedFrame> frames(keys.size());
      for (size_t k = 0; k < keys.size(); ++k) {
        if (sources[k] != nullptr) frames[k] = sources[k]->Render(request, ctx);
        ctx.ThrowIfCancelled();
      }
      frames[2] = Paste(frames[0], frames[1]);
      return frames;
    };
    std::vector<RenderedFrame> neutral;  // the source view's frames (rendered once)
    for (size_t y = 0; y < n_yaw; ++y) {
      const std::vector<RenderedFrame> frames = render_all(report.yaws[y], Expression{});
      if (report.yaws[y] == 0.0) neutral = frames;
      for (size_t k = 0; k < keys.size(); ++k) {
        const face::FaceMeasurement m = metrics.Measure(frames[k].bgr);
        nlohmann::json cell = {{"path", keys[k]}, {"yaw", report.yaws[y]}, {"face", m.found}};
        if (m.found) {
          const face::PairFaceMetrics pair = metrics.Compare(m, reference);
          const double ratio =
              MeanAbsLaplacian(frames[k].bgr, OutsideFaceMask(Opaque(frames[k].alpha), m.landmarks)) / photo_detail;
          acc[k].identity[y] += pair.csim;
          acc[k].detail[y] += ratio;
          acc[k].found[y] += 1;
          cell["identity"] = pair.csim;
          cell["outside_detail"] = ratio;
        } else {
          cell["reason"] = m.reason;
        }
        if (report.yaws[y] == 0.0) {
          const double psnr = cv::PSNR(frames[k].bgr, crop_matted);
          acc[k].psnr += psnr;
          acc[k].psnr_count += 1;
          cell["source_psnr"] = psnr;
        }
        photo_json["cells"].push_back(cell);
        if (static_cast<int>(p) < shown) tiles[k].push_back(frames[k].bgr);
      }
      ctx.Report("orbit " + fs::path(file).filename().string(), static_cast<double>(y + 1) / (n_yaw + 2));
    }
    // The mouth: neutral and opened at the source view.
    Expression open;
    open.controls[options.jaw_control] = static_cast<float>(options.jaw_value);
    if (neutral.empty()) neutral = render_all(0.0, Expression{});
    const std::vector<RenderedFrame> opened = render_all(0.0, open);
    for (size_t k = 0; k < keys.size(); ++k) {
      const face::FaceMeasurement a = metrics.Measure(neutral[k].bgr);
      const face::FaceMeasurement b = metrics.Measure(opened[k].bgr);
      if (a.found && b.found) {
        const double d = face::MouthOpening(b.landmarks) - face::MouthOpening(a.landmarks);
        acc[k].mouth += d;
        acc[k].mouth_found += 1;
        photo_json["mouth_opening"][keys[k]] = d;
      }
      if (static_cast<int>(p) < shown) tiles[k].push_back(opened[k].bgr);
    }
    per_photo.push_back(photo_json);
    report.photos.push_back(file);
    if (static_cast<int>(p) < shown) {
      cv::Mat photo_tile;
      cv::resize(crop, photo_tile, cv::Size(size, size), 0, 0, cv::INTER_AREA);
      for (size_t k = 0; k < keys.size(); ++k) {
        std::vector<cv::Mat> row = {k == 0 ? photo_tile : cv::Mat(size, size, CV_8UC3, cv::Scalar::all(40))};
        for (const cv::Mat& t : tiles[k]) row.push_back(t);
        cv::Mat joined;
        cv::hconcat(row, joined);
        cv::putText(joined, keys[k], cv::Point(size + 6, 20), cv::FONT_HERSHEY_SIMPLEX, 0.6, cv::Scalar(255, 255, 255),
                    2);
        sheet_rows.push_back(joined);
      }
    }
  }

  for (size_t k = 0; k < keys.size(); ++k) {
    OrbitPathResult r;
    r.key = keys[k];
    r.name = names[k];
    r.found = acc[k].found;
    for (size_t y = 0; y < n_yaw; ++y) {
      const int n = acc[k].found[y];
      r.identity.push_back(n > 0 ? acc[k].identity[y] / n : std::nan(""));
      r.outside_detail.push_back(n > 0 ? acc[k].detail[y] / n : std::nan(""));
    }
    r.mouth_found = acc[k].mouth_found;
    r.mouth_opening = r.mouth_found > 0 ? acc[k].mouth / r.mouth_found : std::nan("");
    r.source_psnr = acc[k].psnr_count > 0 ? acc[k].psnr / acc[k].psnr_count : std::nan("");
    report.paths.push_back(r);
  }
  report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  // Markdown: one table per measure, paths as rows and yaws as columns.
  std::ostringstream md;
  md << "# Orbit evaluation (" << report.photos.size() << " photos, " << size << " px, yaw relative to each photo)\n\n";
  for (const std::string& f : report.photos) md << "- " << fs::path(f).filename().string() << "\n";
  md << "\nPaths:\n";
  for (const auto& r : report.paths) md << "- " << r.key << ": " << r.name << "\n";
  auto table = [&](const char* title, auto value) {
    md << "\n## " << title << "\n\n| path |";
    for (double y : report.yaws) md << " " << Fixed(y, 0) << " |";
    md << "\n|---|";
    for (size_t y = 0; y < n_yaw; ++y) md << "---|";
    md << "\n";
    for (const auto& r : report.paths) {
      md << "| " << r.key << " |";
      for (size_t y = 0; y < n_yaw; ++y) md << " " << value(r, y) << " |";
      md << "\n";
    }
  };
  table("Identity cosine to the photo (mean; faces found / photos)", [&](const OrbitPathResult& r, size_t y) {
    return Fmt(r.identity[y], 3) + " (" + std::to_string(r.found[y]) + "/" + std::to_string(report.photos.size()) + ")";
  });
  table("Detail outside the face (fraction of the photo's)",
        [&](const OrbitPathResult& r, size_t y) { return Fmt(r.outside_detail[y], 3); });
  md << "\n## Source view and mouth\n\n| path | PSNR vs matted crop (dB) | mouth opening " << options.jaw_control << " "
     << Fixed(options.jaw_value, 2) << " minus neutral (photos) |\n|---|---|---|\n";
  for (const auto& r : report.paths) {
    md << "| " << r.key << " | " << Fmt(r.source_psnr, 2) << " | " << Fmt(r.mouth_opening, 4) << " (" << r.mouth_found
       << ") |\n";
  }
  md << "\nSeconds: " << Fixed(report.seconds, 1) << "\n";
  report.markdown = md.str();

  nlohmann::json j;
  j["size"] = size;
  j["yaws"] = report.yaws;
  j["checkpoint"] = options.checkpoint;
  j["jaw"] = {{"control", options.jaw_control}, {"value", options.jaw_value}};
  j["seconds"] = report.seconds;
  for (const auto& r : report.paths) {
    j["paths"].push_back({{"key", r.key},
                          {"name", r.name},
                          {"identity", r.identity},
                          {"outside_detail", r.outside_detail},
                          {"found", r.found},
                          {"mouth_opening", r.mouth_opening},
                          {"mouth_found", r.mouth_found},
                          {"source_psnr", r.source_psnr}});
  }
  j["per_photo"] = per_photo;

  ctx.ThrowIfCancelled();
  const fs::path out(options.out);
  fs::create_directories(out);
  report.markdown_path = (out / "orbit.md").string();
  report.json_path = (out / "orbit.json").string();
  WriteBytesAtomically(report.markdown_path, report.markdown);
  // NaN (a path that never showed a face) is written as null.
  WriteBytesAtomically(report.json_path, j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
  if (!sheet_rows.empty()) {
    cv::Mat sheet;
    cv::vconcat(sheet_rows, sheet);
    report.contact_path = (out / "orbit.png").string();
    SaveImage(report.contact_path, sheet);
  }
  ctx.Report("done", 1.0);
  return report;
}

}  // namespace avatar
