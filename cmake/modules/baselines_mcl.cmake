# Monte Carlo localization with image retrieval and visibility areas [W] (DESIGN.md
# "Baselines from the seeds"): occupancy grids (map_server PGM + YAML), the particle
# filter, its experiments and `omnicml mcl`. Owned by helper "mcl".
omnicml_add_library(omnicml_mcl
  SOURCES src/occupancy_grid.cc src/mcl.cc
  DEPS omnicml_sim omnicml_descriptors omnicml_logs omnicml_tracking omnicml_core yaml-cpp
       Eigen3::Eigen ${OpenCV_LIBS})
omnicml_add_test(mcl_test
  SOURCES tests/occupancy_grid_test.cc tests/mcl_test.cc
  DEPS omnicml_mcl)
omnicml_add_benchmark(mcl_benchmark SOURCES bench/mcl_benchmark.cc DEPS omnicml_mcl)
omnicml_add_command(SOURCES apps/cmd_mcl.cc DEPS omnicml_mcl omnicml_cli_support)
