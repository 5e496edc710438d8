# Tracking: Gaussians and mixtures over planar poses with angle-aware arithmetic, the
# odometry motion model and the mixture-of-Gaussians tracker of [G 2.1] (propagation,
# covariance-intersection fusion, simplification, unimodality and summary).
# Owned by helper "tracking".
omnicml_add_library(omnicml_tracking
  SOURCES src/gaussian_mixture.cc src/tracker.cc
  DEPS omnicml_core Eigen3::Eigen)

omnicml_add_test(tracking_test
  SOURCES tests/gaussian_mixture_test.cc tests/tracker_test.cc
  DEPS omnicml_tracking)

omnicml_add_benchmark(tracker_benchmark
  SOURCES bench/tracker_benchmark.cc
  DEPS omnicml_tracking)
