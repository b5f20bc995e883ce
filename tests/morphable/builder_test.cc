#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "core/util/error.h"
#include "morphable_test_util.h"

namespace avatar::morphable {
namespace {

using testing::InstalledTopology;
using testing::OrbitLabel;
using testing::ProjectLandmarks;
using testing::SyntheticModel;

// Synthetic persons and clips from a known model, seen through random cameras.
std::vector<BuildSource> SyntheticSources(const MorphableModel& truth, int persons, int clips, int frames,
                                          std::mt19937& rng, double noise_px = 0.2, double yaw = 25.0) {
  std::normal_distribution<double> n(0.0, 1.0);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<BuildSource> sources;
  for (int p = 0; p < persons; ++p) {
    Alpha a(truth.num_identity());
    for (int k = 0; k < truth.num_identity(); ++k) a[k] = static_cast<float>(n(rng) * truth.identity_std()[k]);
    BuildSource s;
    s.name = "person" + std::to_string(p);
    s.identity = s.name;
    s.is_clip = p < clips;
    const int count = s.is_clip ? frames : 1;
    for (int t = 0; t < count; ++t) {
      Beta b(truth.num_expression(), 0.0f);
      if (s.is_clip) {
        for (int k = 0; k < truth.num_expression(); ++k) b[k] = static_cast<float>(n(rng) * truth.expression_std()[k]);
      }
      std::vector<cv::Point3f> w = truth.Vertices(a, b);
      const float scale = static_cast<float>(1.0 + 0.1 * u(rng));
      for (auto& q : w) q *= scale;
      s.shapes.push_back(ProjectLandmarks(w, OrbitLabel(yaw * u(rng), 0.4 * yaw * u(rng), 0.2 * yaw * u(rng)),
                                          cv::Size(512, 512), noise_px, rng));
    }
    sources.push_back(s);
  }
  return sources;
}

TEST(Builder, RecoversTheExpressionSubspaceAndExplainsItsVariance) {
  const Topology& topo = InstalledTopology();
  const MorphableModel truth = SyntheticModel(topo, 4, 6, 21);
  std::mt19937 rng(4);
  const auto sources = SyntheticSources(truth, 10, 3, 80, rng, 0.02, 5.0);
  MorphableBuildOptions opts;
  opts.expression_components = 6;
  RunContext ctx;
  MorphableBuildReport report;
  const MorphableModel built = BuildMorphableModel(topo, sources, opts, ctx, &report);
  EXPECT_EQ(report.persons, 10);
  EXPECT_EQ(report.clip_frames, 240);
  EXPECT_EQ(built.num_expression(), 6 + 2);  // PCA + two one-sided blink components
  EXPECT_EQ(built.num_identity(), 9 + 5);    // persons - 1 + smooth deformations
  ASSERT_GE(report.expression_cumulative.size(), 6u);
  // Perspective and pixel noise leave a little outside the true 6-d space.
  EXPECT_GT(report.expression_cumulative[5], 0.97);
  // Each true expression direction (after the same similarity normalisation, approximately
  // itself for small displacements) lies in the learned PCA span.
  const int k = 6;
  const auto& b = built.expression_basis();
  const int kt = built.num_expression();
  double captured = 0.0;
  for (int c = 0; c < truth.num_expression(); ++c) {
    std::vector<double> v(468 * 3);
    for (int r = 0; r < 468 * 3; ++r) v[r] = truth.expression_basis()[r * truth.num_expression() + c];
    // The alignment removes the infinitesimal similarity part (translation, rotation, scale fitted
    // on the Procrustes points); take it out of the true direction too.
    const auto mean = built.Vertices({}, {});
    cv::Mat a = cv::Mat::zeros(7, 7, CV_64F), rhs = cv::Mat::zeros(7, 1, CV_64F);
    auto tangent = [&](int i, int d, int j) {  // d-th coordinate of similarity generator j at vertex i
      const cv::Vec3d p(mean[i].x, mean[i].y, mean[i].z);
      if (j < 3) return d == j ? 1.0 : 0.0;
      if (j == 6) return p[d];
      cv::Vec3d w(0, 0, 0);
      w[j - 3] = 1.0;
      return w.cross(p)[d];
    };
    for (const auto& [id, weight] : topo.procrustes) {
      for (int d = 0; d < 3; ++d) {
        for (int j = 0; j < 7; ++j) {
          rhs.at<double>(j) += weight * tangent(id, d, j) * v[3 * id + d];
          for (int l = 0; l < 7; ++l) a.at<double>(j, l) += weight * tangent(id, d, j) * tangent(id, d, l);
        }
      }
    }
    cv::Mat coef;
    cv::solve(a, rhs, coef, cv::DECOMP_SVD);
    for (int i = 0; i < 468; ++i) {
      for (int d = 0; d < 3; ++d) {
        for (int j = 0; j < 7; ++j) v[3 * i + d] -= coef.at<double>(j) * tangent(i, d, j);
      }
    }
    double vv = 0, proj = 0;
    for (double x : v) vv += x * x;
    for (int j = 0; j < k; ++j) {
      double d = 0;
      for (int r = 0; r < 468 * 3; ++r) d += v[r] * b[r * kt + j];
      proj += d * d;
    }
    EXPECT_GT(proj / vv, 0.75) << "true component " << c;
    captured += proj / vv / truth.num_expression();
  }
  std::cout << "[builder] mean captured fraction of the true expression directions " << captured << "\n";
  EXPECT_GT(captured, 0.9);
}

TEST(Builder, NamedControlsMoveTheirMeasures) {
  const Topology& topo = InstalledTopology();
  const MorphableModel truth = SyntheticModel(topo, 3, 12, 5);
  std::mt19937 rng(8);
  const auto sources = SyntheticSources(truth, 6, 2, 150, rng);
  RunContext ctx;
  MorphableBuildOptions opts;
  opts.expression_components = 12;
  const MorphableModel built = BuildMorphableModel(topo, sources, opts, ctx);
  for (const auto& name : RequiredControlNames()) EXPECT_NO_THROW(built.Control(name)) << name;
  const ExpressionMeasures base = MeasureShape(built.Vertices({}, {}));
  auto after = [&](const char* name) {
    return MeasureShape(built.Vertices({}, built.ExpressionFromControls({{name, 1.0f}})));
  };
  EXPECT_GT(after("jawOpen").lip_gap, base.lip_gap);
  EXPECT_GT(after("smile").corner_lift, base.corner_lift);
  EXPECT_LT(after("frown").corner_lift, base.corner_lift);
  EXPECT_GT(after("mouthWide").mouth_width, base.mouth_width);
  EXPECT_LT(after("pucker").mouth_width, base.mouth_width);
  EXPECT_GT(after("browRaise").brow_height, base.brow_height);
  EXPECT_LT(after("browFrown").brow_height, base.brow_height);
  EXPECT_GT(after("eyesWide").eye_open_left + after("eyesWide").eye_open_right,
            base.eye_open_left + base.eye_open_right);
  const ExpressionMeasures bl = after("blinkLeft");
  const ExpressionMeasures br = after("blinkRight");
  EXPECT_LT(bl.eye_open_left, base.eye_open_left);
  EXPECT_LT(std::abs(bl.eye_open_right - base.eye_open_right), 0.25 * std::abs(bl.eye_open_left - base.eye_open_left));
  EXPECT_LT(br.eye_open_right, base.eye_open_right);
  EXPECT_LT(std::abs(br.eye_open_left - base.eye_open_left), 0.25 * std::abs(br.eye_open_right - base.eye_open_right));
}

TEST(Builder, RejectsMissingClipsAndHonoursCancel) {
  const Topology& topo = InstalledTopology();
  const MorphableModel truth = SyntheticModel(topo, 2, 2, 3);
  std::mt19937 rng(1);
  RunContext ctx;
  EXPECT_THROW(BuildMorphableModel(topo, {}, {}, ctx), InvalidInput);
  EXPECT_THROW(BuildMorphableModel(topo, SyntheticSources(truth, 4, 0, 1, rng), {}, ctx), InvalidInput);
  RunContext cancelled;
  cancelled.RequestCancel();
  EXPECT_THROW(BuildMorphableModel(topo, SyntheticSources(truth, 3, 1, 20, rng), {}, cancelled), Cancelled);
}

}  // namespace
}  // namespace avatar::morphable
