# Unwrap: raw catadioptric ring image <-> cylindrical panorama, calibration (YAML),
# auto-calibration (edge points + robust Ceres circle fit), image I/O.
omnicml_add_library(omnicml_unwrap
  SOURCES src/omni_unwrapper.cc src/internal/circle_fit.cc
  DEPS omnicml_core ${OpenCV_LIBS} Ceres::ceres yaml-cpp)

omnicml_add_test(unwrap_test SOURCES tests/omni_unwrapper_test.cc DEPS omnicml_unwrap ${OpenCV_LIBS})

omnicml_add_benchmark(unwrap_benchmark SOURCES bench/unwrap_benchmark.cc DEPS omnicml_unwrap)

omnicml_add_command(SOURCES apps/cmd_unwrap.cc DEPS omnicml_unwrap)
