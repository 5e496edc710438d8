# Helpers shared by the modules' CMakeLists.txt files (src/<module>/, tests/<module>/, bench/).

# Warnings and sanitizers, per target (no global flag changes).
function(omnicml_target_defaults target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic)
  if(OMNICML_SANITIZE)
    string(REPLACE ";" "," _san "${OMNICML_SANITIZE}")
    target_compile_options(${target} PRIVATE -fsanitize=${_san} -fno-omit-frame-pointer)
    target_link_options(${target} PRIVATE -fsanitize=${_san})
  endif()
  # libFuzzer builds (OMNICML_FUZZ, clang only): coverage instrumentation for every target;
  # the harnesses under fuzz/ link the libFuzzer runtime itself (-fsanitize=fuzzer).
  if(OMNICML_FUZZ)
    target_compile_options(${target} PRIVATE -fsanitize=fuzzer-no-link)
  endif()
endfunction()

# omnicml_add_library(NAME SOURCES a.cc b.cc DEPS lib...)
# A static module library; joins the umbrella target omnicml::omnicml.
function(omnicml_add_library name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS" ${ARGN})
  add_library(${name} STATIC ${ARG_SOURCES})
  target_include_directories(${name}
    PUBLIC $<BUILD_INTERFACE:${PROJECT_SOURCE_DIR}/include> $<INSTALL_INTERFACE:${CMAKE_INSTALL_INCLUDEDIR}>
    PRIVATE ${PROJECT_SOURCE_DIR}/src)
  string(REPLACE "omnicml_" "" _alias ${name})
  add_library(omnicml::${_alias} ALIAS ${name})
  target_compile_features(${name} PUBLIC cxx_std_20)
  target_link_libraries(${name} PUBLIC ${ARG_DEPS})
  omnicml_target_defaults(${name})
  if(OMNICML_SANITIZE)
    target_link_options(${name} INTERFACE -fsanitize=$<JOIN:${OMNICML_SANITIZE},,>)
  endif()
  set_property(GLOBAL APPEND PROPERTY OMNICML_LIBS ${name})
  install(TARGETS ${name} EXPORT omnicmlTargets
    ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
    LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR})
endfunction()

# omnicml_add_test(NAME SOURCES x_test.cc DEPS lib...)
# A GoogleTest program registered with CTest. Tests find the source tree through
# OMNICML_SOURCE_DIR (for datasets/ and ../shared/datasets/).
function(omnicml_add_test name)
  if(NOT OMNICML_BUILD_TESTS)
    return()
  endif()
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS} GTest::gtest GTest::gtest_main GTest::gmock)
  target_include_directories(${name} PRIVATE ${PROJECT_SOURCE_DIR}/tests ${PROJECT_SOURCE_DIR}/src)
  target_compile_definitions(${name} PRIVATE OMNICML_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
    OMNICML_BINARY_DIR="${PROJECT_BINARY_DIR}")
  omnicml_target_defaults(${name})
  gtest_discover_tests(${name} DISCOVERY_TIMEOUT 120 PROPERTIES TIMEOUT 900)
endfunction()

# omnicml_add_benchmark(NAME SOURCES x_benchmark.cc DEPS lib...)
function(omnicml_add_benchmark name)
  if(NOT OMNICML_BUILD_BENCHMARKS)
    return()
  endif()
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS} benchmark::benchmark benchmark::benchmark_main)
  omnicml_target_defaults(${name})
endfunction()

# omnicml_use_jemalloc(TARGET): an executable allocates with jemalloc when it was found
# (top-level CMakeLists.txt, OMNICML_JEMALLOC); defines OMNICML_HAVE_JEMALLOC.
function(omnicml_use_jemalloc target)
  if(TARGET PkgConfig::JEMALLOC)
    target_link_libraries(${target} PRIVATE PkgConfig::JEMALLOC)
    target_compile_definitions(${target} PRIVATE OMNICML_HAVE_JEMALLOC=1)
  endif()
endfunction()
