// The source view is the source camera, and both renderers read one expression the same way.
// On the packaged sample portrait (real face analysis and morphable fit):
//  - the view a user starts from (the studio's reset view: ComposeFrame with no user offset)
//    and frame 0 of `animate --view orbit` (PlanFrame) line up with the fit's own render at
//    the source camera, M_neu: face-mask IoU >= 0.97 for the morphable preview, and the neural
//    source renders exactly at C_s;
//  - the morphable preview and the neural session's I_exp use the same beta (exactly) for named
//    controls, relative coefficients and absolute coefficients, and absolute differs from
//    relative on this portrait (its fitted expression is not zero);
//  - an avatar file written and read back renders coefficient expressions unchanged.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>

#include <opencv2/imgproc.hpp>

#include "common/temp_dir.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/morphable/camera_label.h"
#include "core/pipeline/animate.h"
#include "core/pipeline/morphable_expression_source.h"
#include "core/pipeline/morphable_preview.h"
#include "core/pipeline/session_source.h"
#include "core/pipeline/source_analysis.h"
#include "core/util/error.h"
#include "common/sample_analysis.h"

namespace avatar {
namespace {

// The head rotation of a pose as an OpenCV matrix.
cv::Matx33d HeadMatrix(const ViewPose& pose) { return cv::Matx33d(render::HeadRotation(pose).data()); }

class SourceView : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { analysis_ = &testing::SampleAnalysis(); }
  static const morphable::MorphableModel& Model() { return *analysis_->model; }
  static MorphablePreviewSource Preview() {
    return MorphablePreviewSource(Model(), analysis_->morphable_fit, analysis_->texture);
  }
  static const MorphableExpressionSource& NeuralExpressions() {
    const auto* source = dynamic_cast<const MorphableExpressionSource*>(analysis_->fit.expressions.get());
    EXPECT_NE(source, nullptr);
    return *source;
  }
  // M_neu: the fit's neutral face at its own camera C_s (as the training data renders it).
  static cv::Mat NeutralMask(cv::Size size) {
    morphable::RenderOptions options;
    options.supersample = 2;
    const morphable::RenderResult r =
        morphable::RenderNeutral(Model(), analysis_->morphable_fit, analysis_->texture, size, options);
    return r.mask > 0.5f;
  }
  static double IoU(const cv::Mat& a, const cv::Mat& b) {
    const double inter = cv::countNonZero(a & b), uni = cv::countNonZero(a | b);
    return uni > 0 ? inter / uni : 0.0;
  }
  static const SourceAnalysis* analysis_;
};
const SourceAnalysis* SourceView::analysis_ = nullptr;

// The neutral expression of M_neu: zero coefficients, absolute.
FrameExpression ZeroExpression() {
  FrameExpression e;
  e.coefficients_absolute = true;
  return e;
}

TEST_F(SourceView, ResetViewAndOrbitFrameZeroLineUpWithTheSourceCamera) {
  const MorphablePreviewSource preview = Preview();
  const cv::Size size(512, 512);
  const cv::Mat m_neu = NeutralMask(size);
  ASSERT_GT(cv::countNonZero(m_neu), 512 * 512 / 20);

  AnimationPlan orbit;
  orbit.view.mode = "orbit";
  orbit.width = size.width;
  orbit.height = size.height;
  orbit.base_expression = ZeroExpression();
  const FrameRequest frame0 = PlanFrame(preview, orbit, nullptr, false, 0, 100);
  // The studio: Reset View sets the user's offset to zero; the preview worker composes it.
  const FrameRequest reset = ComposeFrame(preview.SourcePose(), ViewPose{}, ZeroExpression(), nullptr, false,
                                          size.width, size.height);
  RunContext ctx;
  for (const auto& [what, request] : {std::make_pair("orbit frame 0", frame0), std::make_pair("reset view", reset)}) {
    const RenderedFrame f = preview.Render(request, ctx);
    const double iou = IoU(f.alpha > 127, m_neu);
    std::cout << what << ": face-mask IoU with M_neu " << iou << "\n";
    EXPECT_GE(iou, 0.97) << what;
  }

  // What the old camera (the head turned in front of the frontal camera, looking at the head's
  // origin from 2.7) gave, for the record: the figure the source-camera camera fixes.
  const morphable::Beta zero = Model().ZeroBeta();
  std::vector<cv::Point3f> turned = morphable::WorldVertices(Model(), analysis_->morphable_fit, &zero);
  const cv::Matx33d r = HeadMatrix(preview.SourcePose());
  for (auto& v : turned) {
    const cv::Vec3d q = r * cv::Vec3d(v.x, v.y, v.z);
    v = cv::Point3f(static_cast<float>(q[0]), static_cast<float>(q[1]), static_cast<float>(q[2]));
  }
  morphable::RenderOptions options;
  options.supersample = 2;
  const morphable::RenderResult old = morphable::RenderMesh(turned, Model().topology(), analysis_->texture,
                                                            morphable::FrontalLabel(), size, options);
  std::cout << "previous frontal-camera source view: face-mask IoU with M_neu " << IoU(old.mask > 0.5f, m_neu)
            << "\n";
}

TEST_F(SourceView, TheNeuralSourceRendersTheSourceViewAtTheSourceCamera) {
  SessionOptions options;
  options.random_weights = true;
  options.config = "tiny";
  auto session = std::make_shared<const Session>(options);
  RunContext ctx;
  const Avatar avatar = session->ReconstructFromAnalysis(analysis_->portrait, analysis_->fit, ctx);
  const SessionFrameSource neural(session, avatar, true);
  EXPECT_EQ(neural.CoefficientCount(), Model().num_expression());
  AnimationPlan orbit;
  orbit.view.mode = "orbit";
  const FrameRequest frame0 = PlanFrame(neural, orbit, nullptr, false, 0, 100);
  const FrameRequest reset = ComposeFrame(neural.SourcePose(), ViewPose{}, {}, nullptr, false, 512, 512);
  for (const FrameRequest* request : {&frame0, &reset}) {
    const CameraLabel25 camera = neural.Camera(request->view);
    for (int i = 0; i < 25; ++i) EXPECT_NEAR(camera[i], analysis_->fit.camera[i], 1e-5) << i;
  }
}

TEST_F(SourceView, PreviewAndNeuralExpressionImageUseTheSameCoefficients) {
  const MorphablePreviewSource preview = Preview();
  const MorphableExpressionSource& neural = NeuralExpressions();
  const morphable::Beta& fitted = analysis_->morphable_fit.beta;
  double fitted_norm = 0.0;
  for (float b : fitted) fitted_norm += static_cast<double>(b) * b;
  ASSERT_GT(fitted_norm, 1e-6) << "the sample portrait's fitted expression should not be exactly neutral";

  const int k = Model().num_expression();
  FrameExpression controls;
  controls.controls = {{"jawOpen", 0.5f}, {"smile", 0.3f}};
  FrameExpression relative;
  for (int i = 0; i < k; ++i) relative.coefficients.push_back(0.2f * std::sin(0.7f * static_cast<float>(i + 1)));
  relative.controls["browRaise"] = 0.25f;
  FrameExpression absolute = relative;
  absolute.coefficients_absolute = true;

  morphable::RenderOptions options;
  options.supersample = 2;
  const int s = 64;
  std::vector<cv::Mat> images;
  for (const FrameExpression* e : {&controls, &relative, &absolute}) {
    const morphable::Beta a = preview.Coefficients(*e);
    const morphable::Beta b = neural.Coefficients(*e);
    EXPECT_EQ(a, b);  // exactly the same numbers
    // The session's I_exp is the morphable render of that beta.
    const cv::Mat exp = neural.Render(*e, s);
    const morphable::RenderResult want = morphable::RenderExpressionImage(
        Model(), analysis_->morphable_fit, analysis_->texture, a, cv::Size(s, s), options);
    cv::Mat want8;
    want.image.convertTo(want8, CV_8UC3, 255.0);
    EXPECT_EQ(cv::norm(exp, want8, cv::NORM_INF), 0.0);
    images.push_back(exp);
  }
  // Relative coefficients are an offset from the portrait's expression, absolute ones are not.
  const morphable::Beta rel = preview.Coefficients(relative), abs = preview.Coefficients(absolute);
  for (int i = 0; i < k; ++i) EXPECT_NEAR(rel[i] - abs[i], fitted[i], 1e-6) << i;
  EXPECT_GT(cv::norm(images[1], images[2], cv::NORM_L1), 0.0);
  // {} is the portrait's own expression.
  EXPECT_EQ(neural.Coefficients({}), fitted);
  // Wrong coefficient counts and unknown names are errors in both.
  FrameExpression bad;
  bad.coefficients = {1.0f};
  EXPECT_THROW(preview.Coefficients(bad), InvalidInput);
  EXPECT_THROW(neural.Render(bad, s), InvalidInput);
}

TEST_F(SourceView, AvatarFilesKeepCoefficientExpressions) {
  SessionOptions options;
  options.random_weights = true;
  options.config = "tiny";
  const Session session(options);
  RunContext ctx;
  const Avatar avatar = session.ReconstructFromAnalysis(analysis_->portrait, analysis_->fit, ctx);
  avatar::testing::TempDir dir;
  session.SaveAvatar(avatar, dir / "a.avatar");
  const Avatar loaded = session.LoadAvatar(dir / "a.avatar");
  EXPECT_EQ(loaded.CoefficientCount(), Model().num_expression());
  Expression e;
  e.coefficients.assign(Model().num_expression(), 0.1f);
  e.coefficients_absolute = true;
  const Frame a = session.Animate(avatar, e, avatar.SourceCamera(), RenderMode::kStandard);
  const Frame b = session.Animate(loaded, e, loaded.SourceCamera(), RenderMode::kStandard);
  EXPECT_EQ(cv::norm(a.bgr, b.bgr, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(a.opacity, b.opacity, cv::NORM_INF), 0.0);
}

}  // namespace
}  // namespace avatar
