# Topological localization by colour-histogram place recognition [UN] (DESIGN.md
# "Baselines from the seeds"): adjacency maps of places, the unanimous-voting localizer,
# the cross-sequence experiment and `omnicml topo`.
omnicml_add_library(omnicml_topo
  SOURCES src/topological.cc
  DEPS omnicml_sim omnicml_descriptors omnicml_logs omnicml_unwrap omnicml_core yaml-cpp
       ${OpenCV_LIBS})
omnicml_add_test(topo_test
  SOURCES tests/topological_test.cc
  DEPS omnicml_topo)
omnicml_add_command(SOURCES apps/cmd_topo.cc DEPS omnicml_topo)
