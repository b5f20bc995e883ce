#pragma once
// Runs avatar-studio command lines inside the test process through the command library
// (app/commands.h), capturing what they print: argument handling without spawning the binary.
// The test executable links avatar_app (avatar_add_gtest ... APP).

#include <cstdlib>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "app/commands.h"
#include "common/run_process.h"

namespace avatar::testing {

// `avatar-studio ARGS...` run in this process: exit code, stdout, stderr.
inline ProcessResult InProcess(const std::vector<std::string>& args) {
  std::ostringstream out, err;
  ProcessResult r;
  r.exit_code = app::RunCommandLine(args, out, err);
  r.out = out.str();
  r.err = err.str();
  return r;
}

// Sends std::cout to `stream` for one scope (for calling a RunXImpl directly).
class CoutTo {
 public:
  explicit CoutTo(std::ostream& stream) : old_(std::cout.rdbuf(stream.rdbuf())) {}
  ~CoutTo() { std::cout.rdbuf(old_); }
  CoutTo(const CoutTo&) = delete;
  CoutTo& operator=(const CoutTo&) = delete;

 private:
  std::streambuf* old_;
};

// Sets an environment variable for one scope and restores the old value.
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const char* value) : name_(name) {
    if (const char* old = std::getenv(name)) old_ = old;
    setenv(name, value, 1);
  }
  ~ScopedEnv() {
    if (old_) {
      setenv(name_, old_->c_str(), 1);
    } else {
      unsetenv(name_);
    }
  }
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;

 private:
  const char* name_;
  std::optional<std::string> old_;
};

}  // namespace avatar::testing
