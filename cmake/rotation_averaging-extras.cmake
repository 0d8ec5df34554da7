# Included by rotation_averagingConfig.cmake (devel and install spaces).
#
# ${catkin_LIBRARIES} after find_package(catkin COMPONENTS rotation_averaging)
# links all three libraries of the package and their ROS dependencies. A
# program that needs only part of it links one of these instead, and loads
# only that part's dependencies:
#
#   rotation_averaging::core      averaging, view graphs, losses, scoring, file I/O (Eigen; no OpenCV, no ROS)
#   rotation_averaging::frontend  the image front end on top of it (OpenCV)
#   rotation_averaging::ros       message conversions, bag replay (roscpp, rosbag, ...)
#
# Each carries the include directories its headers need.

set(_rotavg_parts core frontend ros)
set(_rotavg_previous "")
foreach(_rotavg_part ${_rotavg_parts})
  set(_rotavg_target rotation_averaging::${_rotavg_part})
  if(NOT TARGET ${_rotavg_target})
    unset(_rotavg_lib CACHE)
    find_library(_rotavg_lib rotation_averaging_${_rotavg_part}
      PATHS ${rotation_averaging_LIBRARY_DIRS} NO_DEFAULT_PATH NO_CMAKE_FIND_ROOT_PATH)
    if(NOT _rotavg_lib)
      message(FATAL_ERROR "rotation_averaging: librotation_averaging_${_rotavg_part} not found in "
                          "'${rotation_averaging_LIBRARY_DIRS}'")
    endif()
    add_library(${_rotavg_target} SHARED IMPORTED)
    set_target_properties(${_rotavg_target} PROPERTIES
      IMPORTED_LOCATION "${_rotavg_lib}"
      INTERFACE_INCLUDE_DIRECTORIES "${rotation_averaging_INCLUDE_DIRS}"
      INTERFACE_LINK_LIBRARIES "${_rotavg_previous}")
    unset(_rotavg_lib CACHE)
  endif()
  set(_rotavg_previous ${_rotavg_target})
endforeach()
# The ROS part also needs what its headers' ROS dependencies export.
set(_rotavg_ros_deps ${rotation_averaging_LIBRARIES})
list(FILTER _rotavg_ros_deps EXCLUDE REGEX "librotation_averaging_(core|frontend|ros)\\.")
set_property(TARGET rotation_averaging::ros APPEND PROPERTY INTERFACE_LINK_LIBRARIES ${_rotavg_ros_deps})
unset(_rotavg_ros_deps)
unset(_rotavg_parts)
unset(_rotavg_previous)
unset(_rotavg_target)
