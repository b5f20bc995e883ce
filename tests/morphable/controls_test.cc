// Checks of the committed model (resources/morphable): its named controls move the regions
// their names say, measured on the mesh.

#include <cmath>

#include <gtest/gtest.h>

#include "core/util/error.h"
#include "morphable_test_util.h"

namespace avatar::morphable {
namespace {

const MorphableModel& Committed() { return LoadDefaultModel(DataPaths::Resolve()); }

ExpressionMeasures After(const MorphableModel& m, const Alpha& alpha, const char* name, float value) {
  return MeasureShape(m.Vertices(alpha, m.ExpressionFromControls({{name, value}})));
}

TEST(CommittedModel, LoadsWithEveryRequiredControl) {
  const MorphableModel& m = Committed();
  EXPECT_GE(m.num_expression(), 24);
  EXPECT_GE(m.num_identity(), 10);
  for (const auto& name : RequiredControlNames()) {
    const NamedControl& c = m.Control(name);
    EXPECT_FALSE(c.label.empty());
    EXPECT_FALSE(c.description.empty());
  }
  EXPECT_NE(m.provenance().find("franck.mp4"), std::string::npos);
  // The model lives in the EG3D head box.
  for (const auto& p : m.Vertices({}, {})) {
    EXPECT_LT(std::abs(p.x), 0.5f);
    EXPECT_LT(std::abs(p.y), 0.5f);
    EXPECT_LT(std::abs(p.z), 0.5f);
  }
}

// Each control moves its region in the named direction, on the mean face and on two identities.
TEST(CommittedModel, ControlsMoveTheRegionsTheirNamesSay) {
  const MorphableModel& m = Committed();
  std::vector<Alpha> identities = {m.ZeroAlpha(), m.ZeroAlpha(), m.ZeroAlpha()};
  for (int k = 0; k < m.num_identity(); ++k) {
    identities[1][k] = (k % 2 == 0 ? 1.0f : -1.0f) * m.identity_std()[k];
    identities[2][k] = (k % 3 == 0 ? -1.0f : 0.5f) * m.identity_std()[k];
  }
  for (size_t id = 0; id < identities.size(); ++id) {
    const Alpha& a = identities[id];
    // The blink components are calibrated to close the mean face's eyes fully (see builder.cc).
    const double closed = id == 0 ? 0.3 : 0.6;
    const ExpressionMeasures base = MeasureShape(m.Vertices(a, {}));
    const double eye_base_l = base.eye_open_left, eye_base_r = base.eye_open_right;
    // Mouth opening grows with jawOpen; the brows stay.
    EXPECT_GT(After(m, a, "jawOpen", 1.0f).lip_gap - base.lip_gap, 0.15);
    EXPECT_GT(After(m, a, "jawOpen", 1.0f).lip_gap, After(m, a, "jawOpen", 0.5f).lip_gap);
    EXPECT_LT(std::abs(After(m, a, "jawOpen", 1.0f).brow_height - base.brow_height), 0.01);
    EXPECT_GT(After(m, a, "smile", 1.0f).corner_lift - base.corner_lift, 0.05);
    EXPECT_LT(After(m, a, "frown", 1.0f).corner_lift - base.corner_lift, -0.01);
    EXPECT_GT(After(m, a, "mouthWide", 1.0f).mouth_width - base.mouth_width, 0.1);
    const ExpressionMeasures pucker = After(m, a, "pucker", 1.0f);
    EXPECT_LT(pucker.mouth_width - base.mouth_width, -0.03);
    EXPECT_GT(pucker.lip_protrusion - base.lip_protrusion, 0.02);
    EXPECT_GT(After(m, a, "browRaise", 1.0f).brow_height - base.brow_height, 0.04);
    const ExpressionMeasures frown = After(m, a, "browFrown", 1.0f);
    EXPECT_LT(frown.brow_height - base.brow_height, -0.015);
    EXPECT_LT(frown.brow_inner_gap - base.brow_inner_gap, -0.005);
    const ExpressionMeasures wide = After(m, a, "eyesWide", 1.0f);
    EXPECT_GT(wide.eye_open_left + wide.eye_open_right - eye_base_l - eye_base_r, 0.02);
    // Eyelid distance shrinks with blink, on the named side only.
    const ExpressionMeasures bl = After(m, a, "blinkLeft", 1.0f);
    const ExpressionMeasures br = After(m, a, "blinkRight", 1.0f);
    EXPECT_LT(bl.eye_open_left, closed * eye_base_l);
    EXPECT_NEAR(bl.eye_open_right, eye_base_r, 0.1 * eye_base_r);
    EXPECT_LT(br.eye_open_right, closed * eye_base_r);
    EXPECT_NEAR(br.eye_open_left, eye_base_l, 0.1 * eye_base_l);
    EXPECT_LT(After(m, a, "blinkLeft", 0.5f).eye_open_left, eye_base_l);
  }
}

}  // namespace
}  // namespace avatar::morphable
