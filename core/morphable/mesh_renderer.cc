#include "core/morphable/mesh_renderer.h"

#include <cmath>

#include <opencv2/imgproc.hpp>

#include "core/morphable/rasterizer.h"
#include "core/morphable/texture.h"
#include "core/util/error.h"

namespace avatar::morphable {


void RenderOptions::Validate() const {
  AVATAR_CHECK_OPTION(supersample >= 1 && supersample <= 8) << "--supersample must be in 1..8, got " << supersample;
}

RenderResult RenderMesh(const std::vector<cv::Point3f>& world, const Topology& topo, const Texture& texture,
                        const CameraLabel& camera, cv::Size size, const RenderOptions& options) {
  options.Validate();
  AVATAR_CHECK_INPUT(size.width > 0 && size.height > 0 && size.width <= 8192 && size.height <= 8192)
      << "render size must be 1..8192 per side, got " << size.width << "x" << size.height;
  AVATAR_CHECK_INPUT(world.size() == topo.uv.size() && !world.empty())
      << "render: " << world.size() << " vertices for a topology of " << topo.uv.size();
  const bool use_uv = !texture.uv_image.empty();
  AVATAR_CHECK_INPUT(use_uv || texture.vertex_colors.size() == world.size())
      << "render: the texture has neither a UV image nor one colour per vertex";
  AVATAR_CHECK_INPUT(!use_uv || texture.uv_image.type() == CV_32FC3) << "render: the UV texture must be CV_32FC3";
  for (const auto& p : world) {
    AVATAR_CHECK_INPUT(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z))
        << "render: non-finite vertex positions";
  }
  const PinholeCamera cam = PinholeCamera::FromLabel(camera);
  const int ss = options.supersample;
  const cv::Size big(size.width * ss, size.height * ss);
  std::vector<ScreenVertex> screen(world.size());
  std::vector<cv::Vec3d> wp(world.size());
  for (size_t i = 0; i < world.size(); ++i) {
    wp[i] = cv::Vec3d(world[i].x, world[i].y, world[i].z);
    const cv::Vec3d c = cam.ToCamera(wp[i]);
    const cv::Point2d px = c[2] > 1e-9 ? cam.ToPixel(c, big) : cv::Point2d(0, 0);
    screen[i] = {px.x, px.y, c[2]};
  }
  const RasterBuffers buf = Rasterize(screen, topo.triangles, big);
  cv::Mat image(big, CV_32FC3, cv::Scalar(options.background[0], options.background[1], options.background[2]));
  cv::Mat mask(big, CV_32FC1, cv::Scalar(0));
  for (int y = 0; y < big.height; ++y) {
    for (int x = 0; x < big.width; ++x) {
      const int t = buf.triangle.at<int>(y, x);
      if (t < 0) continue;
      const cv::Vec3f b = buf.bary.at<cv::Vec3f>(y, x);
      const cv::Vec3i& f = topo.triangles[t];
      cv::Vec3f colour;
      if (use_uv) {
        const cv::Point2f uv = b[0] * topo.uv[f[0]] + b[1] * topo.uv[f[1]] + b[2] * topo.uv[f[2]];
        const double u = uv.x, v = uv.y;  // texel centres at (i + 0.5) / size
        colour = SampleBilinear<cv::Vec3f>(texture.uv_image, u * texture.uv_image.cols - 0.5,
                                           v * texture.uv_image.rows - 0.5);
      } else {
        colour = b[0] * texture.vertex_colors[f[0]] + b[1] * texture.vertex_colors[f[1]] +
                 b[2] * texture.vertex_colors[f[2]];
      }
      if (options.shading) {
        const cv::Vec3d n = (wp[f[1]] - wp[f[0]]).cross(wp[f[2]] - wp[f[0]]);
        const cv::Vec3d p = b[0] * wp[f[0]] + b[1] * wp[f[1]] + b[2] * wp[f[2]];
        const cv::Vec3d to_cam = cam.centre - p;
        const double nn = cv::norm(n) * cv::norm(to_cam);
        const double cosine = nn > 0 ? std::abs(n.dot(to_cam)) / nn : 1.0;
        colour *= static_cast<float>(0.35 + 0.65 * cosine);
      }
      image.at<cv::Vec3f>(y, x) = colour;
      mask.at<float>(y, x) = 1.0f;
    }
  }
  RenderResult out;
  cv::Mat depth = buf.depth.clone();
  depth.setTo(0.0f, buf.triangle < 0);
  if (ss == 1) {
    out.image = image;
    out.mask = mask;
    out.depth = depth;
  } else {
    cv::resize(image, out.image, size, 0, 0, cv::INTER_AREA);
    cv::resize(mask, out.mask, size, 0, 0, cv::INTER_AREA);
    cv::resize(depth, out.depth, size, 0, 0, cv::INTER_NEAREST);
  }
  return out;
}

RenderResult Render(const MorphableModel& model, const Alpha& alpha, const Beta& beta, float scale,
                    const Texture& texture, const CameraLabel& camera, cv::Size size, const RenderOptions& options) {
  AVATAR_CHECK_INPUT(std::isfinite(scale) && scale > 0) << "render: scale must be > 0";
  std::vector<cv::Point3f> v = model.Vertices(alpha, beta);
  for (auto& p : v) p *= scale;
  return RenderMesh(v, model.topology(), texture, camera, size, options);
}

RenderResult RenderExpressionImage(const MorphableModel& model, const FitResult& fit, const Texture& texture,
                                   const Beta& beta_target, cv::Size size, const RenderOptions& options) {
  return Render(model, fit.alpha, beta_target, fit.scale, texture, FrontalLabel(), size, options);
}

RenderResult RenderNeutral(const MorphableModel& model, const FitResult& fit, const Texture& texture, cv::Size size,
                           const RenderOptions& options) {
  return Render(model, fit.alpha, model.ZeroBeta(), fit.scale, texture, fit.camera, size, options);
}

std::vector<RenderResult> RenderExpressionImages(const MorphableModel& model, const std::vector<FitResult>& fits,
                                                 const std::vector<Texture>& textures,
                                                 const std::vector<Beta>& beta_targets, cv::Size size,
                                                 const RenderOptions& options) {
  AVATAR_CHECK_INPUT(fits.size() == textures.size() && fits.size() == beta_targets.size())
      << "render: batch sizes differ (" << fits.size() << " fits, " << textures.size() << " textures, "
      << beta_targets.size() << " expressions)";
  std::vector<RenderResult> out;
  out.reserve(fits.size());
  for (size_t i = 0; i < fits.size(); ++i) {
    out.push_back(RenderExpressionImage(model, fits[i], textures[i], beta_targets[i], size, options));
  }
  return out;
}

std::vector<RenderResult> RenderNeutrals(const MorphableModel& model, const std::vector<FitResult>& fits,
                                         const std::vector<Texture>& textures, cv::Size size,
                                         const RenderOptions& options) {
  AVATAR_CHECK_INPUT(fits.size() == textures.size())
      << "render: batch sizes differ (" << fits.size() << " fits, " << textures.size() << " textures)";
  std::vector<RenderResult> out;
  out.reserve(fits.size());
  for (size_t i = 0; i < fits.size(); ++i) out.push_back(RenderNeutral(model, fits[i], textures[i], size, options));
  return out;
}

cv::Mat DrawFitOverlay(const cv::Mat& bgr, const MorphableModel& model, const FitResult& fit,
                       const face::Landmarks& landmarks) {
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3) << "overlay: the image must be 8-bit BGR";
  cv::Mat out = bgr.clone();
  const PinholeCamera cam = PinholeCamera::FromLabel(fit.camera);
  const std::vector<cv::Point3f> world = WorldVertices(model, fit);
  std::vector<cv::Point2d> px(world.size());
  for (size_t i = 0; i < world.size(); ++i) {
    px[i] = cam.ToPixel(cam.ToCamera(cv::Vec3d(world[i].x, world[i].y, world[i].z)), bgr.size());
  }
  const int thickness = std::max(1, bgr.cols / 512);
  for (const auto& t : model.topology().triangles) {
    for (int e = 0; e < 3; ++e) {
      cv::line(out, px[t[e]], px[t[(e + 1) % 3]], cv::Scalar(0, 160, 0), thickness, cv::LINE_AA);
    }
  }
  for (const auto& p : landmarks.points) cv::circle(out, cv::Point2d(p.x, p.y), thickness, cv::Scalar(0, 0, 255), -1);
  return out;
}

}  // namespace avatar::morphable
