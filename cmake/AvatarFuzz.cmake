# The fuzz build (AVATAR_FUZZ=ON, made by scripts/fuzz in its own build folder, build-fuzz/):
# clang with libFuzzer, AddressSanitizer and UndefinedBehaviorSanitizer. Only the sources the
# parsers of untrusted input need are compiled (avatar_fuzz_core, a small static library): the
# rest of core/ (the network, renderer, trainer, pipeline) is neither built nor linked. Each
# tests/fuzz/*_fuzz.cc becomes one libFuzzer executable, fuzz_<name>. Nothing else of the
# project (app, ui, tests, packaging) is configured in this mode.
if(NOT CMAKE_CXX_COMPILER_ID STREQUAL "Clang")
  message(FATAL_ERROR "AVATAR_FUZZ=ON needs clang++ (libFuzzer): configure with -DCMAKE_CXX_COMPILER=clang++ "
                      "(Debian packages clang and libclang-rt-14-dev; scripts/fuzz does this)")
endif()

# Everything is compiled with the fuzzer's coverage instrumentation (fuzzer-no-link) and the two
# sanitizers; only the harness executables link libFuzzer's main (-fsanitize=fuzzer). The same
# compile flags everywhere let the harnesses reuse the library's precompiled header.
# vptr is left out of UBSan: it compares type_info across the boundary to the gcc-built LibTorch
# and OpenCV and reports types that are fine.
set(AVATAR_FUZZ_COMPILE_FLAGS -fsanitize=fuzzer-no-link,address,undefined -fno-sanitize=vptr
                              -fno-omit-frame-pointer -g -O1)
set(AVATAR_FUZZ_LINK_FLAGS -fsanitize=address,undefined -fno-sanitize=vptr)

include(${PROJECT_SOURCE_DIR}/cmake/AvatarFuzzSources.cmake)  # AVATAR_FUZZ_SOURCES
list(TRANSFORM AVATAR_FUZZ_SOURCES PREPEND "${PROJECT_SOURCE_DIR}/")

configure_file(core/util/version.h.in ${PROJECT_BINARY_DIR}/generated/core/util/version.h @ONLY)
find_package(JPEG REQUIRED)
avatar_system_includes(torch)

add_library(avatar_fuzz_core STATIC ${AVATAR_FUZZ_SOURCES})
target_compile_features(avatar_fuzz_core PUBLIC cxx_std_17)
target_compile_options(avatar_fuzz_core PUBLIC ${AVATAR_FUZZ_COMPILE_FLAGS})
target_include_directories(avatar_fuzz_core PUBLIC ${PROJECT_SOURCE_DIR} ${PROJECT_BINARY_DIR}/generated)
target_include_directories(avatar_fuzz_core SYSTEM PUBLIC ${TORCH_INCLUDE_DIRS} ${OpenCV_INCLUDE_DIRS})
target_link_libraries(avatar_fuzz_core
  PUBLIC ${TORCH_LIBRARIES} ${OpenCV_LIBS} glm::glm nlohmann_json::nlohmann_json Threads::Threads JPEG::JPEG)
target_precompile_headers(avatar_fuzz_core PRIVATE <torch/torch.h> <opencv2/core.hpp> <nlohmann/json.hpp>)
avatar_unity_build(avatar_fuzz_core)  # unity batches, as the normal build (cmake/AvatarCompile.cmake)
set_source_files_properties(${PROJECT_SOURCE_DIR}/core/io/resources.cc PROPERTIES
  COMPILE_DEFINITIONS AVATAR_SOURCE_DIR="${PROJECT_SOURCE_DIR}" SKIP_UNITY_BUILD_INCLUSION ON)
set_source_files_properties(${PROJECT_SOURCE_DIR}/core/io/tfjs_graph.cc PROPERTIES SKIP_UNITY_BUILD_INCLUSION ON)

# One executable per tests/fuzz/NAME_fuzz.cc.
set(AVATAR_FUZZ_TARGETS tfjs_graph keras_layers onnx checkpoint avatar_file dataset keyframes model_config image video presets)
# The shared harness code and libFuzzer's entry points, compiled once.
add_library(avatar_fuzz_main OBJECT ${PROJECT_SOURCE_DIR}/tests/fuzz/fuzz_common.cc ${PROJECT_SOURCE_DIR}/tests/fuzz/fuzz_main.cc)
target_link_libraries(avatar_fuzz_main PRIVATE avatar_fuzz_core)
target_precompile_headers(avatar_fuzz_main REUSE_FROM avatar_fuzz_core)
set(exes)
foreach(name IN LISTS AVATAR_FUZZ_TARGETS)
  list(APPEND exes fuzz_${name})
  add_executable(fuzz_${name} ${PROJECT_SOURCE_DIR}/tests/fuzz/${name}_fuzz.cc $<TARGET_OBJECTS:avatar_fuzz_main>)
  target_link_libraries(fuzz_${name} PRIVATE avatar_fuzz_core)
  target_link_options(fuzz_${name} PRIVATE -fsanitize=fuzzer ${AVATAR_FUZZ_LINK_FLAGS})
  target_include_directories(fuzz_${name} PRIVATE ${PROJECT_SOURCE_DIR}/tests/fuzz)
  target_precompile_headers(fuzz_${name} REUSE_FROM avatar_fuzz_core)
endforeach()
add_custom_target(fuzz_all DEPENDS ${exes})
