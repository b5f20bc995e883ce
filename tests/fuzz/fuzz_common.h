#pragma once
// Shared pieces of the libFuzzer targets (tests/fuzz/*_fuzz.cc) and of their regression replay
// (regression_test.cc, normal build).
//
// A target is one function that feeds bytes to a parser of untrusted input. The parser may
// succeed or throw avatar::Error (any kind); every other exception, a crash, a sanitizer report
// or a hang is a finding. Targets register themselves with AVATAR_FUZZ_TARGET; fuzz_main.cc
// turns the one linked target into libFuzzer's entry points, the regression test runs all.
//
// Inputs of parsers that read several files (a model and its weight shards, a dataset folder)
// are one byte string holding named parts (MultiFile below); the first part is the file handed
// to the parser.
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace avatar::fuzz {

// The separator of MultiFile parts; the part's file name follows it up to the next newline.
inline constexpr std::string_view kPartSeparator = "\n--avatar-fuzz-file ";

struct Target {
  std::string name;
  // Feeds one input to the parser; avatar::Error is caught inside, anything else escapes.
  // Returns "" when the parser accepted the input, else the avatar::Error it threw.
  std::function<std::string(std::string_view input)> run;
  // Writes seed inputs (valid files, and edge cases) into `dir`; returns how many.
  std::function<int(const std::filesystem::path& dir)> make_seeds;
};

// Every registered target (one in a fuzz executable, all in the regression test).
std::vector<Target>& Targets();
bool Register(Target target);

// A folder of this process under the system temporary folder (mkdtemp), removed at exit.
const std::filesystem::path& ProcessTempDir();
// An empty folder for one input: ProcessTempDir()/input, emptied on every call.
std::filesystem::path FreshInputDir();

// Writes bytes to a file (parents created). Throws std::runtime_error.
void WriteFile(const std::filesystem::path& path, std::string_view bytes);
std::string ReadFile(const std::filesystem::path& path);

// Parts of a multi-file input: (name, bytes). A name is made safe (letters, digits, . _ - and
// one level of folders; anything else becomes "partN"); the first part has no name line and
// takes `first_name`.
std::vector<std::pair<std::string, std::string>> SplitParts(std::string_view input, const std::string& first_name);
std::string JoinParts(const std::vector<std::pair<std::string, std::string>>& parts);
// Writes the parts into `dir`; returns the path of the first one.
std::filesystem::path WriteParts(const std::filesystem::path& dir,
                                 const std::vector<std::pair<std::string, std::string>>& parts);

// The data folder of scripts/setup ($AVATAR_DATA_DIR, else ~/.cache/avatar-studio), for seeds
// made from its files; "" when it does not exist.
std::filesystem::path DataDir();

// Tensor archives (.ckpt, .avatar) end in a 64-bit FNV-1a checksum of every byte before it; a
// mutated input almost never matches, and the decoder stops there. The archive targets therefore
// write the right checksum into the last 8 bytes (of an input of at least 36 bytes) so that the
// header and tensor checks behind it are fuzzed too.
std::string WithArchiveChecksum(std::string_view input);

// Runs `parse`; avatar::Error (the documented outcome for a bad file) is caught and returned as
// "KIND: message"; "" when `parse` succeeded. Every other exception escapes.
std::string AcceptAvatarErrors(const std::function<void()>& parse);

}  // namespace avatar::fuzz

#define AVATAR_FUZZ_CONCAT2(a, b) a##b
#define AVATAR_FUZZ_CONCAT(a, b) AVATAR_FUZZ_CONCAT2(a, b)
// AVATAR_FUZZ_TARGET("name", run, make_seeds) at namespace scope of a *_fuzz.cc file.
#define AVATAR_FUZZ_TARGET(name, run, seeds)                   \
  static const bool AVATAR_FUZZ_CONCAT(kRegistered_, __LINE__) = \
      ::avatar::fuzz::Register(::avatar::fuzz::Target{name, run, seeds})
