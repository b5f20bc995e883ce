# Shared compile settings for every first-party target.
function(avatar_target_settings target)
  target_compile_features(${target} PUBLIC cxx_std_17)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wno-unused-parameter)
  if(AVATAR_WERROR)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
  if(NOT AVATAR_SANITIZER STREQUAL "none")
    # "address+undefined" (scripts/test-sanitized) is -fsanitize=address,undefined.
    string(REPLACE "+" "," sanitizers "${AVATAR_SANITIZER}")
    target_compile_options(${target} PRIVATE -fsanitize=${sanitizers} -fno-omit-frame-pointer)
    target_link_options(${target} PRIVATE -fsanitize=${sanitizers})
  endif()
endfunction()

# Marks the include directories of an imported target as system headers, so that
# warnings inside LibTorch, OpenCV or Qt headers do not drown ours.
function(avatar_system_includes target)
  get_target_property(dirs ${target} INTERFACE_INCLUDE_DIRECTORIES)
  if(dirs)
    set_target_properties(${target} PROPERTIES INTERFACE_SYSTEM_INCLUDE_DIRECTORIES "${dirs}")
  endif()
endfunction()

# Unity builds: the sources of a library are compiled in batches of AVATAR_UNITY_BATCH (one
# translation unit per batch), which makes a clean build much cheaper (each unit pays the
# precompiled LibTorch header's load once) and an incremental one dearer (an edit recompiles
# its batch). Configure with -DAVATAR_UNITY_BUILD=OFF while editing core sources all day.
option(AVATAR_UNITY_BUILD "Compile the libraries in unity batches (faster clean builds)" ON)
set(AVATAR_UNITY_BATCH 6 CACHE STRING "Sources per unity batch (AVATAR_UNITY_BUILD)")
function(avatar_unity_build target)
  if(AVATAR_UNITY_BUILD)
    set_target_properties(${target} PROPERTIES UNITY_BUILD ON UNITY_BUILD_BATCH_SIZE ${AVATAR_UNITY_BATCH})
  endif()
endfunction()
