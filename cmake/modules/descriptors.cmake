# Descriptors: Fourier signature, invariant feature histogram, colour histogram, the
# common interface with its serialisation, and the factory (DESIGN.md "Descriptors").
omnicml_add_library(omnicml_descriptors
  SOURCES src/descriptor.cc src/descriptor_factory.cc src/fourier_signature.cc
          src/invariant_feature_histogram.cc src/color_histogram.cc
  DEPS omnicml_core ${OpenCV_LIBS} PkgConfig::FFTW3F)

omnicml_add_test(descriptors_test
  SOURCES tests/descriptor_test.cc tests/fourier_signature_test.cc
          tests/invariant_feature_histogram_test.cc tests/color_histogram_test.cc
          tests/antworld_descriptor_test.cc
  DEPS omnicml_descriptors ${OpenCV_LIBS})

omnicml_add_benchmark(descriptor_benchmark SOURCES bench/descriptor_benchmark.cc
  DEPS omnicml_descriptors)

# The describe command reads and unwraps images through the unwrap module.
if(TARGET omnicml_unwrap)
  omnicml_add_command(SOURCES apps/cmd_describe.cc DEPS omnicml_descriptors omnicml_unwrap omnicml_cli_support
    nlohmann_json::nlohmann_json)
endif()
