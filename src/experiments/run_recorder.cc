#include "omnicml/experiments/run_recorder.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <sstream>
#include <system_error>

#include <yaml-cpp/yaml.h>

#include "omnicml/common/common.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/experiments/run_report.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/report/map_export.h"

namespace omnicml {
namespace fs = std::filesystem;

const std::vector<std::string>& StageNames() {
  static const std::vector<std::string> kNames = {"unwrap", "describe", "update",      "apply",
                                                  "match",  "fuse",     "reconstruct", "total"};
  return kNames;
}

std::vector<double> StageTimes(const FrameStats& s) {
  return {s.unwrap_us, s.describe_us, s.update_us,      s.apply_us,
          s.match_us,  s.fuse_us,     s.reconstruct_us, s.total_us};
}

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

const std::vector<std::string>& RunDirectoryMarkers() {
  static const std::vector<std::string> kMarkers = {"frames.csv", "outputs.yaml", "config.yaml",
                                                    "report.html", "table.txt"};
  return kMarkers;
}

namespace {

// Where output `path` lies relative to `run_dir`: 0 outside, 1 directly in it, 2 deeper.
int PlacementIn(const fs::path& path, const fs::path& run_dir) {
  std::error_code ec;
  const fs::path parent = fs::weakly_canonical(fs::absolute(path).parent_path(), ec);
  const fs::path run = fs::weakly_canonical(fs::absolute(run_dir), ec);
  const fs::path rel = parent.lexically_relative(run);
  if (rel.empty() || *rel.begin() == "..") return 0;
  return rel == "." ? 1 : 2;
}

}  // namespace

bool LiesInRunDirectory(const fs::path& path, const fs::path& run_dir) {
  return !path.empty() && !run_dir.empty() && PlacementIn(path, run_dir) == 1;
}

void CheckRunOutputPlacement(const std::string& flag, const fs::path& path,
                             const fs::path& run_dir) {
  if (path.empty() || run_dir.empty()) return;
  if (PlacementIn(path, run_dir) == 2) {
    throw Error(StrCat(flag, " '", path.string(), "': lies in a subdirectory of the run directory '",
                       run_dir.string(), "', which a run replaces whole; write it directly in "
                       "the run directory or outside it"));
  }
}

RunRecorder::RunRecorder(RunRecorderOptions options) : options_(std::move(options)) {
  if (!options_.run_dir.empty()) {
    if (options_.stage) {
      staged_ = std::make_unique<StagedDirectory>(options_.run_dir, "--out", RunDirectoryMarkers());
      write_dir_ = staged_->path();
    } else {
      std::error_code ec;
      fs::create_directories(options_.run_dir, ec);
      if (ec) {
        throw Error(StrCat("cannot create run directory '", options_.run_dir.string(),
                           "': ", ec.message()));
      }
      write_dir_ = options_.run_dir;
    }
    // The files of the run directory are made durable at once when it is committed.
    frames_csv_ = std::make_unique<AtomicFile>(write_dir_ / "frames.csv", FileSync::kDeferred);
    WriteFramesCsvHeader(frames_csv_->stream(), StageNames());
    events_csv_ = std::make_unique<AtomicFile>(write_dir_ / "events.csv", FileSync::kDeferred);
    WriteEventsCsvHeader(events_csv_->stream());
  }
  if (!options_.trajectory_path.empty()) {
    trajectory_write_path_ = WritePathFor("--trajectory-out", options_.trajectory_path);
    trajectory_ = std::make_unique<AtomicFile>(
        trajectory_write_path_, trajectory_write_path_ == options_.trajectory_path
                                    ? FileSync::kFsync
                                    : FileSync::kDeferred);
    trajectory_->stream() << "# omnicml trajectory (TUM): stamp x y z qx qy qz qw\n";
  }
}

RunRecorder::~RunRecorder() {
  if (committed_) return;
  frames_csv_.reset();  // removes the temporaries
  trajectory_.reset();
  events_csv_.reset();
  staged_.reset();  // removes the staging directory
}

fs::path RunRecorder::WritePathFor(const std::string& flag, const fs::path& path) {
  CheckRunOutputPlacement(flag, path, options_.run_dir);
  if (staged_ && PlacementIn(path, options_.run_dir) == 1) return write_dir_ / path.filename();
  locks_.push_back(std::make_unique<OutputLock>(path, flag));
  return path;
}

void RunRecorder::AddOutput(const std::string& flag, const fs::path& path,
                            std::vector<std::uint8_t> bytes) {
  Output o;
  o.flag = flag;
  o.path = path;
  o.write_path = WritePathFor(flag, path);
  o.bytes = std::move(bytes);
  outputs_.push_back(std::move(o));
}

void RunRecorder::Record(const Frame& frame, const FrameResult& result) {
  FrameRecord r;
  r.session = result.session;
  r.frame = frame.index_in_session;
  r.global_frame = result.frame;
  r.stamp_s = frame.stamp_s;
  r.run_stamp_s = clock_.Next(result.session, frame.stamp_s);
  r.has_odometry = true;
  r.odometry = frame.odom_T_robot;
  if (result.estimate) {
    r.has_estimate = true;
    r.estimate = result.estimate->strongest.mean;
    r.mean_estimate = result.estimate->mean.mean;
    r.unimodal = result.estimate->unimodal;
    const Eigen::Matrix3d& c = result.estimate->strongest.covariance;
    r.cov_xx_m2 = c(0, 0);
    r.cov_xy_m2 = c(0, 1);
    r.cov_yy_m2 = c(1, 1);
    r.var_phi_rad2 = c(2, 2);
  }
  if (frame.map_T_robot_truth) {
    r.has_truth = true;
    r.truth = *frame.map_T_robot_truth;
    // Dead reckoning anchored at the session's first ground-truth pose.
    if (anchor_session_ != result.session || !have_anchor_) {
      anchor_session_ = result.session;
      have_anchor_ = true;
      anchor_truth_ = r.truth;
      anchor_odom_ = frame.odom_T_robot;
    }
    const Pose2 dead_reckoning = Compose(anchor_truth_, Between(anchor_odom_, frame.odom_T_robot));
    r.odometry_error_m = (dead_reckoning.head<2>() - r.truth.head<2>()).norm();
  } else if (anchor_session_ != result.session) {
    have_anchor_ = false;
  }
  ComputeErrors(&r);
  const FrameStats& s = result.stats;
  r.nis = s.nis;
  if (r.has_truth) {
    // Stage diagnostics: the prior and the appearance fix against truth (map frame).
    const auto stage_nees = [&r](const std::optional<Gaussian>& g) {
      if (!g) return kNaN;
      const Eigen::Matrix3d& c = g->covariance;
      return PositionNees(g->mean.x() - r.truth.x(), g->mean.y() - r.truth.y(), c(0, 0), c(0, 1),
                          c(1, 1));
    };
    r.prior_nees_xy = stage_nees(result.prior);
    r.fix_nees_xy = stage_nees(result.appearance_fix);
  }
  r.views = static_cast<int>(s.num_views);
  r.map_components = static_cast<int>(s.num_map_components);
  r.hypotheses = s.hypothesis_components;
  r.mixture_components = s.mixture_components;
  r.matches = s.num_matches;
  r.best_similarity = s.best_similarity;
  r.stage_times_us = StageTimes(s);
  if (frames_csv_) WriteFramesCsvRow(frames_csv_->stream(), r);
  if (trajectory_ && r.has_estimate)
    trajectory_->stream() << TumLine(r.run_stamp_s, r.estimate) << "\n";
  records_.push_back(std::move(r));
}

void RunRecorder::RecordSkippedFrames(int session, std::int64_t count) {
  if (count > 0) skipped_frames_[session] += count;
}

void RunRecorder::RecordEvents(const EnvironmentModel& model) {
  const std::uint64_t first = model.first_event_number();
  // First call, or another model (fewer events than already written): start at its oldest.
  if (!next_event_ || *next_event_ > model.events_logged()) next_event_ = first;
  if (*next_event_ < first) {
    events_lost_ += first - *next_event_;
    next_event_ = first;
  }
  const std::deque<MapEvent>& events = model.events();
  if (events_csv_) {
    for (std::size_t i = static_cast<std::size_t>(*next_event_ - first); i < events.size(); ++i) {
      WriteEventsCsvRow(events_csv_->stream(), events[i]);
    }
  }
  next_event_ = model.events_logged();
}

void RunRecorder::Commit(const CmlEngine& engine,
                         const std::vector<std::pair<std::string, std::string>>& notes) {
  if (committed_) return;
  RecordEvents(engine.model());  // what Finish added
  std::vector<std::pair<std::string, std::string>> all_notes = notes;
  if (events_lost_ > 0) {
    all_notes.emplace_back("map events missing from events.csv",
                           StrCat(events_lost_, " (more than model.events.max_events in one frame)"));
  }
  std::vector<std::unique_ptr<AtomicFile>> files;    // in write_dir_
  std::vector<std::unique_ptr<AtomicFile>> outside;  // beside their own targets
  const auto in_run_dir = [&](const std::string& name) {
    return std::make_unique<AtomicFile>(write_dir_ / name, FileSync::kDeferred);
  };
  if (!write_dir_.empty()) {
    auto config = in_run_dir("config.yaml");
    config->stream() << RunConfigYaml(options_.input_description, engine.options());
    files.push_back(std::move(config));

    auto days = in_run_dir("days.csv");
    WriteRunDaysCsv(days->stream(), records_, engine.model(), skipped_frames_);
    files.push_back(std::move(days));

    // evo-ready TUM files on shared run-unique stamps (see the header).
    for (const auto& [name, content] :
         {std::pair{"trajectory.tum", TumContent::kEstimate},
          std::pair{"groundtruth.tum", TumContent::kGroundTruth},
          std::pair{"odometry.tum", TumContent::kOdometry}}) {
      if (content != TumContent::kEstimate && !HasTumContent(records_, content)) {
        std::error_code ec;
        fs::remove(write_dir_ / name, ec);
        continue;
      }
      auto tum = in_run_dir(name);
      WriteTum(tum->stream(), records_, content);
      files.push_back(std::move(tum));
    }

    for (const auto& [name, content] : extra_files_) {
      auto extra = in_run_dir(name);
      extra->stream() << content;
      files.push_back(std::move(extra));
    }

    if (options_.write_report) {
      auto html = in_run_dir("report.html");
      html->stream() << RenderRunReport(options_.title, options_.input_description, records_,
                                        engine, all_notes, skipped_frames_);
      files.push_back(std::move(html));
    }
  }
  // Further outputs, and outputs.yaml recording each with its SHA-256.
  YAML::Emitter manifest;
  manifest << YAML::BeginSeq;
  const auto record = [&](const std::string& flag, const fs::path& path, std::uintmax_t bytes,
                          const std::string& sha256, bool staged) {
    manifest << YAML::BeginMap << YAML::Key << "flag" << YAML::Value << flag << YAML::Key
             << "path" << YAML::Value << YAML::DoubleQuoted << path.string() << YAML::Key
             << "in_run_directory" << YAML::Value << staged << YAML::Key << "bytes"
             << YAML::Value << bytes << YAML::Key << "sha256" << YAML::Value << sha256
             << YAML::EndMap;
  };
  for (const Output& o : outputs_) {
    const bool staged = o.write_path != o.path;
    auto file = std::make_unique<AtomicFile>(o.write_path,
                                             staged ? FileSync::kDeferred : FileSync::kFsync);
    file->stream().write(reinterpret_cast<const char*>(o.bytes.data()),
                         static_cast<std::streamsize>(o.bytes.size()));
    record(o.flag, o.path, o.bytes.size(), Sha256Hex(o.bytes), staged);
    (staged ? files : outside).push_back(std::move(file));
  }
  if (trajectory_) {
    trajectory_->stream().flush();
    if (!trajectory_->stream()) {
      throw Error(StrCat(options_.trajectory_path.string(),
                         ": write error: the data could not be written (disk full?)"));
    }
    std::error_code ec;
    const std::uintmax_t size = fs::file_size(trajectory_->temp_path(), ec);
    record("--trajectory-out", options_.trajectory_path, ec ? 0 : size,
           Sha256OfFile(trajectory_->temp_path()),
           trajectory_write_path_ != options_.trajectory_path);
  }
  manifest << YAML::EndSeq;
  if (!write_dir_.empty() && (!outputs_.empty() || trajectory_)) {
    auto file = in_run_dir("outputs.yaml");
    file->stream() << "# Files this run wrote besides its own (path as given; check one with "
                      "`sha256sum PATH`)\n"
                   << manifest.c_str() << "\n";
    files.push_back(std::move(file));
  }
  // Everything is written. Rename into place: the run directory's files (inside the
  // staging directory, not yet visible), then the files outside it together with the
  // run directory as one unit (StagedDirectory::Commit with companions: a kill leaves
  // the old state or the new one, settled by the next writer).
  if (frames_csv_) frames_csv_->Commit();
  if (events_csv_) events_csv_->Commit();
  for (auto& f : files) f->Commit();
  if (trajectory_ && trajectory_write_path_ == options_.trajectory_path) {
    outside.push_back(std::move(trajectory_));
  } else if (trajectory_) {
    trajectory_->Commit();
  }
  std::vector<AtomicFile*> companions;
  for (auto& f : outside) companions.push_back(f.get());
  if (staged_) {
    staged_->Commit(companions);
  } else {
    for (AtomicFile* f : companions) f->Commit();
  }
  committed_ = true;
}

bool StderrIsTerminal() { return ::isatty(STDERR_FILENO) == 1; }

RunSummary RunEngineOverSource(CmlEngine& engine, FrameSource& source, RunRecorder* recorder,
                               const ProgressOptions& progress,
                               const SessionEndHook& on_session_end,
                               const FrameProcessor& process) {
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
      line << prefix << "day " << current_session + 1 << " done: " << session_frames
           << " frames (" << session_localized << " localized, "
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
      line << "\n";
      std::cerr << line.str();
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
  }
  if (reader != nullptr) {
    for (int s = std::max(current_session + 1, 0); s < reader->NumSessions(); ++s)
      count_skipped(s, nullptr);
  }
  summary.wall_s = elapsed();
  return summary;
}

}  // namespace omnicml
