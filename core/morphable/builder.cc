#include "core/morphable/builder.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>

#include "core/morphable/measures.h"
#include "core/util/error.h"

namespace avatar::morphable {

namespace {

constexpr size_t kCoords = static_cast<size_t>(kVertexCount) * 3;

std::vector<cv::Point3f> CanonicalModelFrame(const Topology& topo) {
  std::vector<cv::Point3f> out;
  for (const auto& p : topo.canonical_cm) out.push_back(p * static_cast<float>(kUnitsPerCm));
  return out;
}

// Weighted similarity (Umeyama) taking `src` onto `dst`; returns the transformed src.
std::vector<cv::Point3f> SimilarityAlign(const std::vector<cv::Point3f>& src, const std::vector<cv::Point3f>& dst,
                                         const std::vector<double>& w) {
  const size_t n = src.size();
  double wsum = 0.0;
  cv::Vec3d ms(0, 0, 0), md(0, 0, 0);
  for (size_t i = 0; i < n; ++i) {
    wsum += w[i];
    ms += w[i] * cv::Vec3d(src[i].x, src[i].y, src[i].z);
    md += w[i] * cv::Vec3d(dst[i].x, dst[i].y, dst[i].z);
  }
  ms /= wsum;
  md /= wsum;
  cv::Matx33d cov = cv::Matx33d::zeros();
  double var = 0.0;
  for (size_t i = 0; i < n; ++i) {
    if (w[i] == 0.0) continue;
    const cv::Vec3d a = cv::Vec3d(src[i].x, src[i].y, src[i].z) - ms;
    const cv::Vec3d b = cv::Vec3d(dst[i].x, dst[i].y, dst[i].z) - md;
    cov += w[i] * (b * a.t());
    var += w[i] * a.dot(a);
  }
  cv::Matx33d u, vt;
  cv::Matx31d sv;
  cv::SVD::compute(cov, sv, u, vt);
  cv::Matx33d d = cv::Matx33d::eye();
  if (cv::determinant(u * vt) < 0) d(2, 2) = -1;
  const cv::Matx33d r = u * d * vt;
  const double s = (sv(0) * d(0, 0) + sv(1) * d(1, 1) + sv(2) * d(2, 2)) / std::max(var, 1e-30);
  AVATAR_CHECK_INPUT(std::isfinite(s) && s > 0) << "alignment: degenerate landmarks";
  std::vector<cv::Point3f> out(n);
  for (size_t i = 0; i < n; ++i) {
    const cv::Vec3d p = s * (r * (cv::Vec3d(src[i].x, src[i].y, src[i].z) - ms)) + md;
    out[i] = cv::Point3f(static_cast<float>(p[0]), static_cast<float>(p[1]), static_cast<float>(p[2]));
  }
  return out;
}

std::vector<double> ProcrustesWeights(const Topology& topo) {
  std::vector<double> w(kVertexCount, 0.0);
  for (const auto& [id, weight] : topo.procrustes) w[id] += weight;
  if (std::accumulate(w.begin(), w.end(), 0.0) <= 0.0) std::fill(w.begin(), w.end(), 1.0);
  return w;
}

std::vector<cv::Point3f> Unflatten(const float* f) {
  std::vector<cv::Point3f> out(kVertexCount);
  for (int i = 0; i < kVertexCount; ++i) out[i] = {f[3 * i], f[3 * i + 1], f[3 * i + 2]};
  return out;
}

double Smoothstep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3 - 2 * t);
}

// Makes a component's sign deterministic: its largest-magnitude entry is positive.
void FixSign(cv::Mat row) {
  double mn, mx;
  cv::minMaxLoc(row, &mn, &mx);
  if (-mn > mx) row *= -1.0;
}

double Quantile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  const double pos = q * (v.size() - 1);
  const size_t i = static_cast<size_t>(pos);
  const size_t j = std::min(i + 1, v.size() - 1);
  return v[i] + (pos - i) * (v[j] - v[i]);
}

}  // namespace

void MorphableBuildOptions::Validate() const {
  AVATAR_CHECK_OPTION(expression_components >= 0 && expression_components <= 200)
      << "--expression-components must be in 0..200";
  AVATAR_CHECK_OPTION(expression_variance > 0.5 && expression_variance < 1.0)
      << "--expression-variance must be in (0.5, 1)";
  AVATAR_CHECK_OPTION(max_identity_components >= 0 && max_identity_components <= 200)
      << "--max-identity-components must be in 0..200";
}

nlohmann::json MorphableBuildReport::ToJson() const {
  nlohmann::json j;
  j["persons"] = persons;
  j["clip_frames"] = clip_frames;
  j["identity_pca_components"] = identity_pca_components;
  j["expression_pca_components"] = expression_pca_components;
  j["expression_cumulative_variance"] = expression_cumulative;
  nlohmann::json rms = nlohmann::json::object();
  for (const auto& [name, v] : alignment_rms) rms[name] = v;
  j["alignment_rms"] = rms;
  j["controls"] = controls;
  return j;
}

std::vector<cv::Point3f> AlignToReference(const face::Landmarks& landmarks, const std::vector<cv::Point3f>& reference,
                                          const Topology& topology, double* rms) {
  AVATAR_CHECK_INPUT(landmarks.points.size() == static_cast<size_t>(kVertexCount))
      << "alignment needs " << kVertexCount << " landmarks, got " << landmarks.points.size();
  std::vector<cv::Point3f> q;
  q.reserve(kVertexCount);
  for (const auto& p : landmarks.points) {
    AVATAR_CHECK_INPUT(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z)) << "non-finite landmarks";
    q.emplace_back(p.x, -p.y, -p.z);
  }
  const std::vector<double> w = ProcrustesWeights(topology);
  std::vector<cv::Point3f> out = SimilarityAlign(q, reference, w);
  if (rms != nullptr) {
    double s = 0.0, ws = 0.0;
    for (int i = 0; i < kVertexCount; ++i) {
      s += w[i] * cv::norm(out[i] - reference[i]) * cv::norm(out[i] - reference[i]);
      ws += w[i];
    }
    *rms = std::sqrt(s / ws);
  }
  return out;
}

MorphableModel BuildMorphableModel(const Topology& topo, const std::vector<BuildSource>& sources,
                                   const MorphableBuildOptions& options, RunContext& ctx,
                                   MorphableBuildReport* report_out) {
  options.Validate();
  MorphableBuildReport report;
  const std::vector<double> weights = ProcrustesWeights(topo);
  // 1. Align every shape; two rounds of generalised Procrustes towards the persons' mean.
  std::vector<cv::Point3f> reference = CanonicalModelFrame(topo);
  std::vector<std::vector<std::vector<cv::Point3f>>> aligned(sources.size());
  std::map<std::string, std::vector<double>> person_sum;  // identity key -> summed flat shape
  std::map<std::string, int> person_count;
  std::vector<std::string> person_order;
  size_t total_shapes = 0;
  for (const auto& s : sources) total_shapes += s.shapes.size();
  AVATAR_CHECK_INPUT(total_shapes > 0) << "build-morphable: no face shapes to build from";
  for (int round = 0; round < 2; ++round) {
    person_sum.clear();
    person_count.clear();
    person_order.clear();
    report.alignment_rms.clear();
    size_t done = 0;
    for (size_t si = 0; si < sources.size(); ++si) {
      const BuildSource& src = sources[si];
      aligned[si].clear();
      double rms_sum = 0.0;
      for (const auto& lm : src.shapes) {
        double rms = 0.0;
        aligned[si].push_back(AlignToReference(lm, reference, topo, &rms));
        rms_sum += rms;
        if ((++done) % 200 == 0)
          ctx.Report("align shapes", 0.3 * (round + static_cast<double>(done) / total_shapes) / 2);
      }
      if (src.shapes.empty()) continue;
      report.alignment_rms.emplace_back(src.name, rms_sum / src.shapes.size());
      // A person's shape is the mean of its sources' means (so a long clip does not outweigh stills).
      std::vector<double> mean(kCoords, 0.0);
      for (const auto& shape : aligned[si]) {
        for (int i = 0; i < kVertexCount; ++i) {
          mean[3 * i] += shape[i].x;
          mean[3 * i + 1] += shape[i].y;
          mean[3 * i + 2] += shape[i].z;
        }
      }
      auto& sum = person_sum[src.identity];
      if (sum.empty()) {
        sum.assign(kCoords, 0.0);
        person_order.push_back(src.identity);
      }
      for (size_t c = 0; c < kCoords; ++c) sum[c] += mean[c] / src.shapes.size();
      person_count[src.identity] += 1;
    }
    // New reference: mean over persons, itself aligned to the canonical frame.
    std::vector<cv::Point3f> mean_shape(kVertexCount, cv::Point3f(0, 0, 0));
    for (const auto& key : person_order) {
      const auto& sum = person_sum[key];
      for (int i = 0; i < kVertexCount; ++i) {
        mean_shape[i] += cv::Point3f(static_cast<float>(sum[3 * i]), static_cast<float>(sum[3 * i + 1]),
                                     static_cast<float>(sum[3 * i + 2])) *
                         static_cast<float>(1.0 / (person_count[key] * person_order.size()));
      }
    }
    if (round == 0) reference = SimilarityAlign(mean_shape, CanonicalModelFrame(topo), weights);
    ctx.ThrowIfCancelled();
  }
  const int persons = static_cast<int>(person_order.size());
  report.persons = persons;
  // 2. Identity: per-person shapes, mean and PCA.
  cv::Mat id_shapes(persons, static_cast<int>(kCoords), CV_64F);
  for (int p = 0; p < persons; ++p) {
    const auto& sum = person_sum[person_order[p]];
    for (size_t c = 0; c < kCoords; ++c)
      id_shapes.at<double>(p, static_cast<int>(c)) = sum[c] / person_count[person_order[p]];
  }
  cv::Mat mean_row;
  cv::reduce(id_shapes, mean_row, 0, cv::REDUCE_AVG);
  std::vector<float> mean(kCoords);
  for (size_t c = 0; c < kCoords; ++c) mean[c] = static_cast<float>(mean_row.at<double>(0, static_cast<int>(c)));
  std::vector<std::vector<float>> id_cols;
  std::vector<float> id_std;
  if (persons >= 2 && options.max_identity_components > 0) {
    cv::Mat centred = id_shapes - cv::repeat(mean_row, persons, 1);
    cv::SVD svd(centred, cv::SVD::MODIFY_A);
    const int k = std::min({options.max_identity_components, persons - 1, svd.vt.rows});
    for (int c = 0; c < k; ++c) {
      const double sv = svd.w.at<double>(c);
      if (sv <= 1e-9 * svd.w.at<double>(0)) break;
      cv::Mat row = svd.vt.row(c).clone();
      FixSign(row);
      std::vector<float> col(kCoords);
      for (size_t i = 0; i < kCoords; ++i) col[i] = static_cast<float>(row.at<double>(0, static_cast<int>(i)));
      id_cols.push_back(col);
      id_std.push_back(static_cast<float>(sv / std::sqrt(persons - 1.0)));
    }
  }
  report.identity_pca_components = static_cast<int>(id_cols.size());
  const std::vector<cv::Point3f> mean_pts = Unflatten(mean.data());
  if (options.smooth_deformations) {
    // Face centre, landmarks of the regions, and cm in model units.
    cv::Point3f c(0, 0, 0);
    for (const auto& p : mean_pts) c += p * (1.0f / kVertexCount);
    const double cm = kUnitsPerCm;
    const double mouth_y = (mean_pts[13].y + mean_pts[14].y) * 0.5;
    const double chin_y = mean_pts[152].y;
    const cv::Point3f nose = mean_pts[4];
    const cv::Point3f eye_r = (mean_pts[33] + mean_pts[133]) * 0.5f;
    const cv::Point3f eye_l = (mean_pts[263] + mean_pts[362]) * 0.5f;
    // Each deformation: displacement field d (model units per unit "amount") and the amount of one std.
    auto add = [&](const std::function<cv::Vec3d(const cv::Point3f&)>& field, double std_amount) {
      std::vector<float> col(kCoords);
      double norm = 0.0;
      for (int i = 0; i < kVertexCount; ++i) {
        const cv::Vec3d d = field(mean_pts[i]);
        for (int k = 0; k < 3; ++k) {
          col[3 * i + k] = static_cast<float>(d[k]);
          norm += d[k] * d[k];
        }
      }
      norm = std::sqrt(norm);
      for (float& v : col) v = static_cast<float>(v / norm);
      id_cols.push_back(col);
      id_std.push_back(static_cast<float>(std_amount * norm));
    };
    // Face width: x stretched about the centre; 1 std = 4%.
    add([&](const cv::Point3f& p) { return cv::Vec3d(p.x - c.x, 0, 0); }, 0.04);
    // Face length: y stretched about the centre; 1 std = 4%.
    add([&](const cv::Point3f& p) { return cv::Vec3d(0, p.y - c.y, 0); }, 0.04);
    // Jaw width: x stretched below the mouth, fading in from the mouth to the chin; 1 std = 6%.
    add([&](const cv::Point3f& p) { return cv::Vec3d((p.x - c.x) * Smoothstep(mouth_y, chin_y, p.y), 0, 0); }, 0.06);
    // Nose: the nose region (Gaussian, radius 1.5 cm) pushed forward; 1 std = 0.35 cm at the tip.
    add(
        [&](const cv::Point3f& p) {
          const double r2 = cv::norm(p - nose) * cv::norm(p - nose) / (1.5 * cm * 1.5 * cm);
          return cv::Vec3d(0, 0, std::exp(-0.5 * r2));
        },
        0.35 * cm);
    // Eye spacing: each eye region (Gaussian, radius 1.5 cm) moved outwards; 1 std = 0.25 cm per eye.
    add(
        [&](const cv::Point3f& p) {
          const double rr = cv::norm(p - eye_r) * cv::norm(p - eye_r) / (1.5 * cm * 1.5 * cm);
          const double rl = cv::norm(p - eye_l) * cv::norm(p - eye_l) / (1.5 * cm * 1.5 * cm);
          return cv::Vec3d(std::exp(-0.5 * rl) - std::exp(-0.5 * rr), 0, 0);
        },
        0.25 * cm);
  }
  ctx.Report("identity basis", 0.4);
  // 3. Expression: frames minus their clip's mean.
  std::vector<const BuildSource*> clips;
  int frames = 0;
  for (const auto& s : sources) {
    if (s.is_clip && s.shapes.size() >= 2) frames += static_cast<int>(s.shapes.size());
  }
  AVATAR_CHECK_INPUT(frames >= 8) << "build-morphable: the expression basis needs clip frames (got " << frames << ")";
  report.clip_frames = frames;
  cv::Mat disp(frames, static_cast<int>(kCoords), CV_64F);
  std::vector<ExpressionMeasures> measures;
  measures.reserve(frames);
  int row = 0;
  for (size_t si = 0; si < sources.size(); ++si) {
    const BuildSource& s = sources[si];
    if (!s.is_clip || s.shapes.size() < 2) continue;
    std::vector<double> clip_mean(kCoords, 0.0);
    for (const auto& shape : aligned[si]) {
      for (int i = 0; i < kVertexCount; ++i) {
        clip_mean[3 * i] += shape[i].x / aligned[si].size();
        clip_mean[3 * i + 1] += shape[i].y / aligned[si].size();
        clip_mean[3 * i + 2] += shape[i].z / aligned[si].size();
      }
    }
    for (const auto& shape : aligned[si]) {
      double* r = disp.ptr<double>(row++);
      for (int i = 0; i < kVertexCount; ++i) {
        r[3 * i] = shape[i].x - clip_mean[3 * i];
        r[3 * i + 1] = shape[i].y - clip_mean[3 * i + 1];
        r[3 * i + 2] = shape[i].z - clip_mean[3 * i + 2];
      }
      measures.push_back(MeasureShape(shape));
    }
  }
  cv::Mat cov;
  cv::mulTransposed(disp, cov, true);  // [1404,1404]
  cov /= std::max(frames - 1, 1);
  ctx.Report("expression PCA", 0.5);
  cv::Mat evals, evecs;
  cv::eigen(cov, evals, evecs);  // descending
  ctx.ThrowIfCancelled();
  const double total = std::max(cv::sum(evals)[0], 1e-30);
  double cum = 0.0;
  report.expression_cumulative.clear();
  for (int k = 0; k < std::min(64, evals.rows); ++k) {
    cum += std::max(evals.at<double>(k), 0.0);
    report.expression_cumulative.push_back(cum / total);
  }
  int kexp = options.expression_components;
  if (kexp == 0) {
    kexp = 24;
    while (kexp < 64 && kexp < static_cast<int>(report.expression_cumulative.size()) &&
           report.expression_cumulative[kexp - 1] < options.expression_variance) {
      ++kexp;
    }
  }
  kexp = std::min({kexp, evals.rows, frames - 1});
  while (kexp > 1 && evals.at<double>(kexp - 1) <= 1e-12 * evals.at<double>(0)) --kexp;
  report.expression_pca_components = kexp;
  std::vector<std::vector<float>> exp_cols;
  std::vector<float> exp_std;
  cv::Mat pca_basis(kexp, static_cast<int>(kCoords), CV_64F);
  for (int k = 0; k < kexp; ++k) {
    cv::Mat r = evecs.row(k).clone();
    FixSign(r);
    r.copyTo(pca_basis.row(k));
    std::vector<float> col(kCoords);
    for (size_t i = 0; i < kCoords; ++i) col[i] = static_cast<float>(r.at<double>(0, static_cast<int>(i)));
    exp_cols.push_back(col);
    exp_std.push_back(static_cast<float>(std::sqrt(std::max(evals.at<double>(k), 1e-18))));
  }
  // Measured quantities of the clip frames (regressors of the controls).
  struct Regressor {
    const char* name;
    double ExpressionMeasures::*field;
  };
  const std::vector<Regressor> regs = {{"lip_gap", &ExpressionMeasures::lip_gap},
                                       {"corner_lift", &ExpressionMeasures::corner_lift},
                                       {"mouth_width", &ExpressionMeasures::mouth_width},
                                       {"brow_height", &ExpressionMeasures::brow_height},
                                       {"brow_inner_gap", &ExpressionMeasures::brow_inner_gap},
                                       {"eye_open", nullptr},
                                       {"lip_protrusion", &ExpressionMeasures::lip_protrusion}};
  enum { kLipGap, kCornerLift, kMouthWidth, kBrowHeight, kBrowInner, kEyeOpen, kLipProtrusion, kRegs };
  auto value_of = [&](const ExpressionMeasures& em, int j) {
    return regs[j].field != nullptr ? em.*regs[j].field : 0.5 * (em.eye_open_left + em.eye_open_right);
  };
  std::vector<std::vector<double>> columns(kRegs, std::vector<double>(frames));
  for (int t = 0; t < frames; ++t) {
    for (int j = 0; j < kRegs; ++j) columns[j][t] = value_of(measures[t], j);
  }
  std::vector<double> up(kRegs), down(kRegs);
  nlohmann::json control_info = nlohmann::json::object();
  for (int j = 0; j < kRegs; ++j) {
    up[j] = Quantile(columns[j], 0.98) - Quantile(columns[j], 0.5);
    down[j] = Quantile(columns[j], 0.5) - Quantile(columns[j], 0.02);
    control_info["measures"][regs[j].name] = {
        {"median", Quantile(columns[j], 0.5)}, {"median_to_p98", up[j]}, {"p2_to_median", down[j]}};
  }
  // Jacobian of the measures with respect to the PCA coefficients at the mean shape.
  cv::Mat g(kRegs, kexp, CV_64F);
  {
    ExpressionMeasures m0 = MeasureShape(mean_pts);
    for (int k = 0; k < kexp; ++k) {
      const double eps = 0.05 * exp_std[k];
      std::vector<cv::Point3f> shape = mean_pts;
      for (int i = 0; i < kVertexCount; ++i) {
        shape[i] +=
            cv::Point3f(exp_cols[k][3 * i], exp_cols[k][3 * i + 1], exp_cols[k][3 * i + 2]) * static_cast<float>(eps);
      }
      const ExpressionMeasures m1 = MeasureShape(shape);
      for (int j = 0; j < kRegs; ++j) g.at<double>(j, k) = (value_of(m1, j) - value_of(m0, j)) / eps;
    }
  }
  // A control is the most probable expression change under the clips' statistics (minimum
  // sum (beta_k / std_k)^2) that moves the chosen measures by the chosen amounts and leaves the
  // listed measures unchanged: beta = S G^T (G S G^T)^-1 delta, S = diag(std^2).
  struct Target {
    int measure;
    double amount;
  };
  auto solve_control = [&](const std::vector<Target>& targets, const std::vector<int>& hold) {
    const int rows = static_cast<int>(targets.size() + hold.size());
    cv::Mat gc(rows, kexp, CV_64F), delta(rows, 1, CV_64F);
    int r = 0;
    for (const auto& t : targets) {
      g.row(t.measure).copyTo(gc.row(r));
      delta.at<double>(r++) = t.amount;
    }
    for (int h : hold) {
      g.row(h).copyTo(gc.row(r));
      delta.at<double>(r++) = 0.0;
    }
    cv::Mat sdiag(kexp, kexp, CV_64F, cv::Scalar(0));
    for (int k = 0; k < kexp; ++k) sdiag.at<double>(k, k) = static_cast<double>(exp_std[k]) * exp_std[k];
    cv::Mat gsg = gc * sdiag * gc.t();
    cv::Mat lambda;
    cv::solve(gsg, delta, lambda, cv::DECOMP_SVD);
    cv::Mat beta = sdiag * gc.t() * lambda;
    Beta out(kexp + 2, 0.0f);
    for (int k = 0; k < kexp; ++k) out[k] = static_cast<float>(beta.at<double>(k));
    return out;
  };
  // 4. One-sided eye closing: regress the displacement on the mean eyelid distance, then split by side.
  {
    cv::Mat e(frames, 1, CV_64F);
    const double emean = std::accumulate(columns[kEyeOpen].begin(), columns[kEyeOpen].end(), 0.0) / frames;
    for (int t = 0; t < frames; ++t) e.at<double>(t) = columns[kEyeOpen][t] - emean;
    const double ee = std::max(e.dot(e), 1e-30);
    cv::Mat v = (e.t() * disp) / ee;  // [1,1404] displacement per unit of eye openness
    // A full blink closes the median eyelid distance.
    const double closing = Quantile(columns[kEyeOpen], 0.5);
    // The eyelid region of each eye: a Gaussian of radius 1.6 cm around the eye centre.
    const cv::Point3f eye_centre[2] = {(mean_pts[263] + mean_pts[362]) * 0.5f, (mean_pts[33] + mean_pts[133]) * 0.5f};
    const double radius = 1.6 * kUnitsPerCm;
    for (int side = 0; side < 2; ++side) {  // 0: subject's left (x > 0), 1: right
      std::vector<float> col(kCoords);
      double norm = 0.0;
      for (int i = 0; i < kVertexCount; ++i) {
        const double r = cv::norm(mean_pts[i] - eye_centre[side]) / radius;
        const double w = std::exp(-0.5 * r * r);
        for (int k = 0; k < 3; ++k) {
          const double d = -w * v.at<double>(0, 3 * i + k);  // closing = minus opening
          col[3 * i + k] = static_cast<float>(d);
          norm += d * d;
        }
      }
      norm = std::sqrt(std::max(norm, 1e-30));
      for (float& x : col) x = static_cast<float>(x / norm);
      // Calibrate on the mean face: the coefficient that brings its eyelids together (the
      // regression slope alone is attenuated by landmark noise in the eyelid distance).
      const auto open_of = [&](const std::vector<cv::Point3f>& shape) {
        const ExpressionMeasures em = MeasureShape(shape);
        return side == 0 ? em.eye_open_left : em.eye_open_right;
      };
      const double eps = 1e-3;
      std::vector<cv::Point3f> moved = mean_pts;
      for (int i = 0; i < kVertexCount; ++i) {
        moved[i] += cv::Point3f(col[3 * i], col[3 * i + 1], col[3 * i + 2]) * static_cast<float>(eps);
      }
      const double open0 = open_of(mean_pts);
      const double slope = (open_of(moved) - open0) / eps;
      const double full = slope < 0 ? -open0 / slope : closing * norm;
      exp_cols.push_back(col);
      // One std = half of a full closing, so that a blink is 2 std.
      exp_std.push_back(static_cast<float>(0.5 * full));
    }
    control_info["blink_closing_amount"] = closing;
  }
  const int kexp_total = kexp + 2;
  // 5. Named controls.
  const std::vector<int> eyes_brows = {kBrowHeight, kBrowInner, kEyeOpen};
  const std::vector<int> mouth = {kLipGap, kCornerLift, kMouthWidth, kLipProtrusion};
  auto concat = [](std::vector<int> a, const std::vector<int>& b) {
    a.insert(a.end(), b.begin(), b.end());
    return a;
  };
  std::vector<NamedControl> controls;
  auto add = [&](const char* name, const char* label, const std::vector<Target>& targets, const std::vector<int>& hold,
                 const std::string& how) {
    controls.push_back({name, label, how, solve_control(targets, hold)});
    control_info[name] = how;
  };
  add("jawOpen", "Jaw open", {{kLipGap, up[kLipGap]}}, eyes_brows,
      "inner-lip gap +(median to 98th percentile of the clips); brows and eyelids held");
  add("smile", "Smile", {{kCornerLift, up[kCornerLift]}, {kMouthWidth, 0.5 * up[kMouthWidth]}},
      concat({kLipGap}, eyes_brows),
      "mouth corners lifted (median to 98th pct) and mouth widened by half its 98th-pct step; lips closed, brows and "
      "eyelids held");
  add("frown", "Frown", {{kCornerLift, -down[kCornerLift]}}, concat({kLipGap, kMouthWidth}, eyes_brows),
      "mouth corners lowered (median to 2nd pct); lip gap, width, brows and eyelids held");
  add("pucker", "Pucker", {{kMouthWidth, -down[kMouthWidth]}, {kLipProtrusion, up[kLipProtrusion]}},
      concat({kLipGap}, eyes_brows),
      "mouth narrowed (median to 2nd pct) and lips pushed forward (median to 98th pct); lip gap, brows and eyelids "
      "held");
  add("mouthWide", "Mouth wide", {{kMouthWidth, up[kMouthWidth]}}, concat({kLipGap, kCornerLift}, eyes_brows),
      "mouth widened (median to 98th pct); lip gap, corner height, brows and eyelids held");
  add("browRaise", "Brows up", {{kBrowHeight, up[kBrowHeight]}}, concat({kEyeOpen}, mouth),
      "brows raised above the eyelids (median to 98th pct); eyelids and mouth held");
  add("browFrown", "Brows frown", {{kBrowHeight, -down[kBrowHeight]}, {kBrowInner, -down[kBrowInner]}},
      concat({kEyeOpen}, mouth),
      "brows lowered and inner brow ends drawn together (median to 2nd pct); eyelids and mouth held");
  {
    Beta l(kexp_total, 0.0f), r(kexp_total, 0.0f);
    l[kexp] = 2.0f * exp_std[kexp];
    r[kexp + 1] = 2.0f * exp_std[kexp + 1];
    const std::string how =
        "one-sided component: regression of the frames' displacement on the eyelid distance, "
        "restricted to a 1.6 cm Gaussian around the eye; 1.0 brings the mean face's eyelids together";
    controls.push_back({"blinkLeft", "Blink left", "subject's left eye; " + how, l});
    controls.push_back({"blinkRight", "Blink right", "subject's right eye; " + how, r});
    control_info["blinkLeft"] = controls[controls.size() - 2].description;
    control_info["blinkRight"] = controls.back().description;
  }
  add("eyesWide", "Eyes wide", {{kEyeOpen, up[kEyeOpen]}}, concat({kBrowHeight, kBrowInner}, mouth),
      "eyelids opened (median to 98th pct); brows and mouth held");
  report.controls = control_info;
  std::vector<float> id_basis(kCoords * id_cols.size()), exp_basis(kCoords * exp_cols.size());
  for (size_t r = 0; r < kCoords; ++r) {
    for (size_t k = 0; k < id_cols.size(); ++k) id_basis[r * id_cols.size() + k] = id_cols[k][r];
    for (size_t k = 0; k < exp_cols.size(); ++k) exp_basis[r * exp_cols.size() + k] = exp_cols[k][r];
  }
  MorphableModel model(topo, mean, id_basis, id_std, exp_basis, exp_std);
  model.SetControls(controls);
  model.set_build_info_json(report.ToJson().dump());
  ctx.Report("done", 1.0);
  if (report_out != nullptr) *report_out = report;
  return model;
}

}  // namespace avatar::morphable
