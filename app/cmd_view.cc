#include "app/cmd_view.h"

#include <iostream>

#include "core/io/image_io.h"
#include "core/util/error.h"
#include "core/util/options.h"

namespace avatar::app {

void ViewOptions::Validate() const {
  AVATAR_CHECK_OPTION(!input.empty()) << "missing IMAGE: give the portrait to open";
  AVATAR_CHECK_OPTION(!output.empty()) << "--output must not be empty";
  preview.Validate();
  common.Validate();
}

int RunViewImpl(const ViewOptions& options, RunContext& ctx) {
  options.Validate();
  const cv::Mat view = RenderPortraitPreview(options.input, options.preview, ctx);
  SaveImage(options.output, view);
  std::cout << "Opened '" << options.input << "' and wrote the viewport image (" << view.cols << "x" << view.rows
            << ") to '" << options.output << "'.\n";
  return kExitOk;
}

int RunView(const std::vector<std::string>& args) {
  return GuardedRun("view", [&] {
    ViewOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio view IMAGE [options]",
                      "Loads a portrait exactly as the studio does and writes the viewport image.", &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.size() <= 1) << "expected one IMAGE, got " << positionals.size() << " arguments";
    if (!positionals.empty()) options.input = positionals[0];
    return RunViewImpl(options, ProcessContext());
  });
}

AVATAR_REGISTER_COMMAND("view", "load a portrait as the studio does and write the viewport image", RunView);

}  // namespace avatar::app
