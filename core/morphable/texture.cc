#include "core/morphable/texture.h"

#include <cmath>

#include <opencv2/imgproc.hpp>

#include "core/morphable/rasterizer.h"
#include "core/util/error.h"
#include "core/util/push_pull.h"

namespace avatar::morphable {

namespace {

// The colour in [0,1] at pixel position (x, y) of `bgr64` (the photo as CV_64FC3 0..255; pixel
// i's centre is at i + 0.5).
cv::Vec3f PhotoColour(const cv::Mat& bgr64, double x, double y) {
  const cv::Vec3d v = SampleBilinear<cv::Vec3d>(bgr64, x - 0.5, y - 0.5);
  return {static_cast<float>(v[0] / 255.0), static_cast<float>(v[1] / 255.0), static_cast<float>(v[2] / 255.0)};
}

}  // namespace

void TextureOptions::Validate() const {
  AVATAR_CHECK_OPTION(size >= 0 && size <= 4096) << "--texture-size must be in 0..4096, got " << size;
  AVATAR_CHECK_OPTION(std::isfinite(depth_tolerance) && depth_tolerance > 0) << "--depth-tolerance must be > 0";
  AVATAR_CHECK_OPTION(std::isfinite(min_matte) && min_matte >= 0.0f && min_matte <= 1.0f)
      << "the texture's matte threshold must be in [0, 1], got " << min_matte;
}

Texture UniformTexture(const cv::Vec3f& bgr) {
  Texture t;
  t.vertex_colors.assign(kVertexCount, bgr);
  return t;
}

Texture SampleTexture(const MorphableModel& model, const FitResult& fit, const cv::Mat& bgr,
                      const TextureOptions& options, const cv::Mat& matte) {
  options.Validate();
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3) << "texture: the source image must be 8-bit BGR";
  AVATAR_CHECK_INPUT(bgr.size() == fit.image_size)
      << "texture: the image is " << bgr.cols << "x" << bgr.rows << " but the fit refers to " << fit.image_size.width
      << "x" << fit.image_size.height;
  AVATAR_CHECK_INPUT(matte.empty() || (matte.type() == CV_32FC1 && matte.size() == bgr.size()))
      << "texture: the matte must be CV_32FC1 of the image's size";
  const PinholeCamera cam = PinholeCamera::FromLabel(fit.camera);
  const std::vector<cv::Point3f> world = WorldVertices(model, fit);
  const auto& topo = model.topology();
  std::vector<ScreenVertex> screen(world.size());
  std::vector<cv::Vec3d> cam_pts(world.size());
  for (size_t i = 0; i < world.size(); ++i) {
    cam_pts[i] = cam.ToCamera(cv::Vec3d(world[i].x, world[i].y, world[i].z));
    const cv::Point2d px = cam.ToPixel(cam_pts[i], bgr.size());
    screen[i] = {px.x, px.y, cam_pts[i][2]};
  }
  const RasterBuffers source = Rasterize(screen, topo.triangles, bgr.size());
  cv::Mat bgr64;
  bgr.convertTo(bgr64, CV_64FC3);
  const double tol = options.depth_tolerance * render::kCameraRadius;
  auto visible = [&](const cv::Vec3d& p, cv::Point2d* px) {
    if (p[2] <= 1e-6) return false;
    *px = cam.ToPixel(p, bgr.size());
    const int x = static_cast<int>(std::floor(px->x)), y = static_cast<int>(std::floor(px->y));
    if (x < 0 || y < 0 || x >= bgr.cols || y >= bgr.rows) return false;
    if (!matte.empty() && !(matte.at<float>(y, x) >= options.min_matte)) return false;
    return p[2] <= source.depth.at<float>(y, x) + tol;
  };
  Texture tex;
  tex.vertex_colors.assign(kVertexCount, cv::Vec3f(0, 0, 0));
  std::vector<bool> vis(kVertexCount, false);
  cv::Vec3d sum(0, 0, 0);
  int count = 0;
  for (int i = 0; i < kVertexCount; ++i) {
    cv::Point2d px;
    if (visible(cam_pts[i], &px)) {
      vis[i] = true;
      tex.vertex_colors[i] = PhotoColour(bgr64, px.x, px.y);
      sum += cv::Vec3d(tex.vertex_colors[i]);
      ++count;
    }
  }
  const cv::Vec3f mean_colour = count > 0 ? cv::Vec3f(sum / count) : cv::Vec3f(0.5f, 0.5f, 0.5f);
  for (int i = 0; i < kVertexCount; ++i) {
    if (vis[i]) continue;
    const int m = topo.mirror.empty() ? -1 : topo.mirror[i];
    tex.vertex_colors[i] = (m >= 0 && vis[m]) ? tex.vertex_colors[m] : mean_colour;
  }
  if (options.size == 0) return tex;
  const int t = options.size;
  std::vector<ScreenVertex> uv_screen(kVertexCount);
  for (int i = 0; i < kVertexCount; ++i) uv_screen[i] = {topo.uv[i].x * t, topo.uv[i].y * t, 1.0};
  const RasterBuffers layout = Rasterize(uv_screen, topo.triangles, cv::Size(t, t));
  cv::Mat colour(t, t, CV_32FC3, cv::Scalar::all(0));
  cv::Mat seen(t, t, CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < t; ++y) {
    for (int x = 0; x < t; ++x) {
      const int tri = layout.triangle.at<int>(y, x);
      if (tri < 0) continue;
      const cv::Vec3f b = layout.bary.at<cv::Vec3f>(y, x);
      const cv::Vec3i& f = topo.triangles[tri];
      const cv::Vec3d p = b[0] * cam_pts[f[0]] + b[1] * cam_pts[f[1]] + b[2] * cam_pts[f[2]];
      cv::Point2d px;
      if (visible(p, &px)) {
        colour.at<cv::Vec3f>(y, x) = PhotoColour(bgr64, px.x, px.y);
        seen.at<uchar>(y, x) = 255;
      }
    }
  }
  // Hidden texels: the mirrored texel if it was seen (the layout is left-right symmetric), then inpainting.
  cv::Mat filled = colour.clone();
  cv::Mat known = seen.clone();
  for (int y = 0; y < t; ++y) {
    for (int x = 0; x < t; ++x) {
      const int mx = t - 1 - x;
      if (!seen.at<uchar>(y, x) && seen.at<uchar>(y, mx)) {
        filled.at<cv::Vec3f>(y, x) = colour.at<cv::Vec3f>(y, mx);
        known.at<uchar>(y, x) = 255;
      }
    }
  }
  tex.uv_image = PushPullFill(filled, known);
  // Keep the exact samples where we have them.
  filled.copyTo(tex.uv_image, known);
  tex.uv_visible = seen;
  return tex;
}

}  // namespace avatar::morphable
