// `avatar-studio eval --checkpoint C --data DIR [--split val] [--max-pairs N] [--out DIR]`:
// evaluates a checkpoint on a dataset split (core/tools/evaluate.h): the deterministic
// renders I_c, I_c+e, I_c+e+p (and SR when trained) and the morphable-preview baseline against
// the targets, with PSNR, SSIM, L1, perceptual, CSIM, AED and APD. Writes OUT/eval.md,
// OUT/eval.json and OUT/contact.png; Ctrl+C cancels (nothing is written then). Ablation
// checkpoints (issue 14) are evaluated as they are: T_e from the target's morphable coefficients
// for expression bases; without an appearance branch the I_c+e+p row is the output I_c+e.
// `avatar-studio eval orbit PHOTO... [--out DIR]`: novel views without ground truth
// (core/tools/orbit_eval.h): every path that renders a photo, orbited and scored against it.

#include <iostream>

#include "app/commands.h"
#include "core/tools/evaluate.h"
#include "core/tools/orbit_eval.h"
#include "core/util/error.h"

namespace avatar::app {
namespace {

struct EvalCommandOptions {
  EvaluateOptions eval;
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    eval.Visit(v);
    common.Visit(v);
  }
  void Validate() const {
    eval.Validate();
    common.Validate();
  }
};

int RunEvalImpl(EvalCommandOptions o, RunContext& ctx) {
  o.eval.data_dir = o.common.data_dir;
  o.Validate();
  const EvaluateReport r = RunEvaluation(o.eval, ctx);
  std::cout << r.markdown << "\nEvaluated " << r.pairs << " pairs in " << r.seconds << " s; wrote '" << r.markdown_path
            << "', '" << r.json_path << "'";
  if (!r.contact_path.empty()) std::cout << " and '" << r.contact_path << "'";
  std::cout << ".\n";
  return kExitOk;
}

struct OrbitCommandOptions {
  OrbitEvalOptions orbit;
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    orbit.Visit(v);
    common.Visit(v);
  }
  void Validate() const {
    orbit.Validate();
    common.Validate();
  }
};

int RunOrbit(const std::vector<std::string>& args) {
  OrbitCommandOptions o;
  std::vector<std::string> positionals;
  if (!ParseCommand(o, args, "avatar-studio eval orbit PHOTO... [--out DIR] [--yaws -30,-15,0,15,30] [--size 256]",
                    "Novel views without ground truth: reconstructs each photo once and renders it at camera yaws "
                    "around its\nown pose with every path (the network alone, the morphable preview, the preview "
                    "pasted over the\nnetwork, the photo's detail on the face and on the head), scored against the "
                    "photo: identity\ncosine (fr_feature), the detail outside the face (mean |Laplacian| as a "
                    "fraction of the photo's),\nthe source view's PSNR against the matted crop and the mouth opening "
                    "of --jaw-control.\nWrites OUT/orbit.md, OUT/orbit.json and OUT/orbit.png.",
                    &positionals)) {
    return kExitOk;
  }
  o.orbit.photos = positionals;
  o.orbit.data_dir = o.common.data_dir;
  o.Validate();
  const OrbitEvalReport r = RunOrbitEvaluation(o.orbit, ProcessContext());
  std::cout << r.markdown << "\nWrote '" << r.markdown_path << "', '" << r.json_path << "'";
  if (!r.contact_path.empty()) std::cout << " and '" << r.contact_path << "'";
  std::cout << ".\n";
  return kExitOk;
}

int RunEval(const std::vector<std::string>& args) {
  if (!args.empty() && args[0] == "orbit") {
    return GuardedRun("eval orbit", [&] { return RunOrbit({args.begin() + 1, args.end()}); });
  }
  return GuardedRun("eval", [&] {
    EvalCommandOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args,
                      "avatar-studio eval --checkpoint C --data DIR [--split val] [--max-pairs N] [--out DIR] "
                      "[--threads T] | avatar-studio eval orbit PHOTO... (see eval orbit --help)",
                      "Evaluates a network checkpoint on a dataset split: the deterministic renders I_c, I_c+e, "
                      "I_c+e+p (and SR when\nit was trained) and the morphable-preview baseline at each target "
                      "camera, against the target, with PSNR, SSIM,\nL1 and perceptual (full image and within the "
                      "target matte), CSIM, AED and APD. Writes OUT/eval.md, OUT/eval.json\nand OUT/contact.png. "
                      "Ablation checkpoints (train --no-appearance / --expression-model bases) are named in "
                      "eval.md;\nwithout an appearance branch the I_c+e+p row is the network's output I_c+e.",
                      &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.empty()) << "eval takes no positional arguments (use --checkpoint and --data)";
    return RunEvalImpl(options, ProcessContext());
  });
}

}  // namespace

AVATAR_REGISTER_COMMAND("eval", "evaluate a trained network on a dataset split", RunEval);

}  // namespace avatar::app
