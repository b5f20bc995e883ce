#include <cstdlib>
#include <iostream>

#include "app/cmd_view.h"
#include "app/commands.h"
#include "core/util/options.h"
#include "ui/studio.h"

namespace avatar::app {
namespace {

struct GuiOptions {
  // Portrait to open at start.
  std::string open;
  // Driving video to load at start.
  std::string driver;
  // Without a display: where the headless equivalent writes the viewport image.
  std::string headless_output = "avatar-studio-view.png";
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("open", open, "Portrait to open at start");
    v("driver", driver, "Driving video to load at start");
    v("headless_output", headless_output, "Without a display, where the viewport image is written");
    common.Visit(v);
  }
  void Validate() const { common.Validate(); }
};

bool HasDisplay() {
  for (const char* var : {"DISPLAY", "WAYLAND_DISPLAY"}) {
    const char* value = std::getenv(var);
    if (value != nullptr && *value != '\0') return true;
  }
  const char* platform = std::getenv("QT_QPA_PLATFORM");
  return platform != nullptr && *platform != '\0';
}

}  // namespace

int RunGui(int argc, char** argv, const std::vector<std::string>& args) {
  GuiOptions options;
  int status = GuardedRun("", [&] {
    const auto positionals = options::ParseFlags(options, args);
    AVATAR_CHECK_OPTION(positionals.empty())
        << "unexpected argument '" << positionals[0] << "'; to open a portrait use --open FILE";
    options.Validate();
    return kExitOk;
  });
  if (status != kExitOk) return status;
  if (options.common.help) {
    std::cout << "Usage: avatar-studio [options]   (starts the studio)\n\nOptions:\n" << options::Help(options);
    return kExitOk;
  }
  if (!HasDisplay()) {
    if (options.open.empty()) {
      std::cerr << "avatar-studio: no display found (DISPLAY and WAYLAND_DISPLAY are unset), so the studio cannot "
                   "start.\nRun it on a desktop, under xvfb-run, or use a command: 'avatar-studio --help'.\n";
      return kExitUsage;
    }
    std::cout << "No display found (DISPLAY and WAYLAND_DISPLAY are unset): running the headless equivalent,\n"
              << "  avatar-studio view " << options.open << " -o " << options.headless_output << "\n";
    return GuardedRun("view", [&] {
      ViewOptions view;
      view.input = options.open;
      view.output = options.headless_output;
      view.common = options.common;
      ApplyCommon(view.common);
      return RunViewImpl(view, ProcessContext());
    });
  }
  ApplyCommon(options.common);
  ui::StudioOptions studio;
  studio.open = options.open;
  studio.driver = options.driver;
  return ui::RunStudio(argc, argv, studio);
}

}  // namespace avatar::app
