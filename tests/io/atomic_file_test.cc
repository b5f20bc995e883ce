#include "core/io/atomic_file.h"

#include <gtest/gtest.h>

#include "common/temp_dir.h"
#include "core/util/error.h"

namespace avatar {
namespace {

using avatar::testing::TempDir;

TEST(AtomicFile, WritesAndReplaces) {
  TempDir dir;
  WriteBytesAtomically(dir / "f.txt", "one");
  WriteBytesAtomically(dir / "f.txt", "two");
  EXPECT_EQ(ReadFileBytes(dir / "f.txt"), "two");
  EXPECT_EQ(dir.List(), std::vector<std::string>{"f.txt"});
}

TEST(AtomicFile, FailedWriteKeepsTheOldFileAndLeavesNoTemporary) {
  TempDir dir;
  WriteBytesAtomically(dir / "f.txt", "precious");
  EXPECT_THROW(WriteFileAtomically(dir / "f.txt",
                                   [](const std::filesystem::path& temp) {
                                     WriteBytesAtomically(temp, "half");
                                     throw Cancelled("stop");
                                   }),
               Cancelled);
  EXPECT_EQ(ReadFileBytes(dir / "f.txt"), "precious");
  EXPECT_EQ(dir.List(), std::vector<std::string>{"f.txt"});
}

TEST(AtomicFile, WriterThatProducesNothingIsAnError) {
  TempDir dir;
  EXPECT_THROW(WriteFileAtomically(dir / "f.txt", [](const std::filesystem::path&) {}), Io);
  EXPECT_TRUE(dir.List().empty());
}

TEST(AtomicFile, TemporaryKeepsTheExtension) {
  TempDir dir;
  std::string seen;
  WriteFileAtomically(dir / "clip.mp4", [&](const std::filesystem::path& temp) {
    seen = temp.extension().string();
    WriteBytesAtomically(temp, "x");
  });
  EXPECT_EQ(seen, ".mp4");
}

TEST(AtomicFile, ReadErrorsNameTheFile) {
  TempDir dir;
  try {
    ReadFileBytes(dir / "nope.bin");
    FAIL();
  } catch (const Io& e) {
    EXPECT_NE(std::string(e.what()).find("nope.bin"), std::string::npos);
  }
}

}  // namespace
}  // namespace avatar
