#pragma once
// The avatar-studio command table. Every subcommand is RunX(args) -> exit code, which
// parses flags into XOptions and calls RunXImpl(options, ctx); tests call the Impl.

#include <functional>
#include <iostream>
#include <string>
#include <vector>

#include "core/util/options.h"
#include "core/util/run_context.h"

namespace avatar::app {

// Exit codes shared by every command.
inline constexpr int kExitOk = 0;
inline constexpr int kExitError = 1;
inline constexpr int kExitUsage = 2;
inline constexpr int kExitCancelled = 130;

// Options every command accepts.
struct CommonOptions {
  // LibTorch intra-op threads; 0 = all cores (env AVATAR_THREADS overrides 0).
  int threads = 0;
  // Folder with the installed model data and samples ("" = AVATAR_DATA_DIR or the default cache).
  std::string data_dir;
  // Print debug log lines.
  bool verbose = false;
  // Print this command's help.
  bool help = false;

  template <typename V>
  void Visit(V&& v) {
    v("threads", threads, "LibTorch intra-op threads (0 = all cores, or AVATAR_THREADS)");
    v("data_dir", data_dir, "Folder with the installed models and samples (default: AVATAR_DATA_DIR, then ~/.cache/avatar-studio)");
    v("verbose", verbose, "Print debug log lines", 'v');
    v("help", help, "Show this help", 'h');
  }
  void Validate() const;
};

using CommandFn = int (*)(const std::vector<std::string>& args);

struct Command {
  const char* name;
  const char* summary;
  CommandFn run;       // nullptr: reserved for a capability that is not built yet.
};

// Every command, in help order: implemented ones plus the names reserved for capabilities
// still to come (run == nullptr).
std::vector<Command> CommandTable();

// Registers an implemented command (see AVATAR_REGISTER_COMMAND). Returns true.
bool RegisterCommand(const Command& command);

// The process-wide context that SIGINT cancels.
RunContext& ProcessContext();

// Applies the common options (threads, log level). Returns false if help was requested.
void ApplyCommon(const CommonOptions& common);

// The start of every command: parses `args` into `options` (a struct with a CommonOptions
// `common` member) and returns the positional arguments in `positionals`. With --help it
// prints `usage`, `description` and the option list, and returns false (the command then
// exits 0). Otherwise it applies the common options (threads, log level) and returns true.
// Throws InvalidOptions for bad flags.
template <typename Options>
bool ParseCommand(Options& options, const std::vector<std::string>& args, const std::string& usage,
                  const std::string& description, std::vector<std::string>* positionals) {
  *positionals = options::ParseFlags(options, args);
  if (options.common.help) {
    std::cout << "Usage: " << usage << "\n\n" << description << "\n\nOptions:\n" << options::Help(Options{});
    return false;
  }
  ApplyCommon(options.common);
  return true;
}

// Runs `body` and maps exceptions to exit codes, printing errors on stderr.
int GuardedRun(const char* command, const std::function<int()>& body);

// Starts the studio (gui_launch.cc, linked into the executable only when the GUI is built).
using GuiLauncher = int (*)(int argc, char** argv, const std::vector<std::string>& args);
int RunGui(int argc, char** argv, const std::vector<std::string>& args);

// The entry point main() calls: a command line with a command word (or --help/--version) runs
// that command (RunCommandLine); anything else starts the studio through `gui`, or, when `gui` is
// nullptr (a build without the GUI), says so and returns kExitUsage. Installs the SIGINT handler
// that cancels ProcessContext().
int Main(int argc, char** argv, GuiLauncher gui);

// Runs one command line (the arguments after the program name) in this process, with everything
// it prints on std::cout / std::cerr sent to `out` / `err` while it runs: the command word
// dispatches to its RunX (which parses flags and calls RunXImpl), --help and --version print
// here. Returns the exit code. A GUI invocation (no command word) is a usage error here. Tests
// call this instead of spawning the executable.
int RunCommandLine(const std::vector<std::string>& args, std::ostream& out, std::ostream& err);

// True when `args` name a command, help or the version (not a GUI start).
bool IsCommandLine(const std::vector<std::string>& args);

}  // namespace avatar::app

// In a command's own source file (app/cmd_x.cc):
//   AVATAR_REGISTER_COMMAND("x", "one-line summary", RunX);
#define AVATAR_REGISTER_COMMAND(name, summary, fn) \
  static const bool avatar_command_registered_##fn = ::avatar::app::RegisterCommand({name, summary, &fn})
