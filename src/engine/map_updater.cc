#include "omnicml/engine/map_updater.h"

#include <chrono>
#include <climits>
#include <utility>

#include "omnicml/common/common.h"

namespace omnicml {

DelayedUpdateQueue::DelayedUpdateQueue(int update_delay_frames) : delay_(update_delay_frames) {
  if (update_delay_frames < 1) {
    throw Error(StrCat("update_delay_frames must be >= 1, got ", update_delay_frames));
  }
}

void DelayedUpdateQueue::Push(MapUpdate update, std::int64_t produced_at_frame) {
  OMNICML_CHECK(update.frame <= produced_at_frame)
      << "update of frame " << update.frame << " pushed at earlier frame " << produced_at_frame;
  OMNICML_CHECK(produced_at_frame >= last_produced_)
      << "updates pushed out of order: " << produced_at_frame << " after " << last_produced_;
  last_produced_ = produced_at_frame;
  update.due_frame = produced_at_frame + delay_;
  items_.push_back(std::move(update));
}

void DelayedUpdateQueue::PushRaw(MapUpdate update) {
  OMNICML_CHECK(items_.empty() || items_.back().due_frame <= update.due_frame)
      << "due frames must not decrease: " << update.due_frame << " after "
      << items_.back().due_frame;
  last_produced_ = std::max(last_produced_, update.due_frame - delay_);
  items_.push_back(std::move(update));
}

std::vector<MapUpdate> DelayedUpdateQueue::PopDue(std::int64_t frame) {
  std::vector<MapUpdate> out;
  while (!items_.empty() && items_.front().due_frame <= frame) {
    out.push_back(std::move(items_.front()));
    items_.pop_front();
  }
  return out;
}

std::vector<MapUpdate> DelayedUpdateQueue::PopAll() {
  std::vector<MapUpdate> out(std::make_move_iterator(items_.begin()),
                             std::make_move_iterator(items_.end()));
  items_.clear();
  return out;
}

MapUpdater::MapUpdater(ApplyFn apply, int update_delay_frames, bool background)
    : apply_(std::move(apply)), background_(background), queue_(update_delay_frames) {
  OMNICML_CHECK(static_cast<bool>(apply_)) << "MapUpdater needs an apply function";
  if (background_) worker_ = std::thread([this] { WorkerLoop(); });
}

MapUpdater::~MapUpdater() {
  if (worker_.joinable()) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    work_cv_.notify_all();
    worker_.join();
  }
}

void MapUpdater::Push(MapUpdate update, std::int64_t produced_at_frame) {
  queue_.Push(std::move(update), produced_at_frame);
}

void MapUpdater::PushRaw(MapUpdate update) { queue_.PushRaw(std::move(update)); }

void MapUpdater::ApplyBatch(std::vector<MapUpdate>& batch) {
  // Runs on the worker (background) or the engine thread (synchronous); the lock is held
  // only for the bookkeeping, never while the model is updated.
  for (const MapUpdate& u : batch) {
    const auto t0 = std::chrono::steady_clock::now();
    apply_(u);
    const double us =
        std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
    std::lock_guard<std::mutex> lock(mutex_);
    ++applied_;
    ++applied_since_barrier_;
    apply_us_since_barrier_ += us;
  }
}

void MapUpdater::WorkerLoop() {
  for (;;) {
    std::vector<MapUpdate> batch;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      work_cv_.wait(lock, [this] { return stop_ || !handed_.empty(); });
      if (handed_.empty()) return;  // stop_ with nothing left
      batch.swap(handed_);
      busy_ = true;
    }
    try {
      ApplyBatch(batch);
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!worker_error_) worker_error_ = std::current_exception();
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      busy_ = false;
    }
    done_cv_.notify_all();
  }
}

void MapUpdater::Schedule(std::int64_t frame) {
  if (!background_) return;
  std::vector<MapUpdate> due = queue_.PopDue(frame);
  if (due.empty()) return;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (MapUpdate& u : due) handed_.push_back(std::move(u));
  }
  work_cv_.notify_one();
}

void MapUpdater::RethrowWorkerError() {
  std::exception_ptr error;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    std::swap(error, worker_error_);
  }
  if (error) std::rethrow_exception(error);
}

int MapUpdater::WaitUntilApplied(std::int64_t frame) {
  if (background_) {
    Schedule(frame);
    std::unique_lock<std::mutex> lock(mutex_);
    done_cv_.wait(lock, [this] { return handed_.empty() && !busy_; });
  } else {
    std::vector<MapUpdate> due = queue_.PopDue(frame);
    ApplyBatch(due);
  }
  RethrowWorkerError();
  std::lock_guard<std::mutex> lock(mutex_);
  const int n = applied_since_barrier_;
  applied_since_barrier_ = 0;
  return n;
}

int MapUpdater::Flush() { return WaitUntilApplied(INT64_MAX); }

std::int64_t MapUpdater::applied_count() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return applied_;
}

double MapUpdater::TakeApplyMicroseconds() {
  std::lock_guard<std::mutex> lock(mutex_);
  const double us = apply_us_since_barrier_;
  apply_us_since_barrier_ = 0.0;
  return us;
}

}  // namespace omnicml
