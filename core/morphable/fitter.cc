#include "core/morphable/fitter.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "core/util/error.h"

namespace avatar::morphable {

namespace {

constexpr int kRightEye[2] = {33, 133};  // subject's right eye corners (outer, inner)
constexpr int kLeftEye[2] = {263, 362};

cv::Matx33d Skew(const cv::Vec3d& v) { return {0, -v[2], v[1], v[2], 0, -v[0], -v[1], v[0], 0}; }

// Rotation matrix of an axis-angle vector.
cv::Matx33d Rodrigues(const cv::Vec3d& w) {
  const double theta = cv::norm(w);
  if (theta < 1e-12) return cv::Matx33d::eye() + Skew(w);
  const cv::Matx33d k = Skew(w * (1.0 / theta));
  return cv::Matx33d::eye() + std::sin(theta) * k + (1.0 - std::cos(theta)) * (k * k);
}

// Pixel camera of an image: square pixels, focal kFocal * width, principal point at the centre.
struct PixelCamera {
  double f = 1.0;
  double cx = 0.0;
  double cy = 0.0;
};

PixelCamera CameraFor(cv::Size size) {
  return {render::kFocal * size.width, render::kPrincipalPoint * size.width, render::kPrincipalPoint * size.height};
}

struct State {
  cv::Matx33d rotation = cv::Matx33d::eye();
  cv::Vec3d translation{0, 0, 1};
  std::vector<double> alpha;
  std::vector<double> beta;
};

// Which parameters move, and the priors that pull them.
struct Problem {
  const MorphableModel* model = nullptr;
  const std::vector<cv::Point3f>* points = nullptr;  // landmarks (pixels)
  PixelCamera cam;
  double iod = 1.0;
  FitOptions options;
  bool solve_pose = true;
  bool solve_alpha = true;
  bool solve_beta = true;
  const std::vector<double>* beta_previous = nullptr;  // temporal prior target (nullable)
};

int NumParams(const Problem& p) {
  return (p.solve_pose ? 6 : 0) + (p.solve_alpha ? p.model->num_identity() : 0) +
         (p.solve_beta ? p.model->num_expression() : 0);
}

std::vector<cv::Vec3d> ModelPoints(const MorphableModel& m, const State& s) {
  const int kid = m.num_identity(), kexp = m.num_expression();
  const auto& mean = m.mean();
  const auto& bid = m.identity_basis();
  const auto& bexp = m.expression_basis();
  std::vector<cv::Vec3d> out(kVertexCount);
  for (int i = 0; i < kVertexCount; ++i) {
    for (int c = 0; c < 3; ++c) {
      const size_t row = static_cast<size_t>(3 * i + c);
      double v = mean[row];
      for (int k = 0; k < kid; ++k) v += bid[row * kid + k] * s.alpha[k];
      for (int k = 0; k < kexp; ++k) v += bexp[row * kexp + k] * s.beta[k];
      out[i][c] = v;
    }
  }
  return out;
}

// Residual vector and (optionally) Jacobian of the problem at `s`.
// Rows: 2 per landmark (u, v), 1 per landmark (relative depth), then priors.
double Evaluate(const Problem& p, const State& s, cv::Mat* jacobian, cv::Mat* residual) {
  const MorphableModel& m = *p.model;
  const int kid = m.num_identity(), kexp = m.num_expression();
  const int n = kVertexCount;
  const int np = NumParams(p);
  const int prior_rows = (p.solve_alpha ? kid : 0) + (p.solve_beta ? kexp * (p.beta_previous ? 2 : 1) : 0);
  const int rows = 3 * n + prior_rows;
  cv::Mat r(rows, 1, CV_64F, cv::Scalar(0));
  cv::Mat j;
  if (jacobian != nullptr) j = cv::Mat(rows, std::max(np, 1), CV_64F, cv::Scalar(0));
  const double inv = 1.0 / (p.options.landmark_sigma * p.iod);
  const double wz = std::sqrt(p.options.depth_weight) * inv;
  const std::vector<cv::Vec3d> model_pts = ModelPoints(m, s);
  std::vector<cv::Vec3d> cam_pts(n);
  double zmean = 0.0, lz_mean = 0.0;
  for (int i = 0; i < n; ++i) {
    cam_pts[i] = s.rotation * model_pts[i] + s.translation;
    zmean += cam_pts[i][2];
    lz_mean += (*p.points)[i].z;
  }
  zmean /= n;
  lz_mean /= n;
  const auto& bid = m.identity_basis();
  const auto& bexp = m.expression_basis();
  const int col_alpha = p.solve_pose ? 6 : 0;
  const int col_beta = col_alpha + (p.solve_alpha ? kid : 0);
  std::vector<double> dxdp(static_cast<size_t>(3) * std::max(np, 1));  // 3 x np for one vertex
  for (int i = 0; i < n; ++i) {
    const cv::Vec3d& x = cam_pts[i];
    const double z = std::max(x[2], 1e-6);
    const cv::Point3f& l = (*p.points)[i];
    r.at<double>(2 * i) = (p.cam.f * x[0] / z + p.cam.cx - l.x) * inv;
    r.at<double>(2 * i + 1) = (p.cam.f * x[1] / z + p.cam.cy - l.y) * inv;
    r.at<double>(2 * n + i) = (p.cam.f * (x[2] - zmean) / zmean - (l.z - lz_mean)) * wz;
    if (jacobian == nullptr) continue;
    // dX/dparams (3 x np)
    std::fill(dxdp.begin(), dxdp.end(), 0.0);
    auto at = [&](int c, int col) -> double& { return dxdp[static_cast<size_t>(c) * np + col]; };
    if (p.solve_pose) {
      const cv::Vec3d rp = x - s.translation;
      const cv::Matx33d sk = Skew(rp);
      for (int c = 0; c < 3; ++c) {
        for (int k = 0; k < 3; ++k) at(c, k) = -sk(c, k);
        at(c, 3 + c) = 1.0;
      }
    }
    auto basis_cols = [&](const std::vector<float>& basis, int kcount, int col0) {
      for (int k = 0; k < kcount; ++k) {
        const cv::Vec3d b(basis[static_cast<size_t>(3 * i) * kcount + k],
                          basis[static_cast<size_t>(3 * i + 1) * kcount + k],
                          basis[static_cast<size_t>(3 * i + 2) * kcount + k]);
        const cv::Vec3d rb = s.rotation * b;
        for (int c = 0; c < 3; ++c) at(c, col0 + k) = rb[c];
      }
    };
    if (p.solve_alpha) basis_cols(bid, kid, col_alpha);
    if (p.solve_beta) basis_cols(bexp, kexp, col_beta);
    const double du[3] = {p.cam.f / z * inv, 0.0, -p.cam.f * x[0] / (z * z) * inv};
    const double dv[3] = {0.0, p.cam.f / z * inv, -p.cam.f * x[1] / (z * z) * inv};
    const double dz = p.cam.f / zmean * wz;
    double* ju = j.ptr<double>(2 * i);
    double* jv = j.ptr<double>(2 * i + 1);
    double* jz = j.ptr<double>(2 * n + i);
    for (int col = 0; col < np; ++col) {
      const double a0 = at(0, col), a1 = at(1, col), a2 = at(2, col);
      ju[col] = du[0] * a0 + du[2] * a2;
      jv[col] = dv[1] * a1 + dv[2] * a2;
      jz[col] = dz * a2;
    }
  }
  if (jacobian != nullptr && np > 0) {
    // The depth residual is relative to the mean depth: remove the mean of its rows.
    cv::Mat zrows = j.rowRange(2 * n, 3 * n);
    cv::Mat mean_row;
    cv::reduce(zrows, mean_row, 0, cv::REDUCE_AVG);
    for (int i = 0; i < n; ++i) zrows.row(i) -= mean_row;
  }
  int row = 3 * n;
  const double sa = std::sqrt(p.options.identity_prior);
  const double sb = std::sqrt(p.options.expression_prior);
  const double st = std::sqrt(p.options.temporal_smoothness);
  if (p.solve_alpha) {
    for (int k = 0; k < kid; ++k, ++row) {
      const double w = sa / m.identity_std()[k];
      r.at<double>(row) = w * s.alpha[k];
      if (jacobian != nullptr) j.at<double>(row, col_alpha + k) = w;
    }
  }
  if (p.solve_beta) {
    for (int k = 0; k < kexp; ++k, ++row) {
      const double w = sb / m.expression_std()[k];
      r.at<double>(row) = w * s.beta[k];
      if (jacobian != nullptr) j.at<double>(row, col_beta + k) = w;
    }
    if (p.beta_previous != nullptr) {
      for (int k = 0; k < kexp; ++k, ++row) {
        const double w = st / m.expression_std()[k];
        r.at<double>(row) = w * (s.beta[k] - (*p.beta_previous)[k]);
        if (jacobian != nullptr) j.at<double>(row, col_beta + k) = w;
      }
    }
  }
  if (jacobian != nullptr) *jacobian = j;
  if (residual != nullptr) *residual = r;
  return r.dot(r);
}

State Apply(const Problem& p, const State& s, const cv::Mat& delta) {
  State out = s;
  int col = 0;
  if (p.solve_pose) {
    const cv::Vec3d w(delta.at<double>(0), delta.at<double>(1), delta.at<double>(2));
    out.rotation = Rodrigues(w) * s.rotation;
    // Rotation increments act about the camera origin, as in the Jacobian.
    out.translation = s.translation + cv::Vec3d(delta.at<double>(3), delta.at<double>(4), delta.at<double>(5));
    col = 6;
  }
  if (p.solve_alpha) {
    for (int k = 0; k < p.model->num_identity(); ++k) out.alpha[k] += delta.at<double>(col++);
  }
  if (p.solve_beta) {
    for (int k = 0; k < p.model->num_expression(); ++k) out.beta[k] += delta.at<double>(col++);
  }
  return out;
}

// Levenberg-Marquardt; returns the iterations used.
int Solve(const Problem& p, State& s, int iterations) {
  const int np = NumParams(p);
  if (np == 0) return 0;
  double mu = 1e-3;
  cv::Mat j, r;
  double cost = Evaluate(p, s, &j, &r);
  int it = 0;
  for (; it < iterations; ++it) {
    cv::Mat a, g;
    cv::mulTransposed(j, a, true);
    g = j.t() * r;
    bool improved = false;
    for (int attempt = 0; attempt < 8 && !improved; ++attempt) {
      cv::Mat damped = a.clone();
      for (int d = 0; d < np; ++d) damped.at<double>(d, d) += mu * (a.at<double>(d, d) + 1e-9);
      cv::Mat delta;
      if (!cv::solve(damped, -g, delta, cv::DECOMP_CHOLESKY)) cv::solve(damped, -g, delta, cv::DECOMP_SVD);
      const State trial = Apply(p, s, delta);
      const double trial_cost = Evaluate(p, trial, nullptr, nullptr);
      if (std::isfinite(trial_cost) && trial_cost < cost) {
        const double gain = (cost - trial_cost) / std::max(cost, 1e-30);
        s = trial;
        cost = trial_cost;
        mu = std::max(mu / 3.0, 1e-9);
        improved = true;
        if (gain < 1e-7) return it + 1;
      } else {
        mu *= 4.0;
      }
    }
    if (!improved) return it + 1;
    Evaluate(p, s, &j, &r);
  }
  return it;
}

// Similarity alignment (Umeyama) of model points onto the landmarks lifted to a y-up, z-towards-
// the-viewer frame; gives the initial rotation, distance and translation.
State InitialPose(const MorphableModel& m, const std::vector<cv::Point3f>& pts, const PixelCamera& cam) {
  const std::vector<cv::Point3f> model = m.Vertices({}, {});
  const int n = kVertexCount;
  cv::Vec3d ms(0, 0, 0), qs(0, 0, 0);
  std::vector<cv::Vec3d> q(n);
  for (int i = 0; i < n; ++i) {
    q[i] = cv::Vec3d(pts[i].x, -pts[i].y, -pts[i].z);
    ms += cv::Vec3d(model[i].x, model[i].y, model[i].z);
    qs += q[i];
  }
  ms /= n;
  qs /= n;
  cv::Matx33d cov = cv::Matx33d::zeros();
  double var = 0.0;
  for (int i = 0; i < n; ++i) {
    const cv::Vec3d a = cv::Vec3d(model[i].x, model[i].y, model[i].z) - ms;
    const cv::Vec3d b = q[i] - qs;
    cov += b * a.t();
    var += a.dot(a);
  }
  cv::Matx33d u, vt;
  cv::Matx31d w;
  cv::SVD::compute(cov, w, u, vt);
  cv::Matx33d d = cv::Matx33d::eye();
  if (cv::determinant(u * vt) < 0) d(2, 2) = -1;
  const cv::Matx33d rw = u * d * vt;
  const double sigma = (w(0) * d(0, 0) + w(1) * d(1, 1) + w(2) * d(2, 2)) / std::max(var, 1e-30);
  AVATAR_CHECK_INPUT(sigma > 1e-9 && std::isfinite(sigma)) << "landmarks are degenerate (all points coincide)";
  State s;
  const cv::Matx33d flip(1, 0, 0, 0, -1, 0, 0, 0, -1);
  s.rotation = flip * rw;
  const double z = cam.f / sigma;
  const cv::Vec3d centre_cam((qs[0] - cam.cx) * z / cam.f, (-qs[1] - cam.cy) * z / cam.f, z);
  s.translation = centre_cam - s.rotation * ms;
  s.alpha.assign(m.num_identity(), 0.0);
  s.beta.assign(m.num_expression(), 0.0);
  return s;
}

void CheckLandmarks(const face::Landmarks& landmarks, cv::Size size) {
  AVATAR_CHECK_INPUT(size.width > 0 && size.height > 0) << "fit: image size must be positive";
  AVATAR_CHECK_INPUT(landmarks.points.size() == static_cast<size_t>(kVertexCount))
      << "fit: expected " << kVertexCount << " facemesh landmarks, got " << landmarks.points.size();
  for (const auto& p : landmarks.points) {
    AVATAR_CHECK_INPUT(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z))
        << "fit: landmarks contain non-finite values";
  }
  const double iod = InterOcularDistance(landmarks.points);
  AVATAR_CHECK_INPUT(iod > 1e-3) << "fit: degenerate landmarks (the eyes coincide)";
}

FitResult Finish(const MorphableModel& m, const Problem& p, const State& s, cv::Size size, int iterations) {
  FitResult out;
  out.alpha.assign(s.alpha.begin(), s.alpha.end());
  out.beta.assign(s.beta.begin(), s.beta.end());
  // Rescale the scene so that the camera centre is at the published radius (the projection
  // is unchanged by a common scale of the scene and the translation).
  const double dist = cv::norm(s.translation);
  const double k = render::kCameraRadius / std::max(dist, 1e-12);
  out.scale = static_cast<float>(k);
  out.rotation = s.rotation;
  out.translation = s.translation * k;
  const cv::Vec3d centre = -(s.rotation.t() * out.translation);
  out.camera = LabelFromPose(s.rotation, centre);
  // Normalised intrinsics of this image (equal to the published ones for square images).
  out.camera[16 + 0] = static_cast<float>(p.cam.f / size.width);
  out.camera[16 + 2] = static_cast<float>(p.cam.cx / size.width);
  out.camera[16 + 4] = static_cast<float>(p.cam.f / size.height);
  out.camera[16 + 5] = static_cast<float>(p.cam.cy / size.height);
  out.image_size = size;
  out.iterations = iterations;
  const std::vector<cv::Vec3d> pts = ModelPoints(m, s);
  out.landmark_error.resize(kVertexCount);
  double sum = 0.0;
  for (int i = 0; i < kVertexCount; ++i) {
    const cv::Vec3d x = s.rotation * pts[i] + s.translation;
    const double u = p.cam.f * x[0] / x[2] + p.cam.cx;
    const double v = p.cam.f * x[1] / x[2] + p.cam.cy;
    const double e = std::hypot(u - (*p.points)[i].x, v - (*p.points)[i].y);
    out.landmark_error[i] = static_cast<float>(e);
    sum += e;
  }
  out.mean_error_px = sum / kVertexCount;
  out.inter_ocular_px = p.iod;
  out.mean_error_iod = out.mean_error_px / p.iod;
  return out;
}

}  // namespace

void FitOptions::Validate() const {
  AVATAR_CHECK_OPTION(std::isfinite(landmark_sigma) && landmark_sigma > 0) << "--landmark-sigma must be > 0";
  AVATAR_CHECK_OPTION(std::isfinite(depth_weight) && depth_weight >= 0) << "--depth-weight must be >= 0";
  AVATAR_CHECK_OPTION(std::isfinite(identity_prior) && identity_prior >= 0) << "--identity-prior must be >= 0";
  AVATAR_CHECK_OPTION(std::isfinite(expression_prior) && expression_prior >= 0) << "--expression-prior must be >= 0";
  AVATAR_CHECK_OPTION(iterations >= 1 && iterations <= 1000) << "--iterations must be in 1..1000";
  AVATAR_CHECK_OPTION(std::isfinite(temporal_smoothness) && temporal_smoothness >= 0)
      << "--temporal-smoothness must be >= 0";
  AVATAR_CHECK_OPTION(sequence_rounds >= 1 && sequence_rounds <= 20) << "--sequence-rounds must be in 1..20";
}

double InterOcularDistance(const std::vector<cv::Point3f>& p) {
  if (p.size() < static_cast<size_t>(kVertexCount)) return 0.0;
  const cv::Point2d r =
      (cv::Point2d(p[kRightEye[0]].x, p[kRightEye[0]].y) + cv::Point2d(p[kRightEye[1]].x, p[kRightEye[1]].y)) * 0.5;
  const cv::Point2d l =
      (cv::Point2d(p[kLeftEye[0]].x, p[kLeftEye[0]].y) + cv::Point2d(p[kLeftEye[1]].x, p[kLeftEye[1]].y)) * 0.5;
  return cv::norm(r - l);
}

std::vector<cv::Point3f> WorldVertices(const MorphableModel& model, const FitResult& fit, const Beta* beta) {
  std::vector<cv::Point3f> v = model.Vertices(fit.alpha, beta != nullptr ? *beta : fit.beta);
  for (auto& p : v) p *= fit.scale;
  return v;
}

FitResult Fit(const MorphableModel& model, const face::Landmarks& landmarks, cv::Size image_size,
              const FitOptions& options) {
  options.Validate();
  CheckLandmarks(landmarks, image_size);
  Problem p;
  p.model = &model;
  p.points = &landmarks.points;
  p.cam = CameraFor(image_size);
  p.iod = InterOcularDistance(landmarks.points);
  p.options = options;
  State s = InitialPose(model, landmarks.points, p.cam);
  // Pose first (robust start), then everything.
  p.solve_alpha = false;
  p.solve_beta = false;
  int used = Solve(p, s, std::max(5, options.iterations / 3));
  p.solve_alpha = options.fit_identity && model.num_identity() > 0;
  p.solve_beta = options.fit_expression && model.num_expression() > 0;
  used += Solve(p, s, options.iterations);
  return Finish(model, p, s, image_size, used);
}

std::vector<FitResult> FitSequence(const MorphableModel& model, const std::vector<face::Landmarks>& frames,
                                   cv::Size image_size, const FitOptions& options, RunContext& ctx) {
  options.Validate();
  AVATAR_CHECK_INPUT(!frames.empty()) << "fit: the clip has no frames with landmarks";
  for (const auto& f : frames) CheckLandmarks(f, image_size);
  const int nframes = static_cast<int>(frames.size());
  const PixelCamera cam = CameraFor(image_size);
  std::vector<State> states(nframes);
  std::vector<Problem> problems(nframes);
  for (int t = 0; t < nframes; ++t) {
    Problem& p = problems[t];
    p.model = &model;
    p.points = &frames[t].points;
    p.cam = cam;
    p.iod = InterOcularDistance(frames[t].points);
    p.options = options;
  }
  const bool fit_alpha = options.fit_identity && model.num_identity() > 0;
  const bool fit_beta = options.fit_expression && model.num_expression() > 0;
  std::vector<double> alpha(model.num_identity(), 0.0);
  const int total_steps = options.sequence_rounds * 2 * nframes + nframes;
  int step = 0;
  auto per_frame_pass = [&](const char* stage) {
    for (int t = 0; t < nframes; ++t) {
      Problem p = problems[t];
      State& s = states[t];
      if (s.alpha.empty()) {
        s = t > 0 ? states[t - 1] : InitialPose(model, frames[t].points, cam);
        if (t > 0) {
          // Re-centre the warm start on this frame's landmarks.
          State init = InitialPose(model, frames[t].points, cam);
          s.rotation = init.rotation;
          s.translation = init.translation;
        }
      }
      s.alpha = alpha;
      p.solve_alpha = false;
      p.solve_beta = false;
      Solve(p, s, 5);
      p.solve_beta = fit_beta;
      std::vector<double> prev;
      if (t > 0 && fit_beta && options.temporal_smoothness > 0) {
        prev = states[t - 1].beta;
        p.beta_previous = &prev;
      }
      Solve(p, s, options.iterations);
      if ((++step) % 16 == 0) ctx.Report(stage, static_cast<double>(step) / total_steps);
    }
  };
  auto identity_pass = [&]() {
    if (!fit_alpha) return;
    const int kid = model.num_identity();
    for (int gn = 0; gn < 3; ++gn) {
      cv::Mat a = cv::Mat::zeros(kid, kid, CV_64F), g = cv::Mat::zeros(kid, 1, CV_64F);
      for (int t = 0; t < nframes; ++t) {
        Problem p = problems[t];
        p.solve_pose = false;
        p.solve_alpha = true;
        p.solve_beta = false;
        p.options.identity_prior = 0.0;  // the prior is added once below, not per frame
        State s = states[t];
        s.alpha = alpha;
        cv::Mat j, r;
        Evaluate(p, s, &j, &r);
        a += j.t() * j;
        g += j.t() * r;
        if ((++step) % 16 == 0 && gn == 0) ctx.Report("fit identity", static_cast<double>(step) / total_steps);
      }
      for (int k = 0; k < kid; ++k) {
        const double w = options.identity_prior / (model.identity_std()[k] * model.identity_std()[k]);
        a.at<double>(k, k) += w + 1e-9;
        g.at<double>(k) += w * alpha[k];
      }
      cv::Mat delta;
      cv::solve(a, -g, delta, cv::DECOMP_CHOLESKY);
      for (int k = 0; k < kid; ++k) alpha[k] += delta.at<double>(k);
    }
  };
  // Start: per-frame fits with free identity on a subset give the initial identity.
  if (fit_alpha) {
    std::vector<double> sum(model.num_identity(), 0.0);
    const int stride = std::max(1, nframes / 16);
    int count = 0;
    for (int t = 0; t < nframes; t += stride) {
      const FitResult f = Fit(model, frames[t], image_size, options);
      for (int k = 0; k < model.num_identity(); ++k) sum[k] += f.alpha[k];
      ++count;
      ctx.ThrowIfCancelled();
    }
    for (int k = 0; k < model.num_identity(); ++k) alpha[k] = sum[k] / count;
  }
  for (int round = 0; round < options.sequence_rounds; ++round) {
    per_frame_pass("fit frames");
    identity_pass();
  }
  per_frame_pass("fit frames");
  ctx.Report("fit frames", 1.0);
  std::vector<FitResult> out;
  out.reserve(nframes);
  for (int t = 0; t < nframes; ++t)
    out.push_back(Finish(model, problems[t], states[t], image_size, options.iterations));
  return out;
}

}  // namespace avatar::morphable
