// Synthetic multi-view heads (core/tools/synthetic_head.h) on inputs the tests make: a
// portrait rendered from the committed morphable model with a smooth pattern, inside a
// head-and-neck matte of patterned "hair".

#include <cmath>
#include <iostream>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "core/io/data_paths.h"
#include "core/morphable/morphable.h"
#include "core/morphable/rasterizer.h"
#include "core/tools/synthetic_head.h"
#include "core/render/camera.h"
#include "core/util/error.h"

namespace avatar {
namespace {

using morphable::CameraLabel;

const morphable::MorphableModel& Model() { return morphable::LoadDefaultModel(DataPaths::Resolve()); }

// The camera at `yaw` to the side and `pitch` above (the head tilted down by `pitch`).
CameraLabel Orbit(double yaw, double pitch) {
  render::ViewPose p;
  p.yaw = yaw;
  p.pitch = -pitch;
  return morphable::LabelFromTensor(render::LabelsFromCameras(
      {render::OrbitCam2World(p).unsqueeze(0), render::DefaultIntrinsics().unsqueeze(0)}));
}

// A smooth colour at a position in [0,1]^2 (low frequencies only, so resampling barely changes it).
cv::Vec3f Pattern(double u, double v) {
  return cv::Vec3f(static_cast<float>(0.25 + 0.5 * u), static_cast<float>(0.3 + 0.4 * v),
                   static_cast<float>(0.5 + 0.25 * std::sin(6.0 * u + 3.0 * v)));
}

struct Portrait {
  morphable::FitResult fit;
  cv::Mat bgr;    // CV_8UC3
  cv::Mat matte;  // CV_32FC1
};

// The model's mean face (alpha = beta = 0) seen from `camera`, over an elliptic head of hair
// and a neck reaching the bottom border.
Portrait MakePortrait(const CameraLabel& camera, int size) {
  const auto& m = Model();
  Portrait p;
  p.fit = morphable::FitFromLabel(m.ZeroAlpha(), m.ZeroBeta(), 1.0f, camera, cv::Size(size, size));
  morphable::Texture tex;
  tex.uv_image = cv::Mat(128, 128, CV_32FC3);
  for (int y = 0; y < 128; ++y) {
    for (int x = 0; x < 128; ++x) tex.uv_image.at<cv::Vec3f>(y, x) = Pattern((x + 0.5) / 128, 1.0 - (y + 0.5) / 128);
  }
  morphable::RenderOptions ro;
  ro.supersample = 1;
  const auto face = morphable::Render(m, {}, {}, 1.0f, tex, camera, cv::Size(size, size), ro);
  cv::Mat colour(size, size, CV_32FC3);
  cv::Mat hair(size, size, CV_8UC1, cv::Scalar(0));
  // Head: an ellipse around the face's bounding box, plus a neck.
  cv::Rect box = cv::boundingRect(face.mask > 0.5f);
  cv::ellipse(hair, cv::Point(box.x + box.width / 2, box.y + box.height / 2 - box.height / 8),
              cv::Size(static_cast<int>(box.width * 0.7), static_cast<int>(box.height * 0.75)), 0, 0, 360, cv::Scalar(255), cv::FILLED);
  cv::rectangle(hair, cv::Point(box.x + box.width / 4, box.y + box.height / 2),
                cv::Point(box.x + 3 * box.width / 4, size - 1), cv::Scalar(255), cv::FILLED);
  for (int y = 0; y < size; ++y) {
    for (int x = 0; x < size; ++x) {
      const cv::Vec3f h = Pattern(1.0 - (x + 0.5) / size, (y + 0.5) / size) * 0.8f;
      colour.at<cv::Vec3f>(y, x) = face.mask.at<float>(y, x) > 0.5f ? face.image.at<cv::Vec3f>(y, x) : h;
    }
  }
  cv::Mat person = (hair > 0) | (face.mask > 0.5f);
  person.convertTo(p.matte, CV_32FC1, 1.0 / 255.0);
  colour.convertTo(p.bgr, CV_8UC3, 255.0);
  return p;
}

// Colour of a render at image position (x, y) (pixel centres at +0.5), bilinear.
cv::Vec3f At(const cv::Mat& img, double x, double y) {
  cv::Mat patch;
  cv::getRectSubPix(img, cv::Size(1, 1), cv::Point2f(static_cast<float>(x - 0.5), static_cast<float>(y - 0.5)), patch);
  return patch.at<cv::Vec3f>(0, 0);
}

TEST(SyntheticHead, SourceCameraReproducesThePhotoAndTheMatte) {
  for (double yaw : {0.0, 20.0}) {
    const Portrait p = MakePortrait(Orbit(yaw, 6.0), 128);
    const SyntheticHead head = BuildSyntheticHead(Model(), p.fit, p.bgr, p.matte, cv::Mat());
    const SyntheticView view = RenderSyntheticView(head, head.vertices, p.fit.camera, cv::Size(128, 128), 2);
    cv::Mat photo;
    p.bgr.convertTo(photo, CV_32FC3, 1.0 / 255.0);
    double se = 0.0;
    int n = 0, inter = 0, uni = 0;
    for (int y = 0; y < 128; ++y) {
      for (int x = 0; x < 128; ++x) {
        const bool a = view.alpha.at<float>(y, x) > 0.5f, b = p.matte.at<float>(y, x) > 0.5f;
        inter += a && b;
        uni += a || b;
        if (!b) continue;
        const cv::Vec3f d = view.image.at<cv::Vec3f>(y, x) - photo.at<cv::Vec3f>(y, x);
        se += d.dot(d) / 3.0;
        ++n;
      }
    }
    ASSERT_GT(n, 2000);
    const double psnr = 10.0 * std::log10(1.0 / std::max(se / n, 1e-12));
    const double iou = static_cast<double>(inter) / uni;
    std::cout << "[synthetic head] yaw " << yaw << ": source-camera PSNR " << psnr << " dB inside the matte, IoU "
              << iou << ", " << head.mirrored_texels << " mirrored texels\n";
    EXPECT_GE(psnr, 30.0);
    EXPECT_GE(iou, 0.95);
  }
}

TEST(SyntheticHead, SurfacePointsSeenInTwoViewsHaveOneColour) {
  // Tolerance: mean absolute colour difference <= 0.02 and 95th percentile <= 0.06 (colours in
  // [0,1]) over the head's vertices visible in both views; the renders resample the texture at
  // different positions, which with this smooth texture changes colours by ~1e-2 at most.
  const Portrait p = MakePortrait(Orbit(5.0, 4.0), 128);
  const SyntheticHead head = BuildSyntheticHead(Model(), p.fit, p.bgr, p.matte, cv::Mat());
  const CameraLabel a_cam = Orbit(-15.0, 8.0), b_cam = Orbit(25.0, -10.0);
  const SyntheticView a = RenderSyntheticView(head, head.vertices, a_cam, cv::Size(128, 128), 2);
  const SyntheticView b = RenderSyntheticView(head, head.vertices, b_cam, cv::Size(128, 128), 2);
  const auto ca = morphable::PinholeCamera::FromLabel(a_cam), cb = morphable::PinholeCamera::FromLabel(b_cam);
  std::vector<char> used(head.vertices.size(), 0);
  for (const auto& t : head.triangles) used[t[0]] = used[t[1]] = used[t[2]] = 1;
  std::vector<double> diffs;
  auto visible = [](const morphable::PinholeCamera& c, const SyntheticView& v, const cv::Vec3d& w, cv::Point2d* px) {
    const cv::Vec3d q = c.ToCamera(w);
    *px = c.ToPixel(q, v.depth.size());
    const int x = static_cast<int>(std::floor(px->x)), y = static_cast<int>(std::floor(px->y));
    if (x < 1 || y < 1 || x >= v.depth.cols - 1 || y >= v.depth.rows - 1) return false;
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) {
        if (v.alpha.at<float>(y + dy, x + dx) < 0.99f) return false;  // away from edges
      }
    }
    const float z = v.depth.at<float>(y, x);
    return z > 0 && std::abs(z - q[2]) < 0.004 * q[2];
  };
  for (size_t i = 0; i < head.vertices.size(); ++i) {
    if (!used[i]) continue;
    const cv::Vec3d w(head.vertices[i].x, head.vertices[i].y, head.vertices[i].z);
    cv::Point2d pa, pb;
    if (!visible(ca, a, w, &pa) || !visible(cb, b, w, &pb)) continue;
    diffs.push_back(cv::norm(At(a.image, pa.x, pa.y) - At(b.image, pb.x, pb.y), cv::NORM_L1) / 3.0);
  }
  ASSERT_GT(diffs.size(), 1500u) << "too few points visible in both views";
  double mean = 0.0;
  for (double d : diffs) mean += d;
  mean /= diffs.size();
  std::sort(diffs.begin(), diffs.end());
  const double p95 = diffs[diffs.size() * 95 / 100];
  std::cout << "[synthetic head] " << diffs.size() << " points seen in both views: mean |colour difference| " << mean
            << ", 95th percentile " << p95 << "\n";
  EXPECT_LE(mean, 0.02);
  EXPECT_LE(p95, 0.06);
}

TEST(SyntheticHead, ExpressionMovesTheFaceAndFadesOutside) {
  const auto& m = Model();
  const Portrait p = MakePortrait(Orbit(0.0, 0.0), 128);
  const SyntheticHead head = BuildSyntheticHead(m, p.fit, p.bgr, p.matte, cv::Mat());
  const morphable::Beta jaw = m.ExpressionFromControls({{"jawOpen", 1.0f}});
  const std::vector<cv::Point3f> moved = HeadVertices(m, p.fit, head, jaw);
  const std::vector<cv::Point3f> same = HeadVertices(m, p.fit, head, p.fit.beta);
  double max_face = 0.0, max_far = 0.0, max_same = 0.0;
  for (size_t v = 0; v < moved.size(); ++v) {
    const double d = cv::norm(moved[v] - head.vertices[v]);
    max_same = std::max(max_same, static_cast<double>(cv::norm(same[v] - head.vertices[v])));
    if (head.face_weight[v] >= 0.999f) max_face = std::max(max_face, d);
    if (head.face_weight[v] < 1e-3f) max_far = std::max(max_far, d);
  }
  EXPECT_EQ(max_same, 0.0) << "the photo's own expression must leave the head unchanged";
  EXPECT_GT(max_face, 0.005) << "jawOpen must move the face (world units)";
  EXPECT_LT(max_far, 1e-4) << "far from the face the expression must fade out";
}

TEST(SyntheticHead, RasterizerAndRenderCameraPutAShapeOnTheSamePixels) {
  // A box (12 triangles) rendered through the synthetic head renderer (the morphable
  // rasterizer) at a label, against the same box projected with core/render's camera
  // (CamerasFromLabels + ProjectPoints) and filled with the same coverage rule.
  SyntheticHead box;
  const cv::Vec3f c(0.05f, -0.02f, 0.1f);
  const float h = 0.15f;
  for (int k = 0; k < 8; ++k) {
    box.vertices.emplace_back(c[0] + ((k & 1) ? h : -h), c[1] + ((k & 2) ? h : -h), c[2] + ((k & 4) ? h : -h));
    box.uv.emplace_back(0.5f, 0.5f);
  }
  const int faces[6][4] = {{0, 1, 3, 2}, {4, 6, 7, 5}, {0, 4, 5, 1}, {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 5, 7, 3}};
  for (const auto& f : faces) {
    box.triangles.emplace_back(f[0], f[1], f[2]);
    box.triangles.emplace_back(f[0], f[2], f[3]);
  }
  box.colour = cv::Mat(1, 1, CV_32FC3, cv::Scalar(1, 1, 1));
  box.aux = cv::Mat(1, 1, CV_32FC2, cv::Scalar(0, 1));
  for (const auto& [yaw, pitch] : std::vector<std::pair<double, double>>{{0, 0}, {30, 12}, {-25, -18}}) {
    const CameraLabel label = Orbit(yaw, pitch);
    const cv::Size size(96, 96);
    const SyntheticView view = RenderSyntheticView(box, box.vertices, label, size, 1);
    const render::Cameras cams = render::CamerasFromLabels(morphable::LabelTensor(label).to(torch::kFloat64));
    torch::Tensor pts = torch::zeros({1, 8, 3}, torch::kFloat64);
    for (int k = 0; k < 8; ++k) {
      pts[0][k][0] = box.vertices[k].x;
      pts[0][k][1] = box.vertices[k].y;
      pts[0][k][2] = box.vertices[k].z;
    }
    const torch::Tensor uvz = render::ProjectPoints(pts, cams);
    std::vector<morphable::ScreenVertex> sv(8);
    const auto pin = morphable::PinholeCamera::FromLabel(label);
    for (int k = 0; k < 8; ++k) {
      sv[k] = {uvz[0][k][0].item<double>() * size.width, uvz[0][k][1].item<double>() * size.height,
               uvz[0][k][2].item<double>()};
      const cv::Point2d ours =
          pin.ToPixel(pin.ToCamera(cv::Vec3d(box.vertices[k].x, box.vertices[k].y, box.vertices[k].z)), size);
      EXPECT_NEAR(ours.x, sv[k].x, 1e-3) << "yaw " << yaw << " vertex " << k;
      EXPECT_NEAR(ours.y, sv[k].y, 1e-3) << "yaw " << yaw << " vertex " << k;
    }
    cv::Mat reference(size, CV_8UC1, cv::Scalar(0));
    for (const auto& t : box.triangles) {
      morphable::ForEachCoveredPixel(sv[t[0]], sv[t[1]], sv[t[2]], size,
                                     [&](int x, int y, double, double, double) { reference.at<uchar>(y, x) = 255; });
    }
    const cv::Mat ours = view.alpha > 0.5f;
    const int covered = cv::countNonZero(reference);
    ASSERT_GT(covered, 300);
    cv::Mat diff;
    cv::bitwise_xor(ours, reference, diff);
    // Only pixels whose centre lies within float rounding of an edge may differ.
    EXPECT_LE(cv::countNonZero(diff), 2) << "yaw " << yaw << ": " << covered << " covered pixels";
  }
}

TEST(SyntheticHead, MirroredLabelRendersTheMirroredHeadAsAFlippedImage) {
  const Portrait p = MakePortrait(Orbit(12.0, 5.0), 96);
  const SyntheticHead head = BuildSyntheticHead(Model(), p.fit, p.bgr, p.matte, cv::Mat());
  const CameraLabel cam = Orbit(20.0, -6.0);
  const SyntheticView view = RenderSyntheticView(head, head.vertices, cam, cv::Size(96, 96), 2);
  std::vector<cv::Point3f> mirrored = head.vertices;
  for (auto& v : mirrored) v.x = -v.x;
  const SyntheticView mv = RenderSyntheticView(head, mirrored, MirroredLabel(cam), cv::Size(96, 96), 2);
  cv::Mat flipped;
  cv::flip(view.image, flipped, 1);
  const double err = cv::norm(flipped, mv.image, cv::NORM_L1) / (96.0 * 96.0 * 3.0);
  EXPECT_LT(err, 0.01) << "mean abs difference between the flipped render and the mirrored head's";
  const cv::Vec2d yp = LabelYawPitch(cam), myp = LabelYawPitch(MirroredLabel(cam));
  EXPECT_NEAR(yp[0], 20.0, 1e-3);
  EXPECT_NEAR(myp[0], -20.0, 1e-3);
  EXPECT_NEAR(myp[1], yp[1], 1e-3);
}

TEST(SyntheticHead, BadInputsAreRefused) {
  const Portrait p = MakePortrait(Orbit(0.0, 0.0), 64);
  EXPECT_THROW(BuildSyntheticHead(Model(), p.fit, p.bgr, cv::Mat::zeros(64, 64, CV_32FC1), cv::Mat()),
               InvalidInput);
  EXPECT_THROW(BuildSyntheticHead(Model(), p.fit, p.bgr, cv::Mat::ones(32, 32, CV_32FC1), cv::Mat()), InvalidInput);
  // A camera at the frontal position looking away from the face (+z).
  const CameraLabel away_label =
      morphable::LabelFromPose(cv::Matx33d(-1, 0, 0, 0, -1, 0, 0, 0, 1), cv::Vec3d(0.0, 0.0, 2.7));
  const morphable::FitResult away =
      morphable::FitFromLabel(Model().ZeroAlpha(), Model().ZeroBeta(), 1.0f, away_label, cv::Size(64, 64));
  EXPECT_THROW(BuildSyntheticHead(Model(), away, p.bgr, p.matte, cv::Mat()), InvalidInput);
}

}  // namespace
}  // namespace avatar
