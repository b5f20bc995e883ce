# Install-time step (cmake --install, cpack): copies the third-party files that
# packaging/data-packages.tsv marks "SHIP deb" from the data folder that scripts/setup filled into
# <prefix>/<AVATAR_INSTALL_SHARE_DIR> (share/avatar-studio), where the installed binary finds them.
# Expects AVATAR_DATA_LIST, AVATAR_PACKAGE_DATA_DIR and AVATAR_INSTALL_SHARE_DIR (set by the
# install(CODE) in packaging/CMakeLists.txt).
cmake_policy(VERSION 3.22)  # install scripts otherwise run with old policies
include("${CMAKE_CURRENT_LIST_DIR}/data_list.cmake")
avatar_read_data_list("${AVATAR_DATA_LIST}")

set(missing "")
set(i 0)
while(i LESS AVATAR_DATA_SHIPPED_COUNT)
  set(member "${AVATAR_DATA_SHIPPED_${i}_MEMBER}")
  set(dest "${AVATAR_DATA_SHIPPED_${i}_DEST}")
  avatar_data_file_path("${dest}" "${member}" relative)
  file(GLOB matches "${AVATAR_PACKAGE_DATA_DIR}/${relative}")
  if(NOT matches)
    list(APPEND missing "${AVATAR_PACKAGE_DATA_DIR}/${relative} (from ${AVATAR_DATA_SHIPPED_${i}_SOURCE})")
  else()
    get_filename_component(dir "${relative}" DIRECTORY)
    file(INSTALL ${matches} DESTINATION "${CMAKE_INSTALL_PREFIX}/${AVATAR_INSTALL_SHARE_DIR}/${dir}")
  endif()
  math(EXPR i "${i} + 1")
endwhile()
if(missing)
  list(JOIN missing "\n  " text)
  message(FATAL_ERROR "The package carries the face networks and samples of the data folder, but these are missing:\n  ${text}\n"
                      "Fill the data folder with scripts/setup, or reconfigure with "
                      "-DAVATAR_PACKAGE_DATA_DIR=<a data folder that holds them>.")
endif()
