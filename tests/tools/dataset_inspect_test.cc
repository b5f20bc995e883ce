// core/pipeline/dataset_inspect (`avatar-studio dataset inspect DIR`) on a tiny dataset built
// here: the counts, split and per-frame values agree with the dataset's own files, both sheets
// are written where asked and have the documented layout, bad options write nothing, --kind
// synthetic on a dataset without synthetic pairs is refused after the histograms, and the
// command prints what the report holds.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "cli/in_process.h"
#include "common/temp_dir.h"
#include "common/tiny_dataset.h"
#include "core/io/atomic_file.h"
#include "core/io/image_io.h"
#include "core/tools/dataset_inspect.h"
#include "core/train/dataset.h"
#include "core/util/error.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::TempDir;

class DatasetInspect : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir();
    RunContext ctx;
    BuildDataset(testing::TinyDatasetOptions(*dir_ / "ds", 1), testing::TinyDatasetPhotos(), {}, ctx);
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static fs::path Data() { return *dir_ / "ds"; }
  static json Load(const std::string& name) { return json::parse(ReadFileBytes(Data() / name)); }

  static TempDir* dir_;
};
TempDir* DatasetInspect::dir_ = nullptr;

TEST_F(DatasetInspect, ReportAgreesWithTheDatasetFilesAndWritesBothSheets) {
  TempDir out;
  DatasetInspectOptions o;
  o.dir = Data().string();
  o.contact = (out / "contact.png").string();
  o.histograms = (out / "hist.png").string();
  o.pairs = 3;
  RunContext ctx;
  const DatasetInspection d = InspectDataset(o, ctx);

  const json ds = Load("dataset.json"), records = Load("records.json");
  EXPECT_EQ(d.size, 128);
  EXPECT_EQ(d.counts.size(), ds.at("counts").size());
  EXPECT_EQ(d.val_identities.size(), ds.at("split").at("val").size());
  EXPECT_EQ(d.val_identities.size(), 1u);
  EXPECT_EQ(d.train_identities, static_cast<int64_t>(ds.at("split").at("train").size()));
  ASSERT_EQ(d.yaw.size(), records.size());
  EXPECT_EQ(d.pitch.size(), records.size());
  EXPECT_EQ(d.expression.size(), records.size());
  for (size_t i = 0; i < records.size(); ++i) {
    EXPECT_DOUBLE_EQ(d.yaw[i], records[i].at("pose").at("yaw").get<double>());
    EXPECT_GE(d.expression[i], 0.0);
  }
  EXPECT_TRUE(d.clip_d_yaw.empty());  // photos only
  EXPECT_FALSE(d.has_synthetic);
  EXPECT_FALSE(d.synthetic.has_value());

  const train::TrainDataset train_set = train::TrainDataset::Open(Data().string(), "train");
  const train::TrainDataset val_set = train::TrainDataset::Open(Data().string(), "val");
  EXPECT_EQ(d.train.pairs, train_set.size());
  EXPECT_EQ(d.val.pairs, val_set.size());
  EXPECT_EQ(d.train.photo_pairs + d.train.clip_pairs, d.train.pairs);
  EXPECT_GT(d.train.pairs, 0);

  // Histograms: 2 rows (clip, synthetic pairs) x 3 panels of 320 x 200; contact: one row of four
  // 128 px tiles per pair.
  EXPECT_EQ(d.histograms_path, o.histograms);
  const cv::Mat hist = LoadImageBgr(o.histograms);
  EXPECT_EQ(hist.cols, 3 * 320);
  EXPECT_EQ(hist.rows, 2 * 200);
  EXPECT_EQ(d.contact_path, o.contact);
  const cv::Mat contact = LoadImageBgr(o.contact);
  EXPECT_EQ(contact.cols, 4 * 128);
  EXPECT_EQ(contact.rows, 3 * 128);
  // Nothing is written into the dataset folder when both paths are given.
  EXPECT_FALSE(fs::exists(Data() / "contact.png"));
  EXPECT_FALSE(fs::exists(Data() / "histograms.png"));
}

TEST_F(DatasetInspect, BadOptionsWriteNothingAndSyntheticWithoutPairsIsRefusedAfterTheHistograms) {
  TempDir out;
  DatasetInspectOptions o;
  o.dir = Data().string();
  o.contact = (out / "contact.png").string();
  o.histograms = (out / "hist.png").string();
  RunContext ctx;
  for (const int pairs : {0, 65}) {
    DatasetInspectOptions bad = o;
    bad.pairs = pairs;
    EXPECT_THROW(InspectDataset(bad, ctx), InvalidOptions) << pairs;
  }
  DatasetInspectOptions bad_kind = o;
  bad_kind.kind = "clips";
  EXPECT_THROW(InspectDataset(bad_kind, ctx), InvalidOptions);
  EXPECT_TRUE(out.List().empty());

  DatasetInspectOptions synthetic = o;
  synthetic.kind = "synthetic";
  try {
    InspectDataset(synthetic, ctx);
    FAIL() << "--kind synthetic was accepted on a dataset without synthetic pairs";
  } catch (const InvalidOptions& e) {
    EXPECT_NE(std::string(e.what()).find("no synthetic pairs"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(fs::exists(out / "hist.png"));
  EXPECT_FALSE(fs::exists(out / "contact.png"));

  DatasetInspectOptions missing = o;
  missing.dir = (out / "nothing-here").string();
  EXPECT_THROW(InspectDataset(missing, ctx), Error);
}

TEST_F(DatasetInspect, IdentityOptionPutsOnlyThatIdentitysPairsOnTheContactSheet) {
  // Identity ids are positions in split.json's names; find a training identity with one pair.
  const json names = Load("split.json").at("identities");
  const train::TrainDataset train_set = train::TrainDataset::Open(Data().string(), "train");
  std::string single;
  for (size_t id = 0; id < names.size() && single.empty(); ++id) {
    int64_t count = 0;
    for (int64_t i = 0; i < train_set.size(); ++i) count += train_set.PairIdentity(i) == static_cast<int64_t>(id);
    if (count == 1) single = names[id].get<std::string>();
  }
  ASSERT_FALSE(single.empty()) << "the tiny dataset has no training identity with exactly one pair";
  ASSERT_GT(train_set.size(), 1) << "the check below needs more than one training pair";

  TempDir out;
  RunContext ctx;
  auto sheet = [&](const std::string& identity, int64_t seed, const std::string& name) {
    DatasetInspectOptions o;
    o.dir = Data().string();
    o.contact = (out / name).string();
    o.histograms = (out / "hist.png").string();
    o.pairs = 4;
    o.seed = seed;
    o.identity = identity;
    InspectDataset(o, ctx);
    return LoadImageBgr(o.contact);
  };
  // One identity with one pair: every row is that pair, whatever the seed.
  const cv::Mat a = sheet(single, 1, "a.png"), b = sheet(single, 2, "b.png");
  ASSERT_EQ(a.rows, 4 * 128);
  EXPECT_EQ(cv::norm(a, b, cv::NORM_INF), 0.0);
  for (int r = 1; r < 4; ++r)
    EXPECT_EQ(cv::norm(a.rowRange(0, 128), a.rowRange(r * 128, (r + 1) * 128), cv::NORM_INF), 0.0) << r;
  // Without the option, rows come from every pair: over a few seeds, some row differs.
  double spread = 0.0;
  for (int64_t seed = 1; seed <= 4; ++seed) {
    const cv::Mat all = sheet("", seed, "all.png");
    for (int r = 1; r < 4; ++r)
      spread = std::max(spread, cv::norm(all.rowRange(0, 128), all.rowRange(r * 128, (r + 1) * 128), cv::NORM_INF));
  }
  EXPECT_GT(spread, 0.0);

  // An unknown name and a validation identity are refused, naming the option.
  DatasetInspectOptions o;
  o.dir = Data().string();
  o.contact = (out / "bad.png").string();
  o.histograms = (out / "hist.png").string();
  for (const std::string& bad : {std::string("nobody"), Load("split.json").at("val").at(0).get<std::string>()}) {
    o.identity = bad;
    try {
      InspectDataset(o, ctx);
      ADD_FAILURE() << "--identity " << bad << " was accepted";
    } catch (const InvalidOptions& e) {
      EXPECT_NE(std::string(e.what()).find("--identity"), std::string::npos) << e.what();
    }
  }
  EXPECT_FALSE(fs::exists(out / "bad.png"));
}

TEST_F(DatasetInspect, CommandPrintsTheReport) {
  TempDir out;
  const std::string contact = (out / "c.png").string(), hist = (out / "h.png").string();
  const auto r = testing::InProcess(
      {"dataset", "inspect", Data().string(), "--contact", contact, "--histograms", hist, "--pairs", "2"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  RunContext ctx;
  DatasetInspectOptions o;
  o.dir = Data().string();
  o.contact = (out / "again.png").string();
  o.histograms = (out / "again-h.png").string();
  const DatasetInspection d = InspectDataset(o, ctx);
  for (const std::string& line :
       {"dataset " + Data().string() + " (size 128)\n",
        "split (seed " + std::to_string(d.split_seed) + "): " + std::to_string(d.train_identities) +
            " train identities, 1 val identities:\n  val: " + d.val_identities.at(0) + "\n",
        "yaw of all frames (degrees) (" + std::to_string(d.yaw.size()) + " values)\n",
        "histograms (clip and synthetic pairs: |d yaw|, |d pitch|, |d beta|): " + hist + "\n",
        "shards: train " + std::to_string(d.train.pairs) + " pairs (" + std::to_string(d.train.photo_pairs) +
            " photo, " + std::to_string(d.train.clip_pairs) + " clip)",
        std::string("synthetic: none (build with --synthetic N)\n"),
        "contact sheet (source | target | I_exp | M_neu, 2 random train pairs): " + contact + "\n"}) {
    EXPECT_NE(r.out.find(line), std::string::npos) << line << "\n---\n" << r.out;
  }
  EXPECT_EQ(LoadImageBgr(contact).rows, 2 * 128);
}

}  // namespace
}  // namespace avatar
