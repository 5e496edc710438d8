#include "omnicml/run/frame_sources.h"

#include <algorithm>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <filesystem>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/limits.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/sim/simulator.h"

namespace omnicml {

void RunInput::Validate() const {
  if (log_dirs.empty() && world.empty()) {
    throw Error("no input: give LOGDIR... or --world NAME");
  }
  if (!log_dirs.empty() && !world.empty()) {
    throw Error("give either LOGDIR... or --world NAME, not both");
  }
  for (const std::string& dir : log_dirs) {
    std::error_code ec;
    if (!std::filesystem::is_directory(dir, ec)) {
      throw Error(StrCat("log directory '", dir, "' ",
                         ec ? ec.message() : "does not exist or is not a directory"));
    }
  }
  CheckLimit("--days", days, 1, kMaxDays);
  CheckLimit("--first-day", first_day, 0, kMaxDays - days);
  CheckLimit("--frames-per-day", frames_per_day, 0, kMaxFramesPerDay);
  const std::int64_t fpd = frames_per_day > 0 ? frames_per_day : SimulatorOptions{}.frames_per_day;
  if (log_dirs.empty() &&
      (first_day + static_cast<std::int64_t>(days)) * fpd > kMaxSimulatedFrames) {
    throw Error(StrCat("--days x --frames-per-day = ", first_day + days, " x ", fpd,
                       " exceeds the limit of ", kMaxSimulatedFrames, " simulated frames"));
  }
  if (!log_dirs.empty() && (first_day != 0)) throw Error("--first-day applies to --world only");
}

std::string RunInput::Describe() const {
  if (!log_dirs.empty()) {
    std::string s = log_dirs.size() == 1 ? "log " : "logs ";
    for (std::size_t i = 0; i < log_dirs.size(); ++i) s += (i ? ", " : "") + log_dirs[i];
    return s;
  }
  const int fpd = frames_per_day > 0 ? frames_per_day : SimulatorOptions{}.frames_per_day;
  return StrCat("world ", world, ", days ", first_day + 1, "-", first_day + days, ", ", fpd,
                " frames/day, seed ", seed,
                sim_image == ImageKind::kPanorama ? ", panorama images" : "");
}

namespace {

// The sessions >= first_day of a simulator, renumbered from 0 (resuming a simulated
// multi-day run from a saved map). Skipped days are still simulated, so the later days
// are exactly those of one run over all days.
class SkipDaysSource : public FrameSource {
 public:
  SkipDaysSource(std::unique_ptr<FrameSource> inner, int first_day)
      : inner_(std::move(inner)), first_day_(first_day) {}
  int NumSessions() const override { return inner_->NumSessions() - first_day_; }
  const SessionInfo& Session(int index) const override {
    return inner_->Session(index + first_day_);
  }
  bool Next(Frame* frame) override {
    while (inner_->Next(frame)) {
      if (frame->session_index < first_day_) continue;
      frame->session_index -= first_day_;
      frame->global_index = delivered_++;
      return true;
    }
    return false;
  }

 private:
  std::unique_ptr<FrameSource> inner_;
  int first_day_;
  std::int64_t delivered_ = 0;
};

// PrefetchFrames: a producer thread runs inner->Next into a bounded queue.
class PrefetchingSource : public FrameSource {
 public:
  PrefetchingSource(std::unique_ptr<FrameSource> inner, int depth)
      : inner_(std::move(inner)), depth_(static_cast<std::size_t>(depth)) {
    thread_ = std::thread([this] { Produce(); });
  }
  ~PrefetchingSource() override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    space_.notify_all();
    thread_.join();
  }
  int NumSessions() const override { return inner_->NumSessions(); }
  const SessionInfo& Session(int index) const override { return inner_->Session(index); }
  bool Next(Frame* frame) override {
    std::unique_lock<std::mutex> lock(mutex_);
    ready_.wait(lock, [&] { return !queue_.empty() || done_; });
    if (queue_.empty()) {
      if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
      return false;
    }
    *frame = std::move(queue_.front());
    queue_.pop_front();
    lock.unlock();
    space_.notify_one();
    return true;
  }

 private:
  void Produce() {
    try {
      while (true) {
        {
          std::unique_lock<std::mutex> lock(mutex_);
          space_.wait(lock, [&] { return queue_.size() < depth_ || stop_; });
          if (stop_) break;
        }
        Frame frame;
        if (!inner_->Next(&frame)) break;
        {
          std::lock_guard<std::mutex> lock(mutex_);
          queue_.push_back(std::move(frame));
        }
        ready_.notify_one();
      }
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex_);
      error_ = std::current_exception();
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      done_ = true;
    }
    ready_.notify_all();
  }

  std::unique_ptr<FrameSource> inner_;
  const std::size_t depth_;
  std::mutex mutex_;
  std::condition_variable ready_;  // a frame was queued, or the producer is done
  std::condition_variable space_;  // a frame was taken, or stop_
  std::deque<Frame> queue_;
  bool done_ = false, stop_ = false;
  std::exception_ptr error_;
  std::thread thread_;  // last: started once every member above exists
};

}  // namespace

std::unique_ptr<FrameSource> PrefetchFrames(std::unique_ptr<FrameSource> inner, int depth) {
  OMNICML_CHECK(inner != nullptr && depth >= 1) << "PrefetchFrames: depth " << depth;
  return std::make_unique<PrefetchingSource>(std::move(inner), depth);
}

namespace {

std::unique_ptr<FrameSource> OpenSource(const RunInput& input, bool images) {
  input.Validate();
  if (!input.log_dirs.empty()) {
    LogReaderOptions options;
    options.skip_unreadable_frames = input.skip_unreadable_frames;
    options.load_images = images;
    return std::make_unique<LogReader>(input.log_dirs, options);
  }
  const std::vector<std::string> names = BuiltinWorldNames();
  const bool builtin = std::find(names.begin(), names.end(), input.world) != names.end();
  std::error_code ec;
  if (!builtin && !std::filesystem::is_regular_file(input.world, ec)) {
    std::string list;
    for (std::size_t i = 0; i < names.size(); ++i) list += (i ? ", " : "") + names[i];
    if (ec && ec != std::errc::no_such_file_or_directory) {
      throw Error(StrCat("--world '", input.world, "': ", ec.message()));
    }
    throw Error(
        StrCat("unknown world '", input.world, "' (built-in: ", list, "; or a world YAML file)"));
  }
  SimulatorOptions options;
  options.world = input.world;
  options.days = input.first_day + input.days;
  if (input.frames_per_day > 0) options.frames_per_day = input.frames_per_day;
  options.seed = input.seed;
  options.output = input.sim_image;
  options.render_images = images;
  std::unique_ptr<FrameSource> source = std::make_unique<SimulatedFrameSource>(options);
  if (input.first_day != 0)
    source = std::make_unique<SkipDaysSource>(std::move(source), input.first_day);
  if (images && input.prefetch_frames) source = PrefetchFrames(std::move(source));
  return source;
}

}  // namespace

std::unique_ptr<FrameSource> OpenFrameSource(const RunInput& input) {
  return OpenSource(input, /*images=*/true);
}

std::unique_ptr<FrameSource> OpenPoseOnlySource(const RunInput& input) {
  return OpenSource(input, /*images=*/false);
}

std::optional<std::int64_t> CountFrames(const RunInput& input, const FrameSource& source) {
  if (input.log_dirs.empty()) {
    const int fpd =
        input.frames_per_day > 0 ? input.frames_per_day : SimulatorOptions{}.frames_per_day;
    return static_cast<std::int64_t>(fpd) * input.days;
  }
  const auto* reader = dynamic_cast<const LogReader*>(&source);
  if (reader == nullptr) return std::nullopt;
  std::int64_t total = 0;
  for (int s = 0; s < reader->NumSessions(); ++s) {
    try {
      LineReader in(std::filesystem::path(reader->SessionDirectory(s)) / "frames.csv",
                    "log frames");
      std::string line;
      in.Next(&line);  // header
      while (in.Next(&line)) {
        if (!line.empty()) ++total;
      }
    } catch (const Error&) {
      return std::nullopt;  // the reader reports the problem when it gets there
    }
  }
  return total;
}

}  // namespace omnicml
