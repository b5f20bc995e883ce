// The quality ladder (core/pipeline/quality.h): every quality level validates, the ladder is ordered
// from cheapest to most refined for every model config, `paper` is the published setting, the
// session renders a level's settings, the estimates cache round-trips and a corrupt or foreign
// cache is measured again instead of trusted, and a measurement on the tiny random-weight model
// gives finite positive times.

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <thread>

#include <nlohmann/json.hpp>

#include "common/temp_dir.h"
#include "common/tiny_checkpoint.h"
#include "core/io/atomic_file.h"
#include "core/model/model_config.h"
#include "core/pipeline/quality.h"
#include "core/pipeline/session.h"
#include "core/util/error.h"
#include "synthetic_expression_source.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::TempDir;

ModelInfo InfoOf(const std::string& config) {
  const ModelConfig c = ModelConfig::FromName(config);
  ModelInfo info;
  info.config_name = c.name;
  info.config_json = ModelConfigToJson(c);
  info.render_size = c.render_size;
  info.sr_size = c.sr_size;
  return info;
}

// Estimates with distinct, valid values for every level.
QualityEstimates Sample(const std::string& model_id, int threads) {
  QualityEstimates e;
  e.model_id = model_id;
  e.threads = threads;
  e.config_json = ModelConfigToJson(ModelConfig::Tiny());
  e.measured_at = "2026-01-01T00:00:00Z";
  e.ladder = QualityLadderFingerprint();
  e.one_shot_seconds = 0.5;
  e.refine_setup_seconds = 0.25;
  e.refine_step_seconds = 0.125;
  double t = 1.0;
  for (const auto& p : QualityLadder()) {
    e.levels.push_back({p.name, t, t / 100.0});
    t += 1.0;
  }
  return e;
}

void WriteText(const fs::path& path, const std::string& text) {
  std::ofstream f(path, std::ios::binary);
  f << text;
}

TEST(QualityLadder, EveryLevelValidatesAndNamesAreUnique) {
  const auto& ladder = QualityLadder();
  ASSERT_EQ(ladder.size(), 6u);
  const std::vector<std::string> names = {"instant", "preview", "standard", "fine", "best", "paper"};
  for (size_t i = 0; i < ladder.size(); ++i) {
    EXPECT_EQ(ladder[i].name, names[i]);
    EXPECT_NO_THROW(ladder[i].Validate()) << ladder[i].name;
    EXPECT_FALSE(ladder[i].summary.empty()) << ladder[i].name;
    EXPECT_EQ(&QualityLevelByName(names[i]), &ladder[i]);
  }
  EXPECT_EQ(QualityLevelNames(), "instant, preview, standard, fine, best, paper");
  try {
    QualityLevelByName("ultra");
    ADD_FAILURE() << "an unknown quality level was accepted";
  } catch (const InvalidOptions& e) {
    EXPECT_NE(std::string(e.what()).find("ultra"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("instant, preview"), std::string::npos) << e.what();
  }
}

TEST(QualityLadder, BadLevelsAreRefused) {
  QualityLevel p = QualityLevelByName("standard");
  p.render_scale = 0.0;
  EXPECT_THROW(p.Validate(), InvalidOptions);
  p = QualityLevelByName("standard");
  p.sample_scale = std::nan("");
  EXPECT_THROW(p.Validate(), InvalidOptions);
  p = QualityLevelByName("standard");
  p.refine_steps = -1;
  EXPECT_THROW(p.Validate(), InvalidOptions);
  p = QualityLevelByName("standard");
  p.refine_seconds = -2.0;
  EXPECT_THROW(p.Validate(), InvalidOptions);
  p = QualityLevelByName("standard");
  p.name.clear();
  EXPECT_THROW(p.Validate(), InvalidOptions);
}

TEST(QualityLadder, OrderedFromInstantToBestForEveryConfig) {
  for (const char* config : {"tiny", "cpu", "lite", "paper"}) {
    const ModelInfo info = InfoOf(config);
    const auto& ladder = QualityLadder();
    // instant .. best: frame cost, SR and refinement never decrease.
    for (size_t i = 1; i + 1 < ladder.size(); ++i) {
      const QualityLevel& a = ladder[i - 1];
      const QualityLevel& b = ladder[i];
      EXPECT_LE(a.FrameCost(info), b.FrameCost(info)) << config << ": " << a.name << " vs " << b.name;
      EXPECT_LE(static_cast<int>(a.super_resolution), static_cast<int>(b.super_resolution)) << config << " " << b.name;
      EXPECT_LE(a.refine_steps, b.refine_steps) << config << ": " << a.name << " vs " << b.name;
    }
    const QualityLevel& instant = QualityLevelByName("instant");
    const QualityLevel& best = QualityLevelByName("best");
    for (const auto& p : ladder) {
      if (p.name != "instant") {
        EXPECT_LT(instant.FrameCost(info), p.FrameCost(info)) << config << " " << p.name;
      }
      if (p.name != "best") {
        EXPECT_LT(p.refine_steps, best.refine_steps) << config << " " << p.name;
      }
    }
    EXPECT_EQ(instant.refine_steps, 0);
    EXPECT_FALSE(instant.super_resolution);
  }
}

TEST(QualityLadder, PaperIsThePublishedSettingAndStandardTheModelsOwn) {
  // The paper config is the published network: 128^2 render, 48 + 48 samples, SR to 512, one shot.
  const ModelInfo paper_info = InfoOf("paper");
  const RenderSettings paper = QualityLevelByName("paper").Render(paper_info);
  EXPECT_EQ(paper.resolution, 128);
  EXPECT_EQ(paper.num_coarse, 48);
  EXPECT_EQ(paper.num_importance, 48);
  EXPECT_TRUE(paper.super_resolution);
  EXPECT_FALSE(QualityLevelByName("paper").Refine().Enabled());
  EXPECT_EQ(QualityLevelByName("paper").Describe(paper_info), "128 px, 48+48 samples, SR to 512 px, no refinement");
  // Any other config: its own render size and samples.
  const ModelConfig cpu = ModelConfig::FromName("cpu");
  const RenderSettings standard = QualityLevelByName("standard").Render(InfoOf("cpu"));
  EXPECT_EQ(standard.resolution, cpu.render_size);
  EXPECT_EQ(standard.num_coarse, cpu.num_coarse);
  EXPECT_EQ(standard.num_importance, cpu.num_importance);
  EXPECT_FALSE(standard.super_resolution);
  const RenderSettings instant = QualityLevelByName("instant").Render(InfoOf("cpu"));
  EXPECT_EQ(instant.resolution, cpu.render_size / 2);
  EXPECT_EQ(instant.num_coarse, cpu.num_coarse / 2);
  // The level's refinement keeps the caller's weights.
  RefineOptions base;
  base.lr = 0.01;
  base.perceptual_weight = 0.0;
  const RefineOptions fine = QualityLevelByName("fine").Refine(base);
  EXPECT_EQ(fine.steps, 30);
  EXPECT_EQ(fine.lr, 0.01);
  EXPECT_EQ(fine.perceptual_weight, 0.0);
}

TEST(QualityLadder, LadderTextListsEveryLevelWithItsEstimateOrNotMeasured) {
  const ModelInfo info = InfoOf("cpu");
  const std::string none = QualityLadderText(&info, std::nullopt);
  for (const auto& p : QualityLadder()) {
    EXPECT_NE(none.find("  " + p.name), std::string::npos) << none;
    EXPECT_NE(none.find(p.Describe(info)), std::string::npos) << none;
  }
  size_t count = 0;
  for (size_t at = none.find("not measured yet"); at != std::string::npos; at = none.find("not measured yet", at + 1))
    ++count;
  EXPECT_EQ(count, QualityLadder().size()) << none;
  const QualityEstimates e = Sample("ckpt:x", 2);
  const std::string some = QualityLadderText(&info, e);
  EXPECT_EQ(some.find("not measured yet"), std::string::npos) << some;
  EXPECT_NE(some.find(FormatQualityEstimate(e.Find("best"))), std::string::npos) << some;
  EXPECT_EQ(FormatQualityEstimate(e.Find("instant")), "reconstruct ~1.00 s, frame 10 ms");
  QualityEstimate detail = *e.Find("instant");
  detail.detail_frame_seconds = 0.025;
  EXPECT_EQ(FormatQualityEstimate(&detail), "reconstruct ~1.00 s, frame 10 ms, with detail 25 ms at 256 px");
}

TEST(QualityCache, RoundTripKeepsOtherEntriesAndReplacesOwn) {
  TempDir dir;
  const fs::path cache = dir / "sub" / "quality-estimates.json";
  std::string why;
  EXPECT_FALSE(ReadCachedQualityEstimates(cache, "ckpt:a", 2, &why));
  EXPECT_NE(why.find("no cache file"), std::string::npos) << why;

  const QualityEstimates a = Sample("ckpt:a", 2);
  QualityEstimates b = Sample("ckpt:b", 2);
  b.levels[0].frame_seconds = 0.75;
  WriteCachedQualityEstimates(cache, a);
  WriteCachedQualityEstimates(cache, b);
  const auto ra = ReadCachedQualityEstimates(cache, "ckpt:a", 2);
  const auto rb = ReadCachedQualityEstimates(cache, "ckpt:b", 2);
  ASSERT_TRUE(ra && rb);
  EXPECT_FALSE(ReadCachedQualityEstimates(cache, "ckpt:a", 1)) << "keyed by the thread count too";
  EXPECT_EQ(ra->levels.size(), a.levels.size());
  for (size_t i = 0; i < a.levels.size(); ++i) {
    EXPECT_EQ(ra->levels[i].level, a.levels[i].level);
    EXPECT_EQ(ra->levels[i].reconstruct_seconds, a.levels[i].reconstruct_seconds);
    EXPECT_EQ(ra->levels[i].frame_seconds, a.levels[i].frame_seconds);
  }
  EXPECT_EQ(ra->one_shot_seconds, a.one_shot_seconds);
  EXPECT_EQ(ra->refine_step_seconds, a.refine_step_seconds);
  EXPECT_EQ(ra->config_json, a.config_json);
  EXPECT_EQ(ra->measured_at, a.measured_at);
  EXPECT_EQ(rb->levels[0].frame_seconds, 0.75);

  QualityEstimates a2 = a;
  a2.one_shot_seconds = 3.0;
  WriteCachedQualityEstimates(cache, a2);
  const json j = json::parse(ReadFileBytes(cache));
  EXPECT_EQ(j["entries"].size(), 2u);
  EXPECT_EQ(ReadCachedQualityEstimates(cache, "ckpt:a", 2)->one_shot_seconds, 3.0);
  for (const auto& name : dir.List()) EXPECT_EQ(name.find(".tmp"), std::string::npos) << name;
}

TEST(QualityCache, LookupByCheckpointFileWithoutLoadingIt) {
  TempDir dir;
  const fs::path cache = dir / "q.json";
  const fs::path ckpt = dir / "model.ckpt";
  WriteText(ckpt, "weights v1");
  QualityEstimates e = Sample("ckpt:c", 3);
  e.checkpoint_path = ckpt.string();
  WriteCachedQualityEstimates(cache, e);
  const auto found = ReadCachedQualityEstimatesForCheckpoint(cache, ckpt, 3);
  ASSERT_TRUE(found);
  EXPECT_EQ(found->model_id, "ckpt:c");
  EXPECT_FALSE(ReadCachedQualityEstimatesForCheckpoint(cache, ckpt, 4));
  // Another file under the same name is another model.
  WriteText(ckpt, "weights version 2, longer");
  EXPECT_FALSE(ReadCachedQualityEstimatesForCheckpoint(cache, ckpt, 3));
  EXPECT_FALSE(ReadCachedQualityEstimatesForCheckpoint(cache, dir / "missing.ckpt", 3));
}

TEST(QualityCache, CorruptOrForeignContentIsNeverTrusted) {
  TempDir dir;
  const fs::path cache = dir / "q.json";
  const QualityEstimates good = Sample("ckpt:a", 2);
  const json good_entry = [&] {
    WriteCachedQualityEstimates(cache, good);
    return json::parse(ReadFileBytes(cache))["entries"][0];
  }();
  auto with_entry = [&](const json& entry) {
    json j = json::parse(ReadFileBytes(cache));
    j["entries"] = json::array({entry});
    return j.dump();
  };
  const std::string valid_file = ReadFileBytes(cache);
  std::vector<std::pair<std::string, std::string>> cases = {
      {"garbage", "\x01\x02 not json {{{"},
      {"truncated", valid_file.substr(0, valid_file.size() / 2)},
      {"array", "[1, 2, 3]"},
      {"other format", R"({"format": "something else", "version": 1, "entries": []})"},
      {"other version", R"({"format": "avatar-studio quality estimates", "version": 99, "entries": []})"},
  };
  json e = good_entry;
  e["presets"]["fine"]["frame_seconds"] = -1.0;
  cases.push_back({"negative time", with_entry(e)});
  e = good_entry;
  e["presets"]["best"]["reconstruct_seconds"] = "fast";
  cases.push_back({"string time", with_entry(e)});
  e = good_entry;
  e["presets"].erase("paper");
  cases.push_back({"missing level", with_entry(e)});
  e = good_entry;
  e["ladder"] = "0000000000000000";
  cases.push_back({"stale ladder", with_entry(e)});
  e = good_entry;
  e["refine_step_seconds"] = 0.0;
  cases.push_back({"zero step time", with_entry(e)});
  cases.push_back({"entry not an object", with_entry(json("text"))});
  for (const auto& [what, text] : cases) {
    WriteText(cache, text);
    std::string why;
    EXPECT_FALSE(ReadCachedQualityEstimates(cache, "ckpt:a", 2, &why)) << what;
    EXPECT_FALSE(why.empty()) << what;
    // Writing replaces a corrupt file with a valid one.
    EXPECT_NO_THROW(WriteCachedQualityEstimates(cache, good)) << what;
    EXPECT_TRUE(ReadCachedQualityEstimates(cache, "ckpt:a", 2)) << what;
  }
  // Incomplete estimates are never written.
  QualityEstimates partial = good;
  partial.levels.pop_back();
  EXPECT_THROW(WriteCachedQualityEstimates(cache, partial), InvalidInput);
}

SessionOptions Tiny() { return testing::TinySessionOptions(5); }

RefineOptions FastRefine() {
  RefineOptions o;
  o.perceptual_weight = 0.0;  // no MobileNetV2 needed; the perceptual term has its own test
  o.tv_points = 200;
  return o;
}

TEST(QualityMeasure, TinyModelGivesFinitePositiveTimesAndCachesThem) {
  const Session session(Tiny());
  TempDir dir;
  const fs::path cache = dir / "q.json";
  WriteText(cache, "corrupt {");
  RunContext ctx;
  bool measured = false;
  const QualityEstimates e = CachedOrMeasuredQualityEstimates(session, cache, ctx, FastRefine(), &measured);
  EXPECT_TRUE(measured) << "a corrupt cache must be measured again";
  EXPECT_TRUE(e.Complete());
  EXPECT_EQ(e.model_id, "random:tiny:5");
  EXPECT_EQ(e.threads, QualityEstimateThreads());
  EXPECT_EQ(ctx.Last().fraction, 1.0);
  for (double v : {e.one_shot_seconds, e.refine_step_seconds}) EXPECT_TRUE(std::isfinite(v) && v > 0) << v;
  for (const auto& p : e.levels) {
    EXPECT_TRUE(std::isfinite(p.reconstruct_seconds) && p.reconstruct_seconds > 0) << p.level;
    EXPECT_TRUE(std::isfinite(p.frame_seconds) && p.frame_seconds > 0) << p.level;
    // The detail path's frame (the test data folder has the morphable model): measured, and at
    // 256 px with the photo's warp on top of the network frame it costs more than the network's.
    EXPECT_TRUE(std::isfinite(p.detail_frame_seconds) && p.detail_frame_seconds > 0) << p.level;
    EXPECT_GT(p.detail_frame_seconds, p.frame_seconds) << p.level;
    EXPECT_NE(FormatQualityEstimate(&p).find("with detail"), std::string::npos) << FormatQualityEstimate(&p);
  }
  // Reconstruct estimates add the level's steps (and the detail path's bake, a few ms) to the
  // same one-shot time.
  const double bake = e.Find("standard")->reconstruct_seconds - e.one_shot_seconds;
  EXPECT_GT(bake, 0.0);
  EXPECT_LT(bake, 1.0);
  EXPECT_NEAR(e.Find("fine")->reconstruct_seconds,
              e.one_shot_seconds + e.refine_setup_seconds + 30 * e.refine_step_seconds, 1.0);
  EXPECT_GT(e.Find("fine")->reconstruct_seconds, e.one_shot_seconds + e.refine_setup_seconds + 30 * e.refine_step_seconds);
  EXPECT_GT(e.Find("best")->reconstruct_seconds, e.Find("fine")->reconstruct_seconds);
  // Now cached: the second call reads the same numbers.
  const QualityEstimates again = CachedOrMeasuredQualityEstimates(session, cache, ctx, FastRefine(), &measured);
  EXPECT_FALSE(measured);
  EXPECT_EQ(again.Find("fine")->frame_seconds, e.Find("fine")->frame_seconds);
  EXPECT_EQ(again.Find("fine")->detail_frame_seconds, e.Find("fine")->detail_frame_seconds);
}

TEST(QualityMeasure, ExpressionBasesModelIsMeasuredFromCoefficients) {
  // A network whose T_e comes from morphable coefficients: the probe gives the zero expression's.
  TempDir dir;
  testing::SaveTinyCheckpoint(dir / "bases.ckpt", 5, {}, /*expression_bases=*/true);
  SessionOptions o;
  o.checkpoint = (dir / "bases.ckpt").string();
  const Session session(o);
  RunContext ctx;
  const QualityEstimates e = MeasureQualityEstimates(session, FastRefine(), ctx);
  EXPECT_TRUE(e.Complete());
  for (const auto& p : e.levels) EXPECT_TRUE(std::isfinite(p.frame_seconds) && p.frame_seconds > 0) << p.level;
  EXPECT_GT(session.Counters().expression_encoder, 0);
  EXPECT_EQ(session.Counters().expression_images, 0);  // no I_exp for this network
}

TEST(QualityMeasure, CancelStopsTheMeasurement) {
  const Session session(Tiny());
  RunContext ctx;
  ctx.RequestCancel();
  EXPECT_THROW(MeasureQualityEstimates(session, FastRefine(), ctx), Cancelled);
}

TEST(QualityRender, SessionRendersEachLevelsSettings) {
  const Session session(Tiny());
  const ModelInfo info = session.Info();
  SourceFit fit;
  fit.camera = avatar::testing::FrontalCameraLabel();
  fit.expressions = std::make_shared<avatar::testing::SyntheticExpressionSource>();
  cv::Mat img(512, 512, CV_8UC3, cv::Scalar(90, 120, 200));
  RunContext ctx;
  const Avatar avatar = session.ReconstructFromAnalysis(PortraitFromAlignedImage(img), fit, ctx);
  for (const auto& p : QualityLadder()) {
    const RenderSettings s = p.Render(info);
    const Frame f = session.Animate(avatar, Expression{}, fit.camera, s);
    EXPECT_EQ(f.render_size, s.resolution) << p.name;
    const int side = p.super_resolution ? info.sr_size : s.resolution;
    EXPECT_EQ(f.bgr.cols, side) << p.name;
    EXPECT_EQ(f.bgr.rows, side) << p.name;
    EXPECT_EQ(f.super_resolved, p.super_resolution) << p.name << " (random weights run the SR)";
  }
  // The RenderMode overload is the settings overload.
  const Frame standard = session.Animate(avatar, Expression{}, fit.camera, RenderMode::kStandard);
  const Frame same = session.Animate(avatar, Expression{}, fit.camera, QualityLevelByName("standard").Render(info));
  ASSERT_EQ(standard.bgr.size(), same.bgr.size());
  EXPECT_EQ(cv::norm(standard.bgr, same.bgr, cv::NORM_INF), 0.0);
  RenderSettings bad;
  bad.resolution = 2;
  EXPECT_THROW(session.Animate(avatar, Expression{}, fit.camera, bad), InvalidOptions);
  bad = {};
  bad.num_importance = -3;
  EXPECT_THROW(session.Animate(avatar, Expression{}, fit.camera, bad), InvalidOptions);
}

}  // namespace
}  // namespace avatar
