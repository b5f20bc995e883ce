#pragma once
// Runs a command line through the shell and captures its exit code, stdout and stderr.

#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>

#include "common/temp_dir.h"

namespace avatar::testing {

struct ProcessResult {
  int exit_code = -1;
  std::string out;
  std::string err;
};

inline ProcessResult RunProcess(const std::string& command, const std::string& env = "") {
  TempDir dir;
  const std::string out_file = (dir / "out").string();
  const std::string err_file = (dir / "err").string();
  const std::string full = env + " " + command + " >'" + out_file + "' 2>'" + err_file + "' </dev/null";
  const int status = std::system(full.c_str());
  ProcessResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  auto slurp = [](const std::string& path) {
    std::ifstream in(path);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
  };
  r.out = slurp(out_file);
  r.err = slurp(err_file);
  return r;
}

}  // namespace avatar::testing
