# Environment model: the adaptive appearance map of [G 2.2, 2.3] (reference views,
# hypothesis, three-phase update with forgetting), its spatial index and the binary
# encoding used for persistence. Owned by helper "envmodel".
#
# The library only uses the header-only contracts of descriptor.h and gaussian_mixture.h
# (no symbols of omnicml_descriptors / omnicml_tracking), so it links omnicml_core alone
# and its tests build even while those modules are being edited; the engine module links
# all of them.
omnicml_add_library(omnicml_envmodel
  SOURCES src/environment_model.cc src/spatial_index.cc src/binary_io.cc
  DEPS omnicml_core Eigen3::Eigen)

omnicml_add_test(envmodel_test
  SOURCES tests/environment_model_test.cc tests/spatial_index_test.cc tests/binary_io_test.cc
  DEPS omnicml_envmodel)

omnicml_add_benchmark(envmodel_benchmark
  SOURCES bench/environment_model_benchmark.cc
  DEPS omnicml_envmodel)

# With the descriptor module present, the tests also run the model on real Fourier
# signatures (heading recovery from rolled panoramas).
if(TARGET envmodel_test AND TARGET omnicml_descriptors)
  target_link_libraries(envmodel_test PRIVATE omnicml_descriptors)
  target_compile_definitions(envmodel_test PRIVATE OMNICML_ENVMODEL_HAVE_DESCRIPTORS=1)
endif()
if(TARGET envmodel_benchmark AND TARGET omnicml_descriptors)
  target_link_libraries(envmodel_benchmark PRIVATE omnicml_descriptors)
  target_compile_definitions(envmodel_benchmark PRIVATE OMNICML_ENVMODEL_HAVE_DESCRIPTORS=1)
endif()
