#include <iostream>

#include "app/cli_util.h"
#include "app/cmd_reconstruct.h"
#include "core/io/gltf_writer.h"
#include "core/pipeline/avatar_file_info.h"
#include "core/util/error.h"
#include "core/util/timer.h"

namespace avatar::app {

void ExportMeshOptions::Validate() const {
  AVATAR_CHECK_OPTION(!input.empty()) << "missing FILE.avatar: give the avatar whose mesh to export";
  std::string ext = std::filesystem::path(output).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  AVATAR_CHECK_OPTION(ext == ".glb" || ext == ".obj")
      << "--output '" << output << "' must end in .glb (binary glTF) or .obj";
  mesh.Validate();
  session.Validate();
  common.Validate();
}

int RunExportMeshImpl(const ExportMeshOptions& options, RunContext& ctx) {
  options.Validate();
  SessionOptions so = options.session;
  so.data_dir = options.common.data_dir;
  const AvatarFileInfo file = ReadAvatarFileInfo(options.input);
  if (so.random_weights && so.checkpoint.empty()) ParseRandomModelId(file.model_id, &so.config, &so.seed);
  Timer timer;
  const auto session = std::make_shared<const Session>(so);
  const Avatar avatar = session->LoadAvatar(options.input);
  const HeadMesh mesh = AvatarHeadMesh(session, avatar, options.common.data_dir, options.mesh, ctx);
  for (const std::string& w : mesh.warnings) std::cerr << "warning: " << w << "\n";
  WriteMeshFile(options.output, mesh.parts, "Avatar Studio export-mesh (" + DescribeModel(session->Info()) + ")");
  std::cout << "Exported the mesh of '" << options.input << "' to '" << options.output << "':";
  for (const TexturedMesh& part : mesh.parts)
    std::cout << " " << part.name << " " << part.positions.size() << " vertices, " << part.triangles.size()
              << " triangles;";
  std::cout << " depth of the " << DescribeModel(session->Info()) << ", in " << timer.Seconds() << " s.\n";
  return kExitOk;
}

int RunExportMesh(const std::vector<std::string>& args) {
  return GuardedRun("export-mesh", [&] {
    ExportMeshOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio export-mesh FILE.avatar -o head.glb|head.obj",
                      "Exports the avatar's geometry proxy with the photo on it: the fitted face mesh and a height "
                      "field of the network's depth for hair, ears and neck (glTF 2.0 binary, or OBJ).",
                      &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.size() <= 1)
        << "expected one FILE.avatar, got " << positionals.size() << " arguments";
    if (!positionals.empty()) options.input = positionals[0];
    return RunExportMeshImpl(options, ProcessContext());
  });
}

AVATAR_REGISTER_COMMAND("export-mesh", "export an avatar's mesh with the photo on it (.glb, .obj)", RunExportMesh);

}  // namespace avatar::app
