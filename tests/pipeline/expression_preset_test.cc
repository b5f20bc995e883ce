// Expression preset files (core/pipeline/expression_preset.h): a saved preset loads back to the
// same controls; wrong types, non-finite values, unknown or empty names, another JSON shape and
// truncated text are refused with InvalidInput naming the file; an unreadable file is Io.
#include <gtest/gtest.h>

#include <fstream>
#include <string>

#include "common/temp_dir.h"
#include "core/pipeline/expression_preset.h"
#include "core/util/error.h"

namespace avatar {
namespace {

using avatar::testing::TempDir;

const std::vector<std::string> kKnown = {"smile", "jawOpen", "browRaise"};

// The InvalidInput message of parsing `text` as the file "NAME.json"; fails the test if accepted.
std::string Refusal(const std::string& text, const std::vector<std::string>& known = kKnown) {
  try {
    ParseExpressionPreset(text, "/presets/bad-preset.json", known);
  } catch (const InvalidInput& e) {
    return e.what();
  }
  ADD_FAILURE() << "accepted: " << text;
  return {};
}

TEST(ExpressionPreset, ValidTextGivesItsControlsClampedToTheSliderRange) {
  const Expression e =
      ParseExpressionPreset(R"({"expression": {"smile": 0.4, "jawOpen": 1.5, "browRaise": -2}})", "p.json", kKnown);
  ASSERT_EQ(e.controls.size(), 3u);
  EXPECT_FLOAT_EQ(e.Get("smile"), 0.4f);
  EXPECT_FLOAT_EQ(e.Get("jawOpen"), 1.0f);
  EXPECT_FLOAT_EQ(e.Get("browRaise"), 0.0f);
  EXPECT_TRUE(e.coefficients.empty());
  EXPECT_FALSE(e.coefficients_absolute);
  // Integers are numbers too; an empty preset is the neutral expression; other keys are ignored.
  EXPECT_FLOAT_EQ(ParseExpressionPreset(R"({"expression": {"smile": 1}})", "p.json", kKnown).Get("smile"), 1.0f);
  EXPECT_TRUE(ParseExpressionPreset(R"({"expression": {}, "note": "x"})", "p.json", kKnown).controls.empty());
  // Without a list of known controls any named control is taken.
  EXPECT_FLOAT_EQ(ParseExpressionPreset(R"({"expression": {"wink": 0.25}})", "p.json", {}).Get("wink"), 0.25f);
}

TEST(ExpressionPreset, SavedPresetLoadsBackExactly) {
  TempDir dir;
  const std::map<std::string, double> controls = {{"smile", 0.4}, {"jawOpen", 0.75}, {"browRaise", 0.0}};
  SaveExpressionPreset(dir / "happy.json", controls);
  const Expression e = LoadExpressionPreset(dir / "happy.json", kKnown);
  EXPECT_EQ(e.controls.size(), 3u);
  EXPECT_EQ(e.Get("smile"), 0.4f);
  EXPECT_EQ(e.Get("jawOpen"), 0.75f);
  EXPECT_EQ(e.Get("browRaise"), 0.0f);
  EXPECT_EQ(dir.List(), std::vector<std::string>{"happy.json"});  // no temporary file left
}

TEST(ExpressionPreset, WrongTypesAreRefusedNamingTheFileAndTheControl) {
  for (const std::string text : {R"({"expression": {"smile": "0.5"}})", R"({"expression": {"smile": true}})",
                                 R"({"expression": {"smile": null}})", R"({"expression": {"smile": [0.5]}})",
                                 R"({"expression": {"smile": {"v": 0.5}}})"}) {
    const std::string m = Refusal(text);
    EXPECT_NE(m.find("bad-preset.json"), std::string::npos) << m;
    EXPECT_NE(m.find("'smile' must be a number in [0,1]"), std::string::npos) << m;
  }
  for (const std::string text : {R"([0.5])", R"({"expression": [0.5]})", R"({"expression": 0.5})", R"({"smile": 0.5})",
                                 R"("expression")", R"(42)"}) {
    const std::string m = Refusal(text);
    EXPECT_NE(m.find("bad-preset.json"), std::string::npos) << m;
    EXPECT_NE(m.find("must be {\"expression\""), std::string::npos) << m;
  }
  EXPECT_NE(Refusal(R"({"expression": {"wink": 0.5}})").find("unknown control 'wink'"), std::string::npos);
  EXPECT_NE(Refusal(R"({"expression": {"": 0.5}})", {}).find("a control without a name"), std::string::npos);
}

TEST(ExpressionPreset, NonFiniteValuesAreRefused) {
  // NaN and Infinity are no JSON, and the parser refuses a number beyond the double range.
  for (const std::string text : {R"({"expression": {"smile": NaN}})", R"({"expression": {"smile": nan}})",
                                 R"({"expression": {"smile": Infinity}})", R"({"expression": {"smile": 1e999}})",
                                 R"({"expression": {"smile": -1e999}})"}) {
    const std::string m = Refusal(text);
    EXPECT_NE(m.find("bad-preset.json"), std::string::npos) << text << ": " << m;
    EXPECT_NE(m.find("is not valid JSON"), std::string::npos) << text << ": " << m;
  }
}

TEST(ExpressionPreset, TruncatedTextIsRefusedAtEveryLength) {
  const std::string full = ExpressionPresetText({{"smile", 0.4}, {"jawOpen", 0.75}});
  ASSERT_NO_THROW(ParseExpressionPreset(full, "p.json", kKnown));
  int refused = 0;
  // Every proper prefix that ends before the closing brace is incomplete JSON.
  const size_t last = full.rfind('}');
  for (size_t n = 0; n < last; ++n) {
    const std::string m = Refusal(full.substr(0, n));
    EXPECT_NE(m.find("bad-preset.json"), std::string::npos) << n << ": " << m;
    refused += !m.empty();
  }
  EXPECT_EQ(refused, static_cast<int>(last));
  EXPECT_NE(Refusal("").find("is not valid JSON"), std::string::npos);
}

TEST(ExpressionPreset, UnreadableFileIsAnIoErrorNamingIt) {
  TempDir dir;
  try {
    LoadExpressionPreset(dir / "missing.json", kKnown);
    FAIL() << "a missing file was accepted";
  } catch (const Io& e) {
    EXPECT_NE(std::string(e.what()).find("missing.json"), std::string::npos) << e.what();
  }
  {
    std::ofstream(dir / "broken.json") << "{ not json";
  }
  try {
    LoadExpressionPreset(dir / "broken.json", kKnown);
    FAIL() << "broken JSON was accepted";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find((dir / "broken.json").string()), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace avatar
