#include "core/pipeline/head_mesh.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "core/compose/depth_detail.h"
#include "core/morphable/rasterizer.h"
#include "core/pipeline/avatar_state.h"
#include "core/pipeline/session_source.h"
#include "core/render/view_pose.h"
#include "core/util/error.h"

namespace avatar {
namespace {

// Turns every triangle of `mesh` around when most of its area faces away from `eye` (glTF's
// front faces are counter-clockwise).
void FaceTowards(TexturedMesh* mesh, const cv::Vec3d& eye) {
  double facing = 0.0;
  for (const cv::Vec3i& f : mesh->triangles) {
    const cv::Point3f a = mesh->positions[f[0]], b = mesh->positions[f[1]], c = mesh->positions[f[2]];
    const cv::Vec3d n = cv::Vec3d(b.x - a.x, b.y - a.y, b.z - a.z).cross(cv::Vec3d(c.x - a.x, c.y - a.y, c.z - a.z));
    const cv::Vec3d to_eye = eye - cv::Vec3d((a.x + b.x + c.x) / 3.0, (a.y + b.y + c.y) / 3.0, (a.z + b.z + c.z) / 3.0);
    facing += n.dot(to_eye) > 0.0 ? cv::norm(n) : -cv::norm(n);
  }
  if (facing < 0.0)
    for (cv::Vec3i& f : mesh->triangles) std::swap(f[1], f[2]);
}

cv::Mat ToBgr8(const cv::Mat& bgr_float01) {
  cv::Mat out;
  bgr_float01.convertTo(out, CV_8UC3, 255.0);
  return out;
}

}  // namespace

void HeadMeshOptions::Validate() const {
  AVATAR_CHECK_OPTION(depth_size >= 16 && depth_size <= 1024) << "--depth-size must be within 16..1024, got " << depth_size;
  AVATAR_CHECK_OPTION(std::isfinite(depth_smoothing) && depth_smoothing >= 0.0 && depth_smoothing <= 0.25)
      << "the depth smoothing must be within 0..0.25, got " << depth_smoothing;
  AVATAR_CHECK_OPTION(std::isfinite(max_depth_step) && max_depth_step > 0.0 && max_depth_step < 1.0)
      << "--max-depth-step must be in (0, 1), got " << max_depth_step;
  AVATAR_CHECK_OPTION(std::isfinite(min_matte) && min_matte >= 0.0f && min_matte <= 1.0f)
      << "the matte threshold must be in [0, 1], got " << min_matte;
  AVATAR_CHECK_OPTION(std::isfinite(align_depth_reach) && align_depth_reach <= 10.0)
      << "the depth alignment's reach must be finite and at most 10 image heights, got " << align_depth_reach;
  AVATAR_CHECK_OPTION(face_texture_size >= 16 && face_texture_size <= 4096)
      << "--face-texture-size must be within 16..4096, got " << face_texture_size;
}

HeadMesh BuildHeadMesh(const SourceAnalysis& analysis, const FrameSource& network, const HeadMeshOptions& options,
                       RunContext& ctx) {
  options.Validate();
  AVATAR_CHECK_INPUT(analysis.model != nullptr) << "export mesh: the portrait's analysis has no morphable model";
  const morphable::MorphableModel& model = *analysis.model;
  const morphable::FitResult& fit = analysis.morphable_fit;
  const cv::Mat& photo = analysis.portrait.image_unmatted;
  AVATAR_CHECK_INPUT(!photo.empty() && photo.type() == CV_8UC3) << "export mesh: the portrait's crop is missing";
  HeadMesh out;

  // The face: the fitted mesh at the portrait's own expression.
  TexturedMesh face;
  face.name = "face";
  face.positions = morphable::WorldVertices(model, fit);
  face.uv = model.topology().uv;
  face.triangles = model.topology().triangles;
  if (!analysis.texture.uv_image.empty()) {
    cv::resize(ToBgr8(analysis.texture.uv_image), face.texture,
               cv::Size(options.face_texture_size, options.face_texture_size), 0, 0, cv::INTER_CUBIC);
  } else {
    // Vertex colours only: a flat texture of their mean keeps the file valid.
    cv::Vec3f mean(0.7f, 0.7f, 0.7f);
    if (!analysis.texture.vertex_colors.empty()) {
      mean = cv::Vec3f(0, 0, 0);
      for (const cv::Vec3f& c : analysis.texture.vertex_colors) mean += c;
      mean *= 1.0f / static_cast<float>(analysis.texture.vertex_colors.size());
    }
    face.texture = cv::Mat(16, 16, CV_8UC3, cv::Scalar(mean[0] * 255, mean[1] * 255, mean[2] * 255));
  }
  const CameraLabel25 camera = render::CameraForView(network.SourcePose(), fit.camera);
  const morphable::PinholeCamera cam = morphable::PinholeCamera::FromLabel(camera);
  FaceTowards(&face, cam.centre);
  ctx.ThrowIfCancelled();

  // The head: the network's depth at the photo's view, lifted to 3D pixel by pixel.
  const int n = options.depth_size;
  const cv::Size size(n, n);
  FrameRequest request;
  request.view = network.SourcePose();
  request.width = request.height = n;
  const RenderedFrame frame = network.Render(request, ctx);
  ctx.ThrowIfCancelled();
  if (frame.depth.empty() || frame.alpha.empty() || cv::countNonZero(frame.alpha >= 128) == 0) {
    out.warnings.push_back("The network renders nothing opaque at the photo's view, so the mesh holds the face only.");
    out.parts.push_back(std::move(face));
    return out;
  }
  cv::Mat depth = frame.depth.clone();
  if (options.align_depth_to_face) {
    const cv::Mat mesh = compose::MeshRayDepth(camera, face.positions, face.triangles, frame.depth.size());
    depth += compose::FaceOffsetField(mesh < std::numeric_limits<float>::infinity(),
                                      compose::FaceDepthOffset(frame.depth, frame.alpha, mesh),
                                      options.align_depth_reach);
  }
  depth.setTo(std::numeric_limits<float>::infinity(), frame.alpha < 128);
  depth = compose::SmoothDepth(depth, options.depth_smoothing);
  if (options.extend_to_matte) depth = compose::FillGaps(depth);
  // Where the face mesh covers the photo's view (eroded by a pixel so that the two parts meet).
  std::vector<morphable::ScreenVertex> screen(face.positions.size());
  for (size_t i = 0; i < face.positions.size(); ++i) {
    const cv::Point3f& p = face.positions[i];
    const cv::Vec3d c = cam.ToCamera(cv::Vec3d(p.x, p.y, p.z));
    const cv::Point2d px = cam.ToPixel(c, size);
    screen[i] = {px.x, px.y, c[2]};
  }
  cv::Mat covered = morphable::Rasterize(screen, model.topology().triangles, size).triangle >= 0;
  cv::erode(covered, covered, cv::Mat());
  cv::Mat matte;
  if (analysis.portrait.matte.empty()) {
    matte = cv::Mat(size, CV_32FC1, cv::Scalar(1.0f));
  } else {
    cv::resize(analysis.portrait.matte, matte, size, 0, 0, cv::INTER_AREA);
  }

  TexturedMesh head;
  head.name = "head";
  head.texture = photo;
  const compose::PixelRays rays(cam);
  cv::Mat index(size, CV_32SC1, cv::Scalar(-1));
  for (int y = 0; y < n; ++y) {
    for (int x = 0; x < n; ++x) {
      const float t = depth.at<float>(y, x);
      if (!std::isfinite(t) || t <= 0.0f || (!options.extend_to_matte && frame.alpha.at<uchar>(y, x) < 128) ||
          matte.at<float>(y, x) < options.min_matte)
        continue;
      const cv::Vec3d p = rays.Point(x, y, size, t);
      index.at<int>(y, x) = static_cast<int>(head.positions.size());
      head.positions.emplace_back(static_cast<float>(p[0]), static_cast<float>(p[1]), static_cast<float>(p[2]));
      head.uv.emplace_back(static_cast<float>((x + 0.5) / n), static_cast<float>((y + 0.5) / n));
    }
  }
  const float step = static_cast<float>(options.max_depth_step * render::kCameraRadius);
  auto add = [&](cv::Point a, cv::Point b, cv::Point c) {
    const int ia = index.at<int>(a), ib = index.at<int>(b), ic = index.at<int>(c);
    if (ia < 0 || ib < 0 || ic < 0) return;
    if (!options.under_face && covered.at<uchar>(a) && covered.at<uchar>(b) && covered.at<uchar>(c))
      return;  // the face part's
    const float da = depth.at<float>(a), db = depth.at<float>(b), dc = depth.at<float>(c);
    if (std::max({da, db, dc}) - std::min({da, db, dc}) > step) return;  // a silhouette
    head.triangles.emplace_back(ia, ib, ic);
  };
  for (int y = 0; y + 1 < n; ++y) {
    for (int x = 0; x + 1 < n; ++x) {
      add({x, y}, {x, y + 1}, {x + 1, y});
      add({x + 1, y}, {x, y + 1}, {x + 1, y + 1});
    }
  }
  out.parts.push_back(std::move(face));
  if (head.triangles.empty()) {
    out.warnings.push_back("The network's depth gives no surface beside the face, so the mesh holds the face only.");
    return out;
  }
  // Drop the vertices no triangle uses.
  std::vector<int> remap(head.positions.size(), -1);
  TexturedMesh used;
  used.name = head.name;
  used.texture = head.texture;
  for (cv::Vec3i& f : head.triangles) {
    for (int k = 0; k < 3; ++k) {
      int& r = remap[f[k]];
      if (r < 0) {
        r = static_cast<int>(used.positions.size());
        used.positions.push_back(head.positions[f[k]]);
        used.uv.push_back(head.uv[f[k]]);
      }
      f[k] = r;
    }
  }
  used.triangles = std::move(head.triangles);
  FaceTowards(&used, cam.centre);
  out.parts.push_back(std::move(used));
  return out;
}

TexturedMesh NetworkViewMesh(const FrameSource& network, const ViewPose& view, const CameraLabel25& source_camera,
                             int size, double max_depth_step, RunContext& ctx) {
  AVATAR_CHECK_OPTION(size >= 8 && size <= 2048) << "network view mesh: size " << size << " is outside 8..2048";
  FrameRequest request;
  request.view = view;
  request.width = request.height = size;
  const RenderedFrame frame = network.Render(request, ctx);
  TexturedMesh mesh;
  mesh.name = "network " + std::to_string(static_cast<int>(std::lround(view.yaw)));
  mesh.texture = frame.bgr;
  if (frame.depth.empty() || frame.alpha.empty() || frame.bgr.empty()) return mesh;
  const morphable::PinholeCamera cam = morphable::PinholeCamera::FromLabel(render::CameraForView(view, source_camera));
  const compose::PixelRays rays(cam);
  const cv::Size grid(size, size);
  cv::Mat index(grid, CV_32SC1, cv::Scalar(-1));
  for (int y = 0; y < size; ++y) {
    for (int x = 0; x < size; ++x) {
      const float t = frame.depth.at<float>(y, x);
      if (frame.alpha.at<uchar>(y, x) < 128 || !std::isfinite(t) || t <= 0.0f) continue;
      const cv::Vec3d p = rays.Point(x, y, grid, t);
      index.at<int>(y, x) = static_cast<int>(mesh.positions.size());
      mesh.positions.emplace_back(static_cast<float>(p[0]), static_cast<float>(p[1]), static_cast<float>(p[2]));
      mesh.uv.emplace_back(static_cast<float>((x + 0.5) / size), static_cast<float>((y + 0.5) / size));
    }
  }
  const float step = static_cast<float>(max_depth_step * render::kCameraRadius);
  for (int y = 0; y + 1 < size; ++y) {
    for (int x = 0; x + 1 < size; ++x) {
      const cv::Point quad[2][3] = {{{x, y}, {x, y + 1}, {x + 1, y}}, {{x + 1, y}, {x, y + 1}, {x + 1, y + 1}}};
      for (const auto& tri : quad) {
        const int ia = index.at<int>(tri[0]), ib = index.at<int>(tri[1]), ic = index.at<int>(tri[2]);
        if (ia < 0 || ib < 0 || ic < 0) continue;
        const float da = frame.depth.at<float>(tri[0]), db = frame.depth.at<float>(tri[1]),
                    dc = frame.depth.at<float>(tri[2]);
        if (std::max({da, db, dc}) - std::min({da, db, dc}) > step) continue;
        mesh.triangles.emplace_back(ia, ib, ic);
      }
    }
  }
  FaceTowards(&mesh, cam.centre);
  return mesh;
}

HeadMesh AvatarHeadMesh(std::shared_ptr<const Session> session, const Avatar& avatar, const std::string& data_dir,
                        const HeadMeshOptions& options, RunContext& ctx) {
  AVATAR_CHECK_INPUT(session != nullptr && avatar.valid()) << "export mesh needs a session and a loaded avatar";
  AVATAR_CHECK_INPUT(avatar.HasPortraitAnalysis())
      << "this avatar file does not keep its portrait's analysis (it was saved before 2026-12-05): reconstruct the "
         "portrait again to export its mesh";
  const AvatarPortrait& kept = *avatar.state()->portrait;
  const SourceAnalysis analysis = AnalysisFromFit(kept.portrait, kept.fit, data_dir);
  const SessionFrameSource network(std::move(session), avatar, false, analysis.overlay);
  return BuildHeadMesh(analysis, network, options, ctx);
}

}  // namespace avatar
