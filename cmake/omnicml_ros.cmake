# ROS 1 as Debian packages it (libroscpp-dev, librosbag-storage-dev, message packages):
# headers and libraries in the system paths. Debian's catkin CMake configs of
# rosbag_storage pull in ROS 2's pluginlib (ament) and fail, and its pkg-config file
# requires a pluginlib.pc that does not exist, so the pieces are found directly.
# Defines OMNICML_HAVE_ROS and, when found, plain lists (absolute paths, so that the module
# libraries stay exportable):
#   OMNICML_ROS_BAG_INCLUDE_DIRS, OMNICML_ROS_BAG_LIBRARIES    rosbag::Bag/View, messages
#   OMNICML_ROS_NODE_INCLUDE_DIRS, OMNICML_ROS_NODE_LIBRARIES  roscpp
set(OMNICML_HAVE_ROS OFF)
find_path(OMNICML_ROSBAG_INCLUDE_DIR rosbag/bag.h)
find_path(OMNICML_ROS_MSGS_INCLUDE_DIR NAMES sensor_msgs/Image.h nav_msgs/Odometry.h
          geometry_msgs/PoseWithCovarianceStamped.h visualization_msgs/MarkerArray.h
          std_srvs/Trigger.h tf2_msgs/TFMessage.h)
find_library(OMNICML_ROSBAG_STORAGE_LIB rosbag_storage)
find_library(OMNICML_ROSLZ4_LIB roslz4)
find_library(OMNICML_ROS_SERIALIZATION_LIB roscpp_serialization)
find_library(OMNICML_ROSTIME_LIB rostime)
find_library(OMNICML_ROS_CPP_COMMON_LIB cpp_common)
find_library(OMNICML_CONSOLE_BRIDGE_LIB console_bridge)
find_library(OMNICML_BOOST_FILESYSTEM_LIB boost_filesystem)
pkg_check_modules(OMNICML_ROSCPP QUIET roscpp)
foreach(_dir pluginlib class_loader ament_index_cpp rcpputils rcutils)
  if(EXISTS /usr/include/${_dir}/${_dir})
    list(APPEND _omnicml_ros_nested_includes /usr/include/${_dir})
  endif()
endforeach()
set(_missing "")
foreach(_v OMNICML_ROSBAG_INCLUDE_DIR OMNICML_ROS_MSGS_INCLUDE_DIR OMNICML_ROSBAG_STORAGE_LIB
           OMNICML_ROS_SERIALIZATION_LIB OMNICML_ROSTIME_LIB OMNICML_ROS_CPP_COMMON_LIB
           OMNICML_CONSOLE_BRIDGE_LIB OMNICML_BOOST_FILESYSTEM_LIB)
  if(NOT ${_v})
    list(APPEND _missing ${_v})
  endif()
endforeach()
if(NOT OMNICML_ROSCPP_FOUND)
  list(APPEND _missing "roscpp (pkg-config)")
endif()
if(_missing)
  message(STATUS "ROS 1 not found (${_missing}): rosbag import/export and omnicml_node are not "
                 "built (scripts/setup.sh installs the Debian packages)")
else()
  set(OMNICML_HAVE_ROS ON)
  message(STATUS "ROS 1 found: building the ros module, rosbag import/export and omnicml_node")
  set(OMNICML_ROS_BAG_INCLUDE_DIRS ${OMNICML_ROSBAG_INCLUDE_DIR} ${OMNICML_ROS_MSGS_INCLUDE_DIR}
      ${_omnicml_ros_nested_includes})
  list(REMOVE_DUPLICATES OMNICML_ROS_BAG_INCLUDE_DIRS)
  set(OMNICML_ROS_BAG_LIBRARIES ${OMNICML_ROSBAG_STORAGE_LIB} ${OMNICML_ROS_SERIALIZATION_LIB}
      ${OMNICML_ROSTIME_LIB} ${OMNICML_ROS_CPP_COMMON_LIB} ${OMNICML_CONSOLE_BRIDGE_LIB}
      ${OMNICML_BOOST_FILESYSTEM_LIB})
  if(OMNICML_ROSLZ4_LIB)
    list(APPEND OMNICML_ROS_BAG_LIBRARIES ${OMNICML_ROSLZ4_LIB})
  endif()
  set(OMNICML_ROS_NODE_INCLUDE_DIRS ${OMNICML_ROSCPP_INCLUDE_DIRS})
  set(OMNICML_ROS_NODE_LIBRARIES ${OMNICML_ROSCPP_LINK_LIBRARIES})
endif()
