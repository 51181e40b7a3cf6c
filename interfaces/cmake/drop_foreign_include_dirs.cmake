# Injected with -DCMAKE_PROJECT_INCLUDE by scripts/build-interfaces.
#
# The PyPI ROS wheels were built in a manylinux container: their exported CMake targets name
# include directories of that machine (/opt/python/cp311-cp311/include/python3.11 and numpy's),
# and CMake refuses to generate with a non-existent path in an imported target. Once the
# project's CMakeLists.txt has imported everything, drop such paths; the generators find this
# machine's Python and numpy headers themselves.
cmake_minimum_required(VERSION 3.21)  # the IMPORTED_TARGETS directory property

function(_ur_rg2_drop_foreign_include_dirs)
  get_property(targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(target IN LISTS targets)
    get_target_property(dirs "${target}" INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT dirs)
      continue()
    endif()
    set(kept "")
    foreach(dir IN LISTS dirs)
      # Keep generator expressions and relative entries; drop absolute paths not on this disk.
      if(dir MATCHES "^/" AND NOT dir MATCHES "\\$<" AND NOT EXISTS "${dir}")
        continue()
      endif()
      list(APPEND kept "${dir}")
    endforeach()
    if(NOT kept STREQUAL dirs)
      set_target_properties("${target}" PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${kept}")
    endif()
  endforeach()
endfunction()

cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _ur_rg2_drop_foreign_include_dirs)
