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
