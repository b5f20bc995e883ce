// `avatar-studio bench train`: the table, the JSON file and the relations between its columns, and
// Ctrl+C, through the real executable; usage errors and help in this process (command library).
#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "cli/in_process.h"
#include "common/run_process.h"
#include "common/temp_dir.h"

namespace avatar {
namespace {

using avatar::testing::InProcess;
using avatar::testing::ProcessResult;
using avatar::testing::TempDir;

ProcessResult Studio(const std::string& args, const std::string& prefix = "") {
  return avatar::testing::RunProcess(prefix + " '" + std::string(AVATAR_STUDIO_EXE) + "' " + args,
                                     "env -u DISPLAY -u WAYLAND_DISPLAY -u QT_QPA_PLATFORM");
}

// The cells of the table row that starts with "| <config> | <batch> |" (empty when absent).
std::vector<std::string> Row(const std::string& out, const std::string& config, int batch) {
  std::istringstream lines(out);
  std::string line;
  const std::string start = "| " + config + " | " + std::to_string(batch) + " |";
  while (std::getline(lines, line)) {
    if (line.rfind(start, 0) != 0) continue;
    std::vector<std::string> cells;
    std::istringstream parts(line);
    std::string cell;
    std::getline(parts, cell, '|');  // before the first bar
    while (std::getline(parts, cell, '|')) {
      const size_t a = cell.find_first_not_of(' '), b = cell.find_last_not_of(' ');
      if (a != std::string::npos) cells.push_back(cell.substr(a, b - a + 1));
    }
    return cells;
  }
  return {};
}

double Number(const std::string& cell) { return std::stod(cell); }  // "1.00x" -> 1.0

// Columns: config, batch, step, forward, backward + update, samples/s, peak RSS, RSS growth,
// step / tiny b1, GEMM GFLOP/s, step / GEMM.
void ExpectSaneRow(const std::vector<std::string>& cells, int batch, const std::string& what) {
  ASSERT_GE(cells.size(), 11u) << what;
  const double step = Number(cells[2]), forward = Number(cells[3]), backward = Number(cells[4]);
  EXPECT_TRUE(std::isfinite(step) && step > 0) << what << ": step " << cells[2];
  EXPECT_TRUE(std::isfinite(forward) && forward > 0) << what << ": forward " << cells[3];
  EXPECT_TRUE(std::isfinite(backward)) << what << ": backward " << cells[4];
  EXPECT_NEAR(Number(cells[5]), batch / step, 0.02 * batch / step + 0.01) << what << ": samples/s";
  EXPECT_GT(Number(cells[6]), 10.0) << what << ": peak RSS (MB)";
  EXPECT_GE(Number(cells[7]), 0.0) << what << ": RSS growth";
  EXPECT_NE(cells[8].find('x'), std::string::npos) << what << ": ratio column " << cells[8];
  EXPECT_GT(Number(cells[8]), 0.0) << what;
  EXPECT_GT(Number(cells[9]), 0.0) << what << ": GEMM GFLOP/s";
  EXPECT_GT(Number(cells[10]), 0.0) << what << ": step / GEMM";
}

TEST(BenchTrain, TinyBatchOnePrintsATableWithPositiveTimesAndRatios) {
  // The default perceptual term (MobileNetV2, as training uses).
  const auto r = Studio("bench train --configs tiny --batches 1 --steps 2");
  if (r.exit_code == 1 && r.err.find("nsfwjs") != std::string::npos) {
    FAIL() << "MobileNetV2 (nsfwjs) weights not installed (run scripts/setup): " << r.err;
  }
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  EXPECT_NE(r.out.find("| step / tiny b1 |"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("perceptual mobilenet"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("GEMM peak (fp32 1024^3"), std::string::npos) << r.out;
  const auto cells = Row(r.out, "tiny", 1);
  ExpectSaneRow(cells, 1, "tiny b1");
  // It is its own reference.
  ASSERT_GE(cells.size(), 9u);
  EXPECT_EQ(cells[8], "1.00x");
}

TEST(BenchTrain, JsonAgreesWithItselfAndTheReferenceIsAddedWhenNotAsked) {
  TempDir dir;
  const std::string json_path = (dir / "bench.json").string();
  // tiny batch 2 only: the tiny batch-1 reference is measured first and marked.
  const auto r = Studio("bench train --configs tiny --batches 2 --steps 3 --warmup 1 --perceptual pyramid --json '" +
                        json_path + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  ExpectSaneRow(Row(r.out, "tiny (reference)", 1), 1, "reference row");
  ExpectSaneRow(Row(r.out, "tiny", 2), 2, "tiny b2");
  std::ifstream in(json_path);
  ASSERT_TRUE(in.good()) << json_path;
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j.at("perceptual"), "pyramid");
  EXPECT_GT(j.at("gemm_gflops_before").get<double>(), 0.0);
  EXPECT_GT(j.at("gemm_gflops_after").get<double>(), 0.0);
  const auto& rows = j.at("rows");
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_TRUE(rows[0].at("reference_only").get<bool>());
  EXPECT_EQ(rows[0].at("batch"), 1);
  EXPECT_FALSE(rows[1].at("reference_only").get<bool>());
  EXPECT_EQ(rows[1].at("batch"), 2);
  const double reference = j.at("reference_step_s").get<double>();
  EXPECT_DOUBLE_EQ(reference, rows[0].at("step_s").get<double>());
  for (const auto& row : rows) {
    const auto steps = row.at("step_times_s").get<std::vector<double>>();
    const auto forwards = row.at("forward_times_s").get<std::vector<double>>();
    ASSERT_EQ(steps.size(), 3u);
    ASSERT_EQ(forwards.size(), 3u);
    for (double t : steps) EXPECT_TRUE(std::isfinite(t) && t > 0);
    for (double t : forwards) EXPECT_TRUE(std::isfinite(t) && t > 0);
    std::vector<double> sorted = steps;
    std::sort(sorted.begin(), sorted.end());
    const double step = row.at("step_s").get<double>();
    EXPECT_DOUBLE_EQ(step, sorted[1]) << "median of 3";
    EXPECT_NEAR(row.at("backward_s").get<double>(), step - row.at("forward_s").get<double>(), 1e-12);
    EXPECT_NEAR(row.at("samples_per_s").get<double>(), row.at("batch").get<double>() / step, 1e-9);
    EXPECT_NEAR(row.at("step_ratio_to_tiny_b1").get<double>(), step / reference, 1e-9);
    const double gemm_s = 2.0 * 1024 * 1024 * 1024 / (row.at("gemm_gflops").get<double>() * 1e9);
    EXPECT_NEAR(row.at("step_ratio_to_gemm").get<double>(), step / gemm_s, 1e-6 * step / gemm_s);
    // The forward pass draws the step's random numbers: it computes the step's loss.
    EXPECT_LT(row.at("forward_loss_rel_diff").get<double>(), 1e-4);
    EXPECT_TRUE(std::isfinite(row.at("last_loss").get<double>()));
    EXPECT_EQ(row.at("skipped_steps"), 0);
    EXPECT_GT(row.at("peak_rss_mb").get<double>(), 10.0);
  }
}

// Argument checks run in this process (the command library); the runs above and below use the binary.
TEST(BenchTrain, BadOptionsAreUsageErrors) {
  const std::vector<std::vector<std::string>> cases = {
      {"--configs", "huge"}, {"--configs", ""},  {"--batches", "0"},    {"--batches", "1,x"},      {"--batches", "65"},
      {"--steps", "0"},      {"--warmup", "-1"}, {"--perceptual", "vgg"}, {"--bogus", "1"}, {"stray"}};
  for (const auto& flags : cases) {
    std::vector<std::string> args = {"bench", "train"};
    args.insert(args.end(), flags.begin(), flags.end());
    const auto r = InProcess(args);
    EXPECT_EQ(r.exit_code, 2) << flags[0] << "\n" << r.err;
    EXPECT_NE(r.err.find("bench train"), std::string::npos) << flags[0] << "\n" << r.err;
  }
}

TEST(BenchTrain, HelpListsTheOptionsAndBenchListsTheSubject) {
  const auto help = InProcess({"bench", "train", "--help"});
  EXPECT_EQ(help.exit_code, 0) << help.err;
  for (const char* flag : {"--configs", "--batches", "--steps", "--warmup", "--perceptual", "--json", "--threads"}) {
    EXPECT_NE(help.out.find(flag), std::string::npos) << flag << "\n" << help.out;
  }
  const auto bench = InProcess({"bench", "--help"});
  EXPECT_EQ(bench.exit_code, 0);
  EXPECT_NE(bench.out.find("  train "), std::string::npos) << bench.out;
}

TEST(BenchTrain, InterruptCancelsCleanly) {
  // SIGINT in the middle of 100 timed steps: exit 130, no table rows for the unfinished case and
  // no JSON file. The signal is sent once the table header is out (the steps are running), not
  // after a fixed time: on a loaded machine a fixed 3 s could land before the handler exists.
  TempDir dir;
  const std::string json_path = (dir / "bench.json").string();
  const std::string out_path = (dir / "stdout").string();
  const std::string script =
      "\"$1\" bench train --configs tiny --batches 1 --steps 100 --warmup 0 --perceptual pyramid --json \"$2\" "
      ">\"$3\" & p=$!; i=0; "
      "until grep -q \"^| config\" \"$3\" || [ $i -ge 3000 ]; do sleep 0.1; i=$((i+1)); done; "
      "kill -INT $p; wait $p; rc=$?; cat \"$3\"; exit $rc";
  const auto r = avatar::testing::RunProcess("sh -c '" + script + "' sh '" + std::string(AVATAR_STUDIO_EXE) + "' '" +
                                                 json_path + "' '" + out_path + "'",
                                             "env -u DISPLAY -u WAYLAND_DISPLAY -u QT_QPA_PLATFORM");
  EXPECT_NE(r.out.find("| config |"), std::string::npos) << "the steps never started\n" << r.out << r.err;
  EXPECT_EQ(r.exit_code, 130) << r.err << r.out;
  EXPECT_NE(r.err.find("cancelled"), std::string::npos) << r.err;
  EXPECT_TRUE(Row(r.out, "tiny", 1).empty()) << r.out;
  EXPECT_FALSE(std::ifstream(json_path).good());
}

}  // namespace
}  // namespace avatar
