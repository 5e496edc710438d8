// Delayed, concurrent application of map updates [G 2.1, 2.3] (docs/design.md "Unimodality,
// reconstruction, delayed update").
//
// Every unimodal estimate (and every reconstructed state) gives a pair (y_t, N(mu_t, C_t))
// that updates the environment model. The pair is not applied at once: it becomes
// visible to the map exactly `update_delay_frames` frames later, so the map never feeds
// back into the estimate it came from, and its application can run on a background
// worker while the engine unwraps and describes the next frames.
//
// Frame numbering: the engine numbers the frames it processes 0, 1, 2, ... (its own
// counter, over all sessions). An update pushed while processing frame t is *due* at
// frame t + update_delay_frames (`due_frame`); updates of reconstructed frames, which are
// produced at the anchor frame t, are due at t + update_delay_frames as well (they
// depend on the anchor's estimate). Updates are applied in push order, and their due
// frames never decrease in push order.
//
// Protocol per frame T (CmlEngine):
//   Schedule(T)          at the end of frame T-1: hand every update due at <= T to the
//                        worker (background mode) — it applies them while the engine
//                        unwraps and describes frame T;
//   WaitUntilApplied(T)  before frame T queries the map: the barrier. On return exactly
//                        the updates due at <= T have been applied (in synchronous mode
//                        they are applied here, on the calling thread).
//   Push(update)         after the estimate of frame T.
// Since the same updates are applied in the same order whether or not the worker runs,
// the map is bit-identical with threads = 1 or 2 and from run to run.
//
// Thread-safety: MapUpdater's public methods must be called from one thread (the
// engine's); the apply function runs on the worker thread in background mode and must
// not be called concurrently with anything else reading the model — the engine only
// reads the model after WaitUntilApplied. If the apply function throws, the exception is
// captured and rethrown by the next WaitUntilApplied / Flush on the engine's thread.
#ifndef OMNICML_ENGINE_MAP_UPDATER_H_
#define OMNICML_ENGINE_MAP_UPDATER_H_

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

#include "omnicml/descriptors/descriptor.h"
#include "omnicml/geometry/gaussian_mixture.h"

namespace omnicml {

// One pending update of the map with (y_t, N(mu_t, C_t)).
struct MapUpdate {
  std::int64_t frame = 0;      // engine frame index of the observation y_t
  std::int64_t due_frame = 0;  // the first frame whose map query sees this update
  int session_index = 0;       // session (day) of the observation, for the model's counters
  Descriptor descriptor;       // y_t
  Gaussian state;              // N(mu_t, C_t) in the map frame; weight unused
  bool reconstructed = false;  // true when the state comes from ReconstructTrajectory
};

// FIFO of MapUpdate ordered by due frame (not thread-safe; MapUpdater guards it).
class DelayedUpdateQueue {
 public:
  // update_delay_frames >= 1 (throws omnicml::Error otherwise).
  explicit DelayedUpdateQueue(int update_delay_frames);

  int update_delay_frames() const { return delay_; }

  // Enqueues the update of an observation made at frame `produced_at_frame` (the current
  // frame): due_frame := produced_at_frame + update_delay_frames. `update.frame` must be
  // <= produced_at_frame and produced_at_frame must not decrease between calls
  // (OMNICML_CHECK).
  void Push(MapUpdate update, std::int64_t produced_at_frame);

  // Enqueues an update with its due_frame already set (loading a saved engine); due
  // frames must not decrease (OMNICML_CHECK).
  void PushRaw(MapUpdate update);

  // Removes and returns, in order, the updates with due_frame <= frame.
  std::vector<MapUpdate> PopDue(std::int64_t frame);
  // Removes and returns every update.
  std::vector<MapUpdate> PopAll();

  bool empty() const { return items_.empty(); }
  std::size_t size() const { return items_.size(); }
  const std::deque<MapUpdate>& items() const { return items_; }
  // Mutable access for corrections of the queued states (global pose graph); the order
  // and due frames must not change.
  std::deque<MapUpdate>& mutable_items() { return items_; }

 private:
  int delay_;
  std::int64_t last_produced_ = INT64_MIN;
  std::deque<MapUpdate> items_;
};

// Applies due updates through `apply`, on a background worker or synchronously.
class MapUpdater {
 public:
  using ApplyFn = std::function<void(const MapUpdate&)>;

  // background: true starts one worker thread (std::thread + condition variable).
  MapUpdater(ApplyFn apply, int update_delay_frames, bool background);
  ~MapUpdater();  // waits for the worker to finish the batch in hand, then joins it
  MapUpdater(const MapUpdater&) = delete;
  MapUpdater& operator=(const MapUpdater&) = delete;

  // Queues the update of an observation at the current frame (see DelayedUpdateQueue).
  void Push(MapUpdate update, std::int64_t produced_at_frame);
  void PushRaw(MapUpdate update);

  // Background mode: hands every queued update due at <= frame to the worker and returns
  // at once. Synchronous mode: no-op (the work happens in WaitUntilApplied).
  void Schedule(std::int64_t frame);

  // Barrier: returns when every update due at <= frame has been applied. Returns the
  // number of updates applied since the previous barrier (including by the worker).
  int WaitUntilApplied(std::int64_t frame);

  // Applies every queued update regardless of its due frame, waits, and returns the count.
  int Flush();

  // Updates still queued (not yet handed to the worker). Call after a barrier.
  const std::deque<MapUpdate>& queued() const { return queue_.items(); }
  // The same, mutable, to correct queued states (global pose graph). Call after a barrier
  // and before the next Schedule (the worker then holds no batch); keep order and due frames.
  std::deque<MapUpdate>& mutable_queued() { return queue_.mutable_items(); }
  int update_delay_frames() const { return queue_.update_delay_frames(); }
  bool background() const { return background_; }
  // Total updates applied so far.
  std::int64_t applied_count() const;
  // Microseconds the apply function has spent since the previous barrier (either thread).
  double TakeApplyMicroseconds();

 private:
  void WorkerLoop();
  void ApplyBatch(std::vector<MapUpdate>& batch);
  void RethrowWorkerError();

  ApplyFn apply_;
  bool background_;
  DelayedUpdateQueue queue_;  // touched only by the engine thread

  mutable std::mutex mutex_;
  std::condition_variable work_cv_;      // engine -> worker: new batch or stop
  std::condition_variable done_cv_;      // worker -> engine: batch finished
  std::vector<MapUpdate> handed_;        // batch handed to the worker (guarded)
  bool busy_ = false;                    // worker holds a batch (guarded)
  bool stop_ = false;                    // guarded
  std::exception_ptr worker_error_;      // guarded
  std::int64_t applied_ = 0;             // guarded
  int applied_since_barrier_ = 0;        // guarded
  double apply_us_since_barrier_ = 0.0;  // guarded
  std::thread worker_;
};

}  // namespace omnicml

#endif  // OMNICML_ENGINE_MAP_UPDATER_H_
