#include "app/commands.h"

#include <csignal>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <iostream>

#include <opencv2/core/version.hpp>
#include <torch/version.h>

#include "app/cli_util.h"
#include "core/pipeline/session.h"
#include "core/pipeline/studio_backend.h"
#include "core/util/error.h"
#include "core/util/logging.h"
#include "core/util/threads.h"
#include "core/util/version.h"

namespace avatar::app {
namespace {

void OnSigint(int /*signal*/) {
  ProcessContext().RequestCancel();
  // A second Ctrl+C ends the process at once.
  std::signal(SIGINT, SIG_DFL);
}

void PrintTopHelp() {
  std::cout << "Avatar Studio " << kVersion << ": a 3D head avatar from one portrait photo.\n\n"
            << "Usage:\n"
            << "  avatar-studio [--open IMAGE] [GUI options]   start the studio (GUI)\n"
            << "  avatar-studio COMMAND [options]              run a command without the GUI\n"
            << "  avatar-studio --help | --version\n\nCommands:\n";
  for (const auto& c : CommandTable()) {
    std::string name = c.name;
    name.resize(16, ' ');
    std::cout << "  " << name << c.summary << (c.run == nullptr ? " (not in this version yet)" : "") << "\n";
  }
  std::cout << "\nRun 'avatar-studio COMMAND --help' for a command's options.\n"
            << "Exit codes: 0 ok, 1 error, 2 usage error, 130 cancelled.\n";
}

}  // namespace

void CommonOptions::Validate() const {
  AVATAR_CHECK_OPTION(threads >= 0 && threads <= 1024) << "--threads must be within 0..1024, got " << threads;
}

RunContext& ProcessContext() {
  static RunContext ctx;
  return ctx;
}

void ApplyCommon(const CommonOptions& common) {
  common.Validate();
  if (common.verbose) SetLogLevel(LogLevel::kDebug);
  ConfigureThreads(common.threads);
}

namespace {

std::vector<Command>& Registry() {
  static std::vector<Command> registry;
  return registry;
}

}  // namespace

bool RegisterCommand(const Command& command) {
  Registry().push_back(command);
  return true;
}

std::vector<Command> CommandTable() {
  // Help order; names without a registered implementation are reserved.
  std::vector<Command> table = {
      {"view", "load a portrait as the studio does and write the viewport image", nullptr},
      {"analyze", "detect the face, landmarks, crop and matte of a photo or video", nullptr},
      {"fit", "fit the morphable face model to a portrait", nullptr},
      {"build-morphable", "build the morphable face model from the packaged clips", nullptr},
      {"inspect", "list the network's modules, shapes, parameters and FLOPs", nullptr},
      {"reconstruct", "reconstruct an avatar from a portrait", nullptr},
      {"render", "render an avatar from a camera and expression", nullptr},
      {"animate", "drive an avatar with a video or keyframes and export a clip", nullptr},
      {"bench", "measure the speed of the renderer and the model", nullptr},
      {"dataset", "build or inspect a training dataset from the packaged faces", nullptr},
      {"train", "train the network", nullptr},
      {"eval", "evaluate a trained network on a dataset split", nullptr},
  };
  for (const Command& registered : Registry()) {
    bool reserved = false;
    for (Command& c : table) {
      if (std::string(c.name) == registered.name) {
        c = registered;
        reserved = true;
      }
    }
    if (!reserved) table.push_back(registered);
  }
  return table;
}

int GuardedRun(const char* command, const std::function<int()>& body) {
  const std::string who = std::string("avatar-studio ") + command;
  try {
    return body();
  } catch (const InvalidOptions& e) {
    std::cerr << who << ": " << e.what() << "\nRun '" << who << " --help' for usage.\n";
    return kExitUsage;
  } catch (const Cancelled&) {
    std::cerr << who << ": cancelled\n";
    return kExitCancelled;
  } catch (const Error& e) {
    std::cerr << who << ": error: " << e.what() << "\n";
    return kExitError;
  } catch (const std::exception& e) {
    std::cerr << who << ": internal error: " << e.what() << "\nPlease report this as a bug.\n";
    return kExitError;
  }
}

namespace {

// Sends std::cout / std::cerr to other streams for its lifetime (no-op for the same streams).
class StreamRedirect {
 public:
  StreamRedirect(std::ostream& out, std::ostream& err)
      : cout_(std::cout.rdbuf(out.rdbuf())), cerr_(std::cerr.rdbuf(err.rdbuf())) {}
  ~StreamRedirect() {
    std::cout.flush();
    std::cerr.flush();
    std::cout.rdbuf(cout_);
    std::cerr.rdbuf(cerr_);
  }
  StreamRedirect(const StreamRedirect&) = delete;
  StreamRedirect& operator=(const StreamRedirect&) = delete;

 private:
  std::streambuf* cout_;
  std::streambuf* cerr_;
};

void PrintVersion() {
  const char* wait_policy = std::getenv("OMP_WAIT_POLICY");
  std::cout << "avatar-studio " << kVersion << " (LibTorch " << TORCH_VERSION << ", OpenCV " << CV_VERSION
            << ", OpenMP wait policy " << (wait_policy != nullptr ? wait_policy : "default") << ")\n";
  // Which neural model renders by default (found, not loaded).
  try {
    std::string origin;
    const std::filesystem::path model = ResolveCheckpoint(SessionOptions{}, &origin);
    std::cout << "default model: " << model.string() << " (" << origin << ")\n";
  } catch (const Error& e) {
    std::cout << "default model: none (" << e.what() << ")\n";
  }
  // Which fusion net finishes the detail frames by default (--detail head).
  std::string note;
  const std::string fusion = FusionWeightsOf(BackendOptions{}, &note);
  std::cout << "detail finish: " << (fusion.empty() ? "the geometric composite (" + note + ")" : fusion + " (bundled)")
            << "\n";
}

// Runs a command line for which IsCommandLine is true.
int Dispatch(const std::vector<std::string>& args) {
  const std::string& first = args.at(0);
  if (first == "--help" || first == "-h" || first == "help") {
    PrintTopHelp();
    return kExitOk;
  }
  if (first == "--version") {
    PrintVersion();
    return kExitOk;
  }
  // Flags renamed in 0.2 still work for one release, with a warning (cli_util.h).
  const std::vector<std::string> line = RewriteRenamedFlags(args, std::cerr);
  for (const auto& c : CommandTable()) {
    if (first != c.name) continue;
    if (c.run == nullptr) {
      std::cerr << "avatar-studio " << c.name << ": not available in version " << kVersion << " yet (" << c.summary
                << "). See 'avatar-studio --help' for what this version can do.\n";
      return kExitError;
    }
    return c.run(std::vector<std::string>(line.begin() + 1, line.end()));
  }
  std::cerr << "avatar-studio: unknown command '" << first << "'. Run 'avatar-studio --help' for the list.\n";
  return kExitUsage;
}

}  // namespace

bool IsCommandLine(const std::vector<std::string>& args) {
  if (args.empty()) return false;
  const std::string& first = args[0];
  return first.empty() || first[0] != '-' || first == "--help" || first == "-h" || first == "--version";
}

int RunCommandLine(const std::vector<std::string>& args, std::ostream& out, std::ostream& err) {
  StreamRedirect redirect(out, err);
  if (!IsCommandLine(args)) {
    std::cerr << "avatar-studio: no command given; run 'avatar-studio --help' for the commands.\n";
    return kExitUsage;
  }
  return Dispatch(args);
}

int Main(int argc, char** argv, GuiLauncher gui) {
  std::signal(SIGINT, OnSigint);
  const std::vector<std::string> args(argv + 1, argv + argc);
  if (IsCommandLine(args)) return Dispatch(args);
  if (gui == nullptr) {
    std::cerr << "avatar-studio: this build has no GUI (AVATAR_BUILD_GUI=OFF); run 'avatar-studio --help' for "
                 "commands.\n";
    return kExitUsage;
  }
  return gui(argc, argv, args);
}

}  // namespace avatar::app
