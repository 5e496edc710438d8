// LiveEngine: the engine for a running robot, independent of any middleware. A ROS 1
// node (src/ros/) and a later ROS 2 node are thin layers over it: they convert messages
// into AddImage / AddOdometry calls and the outputs into messages.
//
// Lifecycle: construct (starts one worker thread) -> AddOdometry / AddImage / commands
// from any threads -> Stop() (processes or drops what is queued, joins the worker) ->
// engine() may be used directly (e.g. to save the map on shutdown).
//
// Flow. AddImage puts the frame into a bounded FIFO of queue_capacity_frames; when it is
// full the oldest waiting frame is dropped and counted (the freshest image wins, so the
// estimate never lags behind by more than the queue). The worker takes the front frame
// once odometry covers its stamp (a sample at or after it) or odometry_wait_s of wall
// time has passed (then the newest odometry sample is held and the frame is counted in
// odometry_held_frames), interpolates odom_T_robot to the stamp (odometry_buffer.h), runs
// CmlEngine::ProcessFrame and hands a LiveOutput to the output callback. Commands
// (BeginSession, SetForgettingMode, Save) enter the same FIFO, are never dropped and run
// in order with the frames, between two ProcessFrame calls.
//
// Sessions: a frame arriving with no session begun (the first frame, or after a gap in
// image stamps larger than session_gap_s, or stamps going backwards) begins one from the
// session template given at construction (first session) or later_sessions (after a gap);
// a template camera of size 0 x 0 gets the frame's size (kind and calibration kept).
//
// A new map (the factory constructor): the engine's per-frame options depend on the
// distance between frames (CmlEngineOptions::reference_frame_step_m), which an offline run
// reads from its log's first session before the first frame. Live, the worker holds the
// first frames (up to frame_step_frames, with their odometry) without processing them, then
// calls the factory with their odometry poses, and processes the held frames in order:
// their outputs come late, and a replayed log gives the outputs of the offline run.
// Commands that arrive meanwhile are held in order with the frames, except that Save, a
// BeginSession after the first held frame, a stamp gap (or stamps going backwards) and
// Stop end the holding early: the factory gets the frames held so far, as an offline run
// reads only its first session. Stop(false) drops the held frames (commands still run).
//
// Frames: map frame = the engine's map; odom frame = that of the odometry poses. The
// output's map_T_odom = map_T_robot (estimate mean) * odom_T_robot^-1, the transform a
// localization node publishes as map -> odom.
//
// Thread-safety: AddImage, AddOdometry, the commands and stats() may be called from any
// thread. The callbacks run on the worker thread, one at a time; they must not call
// Stop(). engine() only after Stop().
#ifndef OMNICML_LIVE_LIVE_ENGINE_H_
#define OMNICML_LIVE_LIVE_ENGINE_H_

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include <opencv2/core.hpp>

#include "omnicml/engine/calibration.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/live/odometry_buffer.h"
#include "omnicml/sensor/frame.h"

namespace omnicml {

struct LiveEngineOptions {
  // Frames waiting for the engine, >= 1. When full, the oldest waiting frame is dropped.
  int queue_capacity_frames = 1;
  // Wall-clock seconds, >= 0, a frame at the queue's front waits for odometry at or after
  // its stamp before the newest odometry sample is used instead.
  double odometry_wait_s = 0.5;
  // Seconds of odometry history kept for interpolation, > 0.
  double odometry_history_s = 30.0;
  // Seconds, >= 0: an image stamp more than this after the previous one begins a new
  // session (later_sessions template); 0 disables. Stamps going backwards always begin one.
  double session_gap_s = 0.0;
  // Every this many processed frames the reference views go to the views callback; >= 0,
  // 0 never.
  int reference_views_every_frames = 0;
  // Factory constructor only: frames held before the factory is called, >= 2. An offline
  // run reads kFrameStepSampleFrames (300) from its log; fewer bound the memory the held
  // images take (100 raw 1280 x 1024 BGR rings: 390 MB) and give the same half-octave
  // factor unless the robot's speed changes over them.
  int frame_step_frames = 100;

  void Validate() const;  // throws omnicml::Error naming the field
};

// One component of a reference view of the map (map frame), for display.
struct LiveViewComponent {
  std::uint64_t view_id = 0;
  Pose2 pose = Pose2::Zero();  // x_m, y_m in the map frame; phi relative to the view
  double weight = 0.0;         // w_ij in [0, 1]
};

// The result of one processed frame.
struct LiveOutput {
  double stamp_s = 0.0;  // the image stamp
  std::int64_t frame = 0;
  int session = 0;
  // The fused estimate p(x_t) summary (map frame); unset while the state is unknown.
  std::optional<Estimate> estimate;
  Mixture hypotheses;                  // the components of p(x_t) (map frame), empty when unknown
  Pose2 odom_T_robot = Pose2::Zero();  // odometry interpolated to stamp_s
  std::optional<Pose2> map_T_odom;     // set with the estimate
  bool odometry_held = false;          // odometry did not cover stamp_s (newest sample used)
  std::int64_t dropped_frames = 0;     // frames dropped from the queue so far
  double queue_wait_us = 0.0;          // from AddImage to the start of processing
  double engine_us = 0.0;              // the ProcessFrame call
};

// Counters, readable at any time.
struct LiveStats {
  std::int64_t received_frames = 0;
  std::int64_t processed_frames = 0;
  std::int64_t dropped_frames = 0;  // dropped from a full queue
  std::int64_t failed_frames = 0;   // ProcessFrame threw (error callback)
  std::int64_t odometry_held_frames = 0;
  std::int64_t rejected_odometry = 0;  // samples not after the previous one, or not finite
  std::int64_t sessions = 0;
};

class LiveEngine {
 public:
  using OutputCallback = std::function<void(const LiveOutput&)>;
  using ViewsCallback = std::function<void(const std::vector<LiveViewComponent>&)>;
  using ErrorCallback = std::function<void(const std::string&)>;

  struct Callbacks {
    OutputCallback on_output;  // each processed frame
    ViewsCallback on_views;    // every reference_views_every_frames frames
    ErrorCallback on_error;    // a frame or command that failed (one line)
  };

  // Takes the engine (fresh or loaded). first_session: the template of the first session;
  // later_sessions: of sessions begun by a stamp gap. Throws omnicml::Error on bad options.
  LiveEngine(std::unique_ptr<CmlEngine> engine, const LiveEngineOptions& options,
             SessionInfo first_session, SessionInfo later_sessions, Callbacks callbacks);
  // A new map whose engine is made once the first frames are held (see the top): the
  // factory gets the odometry poses of the held frames in order (possibly none) and
  // returns the engine; it runs on the worker thread. An exception from it (or no engine)
  // goes to the error callback and every frame then fails.
  using EngineFactory =
      std::function<std::unique_ptr<CmlEngine>(const std::vector<Pose2>& first_odometry)>;
  LiveEngine(EngineFactory make_engine, const LiveEngineOptions& options, SessionInfo first_session,
             SessionInfo later_sessions, Callbacks callbacks);
  ~LiveEngine();  // Stop(false)
  LiveEngine(const LiveEngine&) = delete;
  LiveEngine& operator=(const LiveEngine&) = delete;

  // Odometry sample odom_T_robot at stamp_s (seconds). Out-of-order samples are counted
  // in rejected_odometry and ignored. Returns false for such a sample.
  bool AddOdometry(double stamp_s, const Pose2& odom_T_robot);
  // An image (CV_8UC1 or CV_8UC3 BGR; raw ring or panorama as the session camera says)
  // stamped stamp_s. The Mat is shared, not copied. Returns false when a waiting frame was
  // dropped to make room. After Stop, frames are ignored (false).
  bool AddImage(double stamp_s, cv::Mat image);
  // An image still encoded (a compressed or raw message): `decode` runs on the worker
  // when the frame is taken from the queue, so frames dropped from a full queue cost no
  // decoding. `decode` may throw (std::exception): the frame then fails like a frame the
  // engine rejects (error callback, failed_frames).
  bool AddEncodedImage(double stamp_s, std::function<cv::Mat()> decode);
  // An image with its odometry already known (no interpolation, no waiting).
  bool AddFrame(double stamp_s, cv::Mat image, const Pose2& odom_T_robot);

  // Begins a session before the next frame (the engine's BeginSession; a camera of size
  // 0 x 0 gets the next frame's size).
  void BeginSession(SessionInfo info);
  void SetForgettingMode(ForgettingMode mode);
  // Saves the engine (map and state) to path (engine_io.h, atomic) between two frames.
  // The future holds an empty string on success, else the error message.
  std::future<std::string> Save(std::string path);

  // Stops the worker. drain: process every queued frame and command first; else queued
  // frames are dropped (commands still run). Idempotent.
  void Stop(bool drain = true);

  LiveStats stats() const;
  // Only after Stop() (and, with the factory constructor, once it made an engine).
  CmlEngine& engine();

 private:
  struct QueuedFrame {
    double stamp_s = 0.0;
    cv::Mat image;
    std::optional<Pose2> odom_T_robot;
    std::chrono::steady_clock::time_point received;
    std::function<cv::Mat()> decode = {};  // set: image is decoded by the worker
  };
  struct Command {
    enum class Kind { kOther, kBeginSession, kSave };
    std::function<void()> run;
    Kind kind = Kind::kOther;
  };
  using Item = std::variant<QueuedFrame, Command>;

  // Both public constructors: exactly one of engine and make_engine is set.
  LiveEngine(std::unique_ptr<CmlEngine> engine, EngineFactory make_engine,
             const LiveEngineOptions& options, SessionInfo first_session,
             SessionInfo later_sessions, Callbacks callbacks);
  bool Enqueue(QueuedFrame frame);
  void EnqueueCommand(std::function<void()> run, Command::Kind kind = Command::Kind::kOther);
  void WorkerLoop();
  // Worker: blocks until the front frame may run (odometry or timeout); fills odometry.
  // Called with the lock held; returns with it held.
  void WaitForOdometry(std::unique_lock<std::mutex>& lock, QueuedFrame* frame, bool* held);
  void Process(QueuedFrame frame, bool odometry_held);
  // Factory constructor: holds `frame` for the frame step, or ends the holding first when
  // it begins a new session.
  void Hold(QueuedFrame frame, bool odometry_held);
  // Factory constructor: holds `command` in order with the frames, or ends the holding.
  void HoldCommand(Command command);
  // Makes the engine from the held frames' odometry, then processes the held frames and
  // runs the held commands in order; drop_frames: the held frames are dropped (counted)
  // instead, and the factory gets none. No-op once made.
  void EndHolding(bool drop_frames = false);
  std::size_t HeldFrames() const;
  // Whether a frame stamped stamp_s after one stamped previous_s begins a session: stamps
  // going backwards, or a gap above session_gap_s.
  bool StampsBeginSession(const std::optional<double>& previous_s, double stamp_s) const;
  void BeginSessionNow(SessionInfo info, const cv::Mat& image);
  void EmitViews();

  std::unique_ptr<CmlEngine> engine_;
  LiveEngineOptions options_;
  SessionInfo first_session_;
  SessionInfo later_sessions_;
  Callbacks callbacks_;

  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<Item> queue_;
  int queued_frames_ = 0;
  OdometryBuffer odometry_;
  LiveStats stats_;
  bool stopping_ = false;
  bool drain_ = true;
  bool stopped_ = false;

  // Worker-only state.
  std::optional<SessionInfo> pending_session_;  // begin before the next frame
  bool in_session_ = false;
  EngineFactory make_engine_;  // set until the engine is made
  struct HeldFrame {
    QueuedFrame frame;
    bool odometry_held = false;
  };
  std::vector<std::variant<HeldFrame, Command>> held_;
  std::optional<double> last_held_stamp_s_;
  std::optional<double> last_stamp_s_;
  std::int64_t index_in_session_ = 0;

  std::thread worker_;
};

}  // namespace omnicml

#endif  // OMNICML_LIVE_LIVE_ENGINE_H_
