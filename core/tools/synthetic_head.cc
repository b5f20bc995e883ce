#include "core/tools/synthetic_head.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <opencv2/imgproc.hpp>

#include "core/morphable/rasterizer.h"
#include "core/morphable/texture.h"
#include "core/util/error.h"

namespace avatar {
namespace {

using morphable::CameraLabel;
using morphable::PinholeCamera;

constexpr double kPi = 3.14159265358979323846;

// World direction of the ray through normalised image position (u, v), scaled so that its
// camera z component is 1 (a point at camera depth z is centre + z * direction).
cv::Vec3d RayDirection(const PinholeCamera& cam, double u, double v) {
  const cv::Matx33d& k = cam.k_normalised;
  const double yn = (v - k(1, 2)) / k(1, 1);
  const double xn = (u - k(0, 2) - k(0, 1) * yn) / k(0, 0);
  return cam.world_to_cam.t() * cv::Vec3d(xn, yn, 1.0);
}

cv::Vec3d V3(const cv::Point3f& p) { return {p.x, p.y, p.z}; }

}  // namespace

void SyntheticHeadOptions::Validate() const {
  AVATAR_CHECK_OPTION(falloff > 0.0 && falloff <= 1.0) << "synthetic head: falloff must be in (0,1]";
  AVATAR_CHECK_OPTION(bend_width > 0.0 && bend_width <= 0.5) << "synthetic head: bend_width must be in (0,0.5]";
  AVATAR_CHECK_OPTION(bend_depth >= 0.0 && bend_depth <= 4.0) << "synthetic head: bend_depth must be in [0,4]";
  AVATAR_CHECK_OPTION(grazing_cosine >= 0.0 && grazing_cosine < 0.5)
      << "synthetic head: grazing_cosine must be in [0,0.5)";
  AVATAR_CHECK_OPTION(texture_scale >= 1 && texture_scale <= 4) << "synthetic head: texture_scale must be in 1..4";
}

SyntheticHead BuildSyntheticHead(const morphable::MorphableModel& model, const morphable::FitResult& fit,
                                 const cv::Mat& bgr, const cv::Mat& matte_in, const cv::Mat& eye_mouth_in,
                                 const SyntheticHeadOptions& options) {
  options.Validate();
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.rows == bgr.cols && bgr.rows >= 16 &&
                     (bgr.type() == CV_8UC3 || bgr.type() == CV_32FC3))
      << "synthetic head: the portrait must be a square BGR image of at least 16 px, got " << bgr.cols << "x"
      << bgr.rows;
  AVATAR_CHECK_INPUT(matte_in.size() == bgr.size() && matte_in.channels() == 1)
      << "synthetic head: the matte must be one channel of the portrait's size";
  AVATAR_CHECK_INPUT(eye_mouth_in.empty() || (eye_mouth_in.size() == bgr.size() && eye_mouth_in.channels() == 1))
      << "synthetic head: the eye/mouth mask must be one channel of the portrait's size";
  const int s = bgr.cols;
  const int n = s + 1;  // corners per side
  cv::Mat image, matte, eye_mouth;
  bgr.convertTo(image, CV_32FC3, bgr.type() == CV_8UC3 ? 1.0 / 255.0 : 1.0);
  matte_in.convertTo(matte, CV_32FC1, matte_in.depth() == CV_8U ? 1.0 / 255.0 : 1.0);
  if (eye_mouth_in.empty()) eye_mouth = cv::Mat::zeros(bgr.size(), CV_32FC1);
  else eye_mouth_in.convertTo(eye_mouth, CV_32FC1, eye_mouth_in.depth() == CV_8U ? 1.0 / 255.0 : 1.0);
  AVATAR_CHECK_INPUT(cv::countNonZero(matte > 0.5f) > 0) << "synthetic head: the matte is empty";

  const PinholeCamera cam = PinholeCamera::FromLabel(fit.camera);
  const morphable::Topology& topo = model.topology();
  const std::vector<cv::Point3f> face = morphable::WorldVertices(model, fit);

  // The face rasterized on the corner grid: corner (i, j) sits at image position (i, j), the
  // centre of pixel (i, j) of an (S+1)^2 raster shifted by half a pixel.
  std::vector<morphable::ScreenVertex> screen(face.size());
  for (size_t i = 0; i < face.size(); ++i) {
    const cv::Vec3d c = cam.ToCamera(V3(face[i]));
    const cv::Point2d px = c[2] > 1e-9 ? cam.ToPixel(c, cv::Size(s, s)) : cv::Point2d(-1e7, -1e7);
    screen[i] = {px.x + 0.5, px.y + 0.5, c[2]};
  }
  const morphable::RasterBuffers fr = morphable::Rasterize(screen, topo.triangles, cv::Size(n, n));
  const cv::Mat on_face = fr.triangle >= 0;  // CV_8U 255 on the face
  AVATAR_CHECK_INPUT(cv::countNonZero(on_face) > 0) << "synthetic head: the fitted face is not in view";

  // Head-sized ellipsoid from the face's extent.
  cv::Vec3d lo(1e9, 1e9, 1e9), hi(-1e9, -1e9, -1e9);
  for (const auto& p : face) {
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min(lo[k], static_cast<double>(V3(p)[k]));
      hi[k] = std::max(hi[k], static_cast<double>(V3(p)[k]));
    }
  }
  const double ax = 0.55 * (hi[0] - lo[0]);
  const cv::Vec3d axes(ax, 1.3 * ax, 1.2 * ax);
  const cv::Vec3d centre(0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]) + 0.1 * axes[1],
                         hi[2] - 0.3 * (hi[2] - lo[2]) - axes[2]);

  // Per corner: ray, ellipsoid depth, face depth.
  std::vector<cv::Vec3d> ray(static_cast<size_t>(n) * n);
  cv::Mat ell(n, n, CV_32FC1), offset(n, n, CV_32FC1, cv::Scalar(0)), face_mask(n, n, CV_32FC1, cv::Scalar(0));
  const cv::Vec3d o = cv::Vec3d(cam.centre[0] - centre[0], cam.centre[1] - centre[1], cam.centre[2] - centre[2]);
  const cv::Vec3d os(o[0] / axes[0], o[1] / axes[1], o[2] / axes[2]);
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const cv::Vec3d d = RayDirection(cam, static_cast<double>(i) / s, static_cast<double>(j) / s);
      ray[static_cast<size_t>(j) * n + i] = d;
      const cv::Vec3d ds(d[0] / axes[0], d[1] / axes[1], d[2] / axes[2]);
      const double a = ds.dot(ds), b = os.dot(ds), c = os.dot(os) - 1.0;
      const double disc = b * b - a * c;
      // Front intersection, or the point of closest approach for rays that miss (continuous at the rim).
      const double t = disc >= 0.0 ? (-b - std::sqrt(disc)) / a : -b / a;
      ell.at<float>(j, i) = static_cast<float>(t);
      if (fr.triangle.at<int>(j, i) >= 0) {
        face_mask.at<float>(j, i) = 1.0f;
        offset.at<float>(j, i) = fr.depth.at<float>(j, i) - static_cast<float>(t);
      }
    }
  }
  // The face's offset from the ellipsoid, spread outwards by normalised convolution.
  const double sigma = options.falloff * s;
  cv::Mat num, den;
  cv::GaussianBlur(offset, num, cv::Size(0, 0), sigma);
  cv::GaussianBlur(face_mask, den, cv::Size(0, 0), sigma);
  // Distance of every corner to the nearest face corner, and which one it is.
  cv::Mat not_face = on_face == 0, dist_face, labels;
  cv::distanceTransform(not_face, dist_face, labels, cv::DIST_L2, cv::DIST_MASK_5, cv::DIST_LABEL_PIXEL);
  std::vector<cv::Point> label_pixel(static_cast<size_t>(n) * n + 1, cv::Point(-1, -1));
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      if (fr.triangle.at<int>(j, i) >= 0) label_pixel[static_cast<size_t>(labels.at<int>(j, i))] = cv::Point(i, j);
    }
  }
  // Corner matte (mean of the four pixels around the corner) and distance to the silhouette;
  // the image border is not a silhouette (replicated padding).
  const int pad = static_cast<int>(std::ceil(options.bend_width * s)) + 2;
  cv::Mat matte_pad;
  cv::copyMakeBorder(matte, matte_pad, 1, 1, 1, 1, cv::BORDER_REPLICATE);
  cv::Mat corner_matte(n, n, CV_32FC1);
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      corner_matte.at<float>(j, i) = 0.25f * (matte_pad.at<float>(j, i) + matte_pad.at<float>(j, i + 1) +
                                              matte_pad.at<float>(j + 1, i) + matte_pad.at<float>(j + 1, i + 1));
    }
  }
  cv::Mat inside = corner_matte >= 0.5f, inside_pad, dist_sil_pad;
  cv::copyMakeBorder(inside, inside_pad, pad, pad, pad, pad, cv::BORDER_REPLICATE);
  cv::distanceTransform(inside_pad, dist_sil_pad, cv::DIST_L2, cv::DIST_MASK_5);
  const cv::Mat dist_sil = dist_sil_pad(cv::Rect(pad, pad, n, n));

  const double band = options.bend_width * s;
  const double bend = options.bend_depth * axes[2];
  SyntheticHead head;
  head.vertices.resize(static_cast<size_t>(n) * n);
  head.uv.resize(head.vertices.size());
  head.face_vertex.resize(head.vertices.size());
  head.face_bary.resize(head.vertices.size());
  head.face_weight.resize(head.vertices.size());
  cv::Mat depth(n, n, CV_32FC1);
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const size_t v = static_cast<size_t>(j) * n + i;
      const int tri = fr.triangle.at<int>(j, i);
      double z;
      cv::Point anchor(i, j);
      float weight = 1.0f;
      if (tri >= 0) {
        z = fr.depth.at<float>(j, i);
      } else {
        const double df = dist_face.at<float>(j, i);
        const double w = std::exp(-0.5 * (df / sigma) * (df / sigma));
        const double ext = den.at<float>(j, i) > 1e-6f ? num.at<float>(j, i) / den.at<float>(j, i) : 0.0;
        const double ds = dist_sil.at<float>(j, i);
        const double r = std::max(0.0, 1.0 - ds / band);
        // The bend fades in away from the face so the surface stays continuous where the face
        // itself reaches the silhouette.
        const double near_face = 1.0 - std::exp(-0.5 * (df / (0.4 * band)) * (df / (0.4 * band)));
        z = ell.at<float>(j, i) + w * ext + bend * r * r * near_face;
        anchor = label_pixel[static_cast<size_t>(labels.at<int>(j, i))];
        weight = static_cast<float>(w);
      }
      depth.at<float>(j, i) = static_cast<float>(z);
      const cv::Vec3d p = cam.centre + z * ray[v];
      head.vertices[v] = cv::Point3f(static_cast<float>(p[0]), static_cast<float>(p[1]), static_cast<float>(p[2]));
      head.uv[v] = cv::Point2f(static_cast<float>(i) / s, static_cast<float>(j) / s);
      const int at = anchor.x >= 0 ? fr.triangle.at<int>(anchor.y, anchor.x) : -1;
      if (at >= 0) {
        head.face_vertex[v] = topo.triangles[at];
        head.face_bary[v] = fr.bary.at<cv::Vec3f>(anchor.y, anchor.x);
        head.face_weight[v] = weight;
      } else {
        head.face_vertex[v] = cv::Vec3i(0, 0, 0);
        head.face_bary[v] = cv::Vec3f(0, 0, 0);
        head.face_weight[v] = 0.0f;
      }
    }
  }
  // Quads of every pixel the matte touches.
  for (int y = 0; y < s; ++y) {
    for (int x = 0; x < s; ++x) {
      if (matte.at<float>(y, x) <= 0.5f / 255.0f) continue;
      const int a = y * n + x, b = a + 1, c = a + n + 1, d = a + n;
      head.triangles.emplace_back(a, b, c);
      head.triangles.emplace_back(a, c, d);
    }
  }

  // Texels seen at a grazing angle take their mirror point's colour when it was seen well.
  cv::Mat cosine(s, s, CV_32FC1), pixel_depth(s, s, CV_32FC1);
  std::vector<cv::Vec3d> centre_point(static_cast<size_t>(s) * s);
  for (int y = 0; y < s; ++y) {
    for (int x = 0; x < s; ++x) {
      const cv::Vec3d p00 = V3(head.vertices[y * n + x]), p10 = V3(head.vertices[y * n + x + 1]);
      const cv::Vec3d p01 = V3(head.vertices[(y + 1) * n + x]), p11 = V3(head.vertices[(y + 1) * n + x + 1]);
      const cv::Vec3d pc = 0.25 * (p00 + p10 + p01 + p11);
      const cv::Vec3d nrm = (p11 - p00).cross(p01 - p10);
      const cv::Vec3d view = cam.centre - pc;
      const double nn = cv::norm(nrm) * cv::norm(view);
      cosine.at<float>(y, x) = nn > 0 ? static_cast<float>(std::abs(nrm.dot(view)) / nn) : 0.0f;
      pixel_depth.at<float>(y, x) = static_cast<float>(cam.ToCamera(pc)[2]);
      centre_point[static_cast<size_t>(y) * s + x] = pc;
    }
  }
  cv::Mat colour = image.clone();
  for (int y = 0; y < s; ++y) {
    for (int x = 0; x < s; ++x) {
      if (matte.at<float>(y, x) < 0.5f || cosine.at<float>(y, x) >= options.grazing_cosine) continue;
      const cv::Vec3d p = centre_point[static_cast<size_t>(y) * s + x];
      const cv::Vec3d c = cam.ToCamera(cv::Vec3d(-p[0], p[1], p[2]));
      if (c[2] <= 1e-9) continue;
      const cv::Point2d q = cam.ToPixel(c, cv::Size(s, s));
      const int qx = static_cast<int>(std::floor(q.x)), qy = static_cast<int>(std::floor(q.y));
      if (qx < 0 || qy < 0 || qx >= s || qy >= s) continue;
      if (matte.at<float>(qy, qx) < 0.5f || cosine.at<float>(qy, qx) < 2.0 * options.grazing_cosine) continue;
      if (std::abs(c[2] - pixel_depth.at<float>(qy, qx)) > 0.02 * c[2]) continue;  // hidden
      colour.at<cv::Vec3f>(y, x) = morphable::SampleBilinear<cv::Vec3f>(image, q.x - 0.5, q.y - 0.5);
      ++head.mirrored_texels;
    }
  }
  const int t = s * options.texture_scale;
  if (options.texture_scale == 1) {
    head.colour = colour;
  } else {
    cv::resize(colour, head.colour, cv::Size(t, t), 0, 0, cv::INTER_CUBIC);
    cv::min(cv::max(head.colour, 0.0), 1.0, head.colour);
  }
  cv::Mat aux;
  cv::merge(std::vector<cv::Mat>{eye_mouth, matte}, aux);
  if (options.texture_scale == 1) head.aux = aux;
  else cv::resize(aux, head.aux, cv::Size(t, t), 0, 0, cv::INTER_LINEAR);
  return head;
}

std::vector<cv::Point3f> HeadVertices(const morphable::MorphableModel& model, const morphable::FitResult& fit,
                                      const SyntheticHead& head, const morphable::Beta& beta) {
  const std::vector<cv::Point3f> base = morphable::WorldVertices(model, fit);
  const std::vector<cv::Point3f> moved = morphable::WorldVertices(model, fit, &beta);
  std::vector<cv::Point3f> delta(base.size());
  for (size_t i = 0; i < base.size(); ++i) delta[i] = moved[i] - base[i];
  std::vector<cv::Point3f> out = head.vertices;
  for (size_t v = 0; v < out.size(); ++v) {
    const float w = head.face_weight[v];
    if (w <= 1e-4f) continue;
    const cv::Vec3i& f = head.face_vertex[v];
    const cv::Vec3f& b = head.face_bary[v];
    out[v] += w * (b[0] * delta[f[0]] + b[1] * delta[f[1]] + b[2] * delta[f[2]]);
  }
  return out;
}

SyntheticView RenderSyntheticView(const SyntheticHead& head, const std::vector<cv::Point3f>& vertices,
                                  const CameraLabel& camera, cv::Size size, int supersample) {
  AVATAR_CHECK_INPUT(size.width > 0 && size.height > 0 && size.width <= 4096 && size.height <= 4096)
      << "synthetic render: size must be 1..4096 per side";
  AVATAR_CHECK_INPUT(supersample >= 1 && supersample <= 4) << "synthetic render: supersample must be in 1..4";
  AVATAR_CHECK_INPUT(vertices.size() == head.uv.size()) << "synthetic render: " << vertices.size()
                                                        << " vertices for a head of " << head.uv.size();
  AVATAR_CHECK_INPUT(!head.colour.empty() && head.colour.type() == CV_32FC3 && head.aux.type() == CV_32FC2 &&
                     head.aux.size() == head.colour.size())
      << "synthetic render: the head has no texture";
  const PinholeCamera cam = PinholeCamera::FromLabel(camera);
  const cv::Size big(size.width * supersample, size.height * supersample);
  std::vector<morphable::ScreenVertex> screen(vertices.size());
  for (size_t i = 0; i < vertices.size(); ++i) {
    const cv::Vec3d c = cam.ToCamera(V3(vertices[i]));
    const cv::Point2d px = c[2] > 1e-9 ? cam.ToPixel(c, big) : cv::Point2d(0, 0);
    screen[i] = {px.x, px.y, c[2]};
  }
  const morphable::RasterBuffers buf = morphable::Rasterize(screen, head.triangles, big);
  cv::Mat premult(big, CV_32FC3, cv::Scalar::all(0)), alpha(big, CV_32FC1, cv::Scalar(0));
  cv::Mat eye(big, CV_32FC1, cv::Scalar(0));
  const double tw = head.colour.cols, th = head.colour.rows;
  for (int y = 0; y < big.height; ++y) {
    for (int x = 0; x < big.width; ++x) {
      const int t = buf.triangle.at<int>(y, x);
      if (t < 0) continue;
      const cv::Vec3f b = buf.bary.at<cv::Vec3f>(y, x);
      const cv::Vec3i& f = head.triangles[t];
      const cv::Point2f uv = b[0] * head.uv[f[0]] + b[1] * head.uv[f[1]] + b[2] * head.uv[f[2]];
      const double fx = uv.x * tw - 0.5, fy = uv.y * th - 0.5;
      const cv::Vec3f c = morphable::SampleBilinear<cv::Vec3f>(head.colour, fx, fy);
      const cv::Vec2f a = morphable::SampleBilinear<cv::Vec2f>(head.aux, fx, fy);
      premult.at<cv::Vec3f>(y, x) = c * a[1];
      alpha.at<float>(y, x) = a[1];
      eye.at<float>(y, x) = a[0];
    }
  }
  SyntheticView out;
  cv::Mat depth = buf.depth.clone();
  depth.setTo(0.0f, buf.triangle < 0);
  if (supersample > 1) {
    cv::resize(premult, premult, size, 0, 0, cv::INTER_AREA);
    cv::resize(alpha, out.alpha, size, 0, 0, cv::INTER_AREA);
    cv::resize(eye, out.eye_mouth, size, 0, 0, cv::INTER_AREA);
    cv::resize(depth, out.depth, size, 0, 0, cv::INTER_NEAREST);
  } else {
    out.alpha = alpha;
    out.eye_mouth = eye;
    out.depth = depth;
  }
  out.image = cv::Mat(size, CV_32FC3, cv::Scalar::all(0));
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const float a = out.alpha.at<float>(y, x);
      if (a > 1e-6f) out.image.at<cv::Vec3f>(y, x) = premult.at<cv::Vec3f>(y, x) / a;
    }
  }
  cv::min(cv::max(out.image, 0.0), 1.0, out.image);
  cv::min(cv::max(out.alpha, 0.0), 1.0, out.alpha);
  return out;
}

CameraLabel MirroredLabel(const CameraLabel& label) {
  CameraLabel out = label;
  for (int i = 0; i < 3; ++i) {
    const float mi = i == 0 ? -1.0f : 1.0f;
    for (int j = 0; j < 3; ++j) out[i * 4 + j] = mi * (j == 0 ? -1.0f : 1.0f) * label[i * 4 + j];
    out[i * 4 + 3] = mi * label[i * 4 + 3];
  }
  // u -> 1 - u: the skew changes sign and the principal point mirrors.
  out[16 + 1] = -label[16 + 1];
  out[16 + 2] = 1.0f - label[16 + 2];
  return out;
}

morphable::Beta MirroredExpression(const morphable::MorphableModel& model, const morphable::Beta& beta) {
  const int k = model.num_expression();
  AVATAR_CHECK_INPUT(static_cast<int>(beta.size()) == k)
      << "mirrored expression: " << beta.size() << " coefficients for a model with " << k;
  const int rows = 3 * model.num_vertices();
  const std::vector<float>& basis = model.expression_basis();
  const std::vector<float>& stdev = model.expression_std();
  const std::vector<int>& mirror = model.topology().mirror;
  AVATAR_CHECK_INPUT(static_cast<int>(mirror.size()) == model.num_vertices()) << "the topology has no mirror table";
  // Whitened basis W = B diag(std); target m(B beta).
  cv::Mat w(rows, k, CV_64FC1), target(rows, 1, CV_64FC1);
  std::vector<double> disp(rows, 0.0);
  for (int r = 0; r < rows; ++r) {
    double d = 0.0;
    for (int c = 0; c < k; ++c) {
      w.at<double>(r, c) = basis[static_cast<size_t>(r) * k + c] * stdev[c];
      d += basis[static_cast<size_t>(r) * k + c] * beta[c];
    }
    disp[r] = d;
  }
  for (int v = 0; v < model.num_vertices(); ++v) {
    const int m = mirror[v];
    target.at<double>(3 * v + 0, 0) = -disp[3 * m + 0];
    target.at<double>(3 * v + 1, 0) = disp[3 * m + 1];
    target.at<double>(3 * v + 2, 0) = disp[3 * m + 2];
  }
  cv::Mat normal = w.t() * w;
  const double ridge = 1e-6 * cv::trace(normal)[0] / std::max(k, 1);
  normal += ridge * cv::Mat::eye(k, k, CV_64FC1);
  cv::Mat c;
  cv::solve(normal, w.t() * target, c, cv::DECOMP_CHOLESKY);
  morphable::Beta out(k);
  for (int i = 0; i < k; ++i) out[i] = static_cast<float>(c.at<double>(i, 0) * stdev[i]);
  return out;
}

cv::Vec2d LabelYawPitch(const CameraLabel& label) {
  const cv::Vec3d c(label[3], label[7], label[11]);
  const double r = std::max(cv::norm(c), 1e-12);
  return {std::atan2(c[0], c[2]) * 180.0 / kPi, std::asin(std::clamp(c[1] / r, -1.0, 1.0)) * 180.0 / kPi};
}

}  // namespace avatar
