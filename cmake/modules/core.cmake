# Core: errors, poses, frames. Owned by the skeleton.
omnicml_add_library(omnicml_core
  SOURCES src/common.cc src/pose.cc src/frame.cc
  DEPS Eigen3::Eigen ${OpenCV_LIBS} Threads::Threads)
target_include_directories(omnicml_core PUBLIC ${OpenCV_INCLUDE_DIRS})
omnicml_add_test(core_test SOURCES tests/pose_test.cc DEPS omnicml_core)
