# Injected with -DCMAKE_PROJECT_INCLUDE by scripts/build-interfaces (and tests/test_colcon_build):
# what a message package's build needs on the pip path, where the PyPI ROS wheels are the ROS
# install and Python is the only client. A ROS install needs none of it.
cmake_minimum_required(VERSION 3.21)  # the IMPORTED_TARGETS directory property

# The PyPI ROS wheels were built in a manylinux container: their exported CMake targets name
# include directories of that machine (/opt/python/cp311-cp311/include/python3.11 and numpy's),
# and CMake refuses to generate with a non-existent path in an imported target. Once the
# project's CMakeLists.txt has imported everything, drop such paths; the generators find this
# machine's Python and numpy headers themselves.
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

# Generate for C and Python only: rclpy loads a message's C type support, and nothing on the
# pip path is C++. The registered generators run from ament_execute_extensions, whose EXCLUDE
# rosidl_generate_interfaces does not pass on: this wraps it (ament_cmake_core is included
# once per project, so the package's own find_package(ament_cmake) keeps the wrapper).
find_package(ament_cmake_core REQUIRED QUIET)
set(_ur_rg2_cpp_generators rosidl_generator_cpp rosidl_typesupport_cpp
  rosidl_typesupport_fastrtps_cpp rosidl_typesupport_introspection_cpp)
macro(ament_execute_extensions extension_point)
  if("${extension_point}" STREQUAL "rosidl_generate_idl_interfaces")
    _ament_execute_extensions(${ARGV} EXCLUDE ${_ur_rg2_cpp_generators})
  else()
    _ament_execute_extensions(${ARGV})
  endif()
endmacro()
