// `avatar-studio fusion build|train|eval`: the learned finish of the detail path (issue 33).
//   fusion build --data DATASET --out SET   the detail path's layers of dataset pairs, 3D core frozen
//   fusion train --data SET --out RUN       trains the fusion net on them (resumable; Ctrl+C or
//                                           SIGTERM writes the state and the weights)
//   fusion eval --data SET [--weights W]    per-yaw-bucket table of every path against the targets
//   fusion export --weights W --out FILE    the weights as shipped (float16, inference settings)

#include <csignal>
#include <iomanip>
#include <iostream>

#include "app/commands.h"
#include "core/io/atomic_file.h"
#include "core/tools/fusion_eval.h"
#include "core/tools/fusion_set.h"
#include "core/train/fusion_training.h"
#include "core/util/error.h"

namespace avatar::app {
namespace {

template <typename T>
struct FusionWithCommon {
  T options;
  CommonOptions common;
  template <typename V>
  void Visit(V&& v) {
    options.Visit(v);
    common.Visit(v);
  }
};

void OnFusionSigterm(int) { ProcessContext().RequestCancel(); }

int FusionBuild(const std::vector<std::string>& args) {
  FusionWithCommon<FusionSetOptions> o;
  std::vector<std::string> positionals;
  if (!ParseCommand(o, args, "avatar-studio fusion build --data DATASET --out SET [--size 256] [--checkpoint CKPT]",
                    "Renders the detail path of the dataset's clip pairs (and photo source views) once, with the\n"
                    "3D core frozen, and stores its layers and the target frames for the fusion net. A rerun\n"
                    "resumes; Ctrl+C stops after whole sources.",
                    &positionals)) {
    return kExitOk;
  }
  AVATAR_CHECK_OPTION(positionals.empty()) << "fusion build takes no positional arguments";
  o.options.data_dir = o.common.data_dir;
  const FusionSetReport r = BuildFusionSet(o.options, ProcessContext());
  std::cout << "fusion set " << o.options.out_dir << ": " << r.train_samples << " training frames from "
            << r.train_sources << " sources, " << r.val_samples << " validation frames from " << r.val_sources
            << " sources, " << r.skipped << " skipped (build.log); " << std::fixed << std::setprecision(1) << r.seconds
            << " s (" << r.render_seconds << " s rendering); 3D core: " << r.model << "\n";
  return kExitOk;
}

int FusionTrain(const std::vector<std::string>& args) {
  FusionWithCommon<train::FusionTrainOptions> o;
  std::vector<std::string> positionals;
  if (!ParseCommand(o, args, "avatar-studio fusion train --data SET --out RUN [--hours H] [--steps N] [--no-resume]",
                    "Trains the fusion net on random crops of a fusion set (L1 + MobileNetV2 perceptual), validating\n"
                    "on its val split against the geometric composite. RUN/train.jsonl logs every step;\n"
                    "RUN/fusion.ckpt and RUN/fusion-fp16.ckpt hold the weights, RUN/state.pt the state to resume.",
                    &positionals)) {
    return kExitOk;
  }
  AVATAR_CHECK_OPTION(positionals.empty()) << "fusion train takes no positional arguments";
  o.options.data_dir = o.common.data_dir;
  const auto previous = std::signal(SIGTERM, OnFusionSigterm);
  train::FusionTrainResult r;
  try {
    r = train::TrainFusion(o.options, ProcessContext());
  } catch (...) {
    std::signal(SIGTERM, previous);
    throw;
  }
  std::signal(SIGTERM, previous);
  std::cout << "fusion trained steps " << r.first_step << " -> " << r.last_step << " (stopped by " << r.stopped_by
            << ", " << r.skipped << " non-finite steps skipped); validation loss " << std::fixed << std::setprecision(4)
            << r.last_validation.loss << " (the composite's " << r.last_validation.composite_loss << ", "
            << r.last_validation.samples << " frames); weights: " << o.options.out_dir << "/fusion.ckpt\n";
  return kExitOk;
}

struct FusionEvalCommandOptions {
  FusionEvalOptions eval;
  std::string report;
  template <typename V>
  void Visit(V&& v) {
    eval.Visit(v);
    v("report", report, "Also write the tables to this Markdown file");
  }
};

int FusionEval(const std::vector<std::string>& args) {
  FusionWithCommon<FusionEvalCommandOptions> o;
  std::vector<std::string> positionals;
  if (!ParseCommand(o, args, "avatar-studio fusion eval --data SET [--weights FUSION.ckpt] [--sheet FILE.png] [--report FILE.md]",
                    "Every path of the detail path's frames against the targets of a fusion set's split, per pair\n"
                    "kind and yaw bucket, over the frame and inside / outside the valid-warp mask.",
                    &positionals)) {
    return kExitOk;
  }
  AVATAR_CHECK_OPTION(positionals.empty()) << "fusion eval takes no positional arguments";
  o.options.eval.data_dir = o.common.data_dir;
  const FusionEvalReport r = EvaluateFusionSet(o.options.eval, ProcessContext());
  std::ostringstream text;
  text << "fusion eval of " << o.options.eval.data << " (" << o.options.eval.split << ", " << r.samples << " frames)";
  if (!r.weights_info.empty()) text << ", fusion weights " << o.options.eval.weights << " (" << r.weights_info << ")";
  text << "\n" << FusionEvalMarkdown(r);
  std::cout << text.str();
  if (!o.options.report.empty()) WriteBytesAtomically(o.options.report, text.str());
  if (!o.options.eval.sheet.empty())
    std::cout << "contact sheet (network | preview | composite" << (o.options.eval.weights.empty() ? "" : " | learned")
              << " | target): " << o.options.eval.sheet << "\n";
  return kExitOk;
}

struct FusionExportCommandOptions {
  std::string weights, out;
  FusionExportOptions exported;
  bool float32 = false;
  template <typename V>
  void Visit(V&& v) {
    v("weights", weights, "Fusion weights to export (a run's fusion.ckpt)");
    v("out", out, "The file to write");
    v("turn_open", exported.turn_open,
      "The share (0..1) of the view's turn that opens the warped photo to the net (negative = as stored)");
    v("keep_eye_mouth", exported.keep_eye_mouth,
      "Keep the composite on the target's eyes and mouth (the opened mouth's painted interior)");
    v("keep_face", exported.keep_face,
      "Keep the composite on the whole face mesh (the photo and the fitted texture; eyes and mouth included)");
    v("float32", float32, "Write float32 weights (default: float16, the shipped form)");
  }
};

int FusionExport(const std::vector<std::string>& args) {
  FusionWithCommon<FusionExportCommandOptions> o;
  std::vector<std::string> positionals;
  if (!ParseCommand(o, args, "avatar-studio fusion export --weights FUSION.ckpt --out FILE.ckpt [--turn-open S] [--keep-eye-mouth] [--keep-face]",
                    "Writes trained fusion weights in the form that ships (float16), with their inference\n"
                    "settings changed where asked; the weights themselves stay as trained.",
                    &positionals)) {
    return kExitOk;
  }
  AVATAR_CHECK_OPTION(positionals.empty()) << "fusion export takes no positional arguments";
  AVATAR_CHECK_OPTION(!o.options.weights.empty() && !o.options.out.empty())
      << "fusion export needs --weights FUSION.ckpt and --out FILE.ckpt";
  o.options.exported.half_precision = !o.options.float32;
  const FusionNetInfo info = ExportFusionNet(o.options.weights, o.options.out, o.options.exported);
  std::cout << "fusion weights " << o.options.out << ": step " << info.step << ", fusion:" << info.fingerprint
            << ", turn_open " << info.options.turn_open << (info.options.keep_eye_mouth ? ", eyes and mouth kept" : "")
            << (info.options.keep_face ? ", face kept" : "")
            << (o.options.float32 ? ", float32" : ", float16") << "\n";
  return kExitOk;
}

int RunFusion(const std::vector<std::string>& args) {
  return GuardedRun("fusion", [&] {
    const std::string usage = "Usage: avatar-studio fusion build|train|eval|export [options] (--help on each)\n";
    if (args.empty() || args[0] == "--help" || args[0] == "-h") {
      std::cout << usage;
      return args.empty() ? kExitUsage : kExitOk;
    }
    const std::vector<std::string> rest(args.begin() + 1, args.end());
    if (args[0] == "build") return FusionBuild(rest);
    if (args[0] == "train") return FusionTrain(rest);
    if (args[0] == "eval") return FusionEval(rest);
    if (args[0] == "export") return FusionExport(rest);
    throw InvalidOptions("unknown fusion subcommand '" + args[0] + "': use build, train, eval or export");
  });
}

}  // namespace

AVATAR_REGISTER_COMMAND("fusion", "build, train, evaluate and export the fusion net that finishes detail frames", RunFusion);

}  // namespace avatar::app
