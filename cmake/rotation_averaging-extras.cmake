# Included by rotation_averagingConfig.cmake (devel and install spaces).
#
# ${catkin_LIBRARIES} after find_package(catkin COMPONENTS rotation_averaging)
# links both libraries with public headers and their dependencies. A program
# that needs only the averaging links rotation_averaging::core instead, and
# loads neither OpenCV nor ROS:
#
#   rotation_averaging::core      averaging, view graphs, losses, scoring, file I/O (Eigen)
#                                 headers: rotation_averaging/core/...
#   rotation_averaging::frontend  the image front end on top of it (OpenCV)
#                                 headers: rotation_averaging/frontend/...
#
# Each carries the include directories its headers need.

set(_rotavg_previous "")
foreach(_rotavg_part core frontend)
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
# The front end's headers include OpenCV's: link what catkin exports for them.
set(_rotavg_opencv ${rotation_averaging_LIBRARIES})
list(FILTER _rotavg_opencv INCLUDE REGEX "opencv")
set_property(TARGET rotation_averaging::frontend APPEND PROPERTY INTERFACE_LINK_LIBRARIES ${_rotavg_opencv})
unset(_rotavg_opencv)
unset(_rotavg_previous)
unset(_rotavg_target)
