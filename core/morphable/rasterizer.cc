#include "core/morphable/rasterizer.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/util/error.h"

namespace avatar::morphable {

namespace {

// Vertices snap to 1/256 pixel so that edge functions are exact integers: a shared edge then
// gives exactly opposite values in its two triangles and the fill rule cannot crack.
constexpr int64_t kSubpixel = 256;
constexpr double kMaxCoord = 1 << 20;  // pixels; beyond this the triangle is dropped (overflow guard)

struct Fixed {
  int64_t x, y;
};

inline int64_t Edge(const Fixed& u, const Fixed& v, int64_t px, int64_t py) {
  return (v.x - u.x) * (py - u.y) - (v.y - u.y) * (px - u.x);
}

// Owned edges under our fill rule: for a positively oriented triangle (Edge(a,b,c) > 0), an
// edge u->v owns the samples exactly on it when it points down, or right when horizontal. A
// shared edge is traversed in opposite directions by its two triangles, so exactly one owns it.
inline bool Owns(const Fixed& u, const Fixed& v) { return v.y > u.y || (v.y == u.y && v.x > u.x); }

template <typename Fn>
void Cover(const ScreenVertex& va, const ScreenVertex& vb, const ScreenVertex& vc, cv::Size size, Fn&& fn) {
  for (const auto* v : {&va, &vb, &vc}) {
    if (!std::isfinite(v->x) || !std::isfinite(v->y) || std::abs(v->x) > kMaxCoord || std::abs(v->y) > kMaxCoord) {
      return;
    }
  }
  Fixed p[3] = {{std::llround(va.x * kSubpixel), std::llround(va.y * kSubpixel)},
                {std::llround(vb.x * kSubpixel), std::llround(vb.y * kSubpixel)},
                {std::llround(vc.x * kSubpixel), std::llround(vc.y * kSubpixel)}};
  int idx[3] = {0, 1, 2};
  int64_t area = Edge(p[0], p[1], p[2].x, p[2].y);
  if (area == 0) return;
  if (area < 0) {
    std::swap(p[1], p[2]);
    std::swap(idx[1], idx[2]);
    area = -area;
  }
  const int64_t min_x = std::min({p[0].x, p[1].x, p[2].x});
  const int64_t max_x = std::max({p[0].x, p[1].x, p[2].x});
  const int64_t min_y = std::min({p[0].y, p[1].y, p[2].y});
  const int64_t max_y = std::max({p[0].y, p[1].y, p[2].y});
  const int64_t half = kSubpixel / 2;
  // Pixel i's centre is i*S + S/2: the covered range is ceil((min - S/2)/S) .. floor((max - S/2)/S).
  auto floor_div = [](int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); };
  const int64_t x0 = std::max<int64_t>(0, -floor_div(-(min_x - half), kSubpixel));
  const int64_t x1 = std::min<int64_t>(size.width - 1, floor_div(max_x - half, kSubpixel));
  const int64_t y0 = std::max<int64_t>(0, -floor_div(-(min_y - half), kSubpixel));
  const int64_t y1 = std::min<int64_t>(size.height - 1, floor_div(max_y - half, kSubpixel));
  if (x0 > x1 || y0 > y1) return;
  const bool own0 = Owns(p[1], p[2]);
  const bool own1 = Owns(p[2], p[0]);
  const bool own2 = Owns(p[0], p[1]);
  // Weights come from the unsnapped positions (exact interpolation); snapping only decides coverage.
  const ScreenVertex* v[3] = {&va, &vb, &vc};
  const ScreenVertex& d0 = *v[idx[0]];
  const ScreenVertex& d1 = *v[idx[1]];
  const ScreenVertex& d2 = *v[idx[2]];
  auto edge_d = [](const ScreenVertex& u, const ScreenVertex& w, double px, double py) {
    return (w.x - u.x) * (py - u.y) - (w.y - u.y) * (px - u.x);
  };
  const double area_d = edge_d(d0, d1, d2.x, d2.y);
  if (area_d == 0.0) return;
  const double inv_area = 1.0 / area_d;
  double bary[3];
  for (int64_t y = y0; y <= y1; ++y) {
    const int64_t py = y * kSubpixel + half;
    for (int64_t x = x0; x <= x1; ++x) {
      const int64_t px = x * kSubpixel + half;
      const int64_t w0 = Edge(p[1], p[2], px, py);
      const int64_t w1 = Edge(p[2], p[0], px, py);
      const int64_t w2 = Edge(p[0], p[1], px, py);
      if (w0 < 0 || w1 < 0 || w2 < 0) continue;
      if ((w0 == 0 && !own0) || (w1 == 0 && !own1) || (w2 == 0 && !own2)) continue;
      const double cx = x + 0.5, cy = y + 0.5;
      bary[idx[0]] = edge_d(d1, d2, cx, cy) * inv_area;
      bary[idx[1]] = edge_d(d2, d0, cx, cy) * inv_area;
      bary[idx[2]] = 1.0 - bary[idx[0]] - bary[idx[1]];
      fn(static_cast<int>(x), static_cast<int>(y), bary[0], bary[1], bary[2]);
    }
  }
}

}  // namespace

void ForEachCoveredPixel(const ScreenVertex& a, const ScreenVertex& b, const ScreenVertex& c, cv::Size size,
                         const std::function<void(int, int, double, double, double)>& fn) {
  Cover(a, b, c, size, fn);
}

RasterBuffers Rasterize(const std::vector<ScreenVertex>& vertices, const std::vector<cv::Vec3i>& triangles,
                        cv::Size size, double near) {
  AVATAR_CHECK_INPUT(size.width > 0 && size.height > 0 && static_cast<int64_t>(size.width) * size.height <= (1LL << 28))
      << "render size must be positive and at most 2^28 pixels, got " << size.width << "x" << size.height;
  RasterBuffers out;
  out.triangle = cv::Mat(size, CV_32SC1, cv::Scalar(-1));
  out.bary = cv::Mat(size, CV_32FC3, cv::Scalar::all(0));
  out.depth = cv::Mat(size, CV_32FC1, cv::Scalar(std::numeric_limits<float>::infinity()));
  const int n = static_cast<int>(vertices.size());
  for (size_t t = 0; t < triangles.size(); ++t) {
    const cv::Vec3i& tri = triangles[t];
    for (int c = 0; c < 3; ++c) {
      AVATAR_CHECK_INPUT(tri[c] >= 0 && tri[c] < n)
          << "triangle " << t << " has vertex index " << tri[c] << " outside [0," << n << ")";
    }
    const ScreenVertex& a = vertices[tri[0]];
    const ScreenVertex& b = vertices[tri[1]];
    const ScreenVertex& c = vertices[tri[2]];
    if (!(a.depth > near && b.depth > near && c.depth > near)) continue;
    const double iz[3] = {1.0 / a.depth, 1.0 / b.depth, 1.0 / c.depth};
    const int tid = static_cast<int>(t);
    Cover(a, b, c, size, [&](int x, int y, double b0, double b1, double b2) {
      // 1/z is affine in screen space: interpolate it, then recover perspective-correct weights.
      const double q0 = b0 * iz[0], q1 = b1 * iz[1], q2 = b2 * iz[2];
      const double sum = q0 + q1 + q2;
      const double depth = 1.0 / sum;
      float& zbuf = out.depth.at<float>(y, x);
      if (!(depth < zbuf)) return;
      zbuf = static_cast<float>(depth);
      out.triangle.at<int>(y, x) = tid;
      out.bary.at<cv::Vec3f>(y, x) =
          cv::Vec3f(static_cast<float>(q0 / sum), static_cast<float>(q1 / sum), static_cast<float>(q2 / sum));
    });
  }
  return out;
}

}  // namespace avatar::morphable
