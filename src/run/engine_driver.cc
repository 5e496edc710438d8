#include "omnicml/run/engine_driver.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <sstream>

#include "omnicml/logs/log_format.h"
#include "omnicml/run/run_report.h"

namespace omnicml {
namespace {

std::string FormatDuration(double seconds) {
  if (!std::isfinite(seconds) || seconds < 0) return "--:--";
  const long s = std::lround(seconds);
  char buf[32];
  if (s >= 3600) {
    std::snprintf(buf, sizeof buf, "%ld:%02ld:%02ld", s / 3600, (s / 60) % 60, s % 60);
  } else {
    std::snprintf(buf, sizeof buf, "%ld:%02ld", s / 60, s % 60);
  }
  return buf;
}

}  // namespace

bool StderrIsTerminal() { return ::isatty(STDERR_FILENO) == 1; }

RunSummary RunEngineOverSource(CmlEngine& engine, FrameSource& source, RunRecorder* recorder,
                               const ProgressOptions& progress,
                               const SessionEndHook& on_session_end, const FrameProcessor& process,
                               const std::vector<RunObserver*>& observers) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  auto last_draw = start;
  RunSummary summary;
  int current_session = -1;
  double error_sum = 0;
  std::int64_t error_count = 0, session_frames = 0, session_localized = 0;
  // Skipped unreadable frames (logs only), per source session.
  const LogReader* reader = dynamic_cast<const LogReader*>(&source);
  std::int64_t session_skipped = 0;
  auto count_skipped = [&](int source_session, const FrameResult* last) {
    if (reader == nullptr || source_session < 0) return std::int64_t{0};
    const std::int64_t n = reader->NumSkippedFrames(source_session);
    summary.frames_skipped += n;
    if (recorder != nullptr && last != nullptr) recorder->RecordSkippedFrames(last->session, n);
    return n;
  };
  // "97.3 % localized" (of the frames so far); next to every mean error.
  auto localized_text = [&] {
    return FormatFixed(summary.frames > 0 ? 100.0 * static_cast<double>(summary.frames_localized) /
                                                static_cast<double>(summary.frames)
                                          : 0.0,
                       1) +
           " % localized";
  };
  if (recorder != nullptr && progress.total_frames && *progress.total_frames > 0) {
    recorder->Reserve(static_cast<std::size_t>(*progress.total_frames));
  }
  const std::string prefix = progress.label.empty() ? "" : progress.label + ": ";
  auto elapsed = [&] { return std::chrono::duration<double>(Clock::now() - start).count(); };
  auto status = [&](const FrameResult& r) {
    const double t = elapsed();
    const double fps = t > 0 ? static_cast<double>(summary.frames) / t : 0.0;
    std::ostringstream os;
    os << summary.frames;
    if (progress.total_frames) os << "/" << *progress.total_frames;
    os << " frames, day " << current_session + 1 << ", " << FormatFixed(fps, 1) << " frames/s, "
       << r.stats.num_views << " views, " << localized_text();
    if (error_count > 0)
      os << ", mean error " << FormatFixed(error_sum / static_cast<double>(error_count), 2)
         << " m (localized frames)";
    if (progress.total_frames && fps > 0) {
      os << ", ETA "
         << FormatDuration(static_cast<double>(*progress.total_frames - summary.frames) / fps);
    }
    return os.str();
  };
  auto end_session = [&](const FrameResult* last) {
    if (!progress.quiet && last != nullptr) {
      // One write per line, so runs in parallel threads (compare) never split a line.
      std::ostringstream line;
      if (progress.progress_bar) line << "\r\033[K";
      line << prefix << "day " << current_session + 1 << " done: " << session_frames << " frames ("
           << session_localized << " localized, "
           << FormatFixed(session_frames > 0 ? 100.0 * static_cast<double>(session_localized) /
                                                   static_cast<double>(session_frames)
                                             : 0.0,
                          1)
           << " %";
      if (session_skipped > 0) line << "; " << session_skipped << " unreadable skipped";
      line << "), " << last->stats.num_views << " views, " << engine.model().NumComponents()
           << " components";
      if (error_count > 0)
        line << ", mean error so far "
             << FormatFixed(error_sum / static_cast<double>(error_count), 3)
             << " m over localized frames (" << localized_text() << ")";
      if (engine.model().ViewPersistenceOn()) {
        // View persistence's fit so far (docs/forgetting.md "View persistence").
        const ViewPersistence& p = engine.model().view_persistence();
        if (p.passes_at_fit() == 0) {
          line << "; view persistence: no fit yet (" << p.passes() << " passes)";
        } else {
          line << "; view persistence: h " << FormatFixed(p.hazard(), 3) << " per pass, P_M "
               << FormatFixed(p.miss_probability(), 3) << " from " << p.passes_at_fit()
               << " passes";
        }
      }
      line << "\n";
      std::cerr << line.str();
    }
  };
  static const std::vector<FrameRecord> kNoRecords;
  auto notify_observers = [&] {
    for (RunObserver* o : observers) {
      o->OnSessionEnd(engine, current_session,
                      recorder != nullptr ? recorder->records() : kNoRecords);
    }
  };
  Frame frame;
  FrameResult last;
  bool have_last = false;
  while (source.Next(&frame)) {
    if (frame.session_index != current_session) {
      // Sessions the reader passed without delivering a frame (every frame skipped).
      for (int s = current_session + 1; s < frame.session_index; ++s) count_skipped(s, nullptr);
      if (current_session >= 0) {
        session_skipped = count_skipped(current_session, have_last ? &last : nullptr);
        end_session(have_last ? &last : nullptr);
        notify_observers();
        if (on_session_end) on_session_end(engine, current_session);
      }
      current_session = frame.session_index;
      session_frames = 0;
      session_localized = 0;
      session_skipped = 0;
      engine.BeginSession(source.Session(current_session));
      ++summary.sessions;
    }
    last = process ? process(engine, frame) : engine.ProcessFrame(frame);
    have_last = true;
    ++summary.frames;
    ++session_frames;
    if (last.estimate) {
      ++summary.frames_localized;
      ++session_localized;
    }
    if (recorder != nullptr) {
      recorder->Record(frame, last);
      recorder->RecordEvents(engine.model());
    }
    if (last.estimate && frame.map_T_robot_truth) {
      error_sum +=
          (last.estimate->strongest.mean.head<2>() - frame.map_T_robot_truth->head<2>()).norm();
      ++error_count;
    }
    if (progress.quiet) continue;
    if (progress.progress_bar) {
      const auto now = Clock::now();
      if (now - last_draw > std::chrono::milliseconds(200)) {
        last_draw = now;
        std::string bar;
        if (progress.total_frames && *progress.total_frames > 0) {
          const double f = std::min(1.0, static_cast<double>(summary.frames) /
                                             static_cast<double>(*progress.total_frames));
          const int filled = static_cast<int>(f * 30);
          bar = "[" + std::string(filled, '#') + std::string(30 - filled, '.') + "] " +
                FormatFixed(f * 100, 0) + "% ";
        }
        std::cerr << "\r\033[K" << prefix << bar << status(last) << std::flush;
      }
    } else if (progress.log_every_frames > 0 && summary.frames % progress.log_every_frames == 0) {
      std::cerr << (prefix + status(last) + "\n");
    }
  }
  if (current_session >= 0) {
    session_skipped = count_skipped(current_session, have_last ? &last : nullptr);
    end_session(have_last ? &last : nullptr);
    notify_observers();
  }
  if (reader != nullptr) {
    for (int s = std::max(current_session + 1, 0); s < reader->NumSessions(); ++s)
      count_skipped(s, nullptr);
  }
  summary.wall_s = elapsed();
  return summary;
}

}  // namespace omnicml
