#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "core/morphable/rasterizer.h"
#include "core/util/error.h"
#include "morphable_test_util.h"

namespace avatar::morphable {
namespace {

// Strict inside test at a pixel centre (no fill-rule ties), in double.
int Side(const ScreenVertex& a, const ScreenVertex& b, double x, double y) {
  const double e = (b.x - a.x) * (y - a.y) - (b.y - a.y) * (x - a.x);
  return e > 1e-9 ? 1 : (e < -1e-9 ? -1 : 0);
}

TEST(Rasterizer, SingleTriangleCoverageIsExact) {
  const ScreenVertex a{3.3, 2.1, 1.0}, b{27.8, 9.6, 1.0}, c{11.2, 29.4, 1.0};
  const cv::Size size(32, 32);
  const RasterBuffers buf = Rasterize({a, b, c}, {cv::Vec3i(0, 1, 2)}, size);
  int covered = 0;
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const double px = x + 0.5, py = y + 0.5;
      const int s0 = Side(a, b, px, py), s1 = Side(b, c, px, py), s2 = Side(c, a, px, py);
      const bool inside = (s0 > 0 && s1 > 0 && s2 > 0) || (s0 < 0 && s1 < 0 && s2 < 0);
      const bool drawn = buf.triangle.at<int>(y, x) == 0;
      if (s0 != 0 && s1 != 0 && s2 != 0) {
        EXPECT_EQ(inside, drawn) << x << "," << y;
      }
      covered += drawn;
    }
  }
  // Area of the triangle is 308.1 px^2: the sample count matches it closely.
  EXPECT_NEAR(covered, 308.1, 15.0);
}

TEST(Rasterizer, DepthIsExactForAPlaneSeenInPerspective) {
  // Camera at the origin looking +z, f = 100 px, c = (32,32). Plane z = 2 + 0.5 x_world.
  const double f = 100.0, cx = 32.0;
  auto project = [&](cv::Vec3d p) { return ScreenVertex{f * p[0] / p[2] + cx, f * p[1] / p[2] + cx, p[2]}; };
  const cv::Vec3d p0(-0.3, -0.3, 2.0 - 0.15), p1(0.3, -0.2, 2.0 + 0.15), p2(0.0, 0.35, 2.0);
  const RasterBuffers buf = Rasterize({project(p0), project(p1), project(p2)}, {cv::Vec3i(0, 1, 2)}, cv::Size(64, 64));
  int checked = 0;
  for (int y = 0; y < 64; ++y) {
    for (int x = 0; x < 64; ++x) {
      if (buf.triangle.at<int>(y, x) < 0) continue;
      // Ray through the pixel centre: (xn, yn, 1) * t meets z = 2 + 0.5 x at t = 2 / (1 - 0.5 xn).
      const double xn = (x + 0.5 - cx) / f;
      const double expected = 2.0 / (1.0 - 0.5 * xn);
      EXPECT_NEAR(buf.depth.at<float>(y, x), expected, 2e-6 * expected);
      // Perspective-correct barycentrics reproduce the 3D point on the ray.
      const cv::Vec3f b = buf.bary.at<cv::Vec3f>(y, x);
      const cv::Vec3d p = b[0] * p0 + b[1] * p1 + b[2] * p2;
      EXPECT_NEAR(p[0] / p[2], xn, 1e-5);
      ++checked;
    }
  }
  EXPECT_GT(checked, 300);
}

TEST(Rasterizer, TriangleGridCoversEveryPixelExactlyOnce) {
  // A jittered grid of triangles spanning the image: every pixel centre inside belongs to
  // exactly one triangle (no cracks, no double coverage), including samples on shared edges.
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> jitter(-0.4, 0.4);
  const int n = 9;
  std::vector<ScreenVertex> v;
  for (int j = 0; j <= n; ++j) {
    for (int i = 0; i <= n; ++i) {
      const bool border = i == 0 || j == 0 || i == n || j == n;
      // Some vertices sit exactly on pixel centres or edges to exercise the tie rule.
      const double base_x = i * 8.0, base_y = j * 8.0;
      const double dx = border ? 0.0 : ((i + j) % 3 == 0 ? 0.5 : jitter(rng) * 8.0);
      const double dy = border ? 0.0 : ((i + j) % 3 == 0 ? 0.5 : jitter(rng) * 8.0);
      v.push_back({base_x + dx, base_y + dy, 1.0});
    }
  }
  std::vector<cv::Vec3i> tris;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const int a = j * (n + 1) + i, b = a + 1, c = a + n + 1, d = c + 1;
      tris.emplace_back(a, b, d);
      tris.emplace_back(a, d, c);
    }
  }
  const cv::Size size(72, 72);
  cv::Mat count(size, CV_32SC1, cv::Scalar(0));
  for (const auto& t : tris) {
    ForEachCoveredPixel(v[t[0]], v[t[1]], v[t[2]], size,
                        [&](int x, int y, double, double, double) { ++count.at<int>(y, x); });
  }
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) ASSERT_EQ(count.at<int>(y, x), 1) << "pixel " << x << "," << y;
  }
}

TEST(Rasterizer, ClosedSphereHasNoHolesAndMaskEqualsCoverage) {
  // A UV sphere of radius 0.3 at the origin seen by the frontal camera.
  std::vector<cv::Point3f> pts;
  std::vector<cv::Vec3i> tris;
  const int rings = 24, segs = 40;
  for (int r = 0; r <= rings; ++r) {
    for (int s = 0; s < segs; ++s) {
      const double th = M_PI * r / rings, ph = 2 * M_PI * s / segs;
      pts.emplace_back(0.3 * std::sin(th) * std::cos(ph), 0.3 * std::cos(th), 0.3 * std::sin(th) * std::sin(ph));
    }
  }
  for (int r = 0; r < rings; ++r) {
    for (int s = 0; s < segs; ++s) {
      const int a = r * segs + s, b = r * segs + (s + 1) % segs, c = a + segs, d = b + segs;
      tris.emplace_back(a, c, b);
      tris.emplace_back(b, c, d);
    }
  }
  Topology topo;
  topo.triangles = tris;
  topo.uv.assign(pts.size(), cv::Point2f(0.5f, 0.5f));
  topo.canonical_cm = pts;
  const CameraLabel cam = FrontalLabel();
  const cv::Size size(128, 128);
  Texture white;
  white.vertex_colors.assign(pts.size(), cv::Vec3f(1, 1, 1));
  const RenderResult r = RenderMesh(pts, topo, white, cam, size);
  // The sphere's silhouette: radius f * 0.3 / sqrt(2.7^2 - 0.3^2) in normalised units.
  const double radius_px = render::kFocal * 0.3 / std::sqrt(2.7 * 2.7 - 0.09) * size.width;
  int inside = 0;
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const double d = std::hypot(x + 0.5 - 64.0, y + 0.5 - 64.0);
      const float m = r.mask.at<float>(y, x);
      EXPECT_TRUE(m == 0.0f || m == 1.0f);
      if (d < radius_px - 1.5) {
        ASSERT_EQ(m, 1.0f) << "hole at " << x << "," << y;
        ++inside;
      }
      if (d > radius_px + 0.5) {
        ASSERT_EQ(m, 0.0f) << "spill at " << x << "," << y;
      }
      // Mask == coverage: colour is the texture (white) exactly where the mask is set.
      EXPECT_NEAR(r.image.at<cv::Vec3f>(y, x)[1], m, 1e-5);
      EXPECT_EQ(r.depth.at<float>(y, x) > 0.0f, m > 0.0f);
    }
  }
  EXPECT_GT(inside, 1000);
}

TEST(Rasterizer, RendersAreDeterministicAndProjectionMatchesTheRenderCore) {
  const Topology& topo = testing::InstalledTopology();
  const MorphableModel m = testing::SyntheticModel(topo, 2, 2);
  const CameraLabel cam = testing::OrbitLabel(20, 10, 5);
  RenderOptions opts;
  opts.shading = true;
  opts.supersample = 2;
  const RenderResult a = Render(m, {}, {}, 1.0f, UniformTexture(), cam, cv::Size(96, 80), opts);
  const RenderResult b = Render(m, {}, {}, 1.0f, UniformTexture(), cam, cv::Size(96, 80), opts);
  EXPECT_EQ(cv::norm(a.image, b.image, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(a.mask, b.mask, cv::NORM_INF), 0.0);
  EXPECT_GT(cv::countNonZero(a.mask), 100);
  // CPU projection equals render::ProjectPoints on the same label.
  const auto verts = m.Vertices({}, {});
  torch::Tensor pts = torch::zeros({1, 468, 3}, torch::kFloat64);
  for (int i = 0; i < 468; ++i) {
    pts[0][i][0] = verts[i].x;
    pts[0][i][1] = verts[i].y;
    pts[0][i][2] = verts[i].z;
  }
  const torch::Tensor proj =
      render::ProjectPoints(pts, render::CamerasFromLabels(LabelTensor(cam).to(torch::kFloat64)));
  const PinholeCamera pc = PinholeCamera::FromLabel(cam);
  for (int i = 0; i < 468; i += 37) {
    const cv::Point2d px = pc.ToPixel(pc.ToCamera(cv::Vec3d(verts[i].x, verts[i].y, verts[i].z)), cv::Size(1, 1));
    EXPECT_NEAR(px.x, proj[0][i][0].item<double>(), 1e-5);
    EXPECT_NEAR(px.y, proj[0][i][1].item<double>(), 1e-5);
  }
}

TEST(Rasterizer, HardCasesStayFiniteOrThrowClearly) {
  const Topology& topo = testing::InstalledTopology();
  const MorphableModel m = testing::SyntheticModel(topo, 1, 1);
  // Tiny and wide images, camera behind the head, degenerate triangles.
  for (const cv::Size s : {cv::Size(1, 1), cv::Size(3, 200)}) {
    const RenderResult r = Render(m, {}, {}, 1.0f, UniformTexture(), FrontalLabel(), s);
    EXPECT_TRUE(cv::checkRange(r.image) && cv::checkRange(r.mask));
  }
  const RenderResult back = Render(m, {}, {}, 1.0f, UniformTexture(), testing::OrbitLabel(180, 0, 0), cv::Size(64, 64));
  EXPECT_TRUE(cv::checkRange(back.image));
  const ScreenVertex p{5, 5, 1};
  const RasterBuffers deg = Rasterize({p, p, {9, 9, 1}}, {cv::Vec3i(0, 1, 2)}, cv::Size(16, 16));
  EXPECT_EQ(cv::countNonZero(deg.triangle >= 0), 0);
  EXPECT_THROW(Rasterize({p}, {cv::Vec3i(0, 1, 2)}, cv::Size(16, 16)), InvalidInput);
  EXPECT_THROW(Rasterize({p}, {}, cv::Size(0, 16)), InvalidInput);
  EXPECT_THROW(Render(m, {}, {}, 1.0f, UniformTexture(), FrontalLabel(), cv::Size(0, 0)), InvalidInput);
  CameraLabel bad = FrontalLabel();
  bad[0] = 5.0f;
  EXPECT_THROW(Render(m, {}, {}, 1.0f, UniformTexture(), bad, cv::Size(8, 8)), InvalidInput);
}

}  // namespace
}  // namespace avatar::morphable
