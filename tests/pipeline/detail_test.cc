// The source-guided detail path on the packaged sample portrait (real face analysis and fit):
//  - at the source camera and expression the warp gives the photo back (it is a lookup of the
//    photo at the points it saw): PSNR against the aligned crop inside the valid mask;
//  - the valid region shrinks on the far side when the head turns, and the composite is the
//    base frame outside the face;
//  - hard cases: yaw 60, an expression change (the changed eyes and mouth left to the base frame,
//    a closed-eye source driven to eyes wide), tiny and large
//    outputs: outputs finite, in range, masks consistent; bad options and inputs are refused.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <limits>
#include <optional>

#include <opencv2/imgproc.hpp>

#include "core/compose/depth_detail.h"
#include "core/compose/edge_matte.h"
#include "core/compose/face_detail.h"
#include "core/compose/upscaler.h"
#include "core/face/face_geometry.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/model/fusion_net.h"
#include "core/pipeline/detail_source.h"
#include "core/pipeline/fusion_input.h"
#include "core/pipeline/live.h"
#include "core/pipeline/head_mesh.h"
#include "core/render/view_pose.h"
#include "core/pipeline/morphable_expression_source.h"
#include "core/pipeline/morphable_preview.h"
#include "core/model/checkpoint.h"
#include "core/pipeline/avatar_state.h"
#include "core/pipeline/session.h"
#include "core/pipeline/source_analysis.h"
#include "core/pipeline/studio_backend.h"
#include "core/util/error.h"
#include "common/sample_analysis.h"
#include "common/temp_dir.h"

namespace avatar {
namespace {

class Detail : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { analysis_ = &testing::SampleAnalysis(); }
  static std::shared_ptr<const FrameSource> Base() {
    return std::make_shared<MorphablePreviewSource>(*analysis_->model, analysis_->morphable_fit, analysis_->texture);
  }
  static double ValidFraction(const compose::FaceWarp& w) {
    const int face = cv::countNonZero(w.face);
    return face == 0 ? 0.0 : static_cast<double>(cv::countNonZero(w.valid)) / face;
  }
  static void ExpectSane(const compose::FaceWarp& w, cv::Size size) {
    ASSERT_EQ(w.bgr.size(), size);
    ASSERT_EQ(w.weight.type(), CV_32FC1);
    double lo = 0, hi = 0;
    cv::minMaxLoc(w.weight, &lo, &hi);
    EXPECT_GE(lo, 0.0);
    EXPECT_LE(hi, 1.0);
    EXPECT_TRUE(cv::checkRange(w.weight));
    // Weight only where valid, valid only where the face covers.
    EXPECT_EQ(cv::countNonZero((w.weight > 0) & (w.valid == 0)), 0);
    EXPECT_EQ(cv::countNonZero((w.valid != 0) & (w.face == 0)), 0);
  }
  static const SourceAnalysis* analysis_;
};
const SourceAnalysis* Detail::analysis_ = nullptr;

TEST_F(Detail, SourceViewGivesThePhotoBack) {
  const DetailFrameSource source(Base(), *analysis_);
  FrameRequest request;
  request.view = source.SourcePose();
  request.width = request.height = 512;
  const compose::FaceWarp w = source.Warp(request);
  ExpectSane(w, cv::Size(512, 512));
  // The photo saw (nearly) all of the face from its own camera.
  EXPECT_GT(ValidFraction(w), 0.9);
  const double psnr = cv::PSNR(w.bgr, analysis_->portrait.image_unmatted, 255.0);  // whole image
  cv::Mat a, b;
  w.bgr.copyTo(a, w.valid);
  analysis_->portrait.image_unmatted.copyTo(b, w.valid);
  const double valid_psnr = cv::PSNR(a, b, 255.0);
  std::cout << "[detail] source view: valid " << ValidFraction(w) << " of the face, PSNR in the valid mask "
            << valid_psnr << " dB (whole image " << psnr << " dB)\n";
  // A bilinear lookup at the pixel's own position: only rounding and the mesh's edge pixels differ.
  EXPECT_GT(valid_psnr, 35.0);
}

// A base source that records every request it renders (what the detail path asked the network).
class RecordingSource : public FrameSource {
 public:
  explicit RecordingSource(std::shared_ptr<const FrameSource> base) : base_(std::move(base)) {}
  std::string Label() const override { return base_->Label(); }
  bool SupportsPose() const override { return true; }
  std::vector<std::string> ExpressionControls() const override { return base_->ExpressionControls(); }
  ViewPose SourcePose() const override { return base_->SourcePose(); }
  RenderedFrame Render(const FrameRequest& request, RunContext& ctx) const override {
    requests.push_back(request);
    return base_->Render(request, ctx);
  }
  mutable std::vector<FrameRequest> requests;

 private:
  std::shared_ptr<const FrameSource> base_;
};

// What an expression change recomputes (issue 34's scheduler): after a full frame, a new
// expression at the same view is composed over the kept base frame without calling the base
// source (the network); it is the full frame of that expression except where the base's own
// expression shows; another view or size has nothing kept.
TEST_F(Detail, AnExpressionChangeAtTheSameViewSkipsTheBase) {
  const auto counting = std::make_shared<RecordingSource>(Base());
  const DetailFrameSource source(counting, *analysis_);
  const size_t baked = counting->requests.size();  // the source view's depth, once
  RunContext ctx;
  FrameRequest neutral;
  neutral.view = source.SourcePose();
  neutral.view.yaw += 10.0;
  neutral.width = neutral.height = 256;
  EXPECT_FALSE(source.RenderQuick(neutral, ctx).has_value());  // nothing kept yet
  source.Render(neutral, ctx);
  EXPECT_EQ(counting->requests.size(), baked + 1);
  FrameRequest jaw = neutral;
  jaw.expression.controls["jawOpen"] = 0.9f;
  const std::optional<RenderedFrame> quick = source.RenderQuick(jaw, ctx);
  ASSERT_TRUE(quick.has_value());
  EXPECT_EQ(quick->stages, "face update");
  EXPECT_EQ(counting->requests.size(), baked + 1);  // no base render
  EXPECT_EQ(source.counts().quick, 1);
  const RenderedFrame full = source.Render(jaw, ctx);
  EXPECT_EQ(counting->requests.size(), baked + 2);
  EXPECT_EQ(source.counts().base_renders, 2);
  EXPECT_TRUE(full.stages.empty());
  ASSERT_EQ(quick->bgr.size(), full.bgr.size());
  cv::Mat diff, grey;
  cv::absdiff(quick->bgr, full.bgr, diff);
  cv::cvtColor(diff, grey, cv::COLOR_BGR2GRAY);
  const double same = 1.0 - cv::countNonZero(grey > 8) / static_cast<double>(grey.total());
  std::cout << "[detail] quick frame of jawOpen 0.9 over the neutral base frame: " << same
            << " of the pixels within 8 grey levels of the full frame\n";
  EXPECT_GT(same, 0.95);
  // Another view, another size: nothing kept for them.
  FrameRequest turned = jaw;
  turned.view.yaw += 5.0;
  EXPECT_FALSE(source.RenderQuick(turned, ctx).has_value());
  FrameRequest bigger = jaw;
  bigger.width = bigger.height = 320;
  EXPECT_FALSE(source.RenderQuick(bigger, ctx).has_value());
  // A 512 viewport: the quick frame is composed at 256 and upscaled, so it is softer but the same
  // picture.
  FrameRequest large = neutral;
  large.width = large.height = 512;
  source.Render(large, ctx);
  FrameRequest large_jaw = large;
  large_jaw.expression.controls["jawOpen"] = 0.9f;
  const std::optional<RenderedFrame> large_quick = source.RenderQuick(large_jaw, ctx);
  ASSERT_TRUE(large_quick.has_value());
  ASSERT_EQ(large_quick->bgr.size(), cv::Size(512, 512));
  ASSERT_EQ(large_quick->alpha.size(), cv::Size(512, 512));
  const RenderedFrame large_full = source.Render(large_jaw, ctx);
  cv::absdiff(large_quick->bgr, large_full.bgr, diff);
  cv::cvtColor(diff, grey, cv::COLOR_BGR2GRAY);
  const double large_same = 1.0 - cv::countNonZero(grey > 16) / static_cast<double>(grey.total());
  std::cout << "[detail] the 512 quick frame (composed at 256): " << large_same
            << " of the pixels within 16 grey levels of the full frame\n";
  EXPECT_GT(large_same, 0.9);
}

TEST_F(Detail, TurningShrinksTheVisiblePartAndKeepsTheBaseOutsideTheFace) {
  DetailOptions face_only;
  face_only.mode = "face";
  const DetailFrameSource source(Base(), *analysis_, face_only);
  FrameRequest request;
  request.width = request.height = 256;
  request.view = source.SourcePose();
  const double front = ValidFraction(source.Warp(request));
  request.view.yaw += 40.0;
  const compose::FaceWarp turned = source.Warp(request);
  ExpectSane(turned, cv::Size(256, 256));
  EXPECT_LT(ValidFraction(turned), front);
  EXPECT_GT(ValidFraction(turned), 0.3);
  RunContext ctx;
  const RenderedFrame base = source.base().Render(request, ctx);
  const RenderedFrame frame = source.Render(request, ctx);
  ASSERT_EQ(frame.bgr.size(), base.bgr.size());
  cv::Mat diff;
  cv::absdiff(frame.bgr, base.bgr, diff);
  cv::cvtColor(diff, diff, cv::COLOR_BGR2GRAY);
  // Outside the face mesh nothing changes; on the face outside the photo's weight the fill shows
  // the fit's texture, which is what this base (the textured mesh, antialiased) shows too.
  EXPECT_EQ(cv::countNonZero(diff & (turned.weight == 0) & (turned.face == 0)), 0)
      << "pixels changed outside the face and the warp's weight";
  const cv::Mat fill_only = (turned.weight == 0) & (turned.face != 0);
  const double fill_diff = cv::countNonZero(fill_only) > 0 ? cv::mean(diff, fill_only)[0] : 0.0;
  std::cout << "[detail] the fill against the textured base: mean grey difference " << fill_diff << "\n";
  EXPECT_LT(fill_diff, 4.0);
  EXPECT_GT(cv::countNonZero(diff), 0) << "the photo's detail changed nothing";
  EXPECT_EQ(source.Label(), source.base().Label() + DetailLabel("face"));
}

TEST_F(Detail, HardCasesStayFiniteAndInRange) {
  const DetailFrameSource source(Base(), *analysis_);
  FrameRequest request;
  request.view = source.SourcePose();
  for (const int size : {16, 64, 1024}) {
    request.width = request.height = size;
    ExpectSane(source.Warp(request), cv::Size(size, size));
  }
  request.width = request.height = 128;
  request.view.yaw += 60.0;
  const compose::FaceWarp far = source.Warp(request);
  ExpectSane(far, cv::Size(128, 128));
  // An expression change: the eyes and the mouth that change are left to the base frame.
  request.view = source.SourcePose();
  const compose::FaceWarp same = source.Warp(request);
  EXPECT_EQ(cv::countNonZero(same.changed), 0) << "the source expression changes nothing";
  EXPECT_GT(ValidFraction(same), 0.8);
  request.expression.controls["jawOpen"] = 0.9f;
  request.expression.controls["eyesWide"] = 1.0f;
  const compose::FaceWarp changed = source.Warp(request);
  ExpectSane(changed, cv::Size(128, 128));
  EXPECT_GT(cv::countNonZero(changed.changed), 0);
  EXPECT_EQ(cv::countNonZero(changed.valid & changed.changed), 0) << "the photo drew a changed eye or mouth";
  EXPECT_LT(ValidFraction(changed), ValidFraction(same));
  // Mode network: the whole mouth, lips included, is left to the base frame.
  DetailOptions network_mouth;
  network_mouth.face.changed_eye_mouth = "network";
  const DetailFrameSource whole(Base(), *analysis_, network_mouth);
  const compose::FaceWarp lips_too = whole.Warp(request);
  ExpectSane(lips_too, cv::Size(128, 128));
  EXPECT_GT(cv::countNonZero(lips_too.changed), cv::countNonZero(changed.changed));
  EXPECT_LT(ValidFraction(lips_too), ValidFraction(changed));
}

// Which region changed follows the expression: jawOpen changes the mouth only, a blink one eye
// only (the changed pixels lie below / above the face's middle), and the frame shows the base
// frame exactly there, whatever the photo's layers (face warp, depth warp, textured fill) hold.
TEST_F(Detail, ChangedEyesAndMouthComeFromTheBaseFrame) {
  const DetailFrameSource source(Base(), *analysis_);
  FrameRequest request;
  request.view = source.SourcePose();
  request.width = request.height = 192;
  const compose::FaceWarp neutral = source.Warp(request);
  const cv::Rect face = cv::boundingRect(neutral.face);
  ASSERT_GT(face.area(), 0);
  const int middle = face.y + face.height / 2;
  // The contour motions each control causes (fractions of the eye distance), for the record.
  const compose::FaceDetail detail(*analysis_->model, analysis_->morphable_fit, analysis_->portrait.image_unmatted,
                                   analysis_->portrait.matte, analysis_->portrait.eye_mouth_mask);
  for (const std::string control : {"jawOpen", "eyesWide", "blinkLeft", "smile", "browRaise"}) {
    Expression e;
    e.controls = {{control, 1.0f}};
    const morphable::Beta beta = ExpressionBeta(*analysis_->model, analysis_->morphable_fit.beta, e);
    const std::vector<cv::Point3f> world = morphable::WorldVertices(*analysis_->model, analysis_->morphable_fit, &beta);
    std::cout << "[detail] " << control << " 1.0 moves the right eye by "
              << detail.EyeMouthMotion(world, face::mesh_index::RightEye()) << ", the left eye by "
              << detail.EyeMouthMotion(world, face::mesh_index::LeftEye()) << ", the mouth by "
              << detail.EyeMouthMotion(world, face::mesh_index::LipsOuter()) << " eye distances\n";
  }
  RunContext ctx;
  for (const std::string control : {"jawOpen", "blinkLeft", "blinkRight"}) {
    SCOPED_TRACE(control);
    request.expression.controls = {{control, 1.0f}};
    const DetailLayers layers = source.RenderLayers(request, ctx);
    const compose::FaceWarp w = source.Warp(request);
    const int upper = cv::countNonZero(w.changed.rowRange(0, middle));
    const int lower = cv::countNonZero(w.changed.rowRange(middle, w.changed.rows));
    if (control == "jawOpen") {
      EXPECT_GT(lower, 0);
      EXPECT_EQ(upper, 0) << "jawOpen changed an eye";
    } else {
      EXPECT_GT(upper, 0);
      EXPECT_EQ(lower, 0) << control << " changed the mouth";
    }
    cv::Mat diff;
    cv::absdiff(layers.frame.bgr, layers.network, diff);
    cv::cvtColor(diff, diff, cv::COLOR_BGR2GRAY);
    // The opened mouth's interior is painted (AnOpenedMouthShowsADarkInterior), not the photo's.
    cv::Mat drawn = diff & w.changed;
    if (!w.cavity.empty()) {
      cv::Mat near_cavity;
      cv::dilate(w.cavity, near_cavity, cv::Mat::ones(3, 3, CV_8UC1));
      drawn.setTo(0, near_cavity);
    }
    EXPECT_EQ(cv::countNonZero(drawn), 0) << "a layer of the photo drew a changed eye or mouth";
    EXPECT_TRUE(cv::checkRange(layers.frame.bgr));
  }
  // One blink changes one eye: the two eyes lie on either side of the face's centre column.
  request.expression.controls = {{"blinkLeft", 1.0f}};
  const compose::FaceWarp blink = source.Warp(request);
  const int centre = face.x + face.width / 2;
  const int left = cv::countNonZero(blink.changed.colRange(0, centre));
  const int right = cv::countNonZero(blink.changed.colRange(centre, blink.changed.cols));
  EXPECT_TRUE((left == 0) != (right == 0)) << "left " << left << ", right " << right;
}

// A source whose fit has closed eyes (a blink) driven to eyes wide open: the eyes are the base
// frame's, the rest of the face still the photo's; outputs finite and in range.
TEST_F(Detail, ClosedEyeSourceWithEyesWideTarget) {
  SourceAnalysis closed = *analysis_;
  Expression blink;
  blink.controls = {{"blinkLeft", 1.0f}, {"blinkRight", 1.0f}};
  closed.morphable_fit.beta = ExpressionBeta(*closed.model, analysis_->morphable_fit.beta, blink);
  const DetailFrameSource source(Base(), closed);
  FrameRequest request;
  request.view = source.SourcePose();
  request.width = request.height = 128;
  request.expression.coefficients_absolute = true;
  request.expression.coefficients = analysis_->morphable_fit.beta;
  request.expression.controls = {{"eyesWide", 1.0f}};
  const compose::FaceWarp w = source.Warp(request);
  ExpectSane(w, cv::Size(128, 128));
  EXPECT_GT(cv::countNonZero(w.changed), 0);
  EXPECT_GT(ValidFraction(w), 0.5) << "the rest of the face should still come from the photo";
  RunContext ctx;
  const DetailLayers layers = source.RenderLayers(request, ctx);
  EXPECT_TRUE(cv::checkRange(layers.frame.bgr) && cv::checkRange(layers.frame.alpha));
  cv::Mat diff;
  cv::absdiff(layers.frame.bgr, layers.network, diff);
  cv::cvtColor(diff, diff, cv::COLOR_BGR2GRAY);
  EXPECT_EQ(cv::countNonZero(diff & w.changed), 0);
}

// A photo whose eyes are closed (its landmarks' lids shut) while the fit's mesh keeps them open
// (a blink the fit did not register): at the source expression the mesh's open eyes are changed
// regions (the photo has no open eye to show); with the real (open) landmarks nothing is.
TEST_F(Detail, ClosedEyesOfThePhotoAreChangedWhereTheTargetsEyesAreOpen) {
  const auto& lm = analysis_->portrait.landmarks.points;
  ASSERT_EQ(lm.size(), analysis_->model->topology().uv.size());
  const compose::FaceDetail open(*analysis_->model, analysis_->morphable_fit, analysis_->portrait.image_unmatted,
                                 analysis_->portrait.matte, analysis_->portrait.eye_mouth_mask, {}, lm);
  EXPECT_FALSE(open.PhotoEyeClosed(0));
  EXPECT_FALSE(open.PhotoEyeClosed(1));
  std::vector<cv::Point3f> shut = lm;
  shut[159] = shut[145];  // the subject's right upper lid on the lower one
  const compose::FaceDetail closed(*analysis_->model, analysis_->morphable_fit, analysis_->portrait.image_unmatted,
                                   analysis_->portrait.matte, analysis_->portrait.eye_mouth_mask, {}, shut);
  EXPECT_TRUE(closed.PhotoEyeClosed(0));
  EXPECT_FALSE(closed.PhotoEyeClosed(1));
  const cv::Size size(128, 128);
  const compose::FaceWarp at_open = open.Warp(analysis_->morphable_fit.camera, analysis_->morphable_fit.beta, size);
  const compose::FaceWarp at_closed = closed.Warp(analysis_->morphable_fit.camera, analysis_->morphable_fit.beta, size);
  ExpectSane(at_closed, size);
  EXPECT_EQ(cv::countNonZero(at_open.changed), 0);
  const cv::Rect face = cv::boundingRect(at_closed.face);
  const int changed = cv::countNonZero(at_closed.changed);
  EXPECT_GT(changed, 0);
  EXPECT_EQ(cv::countNonZero(at_closed.changed.rowRange(face.y + face.height / 2, size.height)), 0) << "not an eye";
  EXPECT_EQ(cv::countNonZero(at_closed.valid & at_closed.changed), 0);
  compose::FaceDetailOptions bad;
  bad.closed_eye_ratio = 1.5;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
}

// The depth proxy (mode head): at the photo's own view, lifting each opaque pixel with the
// base's depth and projecting it back into the photo gives the photo back.
TEST_F(Detail, DepthWarpAtTheSourceViewGivesThePhotoBack) {
  const DetailFrameSource source(Base(), *analysis_);
  ASSERT_TRUE(source.HasDepthProxy());
  FrameRequest request;
  request.view = source.SourcePose();
  request.width = request.height = 256;
  RunContext ctx;
  const RenderedFrame base = source.base().Render(request, ctx);
  const compose::FaceWarp w = source.DepthWarp(request, base);
  ExpectSane(w, cv::Size(256, 256));
  const double opaque = cv::countNonZero(base.alpha >= 128);
  ASSERT_GT(opaque, 0);
  const double valid = cv::countNonZero(w.valid) / opaque;
  cv::Mat photo, a, b;
  cv::resize(analysis_->portrait.image_unmatted, photo, cv::Size(256, 256), 0, 0, cv::INTER_AREA);
  w.bgr.copyTo(a, w.valid);
  photo.copyTo(b, w.valid);
  const double psnr = cv::PSNR(a, b, 255.0);
  std::cout << "[detail] depth warp at the source view: valid " << valid << " of the opaque pixels, PSNR " << psnr
            << " dB\n";
  EXPECT_GT(valid, 0.8);
  EXPECT_GT(psnr, 28.0);  // a lookup at the pixel's own position (512 crop sampled bilinearly vs area-resized)
  // Turned by 60 degrees: finite, in range, and less of the head was seen by the photo.
  request.view.yaw += 60.0;
  const RenderedFrame turned = source.base().Render(request, ctx);
  const compose::FaceWarp far = source.DepthWarp(request, turned);
  ExpectSane(far, cv::Size(256, 256));
  const RenderedFrame frame = source.Render(request, ctx);
  EXPECT_TRUE(cv::checkRange(frame.bgr) && cv::checkRange(frame.alpha));
  EXPECT_NE(source.Label().find(DetailLabel("head")), std::string::npos);
}

// Normalised smoothing of a depth map with holes: a constant surface stays constant and its holes
// are filled; an empty map stays empty.
TEST_F(Detail, SmoothDepthFillsHolesOfAConstantSurfaceAndKeepsEmptyEmpty) {
  const float inf = std::numeric_limits<float>::infinity();
  cv::Mat d(64, 64, CV_32FC1, cv::Scalar(2.5f));
  d(cv::Rect(30, 30, 3, 3)).setTo(inf);
  d.at<float>(5, 50) = std::nanf("");
  const cv::Mat s = compose::SmoothDepth(d, 0.05);
  double lo = 0, hi = 0;
  cv::minMaxLoc(s, &lo, &hi);
  EXPECT_NEAR(lo, 2.5, 1e-4);
  EXPECT_NEAR(hi, 2.5, 1e-4);
  const cv::Mat empty = compose::SmoothDepth(cv::Mat(16, 16, CV_32FC1, cv::Scalar(inf)), 0.05);
  EXPECT_EQ(cv::countNonZero(empty < inf), 0);
  EXPECT_THROW(compose::SmoothDepth(cv::Mat(4, 4, CV_8UC1), 0.05), InvalidInput);
}

// Gap filling of a depth map: known values stay exactly, every gap (NaN included) gets a value,
// and a gap next to one value takes (nearly) that value; a map with nothing known stays empty.
TEST_F(Detail, FillGapsKeepsKnownValuesAndFillsEveryGapBetweenThem) {
  const float inf = std::numeric_limits<float>::infinity();
  cv::Mat d(48, 64, CV_32FC1, cv::Scalar(inf));
  d(cv::Rect(0, 0, 16, 48)).setTo(2.0f);   // a near strip on the left
  d(cv::Rect(56, 0, 8, 48)).setTo(3.0f);   // a far strip on the right
  d.at<float>(10, 30) = std::nanf("");
  const cv::Mat f = compose::FillGaps(d);  // the fill itself: util/push_pull_test.cc
  ASSERT_EQ(f.size(), d.size());
  EXPECT_TRUE(cv::checkRange(f)) << "every gap (the NaN too) has a value";
  EXPECT_EQ(f.at<float>(20, 5), 2.0f);
  EXPECT_EQ(f.at<float>(20, 60), 3.0f);
  EXPECT_LT(f.at<float>(20, 17), 2.25f) << "a gap beside the near strip";
  EXPECT_GT(f.at<float>(20, 54), 2.75f) << "a gap beside the far strip";
  const cv::Mat empty = compose::FillGaps(cv::Mat(8, 8, CV_32FC1, cv::Scalar(inf)));
  EXPECT_EQ(cv::countNonZero(empty < inf), 0);
  EXPECT_THROW(compose::FillGaps(cv::Mat(4, 4, CV_8UC1)), InvalidInput);
}

// The network's silhouette is not the person's: with a base that covers the face only (the
// morphable preview), the photo's person beyond it (hair, neck, shoulders under the matte) still
// comes back at the source view through the filled depth; without extend_to_matte only the base's
// opaque pixels do. Turned by 30 degrees the extended head stays finite and in range.
TEST_F(Detail, DepthWarpCoversThePersonBeyondTheBasesSilhouette) {
  const cv::Size size(192, 192);
  // The photo and matte the warps read: the portrait's with the outline cleaned (the default).
  const compose::EdgeMatte cleaned =
      compose::RefineEdgeMatte(analysis_->portrait.image_unmatted, analysis_->portrait.matte);
  cv::Mat matte, photo;
  cv::resize(cleaned.matte, matte, size, 0, 0, cv::INTER_AREA);
  cv::resize(cleaned.bgr, photo, size, 0, 0, cv::INTER_AREA);
  const cv::Mat person = matte >= 0.5f;
  RunContext ctx;
  for (const bool extend : {false, true}) {
    SCOPED_TRACE(extend);
    DetailOptions options;
    options.depth.extend_to_matte = extend;
    const DetailFrameSource source(Base(), *analysis_, options);
    ASSERT_TRUE(source.HasDepthProxy());
    FrameRequest request;
    request.view = source.SourcePose();
    request.width = size.width;
    request.height = size.height;
    const RenderedFrame base = source.base().Render(request, ctx);
    const compose::FaceWarp w = source.DepthWarp(request, base);
    ExpectSane(w, size);
    const cv::Mat beyond = person & (base.alpha < 128);
    ASSERT_GT(cv::countNonZero(beyond), size.area() / 10) << "the sample's person reaches beyond its face";
    const double covered = static_cast<double>(cv::countNonZero(w.valid & beyond)) / cv::countNonZero(beyond);
    std::cout << "[detail] extend_to_matte " << extend << ": " << covered
              << " of the person beyond the base's silhouette is the photo's\n";
    if (!extend) {
      EXPECT_EQ(cv::countNonZero(w.valid & (base.alpha < 128)), 0);
      continue;
    }
    EXPECT_GT(covered, 0.9);
    // The background of the photo is not the person (a pixel of slack: the test's matte is resampled).
    cv::Mat near_person;  // down to the outline's matte (DepthDetailOptions::outline_matte)
    cv::dilate(matte >= options.depth.outline_matte, near_person, cv::Mat::ones(3, 3, CV_8UC1));
    EXPECT_EQ(cv::countNonZero(w.valid & ~near_person), 0);
    cv::Mat a, b;
    w.bgr.copyTo(a, w.valid);
    photo.copyTo(b, w.valid);
    EXPECT_GT(cv::PSNR(a, b, 255.0), 28.0);
    // The whole frame at the source view is (nearly) the matted photo, its soft outline included.
    const RenderedFrame frame = source.Render(request, ctx);
    cv::Mat matted, matte3;
    cv::cvtColor(matte, matte3, cv::COLOR_GRAY2BGR);
    photo.convertTo(matted, CV_32FC3);
    matted = matted.mul(matte3);
    matted.convertTo(matted, CV_8UC3);
    const double psnr = cv::PSNR(frame.bgr, matted, 255.0);
    std::cout << "[detail] source view against the matted photo: " << psnr << " dB\n";
    EXPECT_GT(psnr, 32.0);  // 39.9 dB measured
    request.view.yaw += 30.0;
    const RenderedFrame turned = source.base().Render(request, ctx);
    ExpectSane(source.DepthWarp(request, turned), size);
  }
}

// jawOpen on a closed-mouth photo: the opening inside the target's inner lip line shows a dark
// interior of the photo's lip colour, not the base frame's closed mouth; the shade < 0 leaves it
// to the base frame.
TEST_F(Detail, AnOpenedMouthShowsADarkInterior) {
  const cv::Size size(256, 256);
  FrameRequest request;
  request.width = size.width;
  request.height = size.height;
  request.expression.controls = {{"jawOpen", 0.9f}};
  RunContext ctx;
  for (const double shade : {0.3, -1.0}) {
    SCOPED_TRACE(shade);
    DetailOptions options;
    options.face.mouth_cavity_shade = shade;
    const DetailFrameSource source(Base(), *analysis_, options);
    request.view = source.SourcePose();
    const compose::FaceWarp w = source.Warp(request);
    ExpectSane(w, size);
    const int cavity = w.cavity.empty() ? 0 : cv::countNonZero(w.cavity);
    if (shade < 0) {
      EXPECT_EQ(cavity, 0);
      continue;
    }
    std::cout << "[detail] jawOpen 0.9: the mouth's interior covers " << cavity << " pixels at 256\n";
    EXPECT_GT(cavity, 20);
    EXPECT_EQ(cv::countNonZero(w.cavity & ~w.changed), 0) << "the interior lies in the changed mouth";
    EXPECT_EQ(cv::countNonZero(w.cavity & w.valid), 0) << "no photo pixel shows the interior";
    const RenderedFrame frame = source.Render(request, ctx);
    const cv::Scalar inside = cv::mean(frame.bgr, w.cavity);
    cv::Mat skin;
    cv::resize(analysis_->portrait.image_unmatted, skin, size, 0, 0, cv::INTER_AREA);
    const cv::Scalar face = cv::mean(skin, w.face);
    for (int c = 0; c < 3; ++c) EXPECT_LT(inside[c], 0.5 * face[c]) << "channel " << c;
    EXPECT_TRUE(cv::checkRange(frame.bgr));
  }
  compose::FaceDetailOptions bad;
  bad.mouth_cavity_shade = 2.0;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
}

// A base without depth, or with nothing opaque at the photo's view (empty density), keeps the
// face mesh's warp only and says so; frames stay finite.
TEST_F(Detail, DegenerateProxyFallsBackToTheFaceWithAWarning) {
  class Stub : public FrameSource {
   public:
    Stub(std::shared_ptr<const FrameSource> base, bool with_depth) : base_(std::move(base)), with_depth_(with_depth) {}
    std::string Label() const override { return "stub"; }
    bool SupportsPose() const override { return true; }
    std::vector<std::string> ExpressionControls() const override { return base_->ExpressionControls(); }
    ViewPose SourcePose() const override { return base_->SourcePose(); }
    RenderedFrame Render(const FrameRequest& r, RunContext& ctx) const override {
      RenderedFrame f = base_->Render(r, ctx);
      if (with_depth_) {
        f.depth.setTo(std::numeric_limits<float>::infinity());
      } else {
        f.depth.release();
      }
      return f;
    }

   private:
    std::shared_ptr<const FrameSource> base_;
    bool with_depth_;
  };
  for (const bool with_depth : {false, true}) {
    const DetailFrameSource source(std::make_shared<Stub>(Base(), with_depth), *analysis_);
    EXPECT_FALSE(source.HasDepthProxy());
    ASSERT_EQ(source.Warnings().size(), 1u);
    EXPECT_NE(source.Warnings()[0].find("face only"), std::string::npos) << source.Warnings()[0];
    FrameRequest request;
    request.view = source.SourcePose();
    request.view.yaw += 30.0;
    request.width = request.height = 96;
    RunContext ctx;
    const RenderedFrame frame = source.Render(request, ctx);
    EXPECT_TRUE(cv::checkRange(frame.bgr) && cv::checkRange(frame.alpha));
  }
}

// Hard sources: a photo with its eyes closed driven to eyes wide open (the closed lids are
// stretched over the opened eyes' mesh), and a person whose matte touches the image border
// everywhere (a crop of a body that fills the frame): frames finite and in range, masks
// consistent.
TEST_F(Detail, ClosedEyeSourceAndAMatteTouchingTheBorderStayFiniteAndInRange) {
  SourceAnalysis closed = *analysis_;
  Expression blink;
  blink.controls["blinkLeft"] = 1.0f;
  blink.controls["blinkRight"] = 1.0f;
  closed.morphable_fit.beta = ExpressionBeta(*closed.model, closed.morphable_fit.beta, blink);
  SourceAnalysis border = *analysis_;
  border.portrait.matte = cv::Mat(border.portrait.matte.size(), CV_32FC1, cv::Scalar(1.0f));
  for (const SourceAnalysis* a : {&closed, &border}) {
    const DetailFrameSource source(Base(), *a);
    FrameRequest request;
    request.view = source.SourcePose();
    request.width = request.height = 128;
    request.expression.controls["eyesWide"] = 1.0f;
    for (const double yaw : {0.0, 35.0, -60.0}) {
      request.view.yaw = source.SourcePose().yaw + yaw;
      ExpectSane(source.Warp(request), cv::Size(128, 128));
      RunContext ctx;
      const RenderedFrame frame = source.Render(request, ctx);
      ASSERT_EQ(frame.bgr.size(), cv::Size(128, 128));
      EXPECT_TRUE(cv::checkRange(frame.bgr) && cv::checkRange(frame.alpha));
    }
  }
}

// The fusion net's input is the frame's own layers: RenderLayers().frame is Render()'s frame,
// and FusionInputBytes packs the composite, the network render and the masks in the net's order.
TEST_F(Detail, LayersAreTheFrameAndPackIntoTheFusionInput) {
  const DetailFrameSource source(Base(), *analysis_);
  FrameRequest request;
  request.view = source.SourcePose();
  request.view.yaw += 20.0;
  request.expression.controls["jawOpen"] = 0.6f;
  request.width = request.height = 96;
  RunContext ctx;
  const DetailLayers layers = source.RenderLayers(request, ctx);
  const RenderedFrame frame = source.Render(request, ctx);
  EXPECT_EQ(cv::norm(layers.frame.bgr, frame.bgr, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(layers.frame.alpha, frame.alpha, cv::NORM_INF), 0.0);
  const torch::Tensor bytes = FusionInputBytes(layers);
  ASSERT_EQ(bytes.sizes(), (std::vector<int64_t>{kFusionInputChannels, 96, 96}));
  EXPECT_TRUE(torch::equal(bytes.slice(0, 0, 3), RgbBytes(frame.bgr)));
  EXPECT_TRUE(torch::equal(bytes.slice(0, 3, 6), RgbBytes(layers.network)));
  EXPECT_TRUE(torch::equal(bytes.slice(0, 10, 11), MaskBytes(frame.alpha)));
  const torch::Tensor face = bytes[8] > 0, eye_mouth = bytes[9] > 0, face_weight = bytes[6] > 0;
  EXPECT_GT(face.sum().item<int64_t>(), 500);
  EXPECT_GT(eye_mouth.sum().item<int64_t>(), 20);                             // the mouth and eyes are in view
  EXPECT_EQ((eye_mouth & ~face).sum().item<int64_t>(), 0);                    // only on the face
  EXPECT_EQ((face_weight & ~face).sum().item<int64_t>(), 0);                  // the face warp only on the face
  const torch::Tensor x = FusionInputFromBytes(bytes.unsqueeze(0));
  EXPECT_GE(x.slice(1, 0, 6).min().item<float>(), -1.0f);
  EXPECT_LE(x.slice(1, 0, 6).max().item<float>(), 1.0f);
  EXPECT_GE(x.slice(1, 6).min().item<float>(), 0.0f);
  EXPECT_LE(x.slice(1, 6).max().item<float>(), 1.0f);
  // Round trip of the image bytes.
  EXPECT_EQ(cv::norm(BgrFromRgb(bytes.slice(0, 0, 3)), frame.bgr, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(BgrFromRgb(x[0].slice(0, 0, 3)), frame.bgr, cv::NORM_INF), 0.0);
  // The layers of a frame larger than the net's side, scaled down as the net reads them: every
  // channel is the area average of the full-size layer.
  const DetailLayers small = ScaledFusionLayers(layers, cv::Size(48, 40));
  const torch::Tensor small_bytes = FusionInputBytes(small);
  ASSERT_EQ(small_bytes.sizes(), (std::vector<int64_t>{kFusionInputChannels, 40, 48}));
  cv::Mat area;
  cv::resize(frame.bgr, area, cv::Size(48, 40), 0, 0, cv::INTER_AREA);
  EXPECT_TRUE(torch::equal(small_bytes.slice(0, 0, 3), RgbBytes(area)));
  cv::resize(layers.face_weight, area, cv::Size(48, 40), 0, 0, cv::INTER_AREA);
  EXPECT_TRUE(torch::equal(small_bytes.slice(0, 6, 7), MaskBytes(area)));
  cv::resize(frame.alpha, area, cv::Size(48, 40), 0, 0, cv::INTER_AREA);
  EXPECT_TRUE(torch::equal(small_bytes.slice(0, 10, 11), MaskBytes(area)));
  EXPECT_GT((small_bytes[8] > 0).sum().item<int64_t>(), 500 / 4);  // the face is still there
  EXPECT_THROW(ScaledFusionLayers(layers, cv::Size(0, 40)), InvalidInput);
  DetailLayers missing = layers;
  missing.network = cv::Mat();
  EXPECT_THROW(ScaledFusionLayers(missing, cv::Size(48, 40)), InvalidInput);
}

// A detail source with a fusion net: the frame is the net's output on the frame's own layers;
// above kFusionNetSide the net runs on the layers scaled down to it and its change, scaled up, is
// added to the full-size composite. An untrained net (residual head at zero) leaves every size
// exactly the composite; a net whose change is a constant per channel (red +0.2 = 25.5 grey
// levels, green 0, blue -0.2) gives the composite plus that change at 96 px and at 320 px (the
// scaled path).
TEST_F(Detail, TheFusionNetFinishesTheFrameAndLargeFramesGetItsChangeScaledUp) {
  testing::TempDir dir;
  torch::manual_seed(3);
  FusionNetOptions o;
  o.widths = {4, 8};
  FusionNetInfo info;
  info.step = 7;
  SaveFusionNet(dir / "zero.ckpt", FusionNet(o), info, false);
  FusionNetOptions everywhere = o;
  everywhere.keep_warped = false;  // the residual may act on every pixel
  FusionNet shift(everywhere);
  {
    torch::NoGradGuard no_grad;
    for (auto& p : shift->named_parameters()) {
      if (p.key() == "head.weight") p.value().zero_();
      if (p.key() == "head.bias") {
        // 2 tanh: red +0.2, green 0, blue -0.2 (the net's channels are RGB)
        p.value()[0].fill_(std::atanh(0.1));
        p.value()[1].fill_(0.0);
        p.value()[2].fill_(std::atanh(-0.1));
        p.value().slice(0, 3, 4).fill_(30.0);             // the blend mask at 1
      }
    }
  }
  SaveFusionNet(dir / "shift.ckpt", shift, info, false);
  const DetailFrameSource geometric(Base(), *analysis_);
  DetailOptions zero_options, shift_options;
  zero_options.fusion = (dir / "zero.ckpt").string();
  shift_options.fusion = (dir / "shift.ckpt").string();
  const DetailFrameSource zero(Base(), *analysis_, zero_options), shifted(Base(), *analysis_, shift_options);
  EXPECT_NE(shifted.Label().find("finished by the fusion net (step 7, fusion:"), std::string::npos) << shifted.Label();
  EXPECT_EQ(geometric.Label().find("fusion"), std::string::npos) << geometric.Label();
  for (const int side : {96, 320}) {
    FrameRequest request;
    request.view = geometric.SourcePose();
    request.view.yaw += 20.0;
    request.width = request.height = side;
    RunContext ctx;
    const RenderedFrame composite = geometric.Render(request, ctx);
    const RenderedFrame same = zero.Render(request, ctx), up = shifted.Render(request, ctx);
    ASSERT_EQ(up.bgr.size(), cv::Size(side, side));
    EXPECT_EQ(cv::norm(same.bgr, composite.bgr, cv::NORM_INF), 0.0) << side;
    EXPECT_EQ(cv::norm(up.alpha, composite.alpha, cv::NORM_INF), 0.0) << side;
    cv::Mat expected;
    composite.bgr.convertTo(expected, CV_32FC3);
    expected = cv::max(cv::min(expected + cv::Scalar(-25.5, 0.0, 25.5), 255.0), 0.0);  // BGR
    cv::Mat got;
    up.bgr.convertTo(got, CV_32FC3);
    EXPECT_LE(cv::norm(got, expected, cv::NORM_INF), 1.0) << side;
  }
  // Live driving renders the geometric composite: LiveFrameSource drops the net (and passes a
  // source without the detail path through as it is).
  const auto shared_shifted = std::make_shared<const DetailFrameSource>(Base(), *analysis_, shift_options);
  ASSERT_TRUE(shared_shifted->HasFusion());
  const std::shared_ptr<const FrameSource> live = LiveFrameSource(shared_shifted, 2);
  const auto* live_detail = dynamic_cast<const DetailFrameSource*>(live.get());
  ASSERT_NE(live_detail, nullptr);
  EXPECT_FALSE(live_detail->HasFusion());
  EXPECT_EQ(live->Label(), geometric.Label());
  FrameRequest request;
  request.view = geometric.SourcePose();
  request.view.yaw += 10.0;
  request.width = request.height = 96;
  RunContext ctx;
  EXPECT_EQ(cv::norm(live->Render(request, ctx).bgr, geometric.Render(request, ctx).bgr, cv::NORM_INF), 0.0);
  const std::shared_ptr<const FrameSource> live_named = LiveFrameSource(shared_shifted, 2, true);
  const auto* kept = dynamic_cast<const DetailFrameSource*>(live_named.get());
  ASSERT_NE(kept, nullptr);
  EXPECT_TRUE(kept->HasFusion());  // `live --fusion WEIGHTS`
  const std::shared_ptr<const FrameSource> base = Base();
  EXPECT_EQ(LiveFrameSource(base).get(), base.get());
  EXPECT_THROW(LiveFrameSource(nullptr), InvalidInput);
  // The studio's switch: the same path with or without the net; weights that do not load are an
  // error naming the file (the window shows it and keeps its frame source).
  EXPECT_EQ(shared_shifted->WithFusion("")->Label(), geometric.Label());
  EXPECT_EQ(geometric.WithFusion(shift_options.fusion)->Label(), shifted.Label());
  try {
    geometric.WithFusion((dir / "missing.ckpt").string());
    ADD_FAILURE() << "missing fusion weights were accepted";
  } catch (const Io& e) {
    EXPECT_NE(std::string(e.what()).find("missing.ckpt"), std::string::npos) << e.what();
  }
}

// A stored analysis (the data factory's crop, matte, mask and fit) rebuilds the analysis the
// pipeline made: the same texture and the same preview frames.
TEST_F(Detail, AnalysisFromFitRebuildsTheAnalysis) {
  face::AlignedPortrait stored;
  stored.image_unmatted = analysis_->portrait.image_unmatted.clone();
  stored.matte = analysis_->portrait.matte.clone();
  stored.eye_mouth_mask = analysis_->portrait.eye_mouth_mask.clone();
  const SourceAnalysis rebuilt = AnalysisFromFit(stored, analysis_->morphable_fit, "");
  ASSERT_EQ(rebuilt.model, analysis_->model);
  EXPECT_EQ(rebuilt.fit.camera, analysis_->fit.camera);
  ASSERT_EQ(rebuilt.portrait.image.size(), analysis_->portrait.image.size());
  cv::Mat diff;
  cv::absdiff(rebuilt.portrait.image, analysis_->portrait.image, diff);
  EXPECT_LT(cv::mean(diff)[0], 2.0);  // the matted crop, made the analyser's way
  const MorphablePreviewSource a(*analysis_->model, analysis_->morphable_fit, analysis_->texture);
  const MorphablePreviewSource b(*rebuilt.model, rebuilt.morphable_fit, rebuilt.texture);
  FrameRequest request;
  request.view = a.SourcePose();
  request.view.yaw += 15.0;
  request.width = request.height = 64;
  RunContext ctx;
  EXPECT_EQ(cv::norm(a.Render(request, ctx).bgr, b.Render(request, ctx).bgr, cv::NORM_INF), 0.0);
  // Mismatched sizes are refused with the reason.
  morphable::FitResult other = analysis_->morphable_fit;
  other.image_size = cv::Size(100, 100);
  EXPECT_THROW(AnalysisFromFit(stored, other, ""), InvalidInput);
  face::AlignedPortrait no_matte = stored;
  no_matte.matte = cv::Mat();
  EXPECT_THROW(AnalysisFromFit(no_matte, analysis_->morphable_fit, ""), InvalidInput);
}

TEST_F(Detail, SavedAvatarsKeepTheAnalysisAndRenderWithTheDetailPath) {
  testing::TempDir dir;
  SessionOptions so;
  so.random_weights = true;
  so.config = "tiny";
  const auto session = std::make_shared<const Session>(so);
  RunContext ctx;
  const Avatar avatar = session->ReconstructFromAnalysis(*analysis_, ctx);
  ASSERT_TRUE(avatar.HasPortraitAnalysis());
  session->SaveAvatar(avatar, dir / "a.avatar");
  const Avatar loaded = session->LoadAvatar(dir / "a.avatar");
  ASSERT_TRUE(loaded.HasPortraitAnalysis());
  const AvatarPortrait& a = *avatar.state()->portrait;
  const AvatarPortrait& b = *loaded.state()->portrait;
  EXPECT_EQ(cv::norm(a.portrait.image_unmatted, b.portrait.image_unmatted, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(a.portrait.matte, b.portrait.matte, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(a.portrait.eye_mouth_mask, b.portrait.eye_mouth_mask, cv::NORM_INF), 0.0);
  ASSERT_EQ(a.portrait.landmarks.points.size(), b.portrait.landmarks.points.size());
  EXPECT_EQ(a.portrait.landmarks.points[10], b.portrait.landmarks.points[10]);
  EXPECT_EQ(a.fit.alpha, b.fit.alpha);
  EXPECT_EQ(a.fit.beta, b.fit.beta);
  EXPECT_EQ(a.fit.camera, b.fit.camera);
  EXPECT_EQ(a.fit.image_size, b.fit.image_size);
  EXPECT_LT(cv::norm(a.fit.rotation, b.fit.rotation, cv::NORM_INF), 1e-5);
  EXPECT_LT(cv::norm(a.fit.translation, b.fit.translation, cv::NORM_INF), 1e-4);

  // The saved avatar renders through the detail path, the same frame as the avatar in memory.
  BackendOptions options;
  options.random_weights = true;
  const auto in_memory = SavedAvatarSource(session, avatar, options);
  const auto from_file = SavedAvatarSource(session, loaded, options);
  ASSERT_NE(from_file->Wrapped(), nullptr);
  EXPECT_TRUE(from_file->Warnings().empty());
  EXPECT_NE(from_file->Label().find("photo"), std::string::npos) << from_file->Label();
  FrameRequest request;
  request.view = from_file->SourcePose();
  request.view.yaw += 10.0;
  request.width = request.height = 96;
  const RenderedFrame f1 = in_memory->Render(request, ctx), f2 = from_file->Render(request, ctx);
  EXPECT_LT(cv::norm(f1.bgr, f2.bgr, cv::NORM_INF), 2.0);
  EXPECT_TRUE(cv::checkRange(f2.bgr));
  // --detail off: the network alone, no warning.
  options.detail = "off";
  const auto plain = SavedAvatarSource(session, loaded, options);
  EXPECT_EQ(plain->Wrapped(), nullptr);
  EXPECT_TRUE(plain->Warnings().empty());

  // An avatar without the analysis (as files written before it was stored): the network alone,
  // and the warning says how to get the detail path.
  const Avatar bare = session->ReconstructFromAnalysis(analysis_->portrait, analysis_->fit, ctx);
  EXPECT_FALSE(bare.HasPortraitAnalysis());
  session->SaveAvatar(bare, dir / "old.avatar");
  const Avatar old = session->LoadAvatar(dir / "old.avatar");
  EXPECT_FALSE(old.HasPortraitAnalysis());
  options.detail = "head";
  const auto fallback = SavedAvatarSource(session, old, options);
  EXPECT_EQ(fallback->Wrapped(), nullptr);
  ASSERT_EQ(fallback->Warnings().size(), 1u);
  EXPECT_NE(fallback->Warnings()[0].find("reconstruct the portrait again"), std::string::npos);

  // A damaged stored analysis is refused naming the file.
  TensorArchive archive = ReadTensorArchive(dir / "a.avatar", "goha-avatar");
  archive.meta["portrait_fit"]["camera"] = std::vector<float>(3, 0.0f);
  WriteTensorArchive(dir / "bad.avatar", archive);
  try {
    session->LoadAvatar(dir / "bad.avatar");
    ADD_FAILURE() << "a damaged analysis was read";
  } catch (const ModelLoad& e) {
    EXPECT_NE(std::string(e.what()).find("bad.avatar"), std::string::npos) << e.what();
  }
}

TEST_F(Detail, BadInputsAreRefused) {
  compose::FaceDetailOptions options;
  options.feather = -1.0;
  EXPECT_THROW(options.Validate(), InvalidOptions);
  EXPECT_THROW(ValidateDetailMode("sharp"), InvalidOptions);
  EXPECT_NO_THROW(ValidateDetailMode("face"));
  // Masks of another size than the frame they change: a clear error, the frame untouched.
  compose::FaceWarp odd;
  odd.cavity = cv::Mat(8, 8, CV_8UC1, cv::Scalar(255));
  odd.carved = odd.cavity;
  cv::Mat frame(16, 16, CV_8UC3, cv::Scalar(10, 20, 30)), alpha(16, 16, CV_8UC1, cv::Scalar(255));
  EXPECT_THROW(compose::PaintCavity(frame, odd), InvalidInput);
  EXPECT_THROW(compose::ClearCarved(odd, &frame, &alpha, nullptr), InvalidInput);
  EXPECT_EQ(cv::countNonZero(alpha != 255), 0);
  EXPECT_THROW(compose::FeatheredWeight(cv::Mat::zeros(16, 16, CV_8UC1), 0.1, cv::Mat::zeros(8, 8, CV_8UC1)),
               InvalidInput);
  const morphable::MorphableModel& model = *analysis_->model;
  EXPECT_THROW(compose::FaceDetail(model, analysis_->morphable_fit, cv::Mat(), cv::Mat(), cv::Mat()), InvalidInput);
  EXPECT_THROW(compose::FaceDetail(model, analysis_->morphable_fit, cv::Mat(100, 100, CV_8UC3), cv::Mat(), cv::Mat()),
               InvalidInput);
  const compose::FaceDetail detail(model, analysis_->morphable_fit, analysis_->portrait.image_unmatted, cv::Mat(),
                                   cv::Mat());
  EXPECT_THROW(detail.Warp(analysis_->morphable_fit.camera, morphable::Beta(3, 0.0f), cv::Size(64, 64)), InvalidInput);
  // The depth warp: bad options, an empty or mistyped source depth, a target alpha of another size.
  compose::DepthDetailOptions depth_options;
  depth_options.depth_tolerance = 0.0;
  EXPECT_THROW(depth_options.Validate(), InvalidOptions);
  depth_options = {};
  depth_options.min_alpha = 300;
  EXPECT_THROW(depth_options.Validate(), InvalidOptions);
  const cv::Mat& photo = analysis_->portrait.image_unmatted;
  const morphable::CameraLabel camera = analysis_->morphable_fit.camera;
  const float inf = std::numeric_limits<float>::infinity();
  EXPECT_THROW(compose::DepthDetail(photo, cv::Mat(), {camera, cv::Mat(32, 32, CV_32FC1, cv::Scalar(inf))}),
               InvalidInput);
  EXPECT_THROW(compose::DepthDetail(photo, cv::Mat(), {camera, cv::Mat(32, 32, CV_8UC1)}), InvalidInput);
  EXPECT_THROW(compose::DepthDetail(photo, cv::Mat(10, 10, CV_32FC1), {camera, cv::Mat(32, 32, CV_32FC1, 2.7f)}),
               InvalidInput);
  const compose::DepthDetail depth(photo, cv::Mat(), {camera, cv::Mat(32, 32, CV_32FC1, cv::Scalar(2.7f))});
  EXPECT_THROW(depth.Warp({camera, cv::Mat(32, 32, CV_32FC1, cv::Scalar(2.7f))}, cv::Mat(16, 16, CV_8UC1)),
               InvalidInput);
  const compose::FaceWarp far = depth.Warp({camera, cv::Mat(32, 32, CV_32FC1, cv::Scalar(inf))},
                                           cv::Mat(32, 32, CV_8UC1, cv::Scalar(255)));
  EXPECT_EQ(cv::countNonZero(far.valid), 0);  // an empty target depth: nothing valid, no crash
  morphable::Beta nan_beta = analysis_->morphable_fit.beta;
  nan_beta[0] = std::nanf("");
  EXPECT_THROW(detail.Warp(analysis_->morphable_fit.camera, nan_beta, cv::Size(64, 64)), InvalidInput);
}

}  // namespace
}  // namespace avatar

namespace avatar {
namespace {

// A head that is a sphere (radius 0.45 about (0, 0, -0.1)): depth along each ray, opaque where
// the ray meets it; the photo's pose of the sample portrait.
class SphereSource : public FrameSource {
 public:
  // radius 0: nothing is opaque.
  SphereSource(ViewPose pose, morphable::CameraLabel camera, double radius = 0.45)
      : pose_(pose), camera_(camera), radius_(radius) {}
  std::string Label() const override { return "sphere"; }
  bool SupportsPose() const override { return true; }
  std::vector<std::string> ExpressionControls() const override { return {}; }
  ViewPose SourcePose() const override { return pose_; }
  RenderedFrame Render(const FrameRequest& request, RunContext&) const override {
    const morphable::PinholeCamera cam = morphable::PinholeCamera::FromLabel(render::CameraForView(request.view, camera_));
    const cv::Matx33d k_inv = cam.k_normalised.inv(), to_world = cam.world_to_cam.t();
    RenderedFrame f;
    f.bgr = cv::Mat(request.height, request.width, CV_8UC3, cv::Scalar(90, 120, 160));
    f.alpha = cv::Mat::zeros(request.height, request.width, CV_8UC1);
    f.depth = cv::Mat(request.height, request.width, CV_32FC1, cv::Scalar(std::numeric_limits<float>::infinity()));
    const cv::Vec3d centre(0.0, 0.0, -0.1);
    for (int y = 0; y < request.height; ++y) {
      for (int x = 0; x < request.width; ++x) {
        cv::Vec3d d = to_world * (k_inv * cv::Vec3d((x + 0.5) / request.width, (y + 0.5) / request.height, 1.0));
        d *= 1.0 / cv::norm(d);
        const cv::Vec3d o = cam.centre - centre;
        const double b = o.dot(d), c = o.dot(o) - radius_ * radius_, disc = b * b - c;
        if (radius_ <= 0.0 || disc < 0.0) continue;
        f.depth.at<float>(y, x) = static_cast<float>(-b - std::sqrt(disc));
        f.alpha.at<uchar>(y, x) = 255;
      }
    }
    return f;
  }

 private:
  ViewPose pose_;
  morphable::CameraLabel camera_;
  double radius_;
};

// The exported mesh: the face part is the fitted mesh with its UV texture; the head part lies on
// the head's surface (the sphere), faces the photo's camera, stays off the face and carries the
// photo's UVs; a head that renders nothing leaves the face alone, with a warning.
TEST_F(Detail, HeadMeshLiesOnTheRenderedSurfaceAndLeavesTheFaceToTheFaceMesh) {
  const SphereSource sphere(Base()->SourcePose(), analysis_->morphable_fit.camera);
  HeadMeshOptions options;
  options.depth_size = 96;
  RunContext ctx;
  // The whole person (the default) holds a small head's part and the matte beyond it.
  const SphereSource small(Base()->SourcePose(), analysis_->morphable_fit.camera, 0.2);
  const HeadMesh person = BuildHeadMesh(*analysis_, small, options, ctx);
  options.extend_to_matte = false;
  const HeadMesh inside_only = BuildHeadMesh(*analysis_, small, options, ctx);
  ASSERT_EQ(person.parts.size(), 2u);
  ASSERT_EQ(inside_only.parts.size(), 2u);
  person.parts[1].Validate();
  std::cout << "[detail] head part of a small head: " << person.parts[1].positions.size()
            << " vertices over the person, " << inside_only.parts[1].positions.size() << " inside the head\n";
  EXPECT_GT(person.parts[1].positions.size(), inside_only.parts[1].positions.size() + 100);
  for (const cv::Point3f& p : person.parts[1].positions)
    ASSERT_TRUE(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z));
  const HeadMesh mesh = BuildHeadMesh(*analysis_, sphere, options, ctx);
  ASSERT_EQ(mesh.parts.size(), 2u);
  EXPECT_TRUE(mesh.warnings.empty());
  const TexturedMesh& face = mesh.parts[0];
  const TexturedMesh& head = mesh.parts[1];
  EXPECT_EQ(face.name, "face");
  EXPECT_EQ(face.positions.size(), analysis_->model->topology().uv.size());
  EXPECT_EQ(face.texture.size(), cv::Size(512, 512));
  EXPECT_EQ(head.name, "head");
  face.Validate();
  head.Validate();
  ASSERT_GT(head.triangles.size(), 1000u);
  // On the sphere (the depth is smoothed: a small error at the curved rim).
  std::vector<double> off;
  for (const cv::Point3f& p : head.positions) off.push_back(std::abs(cv::norm(cv::Vec3d(p.x, p.y, p.z + 0.1)) - 0.45));
  std::nth_element(off.begin(), off.begin() + off.size() / 2, off.end());
  EXPECT_LT(off[off.size() / 2], 0.005);
  for (const cv::Point2f& t : head.uv) {
    ASSERT_GE(t.x, 0.0f);
    ASSERT_LE(t.x, 1.0f);
    ASSERT_GE(t.y, 0.0f);
    ASSERT_LE(t.y, 1.0f);
  }
  // Counter-clockwise towards the camera (glTF's front faces), for both parts.
  const morphable::PinholeCamera cam = morphable::PinholeCamera::FromLabel(analysis_->morphable_fit.camera);
  for (const TexturedMesh* part : {&face, &head}) {
    double towards = 0, away = 0;
    for (const cv::Vec3i& f : part->triangles) {
      const cv::Point3f a = part->positions[f[0]], b = part->positions[f[1]], c = part->positions[f[2]];
      const cv::Point3f ab = b - a, ac = c - a;
      const cv::Vec3d n = cv::Vec3d(ab.x, ab.y, ab.z).cross(cv::Vec3d(ac.x, ac.y, ac.z));
      (n.dot(cam.centre - cv::Vec3d(a.x, a.y, a.z)) > 0 ? towards : away) += cv::norm(n);
    }
    EXPECT_GT(towards, 3.0 * away) << part->name;
  }
  // Off the face: no head vertex projects deep inside the face mesh's outline.
  std::vector<cv::Point2f> face_px;
  for (const cv::Point3f& p : face.positions) {
    const cv::Point2d px = cam.ToPixel(cam.ToCamera(cv::Vec3d(p.x, p.y, p.z)), cv::Size(96, 96));
    face_px.emplace_back(static_cast<float>(px.x), static_cast<float>(px.y));
  }
  std::vector<cv::Point2f> hull;
  cv::convexHull(face_px, hull);
  int inside = 0;
  for (const cv::Point3f& p : head.positions) {
    const cv::Point2d px = cam.ToPixel(cam.ToCamera(cv::Vec3d(p.x, p.y, p.z)), cv::Size(96, 96));
    if (cv::pointPolygonTest(hull, cv::Point2f(static_cast<float>(px.x), static_cast<float>(px.y)), true) > 8.0) ++inside;
  }
  EXPECT_LT(inside, static_cast<int>(head.positions.size() / 50)) << inside << " head vertices inside the face";
  // The .glb of both parts holds them (the Khronos validator runs on a CLI export: tests/cli).
  const std::string glb = EncodeGlb(mesh.parts, "test");
  ASSERT_GT(glb.size(), 20u);
  EXPECT_EQ(glb.substr(0, 4), "glTF");
  // Nothing opaque: the face alone, and the user is told.
  const SphereSource nothing(Base()->SourcePose(), analysis_->morphable_fit.camera, 0.0);
  const HeadMesh bare = BuildHeadMesh(*analysis_, nothing, options, ctx);
  ASSERT_EQ(bare.parts.size(), 1u);
  EXPECT_EQ(bare.parts[0].name, "face");
  ASSERT_EQ(bare.warnings.size(), 1u);
  EXPECT_NE(bare.warnings[0].find("face only"), std::string::npos) << bare.warnings[0];
  HeadMeshOptions bad;
  bad.depth_size = 4;
  EXPECT_THROW(BuildHeadMesh(*analysis_, sphere, bad, ctx), InvalidOptions);
}

// Live driving's cheaper frame (DetailOptions::base_expression_every): the base source (the
// network) is given a new expression on every Nth frame only, the other frames ask it for its last
// one at their own view; the photo's face still follows every frame's expression.
TEST_F(Detail, TheNetworkTakesANewExpressionOnEveryNthFrameAndTheFaceOnEvery) {
  const auto recording = std::make_shared<RecordingSource>(Base());
  DetailOptions options;
  options.base_expression_every = 3;
  const DetailFrameSource source(recording, *analysis_, options);
  const size_t baked = recording->requests.size();  // the source view's depth
  RunContext ctx;
  std::vector<cv::Mat> frames;
  for (int k = 0; k < 7; ++k) {
    FrameRequest r;
    r.view = source.SourcePose();
    r.view.yaw += 2.0 * k;
    r.width = r.height = 128;
    r.expression.controls["jawOpen"] = 0.12f * static_cast<float>(k);
    frames.push_back(source.Render(r, ctx).bgr);
    ASSERT_EQ(recording->requests.size(), baked + k + 1);
    const FrameRequest& asked = recording->requests.back();
    EXPECT_EQ(asked.view, r.view) << k;  // every frame's own view
    const float expected = 0.12f * static_cast<float>(k - k % 3);  // frames 0, 3, 6 bring a new one
    EXPECT_FLOAT_EQ(asked.expression.Get("jawOpen"), expected) << k;
  }
  // Frames 1 and 2 got frame 0's expression from the network, yet the face opens its mouth more
  // in each: the composite differs from what frame 0's expression gives at frame 2's view.
  DetailOptions every;
  const DetailFrameSource exact(Base(), *analysis_, every);
  FrameRequest r2;
  r2.view = source.SourcePose();
  r2.view.yaw += 4.0;
  r2.width = r2.height = 128;
  r2.expression.controls["jawOpen"] = 0.0f;
  const cv::Mat closed = exact.Render(r2, ctx).bgr;
  cv::Mat diff;
  cv::absdiff(frames[2], closed, diff);
  const int changed = cv::countNonZero(diff.reshape(1) > 16);
  std::cout << "[detail] jawOpen 0.24 over the network's jawOpen 0: " << changed << " channel values differ from jawOpen 0\n";
  EXPECT_GT(changed, 100);
  for (const cv::Mat& f : frames) EXPECT_EQ(f.size(), cv::Size(128, 128));
  // Live driving's source: the same path over the same base, every 2nd frame.
  const std::shared_ptr<const DetailFrameSource> every2 = source.ForLive(2);
  const size_t rebaked = recording->requests.size();  // its own source-view depth
  for (int k = 0; k < 3; ++k) {
    FrameRequest r;
    r.view = source.SourcePose();
    r.width = r.height = 64;
    r.expression.controls["jawOpen"] = 0.3f * static_cast<float>(k);
    every2->Render(r, ctx);
    ASSERT_EQ(recording->requests.size(), rebaked + k + 1);
    EXPECT_FLOAT_EQ(recording->requests.back().expression.Get("jawOpen"), 0.3f * static_cast<float>(k - k % 2)) << k;
  }
  EXPECT_THROW(source.ForLive(0), InvalidOptions);
  DetailOptions bad;
  bad.base_expression_every = 0;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
}

// The studio's OpenGL viewport (issue 34): the detail source's meshes are the face, the head's
// height field (continued under the face, unlike the exported file's) and the network's own frames
// at the photo's view and turned 30 degrees each way, lying on the network's surface; the view of
// a request is the detail path's camera and the face mesh at the request's expression.
TEST_F(Detail, ViewportMeshesHoldThePhotosPartsThenTheNetworksAndFollowTheExpression) {
  const auto sphere = std::make_shared<SphereSource>(Base()->SourcePose(), analysis_->morphable_fit.camera);
  const DetailFrameSource detail(sphere, *analysis_);
  EXPECT_EQ(DetailFrameSource::Find(&detail), &detail);
  EXPECT_EQ(DetailFrameSource::Find(sphere.get()), nullptr);
  RunContext ctx;
  const std::shared_ptr<const HeadMesh> mesh = detail.ViewportMesh(ctx);
  ASSERT_EQ(mesh->parts.size(), 5u);
  EXPECT_EQ(mesh->parts[0].name, "face");
  EXPECT_EQ(mesh->parts[1].name, "head");
  for (const TexturedMesh& part : mesh->parts) {
    part.Validate();
    EXPECT_GT(part.triangles.size(), 100u) << part.name;
  }
  // Under the face: more of the head's height field than the exported mesh keeps.
  HeadMeshOptions exported;
  exported.max_depth_step = 0.1;
  const HeadMesh file = BuildHeadMesh(*analysis_, *sphere, exported, ctx);
  ASSERT_EQ(file.parts.size(), 2u);
  EXPECT_GT(mesh->parts[1].triangles.size(), file.parts[1].triangles.size() + 500);
  // The network's parts lie on its surface (the sphere about (0, 0, -0.1), radius 0.45).
  for (size_t i = 2; i < mesh->parts.size(); ++i) {
    const TexturedMesh& part = mesh->parts[i];
    EXPECT_EQ(part.name.rfind("network", 0), 0u) << part.name;
    std::vector<double> off;
    for (const cv::Point3f& p : part.positions) off.push_back(std::abs(cv::norm(cv::Vec3d(p.x, p.y, p.z + 0.1)) - 0.45));
    std::nth_element(off.begin(), off.begin() + off.size() / 2, off.end());
    EXPECT_LT(off[off.size() / 2], 0.005) << part.name;
  }
  // The view of a request: the detail path's own camera; the face as built at the portrait's
  // expression, and only the face's lower part moves with jawOpen.
  FrameRequest request;
  request.view = detail.SourcePose();
  request.view.yaw += 20.0;
  request.width = request.height = 256;
  const DetailFrameSource::MeshView view = detail.ViewportView(request);
  EXPECT_EQ(view.camera, render::CameraForView(request.view, analysis_->morphable_fit.camera));
  ASSERT_EQ(view.face.size(), mesh->parts[0].positions.size());
  double built = 0.0;
  for (size_t i = 0; i < view.face.size(); ++i) built = std::max(built, cv::norm(view.face[i] - mesh->parts[0].positions[i]));
  EXPECT_LT(built, 1e-5);
  request.expression.controls["jawOpen"] = 0.9f;
  const DetailFrameSource::MeshView jaw = detail.ViewportView(request);
  ASSERT_EQ(jaw.face.size(), view.face.size());
  float top = -1e9f, bottom = 1e9f;
  for (const cv::Point3f& p : view.face) {
    top = std::max(top, p.y);
    bottom = std::min(bottom, p.y);
  }
  // Mean vertex move over the lowest and the highest fifth of the face.
  double low = 0.0, high = 0.0, largest = 0.0;
  int n_low = 0, n_high = 0;
  for (size_t i = 0; i < jaw.face.size(); ++i) {
    const double d = cv::norm(jaw.face[i] - view.face[i]);
    ASSERT_TRUE(std::isfinite(d));
    largest = std::max(largest, d);
    if (view.face[i].y < bottom + 0.2f * (top - bottom)) {
      low += d;
      ++n_low;
    } else if (view.face[i].y > bottom + 0.8f * (top - bottom)) {
      high += d;
      ++n_high;
    }
  }
  ASSERT_GT(n_low, 0);
  ASSERT_GT(n_high, 0);
  low /= n_low;
  high /= n_high;
  std::cout << "[detail] viewport face, jawOpen 0.9: largest vertex move " << largest << ", mean over the chin "
            << low << ", over the forehead " << high << "\n";
  EXPECT_GT(largest, 0.005);
  EXPECT_GT(low, 3.0 * high);
}

// A network that is opaque far beyond the person (a large sphere: the bundled model's fog): the
// pixels whose surface point the photo sees against its background are cleared from the frame,
// the person's are not; carve_matte < 0 keeps the fog. Turned, the frame stays finite.
TEST_F(Detail, TheNetworksFogOutsideThePersonIsCarved) {
  const cv::Size size(160, 160);
  const auto fog = std::make_shared<SphereSource>(Base()->SourcePose(), analysis_->morphable_fit.camera, 1.2);
  cv::Mat matte;  // the matte the warps read: the portrait's with the outline cleaned (the default)
  cv::resize(compose::RefineEdgeMatte(analysis_->portrait.image_unmatted, analysis_->portrait.matte).matte, matte, size,
             0, 0, cv::INTER_AREA);
  // A pixel of slack on either side: the test's matte is resampled.
  cv::Mat person = matte >= 0.5f, background = matte < 0.25f;
  cv::erode(person, person, cv::Mat::ones(3, 3, CV_8UC1));
  cv::erode(background, background, cv::Mat::ones(3, 3, CV_8UC1));
  ASSERT_GT(cv::countNonZero(background), size.area() / 10) << "the sample has background";
  RunContext ctx;
  for (const float carve : {0.25f, -1.0f}) {
    SCOPED_TRACE(carve);
    DetailOptions options;
    options.depth.carve_matte = carve;
    const DetailFrameSource source(fog, *analysis_, options);
    ASSERT_TRUE(source.HasDepthProxy());
    FrameRequest request;
    request.view = source.SourcePose();
    request.width = size.width;
    request.height = size.height;
    const RenderedFrame base = fog->Render(request, ctx);
    ASSERT_EQ(cv::countNonZero(base.alpha), size.area()) << "the fog covers the frame";
    const compose::FaceWarp w = source.DepthWarp(request, base);
    ExpectSane(w, size);
    const RenderedFrame frame = source.Render(request, ctx);
    EXPECT_TRUE(cv::checkRange(frame.bgr) && cv::checkRange(frame.alpha));
    const double carved = static_cast<double>(cv::countNonZero(w.carved & background)) / cv::countNonZero(background);
    const double cleared =
        static_cast<double>(cv::countNonZero((frame.alpha == 0) & background)) / cv::countNonZero(background);
    std::cout << "[detail] carve_matte " << carve << ": " << carved << " of the photo's background carved, " << cleared
              << " transparent in the frame\n";
    if (carve < 0) {
      EXPECT_EQ(cv::countNonZero(w.carved), 0);
      EXPECT_EQ(cleared, 0.0);
      continue;
    }
    EXPECT_GT(carved, 0.95);
    EXPECT_GT(cleared, 0.95);
    EXPECT_EQ(cv::countNonZero(w.carved & person), 0) << "the person is never carved";
    EXPECT_EQ(cv::countNonZero((frame.alpha < 255) & person & (matte >= 0.99f)), 0) << "the person stays opaque";
    // Turned, most of this fog projects outside the photo, where the photo says nothing: kept.
    request.view.yaw += 30.0;
    const RenderedFrame turned = source.Render(request, ctx);
    EXPECT_TRUE(cv::checkRange(turned.bgr) && cv::checkRange(turned.alpha));
  }
  compose::DepthDetailOptions bad;
  bad.carve_matte = 2.0f;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
}

// The network's depth moved onto the fitted face mesh (DetailOptions::align_depth_to_face, opt-in,
// compose::MeshRayDepth, FaceDepthOffset and FaceOffsetField):
//  - the mesh's ray depth at a visible vertex's pixel is that vertex's distance from the camera;
//  - the offset is the median gap over the pixels both cover (outliers and transparent pixels do
//    not move it; too few shared pixels give 0; maps of different sizes are refused);
//  - a base whose depth is the face mesh itself (the morphable preview) is not moved; a sphere is,
//    and then the head's warp agrees better with the face's warp where both reach at a turned view
//    (the hair and temples turn with the face: issue 32), while the source view still gives the
//    photo back; the exported head mesh moves by the same offset along the photo's rays.
TEST_F(Detail, TheNetworksDepthIsMovedOntoTheFaceMesh) {
  const morphable::FitResult& fit = analysis_->morphable_fit;
  const std::vector<cv::Point3f> world = morphable::WorldVertices(*analysis_->model, fit);
  const cv::Size size(128, 128);
  const cv::Mat mesh = compose::MeshRayDepth(fit.camera, world, analysis_->model->topology().triangles, size);
  ASSERT_GT(cv::countNonZero(mesh < 1e9f), size.area() / 20);
  const morphable::PinholeCamera cam = morphable::PinholeCamera::FromLabel(fit.camera);
  std::vector<double> errors;
  for (const cv::Point3f& v : world) {
    const cv::Vec3d p(v.x, v.y, v.z);
    const cv::Point2d px = cam.ToPixel(cam.ToCamera(p), size);
    const int x = static_cast<int>(std::floor(px.x)), y = static_cast<int>(std::floor(px.y));
    if (x < 0 || y < 0 || x >= size.width || y >= size.height) continue;
    const float d = mesh.at<float>(y, x);
    if (std::isfinite(d)) errors.push_back(std::abs(d - cv::norm(p - cam.centre)));
  }
  ASSERT_GT(errors.size(), world.size() / 3);
  std::nth_element(errors.begin(), errors.begin() + errors.size() / 2, errors.end());
  std::cout << "[detail] mesh ray depth at its vertices: median error " << errors[errors.size() / 2] << "\n";
  EXPECT_LT(errors[errors.size() / 2], 0.003);  // a pixel's footprint on a curved face (camera distance 2.7)

  {
    const float inf = std::numeric_limits<float>::infinity();
    cv::Mat m(40, 40, CV_32FC1, cv::Scalar(inf)), n(40, 40, CV_32FC1, cv::Scalar(2.6f));
    cv::Mat a(40, 40, CV_8UC1, cv::Scalar(255));
    m(cv::Rect(10, 10, 20, 20)).setTo(2.5f);
    n(cv::Rect(10, 10, 20, 20)).setTo(2.54f);  // the network 0.04 behind the mesh
    n(cv::Rect(10, 10, 20, 3)).setTo(9.0f);    // outliers: 15% of the shared pixels
    a(cv::Rect(25, 10, 5, 20)).setTo(0);       // transparent: not counted
    n(cv::Rect(25, 10, 5, 20)).setTo(0.0f);
    EXPECT_NEAR(compose::FaceDepthOffset(n, a, m), -0.04, 1e-6);
    EXPECT_EQ(compose::FaceDepthOffset(n, a, m, 128, 1000), 0.0) << "too few shared pixels";
    EXPECT_THROW(compose::FaceDepthOffset(n, a, cv::Mat(20, 20, CV_32FC1)), InvalidInput);
    // Spread over the view: the offset on the face, exp(-1) of it one reach away, nothing far off.
    cv::Mat face_mask = cv::Mat::zeros(100, 100, CV_8UC1);
    face_mask(cv::Rect(0, 0, 100, 30)).setTo(255);  // rows 0-29
    const cv::Mat field = compose::FaceOffsetField(face_mask, -0.04, 0.1);
    EXPECT_FLOAT_EQ(field.at<float>(10, 50), -0.04f);
    EXPECT_NEAR(field.at<float>(39, 50), -0.04 * std::exp(-1.0), 1e-3);  // 10 px = 0.1 x 100 from the face
    EXPECT_NEAR(field.at<float>(99, 50), 0.0, 1e-6);
    EXPECT_FLOAT_EQ(compose::FaceOffsetField(face_mask, -0.04, 0.0).at<float>(99, 50), -0.04f);
    EXPECT_EQ(cv::countNonZero(compose::FaceOffsetField(cv::Mat::zeros(8, 8, CV_8UC1), -0.04, 0.1)), 0);
    EXPECT_THROW(compose::FaceOffsetField(cv::Mat(8, 8, CV_32FC1), -0.04, 0.1), InvalidInput);
  }

  RunContext ctx;
  DetailOptions align;  // opt-in (DetailOptions::align_depth_to_face)
  align.align_depth_to_face = true;
  const DetailFrameSource on_preview(Base(), *analysis_, align);
  std::cout << "[detail] depth offset of the morphable preview base: " << on_preview.depth_offset() << "\n";
  // The preview's depth is the face mesh's camera z, not its distance along the ray: 0.1% apart
  // near the optical axis (measured 0.0026 of 2.7).
  EXPECT_LT(std::abs(on_preview.depth_offset()), 0.005) << "the preview's depth is the face mesh";
  const auto sphere = std::make_shared<SphereSource>(Base()->SourcePose(), fit.camera);
  const DetailFrameSource moved(sphere, *analysis_, align), kept(sphere, *analysis_);
  EXPECT_EQ(kept.depth_offset(), 0.0);
  std::cout << "[detail] depth offset of a sphere base: " << moved.depth_offset() << "\n";
  EXPECT_GT(std::abs(moved.depth_offset()), 0.01);
  // Where the face's warp and the head's warp both reach, at a view turned 25 degrees: the moved
  // head's photo lands where the face mesh puts it.
  FrameRequest request;
  request.view = moved.SourcePose();
  request.width = request.height = 160;
  const RenderedFrame source_base = sphere->Render(request, ctx);
  const compose::FaceWarp back = moved.DepthWarp(request, source_base);
  cv::Mat photo, a, b;
  cv::resize(analysis_->portrait.image_unmatted, photo, cv::Size(160, 160), 0, 0, cv::INTER_AREA);
  back.bgr.copyTo(a, back.valid);
  photo.copyTo(b, back.valid);
  EXPECT_GT(cv::PSNR(a, b, 255.0), 28.0) << "the source view gives the photo back";
  request.view.yaw += 25.0;
  const RenderedFrame turned = sphere->Render(request, ctx);
  const compose::FaceWarp face = moved.Warp(request);
  double disagreement[2] = {0, 0};
  int index = 0;
  for (const DetailFrameSource* source : {&kept, &moved}) {
    const compose::FaceWarp head = source->DepthWarp(request, turned);
    const cv::Mat both = (face.valid != 0) & (head.valid != 0);
    ASSERT_GT(cv::countNonZero(both), 500);
    cv::Mat diff;
    cv::absdiff(face.bgr, head.bgr, diff);
    disagreement[index++] = cv::mean(diff, both)[0] + cv::mean(diff, both)[1] + cv::mean(diff, both)[2];
  }
  std::cout << "[detail] head warp vs face warp at yaw +25 (sum of channel mean abs differences): not moved "
            << disagreement[0] << ", moved " << disagreement[1] << "\n";
  EXPECT_LT(disagreement[1], 0.8 * disagreement[0]);
  // The exported head mesh: the same offset along the photo's rays.
  // The whole head moved (reach 0) against the default reach: the move fades away from the face.
  DetailOptions whole = align;
  whole.align_depth_reach = 0.0;
  const DetailFrameSource moved_whole(sphere, *analysis_, whole);
  DetailOptions bad;
  bad.align_depth_reach = std::nan("");
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  HeadMeshOptions bad_mesh;
  bad_mesh.align_depth_reach = std::numeric_limits<double>::infinity();
  EXPECT_THROW(bad_mesh.Validate(), InvalidOptions);
  // The exported head mesh: the same offset along the photo's rays, on the whole head with reach
  // 0; with the default reach near the face only, never more than the offset.
  HeadMeshOptions mesh_options;
  mesh_options.depth_size = 128;
  const HeadMesh plain = BuildHeadMesh(*analysis_, *sphere, mesh_options, ctx);  // the default: not moved
  mesh_options.align_depth_to_face = true;
  const HeadMesh near_face = BuildHeadMesh(*analysis_, *sphere, mesh_options, ctx);
  mesh_options.align_depth_reach = 0.0;
  const HeadMesh aligned = BuildHeadMesh(*analysis_, *sphere, mesh_options, ctx);
  const morphable::PinholeCamera photo_cam =
      morphable::PinholeCamera::FromLabel(render::CameraForView(sphere->SourcePose(), fit.camera));
  auto moves_of = [&](const HeadMesh& m) {
    EXPECT_EQ(m.parts.size(), 2u);
    EXPECT_EQ(m.parts[1].positions.size(), plain.parts[1].positions.size());
    std::vector<double> moves;
    for (size_t i = 0; i < std::min(m.parts[1].positions.size(), plain.parts[1].positions.size()); ++i) {
      const cv::Point3f p = plain.parts[1].positions[i], q = m.parts[1].positions[i];
      moves.push_back(cv::norm(cv::Vec3d(q.x, q.y, q.z) - photo_cam.centre) -
                      cv::norm(cv::Vec3d(p.x, p.y, p.z) - photo_cam.centre));
    }
    std::sort(moves.begin(), moves.end());
    return moves;
  };
  const std::vector<double> all = moves_of(aligned), near = moves_of(near_face);
  ASSERT_FALSE(all.empty());
  EXPECT_NEAR(all[all.size() / 2], moved_whole.depth_offset(), 2e-3);
  EXPECT_NEAR(moved.depth_offset(), moved_whole.depth_offset(), 1e-9) << "one offset, spread differently";
  const double largest = std::max(std::abs(near.front()), std::abs(near.back()));
  EXPECT_NEAR(largest, std::abs(moved.depth_offset()), 3e-3) << "next to the face: the whole offset";
  EXPECT_LT(std::abs(near[near.size() / 10]) + std::abs(near[near.size() * 9 / 10]), 2.0 * largest);
  const size_t still = static_cast<size_t>(
      std::count_if(near.begin(), near.end(), [&](double v) { return std::abs(v) < 0.05 * largest; }));
  std::cout << "[detail] head mesh, default reach: " << still << " of " << near.size()
            << " vertices moved by less than 5% of the offset\n";
  EXPECT_GT(still, near.size() / 10) << "far from the face the head stays";
}

// The 256 -> 512 export step's upscalers (compose/upscaler.h): the installed esrgan-slim x2 keeps
// a smooth picture (its colours and layout: close to bicubic, within a few grey levels) while
// adding its own sharpening; any output size; clear errors for a bad name, a missing model and
// a bad image. (The network itself is checked against TensorFlow.js in model/mobilenet_v2.)
// A disc of person colour F on a background B, its edge a 4 px ramp of coverage, and a
// segmentation matte 4 px too wide (as the photo's matte is on a blue background): the cleaned
// matte follows the true coverage, never exceeds the segmentation's, and the edge's colour is
// F; the inside is untouched, and a busy background or one of the person's colour changes nothing.
TEST(EdgeMatte, TheBackgroundShareOfTheOutlineIsTakenOut) {
  const cv::Size size(160, 160);
  const cv::Vec3f f(60.0f, 90.0f, 200.0f), b(240.0f, 125.0f, 55.0f);
  const double radius = 50.0;
  cv::Mat photo(size, CV_8UC3), matte(size, CV_32FC1), coverage(size, CV_32FC1);
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const double r = std::hypot(x + 0.5 - 80.0, y + 0.5 - 80.0);
      const float a = static_cast<float>(std::clamp((radius + 2.0 - r) / 4.0, 0.0, 1.0));
      coverage.at<float>(y, x) = a;
      matte.at<float>(y, x) = static_cast<float>(std::clamp((radius + 6.0 - r) / 4.0, 0.0, 1.0));
      const cv::Vec3f c = a * f + (1.0f - a) * b;
      photo.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uchar>(c[0]), cv::saturate_cast<uchar>(c[1]),
                                            cv::saturate_cast<uchar>(c[2]));
    }
  }
  // A lone pixel of the background's colour inside the person, within the band: a bluish
  // highlight, not a hole.
  photo.at<cv::Vec3b>(80, 80 + static_cast<int>(radius) - 8) = cv::Vec3b(240, 125, 55);
  compose::EdgeMatteOptions o;
  o.band = 0.1;  // 16 px: the person's and background's colours from farther than the ramps
  const compose::EdgeMatte out = compose::RefineEdgeMatte(photo, matte, o);
  ASSERT_EQ(out.bgr.size(), size);
  ASSERT_EQ(out.matte.type(), CV_32FC1);
  EXPECT_TRUE(cv::checkRange(out.matte, true, nullptr, 0.0, 1.0 + 1e-6));
  EXPECT_EQ(cv::countNonZero(out.matte > matte + 1e-6f), 0);  // never above the segmentation's
  double worst_matte = 0.0, worst_colour = 0.0, before = 0.0;
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const double r = std::hypot(x + 0.5 - 80.0, y + 0.5 - 80.0);
      const bool lone = y == 80 && x == 80 + static_cast<int>(radius) - 8;
      if (r < radius - 20.0 || lone) {  // inside: as it was
        ASSERT_EQ(out.bgr.at<cv::Vec3b>(y, x), photo.at<cv::Vec3b>(y, x));
        ASSERT_EQ(out.matte.at<float>(y, x), matte.at<float>(y, x));
      }
      if (lone) continue;
      worst_matte = std::max(worst_matte, std::abs(out.matte.at<float>(y, x) - coverage.at<float>(y, x)) * 1.0);
      if (out.matte.at<float>(y, x) >= 0.5f) {
        const cv::Vec3b c = out.bgr.at<cv::Vec3b>(y, x);
        worst_colour = std::max(worst_colour, cv::norm(cv::Vec3f(c[0], c[1], c[2]) - f));
      }
      if (matte.at<float>(y, x) >= 0.5f) {
        const cv::Vec3b p = photo.at<cv::Vec3b>(y, x);
        before = std::max(before, cv::norm(cv::Vec3f(p[0], p[1], p[2]) - f));
      }
    }
  }
  std::cout << "edge matte: worst matte error " << worst_matte << ", worst colour error of the kept edge "
            << worst_colour << " levels (the photo's: " << before << ")\n";
  EXPECT_LT(worst_matte, 0.05);
  EXPECT_LT(worst_colour, 6.0);
  EXPECT_GT(before, 100.0);
  // A busy background (stripes of the background's colour and of white, 3 px each): its local
  // mean is no pixel's colour, so the outline stays the segmentation's.
  cv::Mat striped = photo.clone();
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x)
      if (matte.at<float>(y, x) <= 0.0f && (y / 3) % 2 == 0) striped.at<cv::Vec3b>(y, x) = cv::Vec3b(250, 250, 250);
  const compose::EdgeMatte busy = compose::RefineEdgeMatte(striped, matte, o);
  EXPECT_EQ(cv::norm(busy.matte, matte, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(busy.bgr, striped, cv::NORM_INF), 0.0);
  // A background of the person's colour: nothing to tell apart, nothing changes.
  const compose::EdgeMatte same = compose::RefineEdgeMatte(cv::Mat(size, CV_8UC3, cv::Scalar(60, 90, 200)), matte, o);
  EXPECT_EQ(cv::norm(same.matte, matte, cv::NORM_INF), 0.0);
  // No person, or no background: as it was.
  const cv::Mat ones(size, CV_32FC1, cv::Scalar(1.0f)), zeros(size, CV_32FC1, cv::Scalar(0.0f));
  EXPECT_EQ(cv::norm(compose::RefineEdgeMatte(photo, ones, o).matte, ones, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(compose::RefineEdgeMatte(photo, zeros, o).bgr, photo, cv::NORM_INF), 0.0);
  // A matte with NaN (a damaged file): read as background there, every output finite and in range.
  cv::Mat holed = matte.clone();
  holed.at<float>(80, 80 + static_cast<int>(radius)) = std::numeric_limits<float>::quiet_NaN();
  holed.at<float>(10, 10) = std::numeric_limits<float>::quiet_NaN();
  const compose::EdgeMatte nan = compose::RefineEdgeMatte(photo, holed, o);
  EXPECT_TRUE(cv::checkRange(nan.matte, true, nullptr, 0.0, 1.0 + 1e-6));
  EXPECT_EQ(nan.matte.at<float>(10, 10), 0.0f);
  EXPECT_THROW(compose::RefineEdgeMatte(cv::Mat(), matte, o), InvalidInput);
  EXPECT_THROW(compose::RefineEdgeMatte(photo, cv::Mat(size, CV_8UC1, cv::Scalar(0)), o), InvalidInput);
  EXPECT_THROW(compose::RefineEdgeMatte(photo, cv::Mat(cv::Size(8, 8), CV_32FC1, cv::Scalar(1.0f)), o), InvalidInput);
  compose::EdgeMatteOptions bad;
  bad.band = 0.0;
  EXPECT_THROW(compose::RefineEdgeMatte(photo, matte, bad), InvalidOptions);
  bad = {};
  bad.min_solve = 0.0f;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
}

// The fit's texture read only from the person when a matte is given: with the matte at zero
// nothing is seen (every texel inpainted), with the matte at one it is the texture without one.
TEST_F(Detail, TheTextureIsSampledOnlyFromThePerson) {
  const cv::Mat& photo = analysis_->portrait.image_unmatted;
  const morphable::Texture plain = morphable::SampleTexture(*analysis_->model, analysis_->morphable_fit, photo);
  const morphable::Texture all = morphable::SampleTexture(*analysis_->model, analysis_->morphable_fit, photo, {},
                                                           cv::Mat(photo.size(), CV_32FC1, cv::Scalar(1.0f)));
  const morphable::Texture none = morphable::SampleTexture(*analysis_->model, analysis_->morphable_fit, photo, {},
                                                            cv::Mat(photo.size(), CV_32FC1, cv::Scalar(0.0f)));
  EXPECT_GT(cv::countNonZero(plain.uv_visible), 1000);
  EXPECT_EQ(cv::norm(all.uv_image, plain.uv_image, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::countNonZero(none.uv_visible), 0);
  EXPECT_TRUE(cv::checkRange(none.uv_image));
  EXPECT_THROW(morphable::SampleTexture(*analysis_->model, analysis_->morphable_fit, photo, {},
                                        cv::Mat(cv::Size(8, 8), CV_32FC1, cv::Scalar(1.0f))),
               InvalidInput);
}

TEST(Upscaler, KeepsThePictureAndRefusesBadInput) {
  cv::Mat img(40, 48, CV_8UC3);
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x)
      img.at<cv::Vec3b>(y, x) = cv::Vec3b(static_cast<uchar>(40 + 3 * x), static_cast<uchar>(200 - 4 * y),
                                          static_cast<uchar>(100 + 40 * std::sin(x * 0.3) * std::cos(y * 0.2)));
  const compose::ImageUpscaler bicubic("bicubic");
  const compose::ImageUpscaler esrgan("esrgan-slim");
  EXPECT_EQ(esrgan.name(), "esrgan-slim");
  EXPECT_GT(esrgan.MultiplyAdds(48, 40), 1e6);
  EXPECT_EQ(bicubic.MultiplyAdds(48, 40), 0.0);
  const cv::Mat a = bicubic.Upscale(img, cv::Size(96, 80));
  const cv::Mat b = esrgan.Upscale(img, cv::Size(96, 80));
  ASSERT_EQ(b.size(), cv::Size(96, 80));
  ASSERT_EQ(b.type(), CV_8UC3);
  // Inside the border (the model pads with zeros there): mean difference to bicubic.
  const cv::Rect inner(4, 4, 88, 72);
  cv::Mat diff;
  cv::absdiff(a(inner), b(inner), diff);
  const cv::Scalar mean = cv::mean(diff);
  std::cout << "esrgan-slim vs bicubic on a smooth image: mean abs difference " << mean << "\n";
  for (int c = 0; c < 3; ++c) EXPECT_LT(mean[c], 6.0) << "channel " << c;
  const cv::Mat odd = esrgan.Upscale(img, cv::Size(90, 75));
  EXPECT_EQ(odd.size(), cv::Size(90, 75));
  EXPECT_THROW(esrgan.Upscale(cv::Mat(), cv::Size(8, 8)), InvalidInput);
  EXPECT_THROW(esrgan.Upscale(cv::Mat(8, 8, CV_8UC1, cv::Scalar(0)), cv::Size(16, 16)), InvalidInput);
  EXPECT_THROW(esrgan.Upscale(img, cv::Size(0, 16)), InvalidInput);
  EXPECT_THROW(compose::ImageUpscaler("lanczos9"), InvalidOptions);
  testing::TempDir empty;
  try {
    compose::ImageUpscaler missing("esrgan-slim", empty.path().string());
    ADD_FAILURE() << "no MissingData for an empty data folder";
  } catch (const MissingData& e) {
    EXPECT_NE(std::string(e.what()).find("scripts/setup"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace avatar


