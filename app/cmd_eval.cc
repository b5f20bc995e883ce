// `avatar-studio eval --checkpoint C --data DIR [--split val] [--max-pairs N] [--out DIR]`:
// evaluates a checkpoint on a dataset split (core/tools/evaluate.h): the deterministic
// renders I_c, I_c+e, I_c+e+p (and SR when trained) and the morphable-preview baseline against
// the targets, with PSNR, SSIM, L1, perceptual, CSIM, AED and APD. Writes OUT/eval.md,
// OUT/eval.json and OUT/contact.png; Ctrl+C cancels (nothing is written then). Ablation
// checkpoints (issue 14) are evaluated as they are: T_e from the target's morphable coefficients
// for expression bases; without an appearance branch the I_c+e+p row is the output I_c+e.

#include <iostream>

#include "app/commands.h"
#include "core/tools/evaluate.h"
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

int RunEval(const std::vector<std::string>& args) {
  return GuardedRun("eval", [&] {
    EvalCommandOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args,
                      "avatar-studio eval --checkpoint C --data DIR [--split val] [--max-pairs N] [--out DIR] "
                      "[--threads T]",
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
