// Sizes the library and the `omnicml` commands refuse up front, before any work starts
// (a run of 10000 days, 2^31 frames a day or 100000 threads would otherwise start and
// exhaust disk, memory or the scheduler hours later). One place for each ceiling; the
// commands' --help names them. File sizes and line lengths of the readers are in
// file_io.h (kMaxTextFileBytes, kMaxCsvLineBytes, ...).
//
// Thread-safety: constants and a pure function.
#ifndef OMNICML_COMMON_LIMITS_H_
#define OMNICML_COMMON_LIMITS_H_

#include <cstdint>
#include <string_view>

#include "omnicml/common/common.h"

namespace omnicml {

// Simulated or processed days (sessions) of one run.
inline constexpr int kMaxDays = 1000;
// Frames of one simulated day.
inline constexpr int kMaxFramesPerDay = 1'000'000;
// Frames of one simulated run, days x frames per day (about 100 hours of rendering, and
// 10 GB of panoramas written by `omnicml simulate` at 180 x 36 px).
inline constexpr std::int64_t kMaxSimulatedFrames = 10'000'000;
// Engine threads (CmlEngineOptions::threads) and parallel jobs (`compare --jobs`).
inline constexpr int kMaxThreads = 64;
// Repetitions of an experiment (`mcl --runs`).
inline constexpr int kMaxRuns = 100'000;
// Particles of a Monte Carlo localizer (`mcl --particles`, MclOptions::num_particles).
inline constexpr int kMaxParticles = 10'000'000;
// Positions in logs (session.yaml start pose, frames.csv odometry and ground truth), metres:
// |x|, |y| above this are rejected (a unit or parsing mistake, not a building).
inline constexpr double kMaxPositionM = 1e6;
// Headings in logs, radians: |phi| above this is rejected (odometry headings may be
// unwrapped, so more than 2 pi is allowed).
inline constexpr double kMaxHeadingRad = 1e6;
// Variances of a session's start covariance: position (m^2, a standard deviation of
// 1000 km) and heading (rad^2, a standard deviation of 10 rad, far beyond uniform).
inline constexpr double kMaxPositionVarianceM2 = 1e12;
inline constexpr double kMaxHeadingVarianceRad2 = 100.0;

// Jobs of one sweep (`omnicml sweep`: inputs x seeds x option values), checked before
// anything is expanded or written.
inline constexpr std::int64_t kMaxSweepJobs = 10'000;
// Frames a video file may declare (logs' video frames, `import video`): 100 million is
// five weeks at 30 frames/s; a larger count in a container header is a damaged or hostile
// file, refused before any frame is decoded.
inline constexpr std::int64_t kMaxVideoFrames = 100'000'000;
// Pixels of one panorama side (width or height) in logs, calibrations and options: far
// beyond any camera, small enough that a panorama's buffers fit in memory.
inline constexpr int kMaxPanoramaSidePx = 16'384;
// YAML documents: nodes visited with every alias expanded, and nesting depth. A
// configuration has some hundreds of nodes; an alias bomb ("billion laughs") expands to
// billions and is refused before it is materialised.
inline constexpr std::int64_t kMaxYamlNodes = 1'000'000;
inline constexpr int kMaxYamlDepth = 64;

// Throws omnicml::Error "<name> must lie in [min, max] (got value)" unless
// min <= value <= max. `name` is what the user wrote: a flag ("--days") or a key.
inline void CheckLimit(std::string_view name, std::int64_t value, std::int64_t min,
                       std::int64_t max) {
  if (value < min || value > max) {
    throw Error(StrCat(name, " must lie in [", min, ", ", max, "] (got ", value, ")"));
  }
}

}  // namespace omnicml

#endif  // OMNICML_COMMON_LIMITS_H_
