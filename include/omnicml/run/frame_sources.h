// Frame sources of a run: where the frames come from (logs on disk or a built-in
// simulated world rendered in-process), opened as one FrameSource, optionally read ahead
// on a thread of their own, and counted for progress.
//
// Thread-safety: RunInput and the free functions are thread-safe; a FrameSource is
// driven by one thread (PrefetchFrames documents its own thread).
#ifndef OMNICML_RUN_FRAME_SOURCES_H_
#define OMNICML_RUN_FRAME_SOURCES_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "omnicml/sensor/frame.h"

namespace omnicml {

// Where the frames of a run come from: logs on disk (the sessions of every LOGDIR in
// order) or a built-in simulated world rendered in-process.
struct RunInput {
  std::vector<std::string> log_dirs;  // multi-day logs or single sessions, in order
  std::string world;                  // built-in world name, when log_dirs is empty
  int days = 1;                       // simulated days (world only), >= 1
  int first_day = 0;                  // first simulated day (world only; resume a run), >= 0
  int frames_per_day = 0;  // simulated frames per day; 0 = SimulatorOptions' default (300)
  std::uint64_t seed = 1;  // simulator seed (world only)
  // Simulated images (world only; --sim-image): kRawRing renders the panorama, then the
  // catadioptric ring the engine unwraps (exercises the unwrapper); kPanorama hands the
  // engine the rendered panorama with sensor noise, no ring and no unwrap (faster; the
  // pixels differ by the ring's resampling, so the errors differ a little: docs/results.md
  // "Simulator speed").
  ImageKind sim_image = ImageKind::kRawRing;
  // World only: render the frames on a thread of their own, up to a few frames ahead of
  // the engine (PrefetchFrames); the frames are the same bytes either way.
  bool prefetch_frames = true;
  bool skip_unreadable_frames = false;  // logs only: skip (and count) unreadable frames

  // Exactly one of log_dirs / world; days >= 1; frames_per_day >= 0. Throws
  // omnicml::Error naming the flag; a missing log directory is named too.
  void Validate() const;
  // One line for reports ("logs a, b" or "world home_store, days 1-3, 400 frames/day, seed 1").
  std::string Describe() const;
};

// Opens the input. For logs the constructor of LogReader validates every session.yaml
// and frames.csv header; for worlds the simulator is built. Throws omnicml::Error.
std::unique_ptr<FrameSource> OpenFrameSource(const RunInput& input);

// OpenFrameSource without images (Frame::image empty): the log's frames.csv rows, or
// the simulator's trajectory and odometry without rendering; for pose-only passes such as
// the median odometry step. Throws omnicml::Error as OpenFrameSource.
std::unique_ptr<FrameSource> OpenPoseOnlySource(const RunInput& input);

// A source that reads `inner` on a thread of its own, at most `depth` (>= 1) frames
// ahead of the consumer, and delivers exactly inner's frames in inner's order (so the
// output does not depend on whether frames are prefetched). inner's NumSessions and
// Session must be constant (they are called from the consumer's thread while the
// thread reads frames); an exception thrown by inner's Next is rethrown by the Next
// that would have delivered the frame. Destroying the source stops the thread.
std::unique_ptr<FrameSource> PrefetchFrames(std::unique_ptr<FrameSource> inner, int depth = 4);

// Frames the source will deliver (counted from the frames.csv files or days x frames
// per day), or std::nullopt when unknown; for progress and ETA only.
std::optional<std::int64_t> CountFrames(const RunInput& input, const FrameSource& source);

}  // namespace omnicml

#endif  // OMNICML_RUN_FRAME_SOURCES_H_
