#include "omnicml/live/live_engine.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <utility>

#include "omnicml/common/common.h"
#include "omnicml/engine/engine_io.h"

namespace omnicml {

void LiveEngineOptions::Validate() const {
  if (queue_capacity_frames < 1) throw Error("queue_capacity_frames must be >= 1");
  if (!(odometry_wait_s >= 0.0) || !std::isfinite(odometry_wait_s))
    throw Error("odometry_wait_s must be finite and >= 0");
  if (!(odometry_history_s > 0.0) || !std::isfinite(odometry_history_s))
    throw Error("odometry_history_s must be finite and > 0");
  if (!(session_gap_s >= 0.0) || !std::isfinite(session_gap_s))
    throw Error("session_gap_s must be finite and >= 0");
  if (reference_views_every_frames < 0) throw Error("reference_views_every_frames must be >= 0");
  if (frame_step_frames < 2) throw Error("frame_step_frames must be >= 2");
}

namespace {

// `p` itself, or omnicml::Error(what) when it is empty.
template <class T>
T NonEmpty(T p, const char* what) {
  if (!p) throw Error(what);
  return p;
}

}  // namespace

LiveEngine::LiveEngine(std::unique_ptr<CmlEngine> engine, EngineFactory make_engine,
                       const LiveEngineOptions& options, SessionInfo first_session,
                       SessionInfo later_sessions, Callbacks callbacks)
    : engine_(std::move(engine)),
      options_(options),
      first_session_(std::move(first_session)),
      later_sessions_(std::move(later_sessions)),
      callbacks_(std::move(callbacks)),
      odometry_(options.odometry_history_s),
      make_engine_(std::move(make_engine)) {
  options_.Validate();
  worker_ = std::thread([this] { WorkerLoop(); });
}

LiveEngine::LiveEngine(std::unique_ptr<CmlEngine> engine, const LiveEngineOptions& options,
                       SessionInfo first_session, SessionInfo later_sessions, Callbacks callbacks)
    : LiveEngine(NonEmpty(std::move(engine), "LiveEngine: no engine"), nullptr, options,
                 std::move(first_session), std::move(later_sessions), std::move(callbacks)) {}

LiveEngine::LiveEngine(EngineFactory make_engine, const LiveEngineOptions& options,
                       SessionInfo first_session, SessionInfo later_sessions, Callbacks callbacks)
    : LiveEngine(nullptr, NonEmpty(std::move(make_engine), "LiveEngine: no engine factory"),
                 options, std::move(first_session), std::move(later_sessions),
                 std::move(callbacks)) {}

LiveEngine::~LiveEngine() { Stop(false); }

bool LiveEngine::AddOdometry(double stamp_s, const Pose2& odom_T_robot) {
  bool ok;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ok = odometry_.Add(stamp_s, odom_T_robot);
    if (!ok) ++stats_.rejected_odometry;
  }
  cv_.notify_all();
  return ok;
}

bool LiveEngine::AddImage(double stamp_s, cv::Mat image) {
  return Enqueue({stamp_s, std::move(image), std::nullopt, std::chrono::steady_clock::now()});
}

bool LiveEngine::AddEncodedImage(double stamp_s, std::function<cv::Mat()> decode) {
  return Enqueue(
      {stamp_s, cv::Mat(), std::nullopt, std::chrono::steady_clock::now(), std::move(decode)});
}

bool LiveEngine::AddFrame(double stamp_s, cv::Mat image, const Pose2& odom_T_robot) {
  return Enqueue({stamp_s, std::move(image), odom_T_robot, std::chrono::steady_clock::now()});
}

bool LiveEngine::Enqueue(QueuedFrame frame) {
  bool dropped = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return false;
    ++stats_.received_frames;
    if (queued_frames_ >= options_.queue_capacity_frames) {
      // Drop the oldest waiting frame (commands stay).
      for (auto it = queue_.begin(); it != queue_.end(); ++it) {
        if (std::holds_alternative<QueuedFrame>(*it)) {
          queue_.erase(it);
          --queued_frames_;
          ++stats_.dropped_frames;
          dropped = true;
          break;
        }
      }
    }
    queue_.emplace_back(std::move(frame));
    ++queued_frames_;
  }
  cv_.notify_all();
  return !dropped;
}

void LiveEngine::EnqueueCommand(std::function<void()> run, Command::Kind kind) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    queue_.emplace_back(Command{std::move(run), kind});
  }
  cv_.notify_all();
}

void LiveEngine::BeginSession(SessionInfo info) {
  EnqueueCommand([this, info = std::move(info)] { pending_session_ = info; },
                 Command::Kind::kBeginSession);
}

void LiveEngine::SetForgettingMode(ForgettingMode mode) {
  EnqueueCommand([this, mode] {
    if (engine_) engine_->SetForgettingMode(mode);
  });
}

std::future<std::string> LiveEngine::Save(std::string path) {
  auto promise = std::make_shared<std::promise<std::string>>();
  std::future<std::string> result = promise->get_future();
  EnqueueCommand(
      [this, promise, path = std::move(path)] {
        try {
          if (!engine_) throw Error("no engine (its factory failed)");
          SaveEngine(*engine_, path);
          promise->set_value("");
        } catch (const std::exception& e) {
          promise->set_value(e.what());
        }
      },
      Command::Kind::kSave);
  return result;
}

void LiveEngine::Stop(bool drain) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopped_) return;
    stopping_ = true;
    drain_ = drain;
  }
  cv_.notify_all();
  if (worker_.joinable()) worker_.join();
  stopped_ = true;
}

LiveStats LiveEngine::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

CmlEngine& LiveEngine::engine() {
  OMNICML_CHECK(stopped_) << "LiveEngine::engine() before Stop()";
  OMNICML_CHECK(engine_ != nullptr) << "LiveEngine::engine(): its factory made no engine";
  return *engine_;
}

void LiveEngine::WorkerLoop() {
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    cv_.wait(lock, [&] { return stopping_ || !queue_.empty(); });
    if (queue_.empty()) {
      if (stopping_) {
        if (make_engine_) {
          lock.unlock();
          EndHolding(/*drop_frames=*/!drain_);
          lock.lock();
        }
        break;
      }
      continue;
    }
    if (auto* command = std::get_if<Command>(&queue_.front())) {
      Command c = std::move(*command);
      queue_.pop_front();
      lock.unlock();
      if (make_engine_) {
        HoldCommand(std::move(c));
      } else {
        c.run();
      }
      lock.lock();
      continue;
    }
    auto& front = std::get<QueuedFrame>(queue_.front());
    if (stopping_ && !drain_) {
      queue_.pop_front();
      --queued_frames_;
      ++stats_.dropped_frames;
      continue;
    }
    // Wait for odometry at or after the frame's stamp, at most odometry_wait_s.
    const bool ready =
        front.odom_T_robot.has_value() || odometry_.Covers(front.stamp_s) || stopping_;
    const auto deadline =
        front.received + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                             std::chrono::duration<double>(options_.odometry_wait_s));
    if (!ready && std::chrono::steady_clock::now() < deadline) {
      cv_.wait_until(lock, deadline);
      continue;  // the front may have changed (dropped) meanwhile
    }
    QueuedFrame frame = std::move(front);
    queue_.pop_front();
    --queued_frames_;
    bool held = false;
    if (!frame.odom_T_robot) {
      if (std::optional<Pose2> odom = odometry_.At(frame.stamp_s)) {
        frame.odom_T_robot = *odom;
      } else {
        held = true;
        const auto newest = odometry_.Newest();
        frame.odom_T_robot = newest ? newest->second : Pose2::Zero();
      }
    }
    if (held) ++stats_.odometry_held_frames;
    lock.unlock();
    if (make_engine_) {
      Hold(std::move(frame), held);
    } else {
      Process(std::move(frame), held);
    }
    lock.lock();
  }
}

bool LiveEngine::StampsBeginSession(const std::optional<double>& previous_s, double stamp_s) const {
  return previous_s && (stamp_s <= *previous_s || (options_.session_gap_s > 0.0 &&
                                                   stamp_s - *previous_s > options_.session_gap_s));
}

std::size_t LiveEngine::HeldFrames() const {
  return static_cast<std::size_t>(std::count_if(held_.begin(), held_.end(), [](const auto& item) {
    return std::holds_alternative<HeldFrame>(item);
  }));
}

void LiveEngine::Hold(QueuedFrame frame, bool odometry_held) {
  if (StampsBeginSession(last_held_stamp_s_, frame.stamp_s)) {
    // The first session ends here (an offline run reads its first session only).
    EndHolding();
    Process(std::move(frame), odometry_held);
    return;
  }
  last_held_stamp_s_ = frame.stamp_s;
  held_.emplace_back(HeldFrame{std::move(frame), odometry_held});
  if (HeldFrames() >= static_cast<std::size_t>(options_.frame_step_frames)) EndHolding();
}

void LiveEngine::HoldCommand(Command command) {
  const bool ends = command.kind == Command::Kind::kSave ||
                    (command.kind == Command::Kind::kBeginSession && HeldFrames() > 0);
  held_.emplace_back(std::move(command));
  if (ends) EndHolding();
}

void LiveEngine::EndHolding(bool drop_frames) {
  if (!make_engine_) return;
  const EngineFactory make = std::move(make_engine_);
  make_engine_ = nullptr;
  if (drop_frames) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stats_.dropped_frames += static_cast<std::int64_t>(HeldFrames());
    }
    std::erase_if(held_, [](const auto& item) { return std::holds_alternative<HeldFrame>(item); });
  }
  std::vector<Pose2> odometry;
  for (const auto& item : held_)
    if (const auto* h = std::get_if<HeldFrame>(&item)) odometry.push_back(*h->frame.odom_T_robot);
  try {
    engine_ = make(odometry);
    if (!engine_) throw Error("the engine factory returned no engine");
  } catch (const std::exception& e) {
    engine_.reset();
    if (callbacks_.on_error) callbacks_.on_error(StrCat("new map: ", e.what()));
  }
  std::vector<std::variant<HeldFrame, Command>> held = std::move(held_);
  held_.clear();
  for (auto& item : held) {
    if (auto* h = std::get_if<HeldFrame>(&item)) {
      Process(std::move(h->frame), h->odometry_held);
    } else {
      std::get<Command>(item).run();
    }
  }
}

void LiveEngine::BeginSessionNow(SessionInfo info, const cv::Mat& image) {
  if (info.camera.image_width == 0 && info.camera.image_height == 0) {
    info.camera.image_width = image.cols;
    info.camera.image_height = image.rows;
  }
  engine_->BeginSession(info);
  in_session_ = true;
  index_in_session_ = 0;
  std::lock_guard<std::mutex> lock(mutex_);
  ++stats_.sessions;
}

void LiveEngine::Process(QueuedFrame queued, bool odometry_held) {
  const auto t_start = std::chrono::steady_clock::now();
  try {
    if (!engine_) throw Error("no engine (its factory failed)");
    if (queued.decode) queued.image = queued.decode();
    // Sessions: an explicit one, the first, or one begun by a gap in the stamps.
    if (pending_session_) {
      SessionInfo info = std::move(*pending_session_);
      pending_session_.reset();
      BeginSessionNow(std::move(info), queued.image);
    } else if (!in_session_) {
      BeginSessionNow(first_session_, queued.image);
    } else if (StampsBeginSession(last_stamp_s_, queued.stamp_s)) {
      BeginSessionNow(later_sessions_, queued.image);
    }
    Frame frame;
    frame.session_index = engine_->session_state().session;
    frame.index_in_session = index_in_session_;
    frame.global_index = engine_->next_frame();
    frame.stamp_s = queued.stamp_s;
    frame.image = std::move(queued.image);
    frame.odom_T_robot = *queued.odom_T_robot;
    const FrameResult result = engine_->ProcessFrame(frame);
    ++index_in_session_;
    last_stamp_s_ = queued.stamp_s;

    LiveOutput out;
    out.stamp_s = queued.stamp_s;
    out.frame = result.frame;
    out.session = result.session;
    out.estimate = result.estimate;
    out.odom_T_robot = frame.odom_T_robot;
    out.odometry_held = odometry_held;
    if (result.estimate) {
      out.hypotheses = engine_->tracker().state();
      // map_T_odom = map_T_robot * (odom_T_robot)^-1.
      out.map_T_odom =
          Compose(result.estimate->strongest.mean, Between(frame.odom_T_robot, Pose2::Zero()));
    }
    out.queue_wait_us =
        std::chrono::duration<double, std::micro>(t_start - queued.received).count();
    out.engine_us = result.stats.total_us;
    std::int64_t processed;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      processed = ++stats_.processed_frames;
      out.dropped_frames = stats_.dropped_frames;
    }
    if (callbacks_.on_output) callbacks_.on_output(out);
    if (options_.reference_views_every_frames > 0 &&
        processed % options_.reference_views_every_frames == 0)
      EmitViews();
  } catch (const std::exception& e) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ++stats_.failed_frames;
    }
    if (callbacks_.on_error)
      callbacks_.on_error(StrCat("frame at stamp ", queued.stamp_s, " s: ", e.what()));
  }
}

void LiveEngine::EmitViews() {
  if (!callbacks_.on_views) return;
  std::vector<LiveViewComponent> components;
  for (const ReferenceView& view : engine_->model().views())
    for (const ViewComponent& c : view.components)
      components.push_back({view.id, c.mean, c.weight});
  callbacks_.on_views(components);
}

}  // namespace omnicml
