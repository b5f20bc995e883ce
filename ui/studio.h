#pragma once
// Starts the studio GUI. Used by app/ (avatar-studio with no subcommand).

#include <string>

namespace avatar::ui {

struct StudioOptions {
  // Portrait to open at start ("" = start empty).
  std::string open;
  // Driving video to load at start ("" = none).
  std::string driver;
};

// Creates the QApplication and the main window and runs the event loop; returns its exit code.
int RunStudio(int& argc, char** argv, const StudioOptions& options);

// Sets the organisation and application names that QSettings uses.
void SetApplicationIdentity();

}  // namespace avatar::ui
