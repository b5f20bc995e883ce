#pragma once
// `avatar-studio view IMAGE [-o OUT.png]`: the headless equivalent of opening a portrait in
// the studio: the same loader, the same viewport layout, written to a PNG.

#include <string>

#include "app/commands.h"
#include "core/pipeline/portrait_preview.h"

namespace avatar::app {

struct ViewOptions {
  // Portrait image to open.
  std::string input;
  // Where to write the viewport image (PNG or JPEG by extension).
  std::string output = "avatar-studio-view.png";
  // Viewport layout.
  PreviewOptions preview;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("output", output, "Output image (.png or .jpg)", 'o');
    preview.Visit(v);
    common.Visit(v);
  }
  void Validate() const;
};

// Parses flags and runs; returns an exit code.
int RunView(const std::vector<std::string>& args);

// Throws avatar::Error subclasses; returns kExitOk.
int RunViewImpl(const ViewOptions& options, RunContext& ctx);

}  // namespace avatar::app
