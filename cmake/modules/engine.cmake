# CML engine: trajectory reconstruction (Ceres pose graph), the delayed concurrent map
# updater, the CmlEngine (frame pipeline, sessions, statistics) and engine persistence.
# Owned by helper "engine".
omnicml_add_library(omnicml_engine
  SOURCES src/trajectory_reconstruction.cc src/map_updater.cc src/cml_engine.cc src/engine_io.cc
  DEPS omnicml_envmodel omnicml_tracking omnicml_descriptors omnicml_unwrap omnicml_core
       Ceres::ceres Threads::Threads)

omnicml_add_test(engine_test
  SOURCES tests/trajectory_reconstruction_test.cc tests/map_updater_test.cc tests/cml_engine_test.cc
          tests/engine_io_test.cc
  DEPS omnicml_engine)

omnicml_add_test(end_to_end_test
  SOURCES tests/end_to_end_test.cc
  DEPS omnicml_engine omnicml_sim)

omnicml_add_benchmark(engine_benchmark
  SOURCES bench/engine_benchmark.cc
  DEPS omnicml_engine)
