#include "core/util/options.h"

#include <gtest/gtest.h>

namespace avatar {
namespace {

struct SampleOptions {
  // A count.
  int count = 3;
  // A ratio.
  double ratio = 0.5;
  // A switch.
  bool fast = false;
  // A name.
  std::string name = "default";
  // Repeatable.
  std::vector<std::string> expr;
  // Big number.
  int64_t seed = 7;

  template <typename V>
  void Visit(V&& v) {
    v("count", count, "How many", 'n');
    v("ratio", ratio, "A ratio");
    v("fast", fast, "Go fast", 'f');
    v("name", name, "A name");
    v("expr", expr, "name=value, repeatable");
    v("seed", seed, "Random seed");
  }
  void Validate() const { AVATAR_CHECK_OPTION(count > 0) << "--count must be > 0"; }
};

TEST(Options, ParsesEveryFlagForm) {
  SampleOptions o;
  const auto pos = options::ParseFlags(
      o, {"in.jpg", "--count", "5", "--ratio=0.25", "--fast", "--name", "-dash", "--expr", "smile=1", "--expr=jawOpen=0.5",
          "--seed", "-3", "out.png"});
  EXPECT_EQ(o.count, 5);
  EXPECT_DOUBLE_EQ(o.ratio, 0.25);
  EXPECT_TRUE(o.fast);
  EXPECT_EQ(o.name, "-dash");  // A value-taking flag takes the next argument verbatim.
  EXPECT_EQ(o.expr, (std::vector<std::string>{"smile=1", "jawOpen=0.5"}));
  EXPECT_EQ(o.seed, -3);
  EXPECT_EQ(pos, (std::vector<std::string>{"in.jpg", "out.png"}));
}

TEST(Options, AliasesNegationAndDoubleDash) {
  SampleOptions o;
  o.fast = true;
  const auto pos = options::ParseFlags(o, {"-n", "9", "--no-fast", "--", "--count"});
  EXPECT_EQ(o.count, 9);
  EXPECT_FALSE(o.fast);
  EXPECT_EQ(pos, (std::vector<std::string>{"--count"}));
  options::ParseFlags(o, {"-f"});
  EXPECT_TRUE(o.fast);
  options::ParseFlags(o, {"--fast=no"});
  EXPECT_FALSE(o.fast);
}

TEST(Options, NegativeNumbersArePositionals) {
  SampleOptions o;
  EXPECT_EQ(options::ParseFlags(o, {"-5"}), (std::vector<std::string>{"-5"}));
}

TEST(Options, BadFlagsThrowInvalidOptionsNamingTheFlag) {
  auto message = [](std::vector<std::string> args) {
    SampleOptions o;
    try {
      options::ParseFlags(o, args);
    } catch (const InvalidOptions& e) {
      return std::string(e.what());
    }
    return std::string("<no error>");
  };
  EXPECT_NE(message({"--bogus", "1"}).find("--bogus"), std::string::npos);
  EXPECT_NE(message({"--count", "abc"}).find("--count"), std::string::npos);
  EXPECT_NE(message({"--count", "5x"}).find("integer"), std::string::npos);
  EXPECT_NE(message({"--count", "99999999999"}).find("out of range"), std::string::npos);
  EXPECT_NE(message({"--ratio", "nan"}).find("--ratio"), std::string::npos);
  EXPECT_NE(message({"--ratio", "inf"}).find("--ratio"), std::string::npos);
  EXPECT_NE(message({"--count"}).find("needs a value"), std::string::npos);
  EXPECT_NE(message({"--fast=maybe"}).find("true or false"), std::string::npos);
  EXPECT_NE(message({"--no-count"}).find("--no-count"), std::string::npos);
  EXPECT_NE(message({"-x"}).find("-x"), std::string::npos);
  EXPECT_NE(message({"-nfoo"}).find("unknown option -nfoo"), std::string::npos);
}

TEST(Options, JsonRoundTripKeepsEveryField) {
  SampleOptions a;
  a.count = 11;
  a.ratio = 0.125;
  a.fast = true;
  a.name = "x y";
  a.expr = {"smile=1"};
  a.seed = 1234567890123LL;
  const nlohmann::json j = options::ToJson(a);
  SampleOptions b;
  options::FromJson(b, j);
  EXPECT_EQ(options::ToJson(b), j);
  EXPECT_EQ(b.seed, a.seed);
  EXPECT_EQ(b.expr, a.expr);
}

TEST(Options, JsonRejectsUnknownKeysAndWrongTypes) {
  SampleOptions o;
  EXPECT_THROW(options::FromJson(o, nlohmann::json{{"nope", 1}}), InvalidOptions);
  EXPECT_THROW(options::FromJson(o, nlohmann::json{{"count", "three"}}), InvalidOptions);
  EXPECT_THROW(options::FromJson(o, nlohmann::json::array()), InvalidOptions);
  options::FromJson(o, nlohmann::json{{"count", 4}});
  EXPECT_EQ(o.count, 4);
  EXPECT_EQ(o.name, "default");  // Absent keys keep their value.
}

TEST(Options, HelpListsFlagsAliasesAndDefaults) {
  const std::string help = options::Help(SampleOptions{});
  EXPECT_NE(help.find("-n, --count VALUE"), std::string::npos) << help;
  EXPECT_NE(help.find("[default: 3]"), std::string::npos) << help;
  EXPECT_NE(help.find("-f, --fast "), std::string::npos) << help;
  EXPECT_EQ(help.find("--fast VALUE"), std::string::npos) << help;
}

TEST(Options, ValidateThrowsInvalidOptions) {
  SampleOptions o;
  o.count = 0;
  EXPECT_THROW(o.Validate(), InvalidOptions);
}

}  // namespace
}  // namespace avatar
