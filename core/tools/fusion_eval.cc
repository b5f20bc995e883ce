#include "core/tools/fusion_eval.h"

#include <chrono>
#include <cmath>
#include <iomanip>
#include <map>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "core/io/image_io.h"
#include "core/model/fusion_net.h"
#include "core/pipeline/fusion_input.h"
#include "core/train/fusion_training.h"
#include "core/train/metrics.h"
#include "core/tools/face_metrics.h"
#include "core/train/perceptual.h"
#include "core/util/error.h"
#include "core/util/progress_line.h"

namespace avatar {
namespace {

const char* kFusionBuckets[] = {"0-10", "10-20", "20-35", "35+"};

const char* FusionBucketOf(double d_yaw) {
  const double a = std::abs(d_yaw);
  if (a < 10) return kFusionBuckets[0];
  if (a < 20) return kFusionBuckets[1];
  if (a < 35) return kFusionBuckets[2];
  return kFusionBuckets[3];
}

struct FusionSums {
  int64_t n = 0;
  double psnr = 0, ssim = 0, l1 = 0, perceptual = 0;
  int64_t face_n = 0;
  double csim = 0, aed = 0;
};

}  // namespace

void FusionEvalOptions::Validate() const {
  AVATAR_CHECK_OPTION(!data.empty()) << "--data must name a fusion set folder";
  AVATAR_CHECK_OPTION(split == "val" || split == "train") << "--split must be val or train";
  AVATAR_CHECK_OPTION(sheet_rows >= 1 && sheet_rows <= 64) << "--sheet-rows must be within 1..64";
}

FusionEvalReport EvaluateFusionSet(const FusionEvalOptions& options, RunContext& ctx) {
  options.Validate();
  const train::FusionSamples s = train::LoadFusionSplit(options.data, options.split);
  AVATAR_CHECK_INPUT(s.size() > 0) << options.data << ": the " << options.split << " split has no frames";
  FusionEvalReport report;
  report.samples = s.size();
  FusionNet net{nullptr};
  if (!options.weights.empty()) {
    FusionNetInfo info;
    net = LoadFusionNet(options.weights, &info);
    report.weights_info = "step " + std::to_string(info.step) + ", fusion:" + info.fingerprint;
  }
  PerceptualOptions po;
  po.data_dir = options.data_dir;
  const PerceptualLoss perceptual(po);
  std::unique_ptr<face::FaceMetrics> face_metrics;
  if (options.face_metrics) {
    face::FaceMetricsOptions fo;
    fo.data_dir = options.data_dir;
    face_metrics = std::make_unique<face::FaceMetrics>(fo);
  }
  std::vector<std::string> paths = {"network (bicubic)", "morphable preview", "geometric composite"};
  if (net) paths.push_back("learned fusion");
  const char* regions[] = {"frame", "valid warp", "outside warp"};
  // kind|bucket|region|path -> sums
  std::map<std::string, FusionSums> sums;
  std::vector<cv::Mat> sheet_rows;
  const int64_t sheet_every = std::max<int64_t>(1, s.size() / options.sheet_rows);
  torch::NoGradGuard no_grad;
  ProgressLine progress = ProgressLine::ForStderr();
  const auto start = std::chrono::steady_clock::now();
  for (int64_t i = 0; i < s.size(); i += 4) {
    ctx.ThrowIfCancelled();
    const int64_t m = std::min<int64_t>(4, s.size() - i);
    const torch::Tensor x = FusionInputFromBytes(s.input.narrow(0, i, m));
    const torch::Tensor target = FusionInputFromBytes(s.target.narrow(0, i, m), 3);
    std::vector<torch::Tensor> outs = {x.slice(1, 3, 6), FusionInputFromBytes(s.preview.narrow(0, i, m), 3),
                                       x.slice(1, 0, 3)};
    if (net) outs.push_back(net->forward(x, s.Turn().narrow(0, i, m)).clamp(-1.0, 1.0));
    const torch::Tensor valid = (torch::max(x.slice(1, 6, 7), x.slice(1, 7, 8)) > 0.5).to(torch::kFloat32);
    const torch::Tensor masks[] = {torch::Tensor(), valid, 1.0 - valid};
    // Features once per image; each region is a mask over the same feature distance maps.
    const std::vector<torch::Tensor> target_features = perceptual.Features(target);
    auto kind_of = [&](int64_t b) {
      const float k = s.meta[i + b][3].item<float>();
      return std::string(k > 1.5f ? "synthetic" : (k > 0.5f ? "clip" : "photo"));
    };
    std::vector<face::FaceMeasurement> target_faces(m);
    if (face_metrics)
      for (int64_t b = 0; b < m; ++b)
        target_faces[b] = face_metrics->Measure(BgrFromRgb(target[b]));
    for (size_t p = 0; p < outs.size(); ++p) {
      const std::vector<torch::Tensor> features = perceptual.Features(outs[p]);
      auto distance = [&](const torch::Tensor&, const torch::Tensor&, const torch::Tensor& mask) {
        return perceptual.FeatureDistance(features, target_features, mask);
      };
      for (int r = 0; r < 3; ++r) {
        const train::ImageMetrics im = train::ComputeImageMetrics(outs[p], target, masks[r], distance);
        for (int64_t b = 0; b < m; ++b) {
          const torch::Tensor meta = s.meta[i + b];
          if (r > 0 && masks[r][b].sum().item<double>() < 16.0) continue;  // region absent in this frame
          const std::string kind = kind_of(b);
          face::PairFaceMetrics face_pair;
          if (face_metrics && r == 0)
            face_pair = face_metrics->Compare(face_metrics->Measure(BgrFromRgb(outs[p][b])), target_faces[b]);
          for (const std::string& bucket : {std::string(FusionBucketOf(meta[0].item<float>())), std::string("all")}) {
            FusionSums& sum = sums[kind + "|" + bucket + "|" + regions[r] + "|" + paths[p]];
            const double psnr = im.psnr[b].item<double>();
            ++sum.n;
            sum.psnr += std::isfinite(psnr) ? psnr : 100.0;
            sum.ssim += im.ssim[b].item<double>();
            sum.l1 += im.l1[b].item<double>();
            sum.perceptual += im.perceptual[b].item<double>();
            if (face_pair.valid()) {
              ++sum.face_n;
              sum.csim += face_pair.csim;
              sum.aed += face_pair.aed;
            }
          }
        }
      }
    }
    if (!options.sheet.empty()) {
      for (int64_t b = 0; b < m; ++b) {
        if ((i + b) % sheet_every != 0 || static_cast<int>(sheet_rows.size()) >= options.sheet_rows) continue;
        std::vector<cv::Mat> tiles;
        for (const auto& o : outs) tiles.push_back(BgrFromRgb(o[b]));
        tiles.push_back(BgrFromRgb(target[b]));
        cv::Mat row;
        cv::hconcat(tiles, row);
        sheet_rows.push_back(row);
      }
    }
    ctx.Report("fusion eval", static_cast<double>(i + m) / static_cast<double>(s.size()));
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::ostringstream line;
    line << "fusion eval: " << (i + m) << "/" << s.size() << " frames, " << static_cast<int64_t>(seconds) << " s, ETA "
         << static_cast<int64_t>(seconds / static_cast<double>(i + m) * static_cast<double>(s.size() - i - m)) << " s";
    progress.Update(line.str());
  }
  progress.Finish();
  for (const std::string kind : {"clip", "synthetic", "photo"}) {
    for (const char* region : regions) {
      for (const std::string bucket : {"0-10", "10-20", "20-35", "35+", "all"}) {
        for (const auto& path : paths) {
          const auto it = sums.find(kind + "|" + bucket + "|" + region + "|" + path);
          if (it == sums.end() || it->second.n == 0) continue;
          const FusionSums& t = it->second;
          FusionEvalRow row{kind, bucket, region, path, t.n, t.psnr / t.n, t.ssim / t.n, t.l1 / t.n,
                            t.perceptual / t.n};
          row.face_pairs = t.face_n;
          if (t.face_n > 0) {
            row.csim = t.csim / t.face_n;
            row.aed = t.aed / t.face_n;
          }
          report.rows.push_back(row);
        }
      }
    }
  }
  if (!options.sheet.empty() && !sheet_rows.empty()) {
    cv::Mat sheet;
    cv::vconcat(sheet_rows, sheet);
    SaveImage(options.sheet, sheet);
  }
  return report;
}

std::string FusionEvalMarkdown(const FusionEvalReport& report) {
  std::ostringstream out;
  out << std::fixed;
  std::string section;
  bool faces = false;
  for (const auto& r : report.rows) {
    const std::string s = r.kind + " pairs, " + r.region;
    if (s != section) {
      section = s;
      faces = false;
      for (const auto& o : report.rows) faces = faces || (o.kind + " pairs, " + o.region == s && o.face_pairs > 0);
      out << "\n### " << s << "\n\n| yaw bucket | path | pairs | PSNR | SSIM | L1 | perceptual |"
          << (faces ? " faces | CSIM | AED |\n|---|---|---|---|---|---|---|---|---|---|\n" : "\n|---|---|---|---|---|---|---|\n");
    }
    out << "| " << r.bucket << " | " << r.path << " | " << r.pairs << " | " << std::setprecision(2) << r.psnr << " | "
        << std::setprecision(3) << r.ssim << " | " << r.l1 << " | " << r.perceptual << " |";
    if (faces) out << " " << r.face_pairs << " | " << r.csim << " | " << std::setprecision(4) << r.aed << " |";
    out << "\n";
  }
  return out.str();
}

}  // namespace avatar
