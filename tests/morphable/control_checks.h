#pragma once
// Checks that a model's named controls move the regions their names say, measured with the
// test's own geometry (centimetres, other landmarks and references than core/morphable's
// measures.h, which the builder uses to solve the controls): a control that only satisfies the
// builder's own measure, or a measure that is wrong the same way as the builder, fails here.

#include <cmath>
#include <initializer_list>
#include <iostream>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "core/morphable/morphable.h"

namespace avatar::morphable::testing {

// Face regions in centimetres of the model frame (y up, z towards the viewer).
struct RegionMeasures {
  double mouth_open = 0.0;   // inner-lip contour pairs beside the centre (82-87, 312-317, 81-178, 311-402)
  double chin_drop = 0.0;    // chin (152) below the nose tip (1)
  double corner_height = 0.0;  // inner mouth corners (78, 308) relative to the nose tip
  double mouth_width = 0.0;  // inner mouth corners 78 to 308
  double lip_forward = 0.0;  // outer-lip points (0, 37, 267, 17, 84, 314) in front of the nose tip
  double lip_ahead = 0.0;    // the same points in front of the inner mouth corners (78, 308)
  double brow_height = 0.0;  // lower brow contours (46 53 52 65 55, 276 283 282 295 285) above the eye corners
  double brow_inner = 0.0;   // inner lower brow ends 55 to 285
  double eye_right = 0.0;    // subject's right eyelids beside the centre (160-144, 158-153)
  double eye_left = 0.0;     // subject's left eyelids beside the centre (387-373, 385-380)
};

inline RegionMeasures MeasureRegions(const std::vector<cv::Point3f>& v) {
  const double cm = 1.0 / kUnitsPerCm;
  auto d = [&](int a, int b) { return cv::norm(v[a] - v[b]) * cm; };
  auto mean_y = [&](std::initializer_list<int> ids) {
    double s = 0.0;
    for (int i : ids) s += v[i].y;
    return s / static_cast<double>(ids.size()) * cm;
  };
  auto mean_z = [&](std::initializer_list<int> ids) {
    double s = 0.0;
    for (int i : ids) s += v[i].z;
    return s / static_cast<double>(ids.size()) * cm;
  };
  RegionMeasures r;
  r.mouth_open = (d(82, 87) + d(312, 317) + d(81, 178) + d(311, 402)) / 4.0;
  r.chin_drop = (v[1].y - v[152].y) * cm;
  r.corner_height = mean_y({78, 308}) - v[1].y * cm;
  r.mouth_width = d(78, 308);
  r.lip_forward = mean_z({0, 37, 267, 17, 84, 314}) - v[1].z * cm;
  r.lip_ahead = mean_z({0, 37, 267, 17, 84, 314}) - mean_z({78, 308});
  r.brow_height = mean_y({46, 53, 52, 65, 55, 276, 283, 282, 295, 285}) - mean_y({33, 133, 263, 362});
  r.brow_inner = d(55, 285);
  r.eye_right = (d(160, 144) + d(158, 153)) / 2.0;
  r.eye_left = (d(387, 373) + d(385, 380)) / 2.0;
  return r;
}

// Minimum effects (cm) of the controls at value 1.0: about half of what the committed model
// gives on its mean face (jawOpen opens the inner lips 1.55 cm and drops the chin 0.77 cm, smile
// lifts the corners 0.90 cm, frown lowers them 0.18 cm, mouthWide widens 1.18 cm, pucker narrows
// 0.57 cm and brings the lips 0.35 cm ahead of the corners, browRaise 0.40 cm, browFrown -0.17 cm
// and inner ends -0.09 cm, eyesWide +0.30 cm over both eyes). A rebuilt model gets its own.
struct ControlEffects {
  double jaw_mouth_open = 0.75;  // jawOpen opens the inner lips by at least this
  double jaw_chin_drop = 0.35;   // and lowers the chin
  double smile_corners = 0.45;   // smile lifts the mouth corners
  double frown_corners = 0.08;   // frown lowers them
  double wide_width = 0.6;       // mouthWide widens the mouth
  double pucker_width = 0.25;    // pucker narrows it
  double pucker_ahead = 0.15;    // and brings the lips forward of the corners
  double brow_raise = 0.2;       // browRaise lifts the brows
  double brow_lower = 0.08;      // browFrown lowers them
  double brow_inner = 0.04;      // and draws their inner ends together
  double eyes_wide = 0.15;       // eyesWide opens both eyes (sum of the two)
  double held = 0.1;             // regions a control holds move less than this
  double blink_closed = 0.6;     // a blink leaves less than this fraction of the eye's opening
};

// Applies every control at 1.0 (and jawOpen at 0.5) to identity `alpha` and checks the
// regions; `what` names the model and identity in failures. Prints the measured effects.
inline void ExpectControlsMoveTheirRegions(const MorphableModel& m, const Alpha& alpha, const ControlEffects& e,
                                           const std::string& what) {
  SCOPED_TRACE(what);
  const RegionMeasures base = MeasureRegions(m.Vertices(alpha, {}));
  auto after = [&](const char* name, float value) {
    return MeasureRegions(m.Vertices(alpha, m.ExpressionFromControls({{name, value}})));
  };
  const RegionMeasures jaw = after("jawOpen", 1.0f), half_jaw = after("jawOpen", 0.5f);
  const RegionMeasures smile = after("smile", 1.0f), frown = after("frown", 1.0f);
  const RegionMeasures wide = after("mouthWide", 1.0f), pucker = after("pucker", 1.0f);
  const RegionMeasures raise = after("browRaise", 1.0f), lower = after("browFrown", 1.0f);
  const RegionMeasures eyes = after("eyesWide", 1.0f);
  const RegionMeasures blink_l = after("blinkLeft", 1.0f), blink_r = after("blinkRight", 1.0f);
  std::cout << "[controls] " << what << " (cm): jawOpen mouth +" << jaw.mouth_open - base.mouth_open << " chin +"
            << jaw.chin_drop - base.chin_drop << " brows " << jaw.brow_height - base.brow_height << "; smile corners "
            << smile.corner_height - base.corner_height << "; frown corners "
            << frown.corner_height - base.corner_height << "; mouthWide width " << wide.mouth_width - base.mouth_width
            << "; pucker width " << pucker.mouth_width - base.mouth_width << " forward "
            << pucker.lip_forward - base.lip_forward << " ahead of the corners " << pucker.lip_ahead - base.lip_ahead
            << "; browRaise " << raise.brow_height - base.brow_height
            << " mouth " << raise.mouth_open - base.mouth_open << "; browFrown " << lower.brow_height - base.brow_height
            << " inner " << lower.brow_inner - base.brow_inner << "; eyesWide "
            << eyes.eye_left + eyes.eye_right - base.eye_left - base.eye_right << "; blinkLeft eyes "
            << blink_l.eye_left / base.eye_left << "x/" << blink_l.eye_right / base.eye_right << "x; blinkRight eyes "
            << blink_r.eye_left / base.eye_left << "x/" << blink_r.eye_right / base.eye_right << "x\n";
  // jawOpen opens the mouth, more at 1.0 than at 0.5, drops the chin and leaves the brows.
  EXPECT_GT(jaw.mouth_open - base.mouth_open, e.jaw_mouth_open);
  EXPECT_GT(jaw.mouth_open, half_jaw.mouth_open);
  EXPECT_GT(half_jaw.mouth_open, base.mouth_open);
  EXPECT_GT(jaw.chin_drop - base.chin_drop, e.jaw_chin_drop);
  EXPECT_LT(std::abs(jaw.brow_height - base.brow_height), e.held);
  // Mouth corners: up with smile, down with frown.
  EXPECT_GT(smile.corner_height - base.corner_height, e.smile_corners);
  EXPECT_LT(frown.corner_height - base.corner_height, -e.frown_corners);
  // Width: wider with mouthWide, narrower and forward with pucker.
  EXPECT_GT(wide.mouth_width - base.mouth_width, e.wide_width);
  EXPECT_LT(pucker.mouth_width - base.mouth_width, -e.pucker_width);
  // Relative to the corners: the committed pucker also brings the nose tip 0.25 cm forward, so
  // the lips move back relative to the nose (lip_forward, printed above).
  EXPECT_GT(pucker.lip_ahead - base.lip_ahead, e.pucker_ahead);
  // Brows: up with browRaise, down and together with browFrown; the mouth stays closed.
  EXPECT_GT(raise.brow_height - base.brow_height, e.brow_raise);
  EXPECT_LT(std::abs(raise.mouth_open - base.mouth_open), e.held);
  EXPECT_LT(lower.brow_height - base.brow_height, -e.brow_lower);
  EXPECT_LT(lower.brow_inner - base.brow_inner, -e.brow_inner);
  EXPECT_GT(eyes.eye_left + eyes.eye_right - base.eye_left - base.eye_right, e.eyes_wide);
  // Blinks close the named eye (the builder calibrates them on the mean face's middle eyelid
  // pair; these are the pairs beside it) and leave the other within 10 %.
  EXPECT_LT(blink_l.eye_left, e.blink_closed * base.eye_left);
  EXPECT_NEAR(blink_l.eye_right, base.eye_right, 0.1 * base.eye_right);
  EXPECT_LT(blink_r.eye_right, e.blink_closed * base.eye_right);
  EXPECT_NEAR(blink_r.eye_left, base.eye_left, 0.1 * base.eye_left);
}

}  // namespace avatar::morphable::testing
