# The sources of avatar_fuzz_core (cmake/AvatarFuzz.cmake): the parsers of untrusted input and what
# they need (follow the includes of each parser; keep this list small). The normal configure checks
# that every file here exists (CMakeLists.txt), so a rename breaks the ordinary build at once rather
# than only the fuzz build in CI.
set(AVATAR_FUZZ_SOURCES
  core/util/error.cc
  core/util/logging.cc
  core/util/options.cc
  core/util/run_context.cc
  core/io/atomic_file.cc
  core/io/data_paths.cc
  core/io/resources.cc
  core/io/image_io.cc
  core/io/video_io.cc
  core/io/tfjs_graph.cc
  core/io/keras_layers.cc
  core/model/checkpoint.cc
  core/model/model_config.cc
  core/face/identity_net.cc
  core/face/head_pose_net.cc
  core/face/face_geometry.cc
  core/face/warp.cc
  core/pipeline/avatar_file.cc
  core/morphable/fit_from_label.cc
  core/morphable/camera_label.cc
  core/render/camera.cc
  core/pipeline/source_fit.cc
  core/pipeline/driving.cc
  core/pipeline/expression.cc
  core/pipeline/expression_preset.cc
  core/render/view_pose.cc
  core/train/dataset.cc
  core/train/shard_check.cc
  core/train/sample.cc
)
