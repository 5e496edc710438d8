#include "omnicml/experiments/run_recorder.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <map>
#include <sstream>
#include <system_error>

#include "omnicml/common/binary_io.h"
#include "omnicml/common/common.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/report/map_export.h"
#include "omnicml/experiments/run_config.h"
#include "omnicml/report/svg_plot.h"

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

std::string Fixed(double v, int decimals) {
  if (!std::isfinite(v)) return "-";
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}


std::string CsvText(std::string s) {
  // Event reasons are plain text; keep the CSV simple by quoting when needed.
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string out = "\"";
  for (char c : s) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + "\"";
}

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

struct SessionEvents {
  int views_inserted = 0;
  int views_removed = 0;
  int components_removed = 0;
};

std::map<int, SessionEvents> EventsBySession(const EnvironmentModel& model) {
  std::map<int, SessionEvents> out;
  for (const MapEvent& e : model.events()) {
    SessionEvents& s = out[e.session];
    if (e.type == MapEventType::kViewInserted) ++s.views_inserted;
    if (e.type == MapEventType::kViewRemoved) ++s.views_removed;
    if (e.type == MapEventType::kComponentRemoved) ++s.components_removed;
  }
  return out;
}

std::string RenderRunReport(const std::string& title, const std::string& input,
                            const std::vector<FrameRecord>& records, const CmlEngine& engine,
                            const std::vector<std::pair<std::string, std::string>>& notes) {
  HtmlReport report(title);
  FramesTable table;
  table.stage_names = StageNames();
  table.records = records;
  const EvaluationResult eval = Evaluate(table, Alignment::kNone);
  const EnvironmentModel& model = engine.model();
  std::vector<std::pair<std::string, std::string>> summary = {
      {"input", input},
      {"frames", std::to_string(records.size())},
      {"sessions (days)", std::to_string(eval.days.size())},
      {"descriptor", ToString(engine.options().descriptor.kind)},
      {"forgetting", ToString(model.options().forgetting)},
      {"reference views at the end", std::to_string(model.NumViews())},
      {"map components at the end", std::to_string(model.NumComponents())},
      {"map memory", Fixed(model.MemoryBytes() / 1024.0, 1) + " KiB"},
      {"unimodal frames", Fixed(eval.overall.unimodal_fraction * 100, 1) + " %"},
      {"position error mean / p95 / max", Fixed(eval.overall.position_m.mean, 3) + " / " +
                                              Fixed(eval.overall.position_m.p95, 3) + " / " +
                                              Fixed(eval.overall.position_m.max, 3) + " m"},
      {"odometry-only error mean", Fixed(eval.overall.odometry_m.mean, 3) + " m"},
      {"mean time per frame", Fixed(eval.overall.mean_frame_time_us / 1000.0, 2) + " ms"},
  };
  for (const auto& n : notes) summary.push_back(n);
  report.AddHeading("Summary");
  report.AddKeyValues(summary);

  report.AddHeading("Per day");
  const auto events = EventsBySession(model);
  std::vector<std::vector<std::string>> rows;
  for (const DayEvaluation& d : eval.days) {
    const auto it = events.find(d.session);
    const SessionEvents ev = it == events.end() ? SessionEvents{} : it->second;
    rows.push_back({std::to_string(d.session + 1), std::to_string(d.frames),
                    Fixed(d.unimodal_fraction * 100, 1), Fixed(d.position_m.mean, 3),
                    Fixed(d.position_m.median, 3), Fixed(d.position_m.p95, 3),
                    Fixed(d.position_m.max, 3), Fixed(d.heading_rad.mean * 180 / kPi, 2),
                    Fixed(d.odometry_m.mean, 3), std::to_string(d.views_at_end),
                    std::to_string(ev.views_inserted), std::to_string(ev.views_removed),
                    std::to_string(ev.components_removed)});
  }
  report.AddTable(
      {"day", "frames", "unimodal %", "mean m", "median m", "p95 m", "max m", "heading mean deg",
       "odometry mean m", "views at end", "views inserted", "views removed", "components removed"},
      rows);

  std::vector<double> x, err, odo, views, comps;
  std::vector<Pose2> trajectory;
  for (const FrameRecord& r : records) {
    x.push_back(static_cast<double>(r.global_frame));
    err.push_back(r.position_error_m);
    odo.push_back(r.odometry_error_m);
    views.push_back(r.views);
    comps.push_back(r.map_components);
    if (r.has_estimate) trajectory.push_back(r.estimate);
  }
  report.AddHeading("Plots");
  SvgPlot err_plot("Position error", "frame", "error [m]", 960, 300);
  err_plot.AddLine("estimate (strongest)", x, err);
  err_plot.AddLine("odometry only", x, odo);
  report.AddSvg(err_plot.Render());
  SvgPlot map_plot("Map growth", "frame", "count", 960, 260);
  map_plot.AddLine("reference views", x, views);
  map_plot.AddLine("components", x, comps);
  report.AddSvg(map_plot.Render());
  report.AddSvg(RenderPositionHistogramSvg(eval));

  report.AddHeading("Time per stage (mean over frames)");
  std::vector<std::vector<std::string>> stage_rows;
  for (std::size_t s = 0; s < StageNames().size(); ++s) {
    std::vector<double> v;
    for (const FrameRecord& r : records) {
      if (s < r.stage_times_us.size()) v.push_back(r.stage_times_us[s]);
    }
    const ErrorStats st = ComputeStats(v);
    stage_rows.push_back({StageNames()[s], Fixed(st.mean, 1), Fixed(st.median, 1), Fixed(st.p95, 1),
                          Fixed(st.max, 1)});
  }
  report.AddTable({"stage", "mean us", "median us", "p95 us", "max us"}, stage_rows);

  report.AddHeading("Map over the estimated trajectory");
  MapPictureOptions pic;
  pic.width_px = 900;
  report.AddSvg(MapToSvg(model, trajectory, pic));

  report.AddHeading("Effective configuration");
  report.AddPreformatted(EngineOptionsToYaml(engine.options()));
  return report.Render();
}

}  // namespace

RunRecorder::RunRecorder(RunRecorderOptions options) : options_(std::move(options)) {
  if (!options_.run_dir.empty()) {
    std::error_code ec;
    if (!fs::exists(options_.run_dir)) {
      fs::create_directories(options_.run_dir, ec);
      if (ec)
        throw Error(StrCat("cannot create run directory '", options_.run_dir.string(),
                           "': ", ec.message()));
      created_dir_ = true;
    } else if (!fs::is_directory(options_.run_dir)) {
      throw Error(StrCat("--out '", options_.run_dir.string(), "' exists and is not a directory"));
    }
    frames_csv_ = std::make_unique<AtomicFile>(options_.run_dir / "frames.csv");
    WriteFramesCsvHeader(frames_csv_->stream(), StageNames());
  }
  if (!options_.trajectory_path.empty()) {
    trajectory_ = std::make_unique<AtomicFile>(options_.trajectory_path);
    trajectory_->stream() << "# omnicml trajectory (TUM): stamp x y z qx qy qz qw\n";
  }
}

RunRecorder::~RunRecorder() {
  if (committed_) return;
  frames_csv_.reset();  // removes the temporaries
  trajectory_.reset();
  if (created_dir_) {
    std::error_code ec;
    if (fs::is_empty(options_.run_dir, ec) && !ec) fs::remove(options_.run_dir, ec);
  }
}

void RunRecorder::Record(const Frame& frame, const FrameResult& result) {
  FrameRecord r;
  r.session = result.session;
  r.frame = frame.index_in_session;
  r.global_frame = result.frame;
  r.stamp_s = frame.stamp_s;
  if (result.estimate) {
    r.has_estimate = true;
    r.estimate = result.estimate->strongest.mean;
    r.mean_estimate = result.estimate->mean.mean;
    r.unimodal = result.estimate->unimodal;
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
  if (r.has_estimate && r.has_truth) {
    r.position_error_m = (r.estimate.head<2>() - r.truth.head<2>()).norm();
    r.heading_error_rad = std::abs(WrapAngle(r.estimate.z() - r.truth.z()));
  }
  const FrameStats& s = result.stats;
  r.views = static_cast<int>(s.num_views);
  r.map_components = static_cast<int>(s.num_map_components);
  r.hypotheses = s.hypothesis_components;
  r.mixture_components = s.mixture_components;
  r.stage_times_us = StageTimes(s);
  if (frames_csv_) WriteFramesCsvRow(frames_csv_->stream(), r);
  if (trajectory_ && r.has_estimate)
    trajectory_->stream() << TumLine(r.stamp_s, r.estimate) << "\n";
  records_.push_back(std::move(r));
}

void RunRecorder::Commit(const CmlEngine& engine,
                         const std::vector<std::pair<std::string, std::string>>& notes) {
  if (committed_) return;
  std::vector<std::unique_ptr<AtomicFile>> files;
  if (!options_.run_dir.empty()) {
    auto config = std::make_unique<AtomicFile>(options_.run_dir / "config.yaml");
    config->stream() << "# omnicml effective configuration (load with --config)\n# input: "
                     << options_.input_description << "\n"
                     << EngineOptionsToYaml(engine.options());
    files.push_back(std::move(config));

    auto days = std::make_unique<AtomicFile>(options_.run_dir / "days.csv");
    const auto events = EventsBySession(engine.model());
    WriteDaysCsv(days->stream(), records_, StageNames(),
                 {"views_inserted", "views_removed", "components_removed"}, [&](int session) {
                   const auto it = events.find(session);
                   const SessionEvents ev = it == events.end() ? SessionEvents{} : it->second;
                   return std::vector<std::string>{std::to_string(ev.views_inserted),
                                                   std::to_string(ev.views_removed),
                                                   std::to_string(ev.components_removed)};
                 });
    files.push_back(std::move(days));

    auto ev = std::make_unique<AtomicFile>(options_.run_dir / "events.csv");
    ev->stream() << "type,frame,session,view_id,component_id,x_m,y_m,phi_rad,weight,reason\n";
    for (const MapEvent& e : engine.model().events()) {
      ev->stream() << ToString(e.type) << ',' << e.frame << ',' << e.session << ',' << e.view_id
                   << ',' << e.component_id << ',' << ShortestDouble(e.position.x()) << ','
                   << ShortestDouble(e.position.y()) << ',' << ShortestDouble(e.position.z()) << ','
                   << ShortestDouble(e.weight) << ',' << CsvText(e.reason) << '\n';
    }
    files.push_back(std::move(ev));

    if (options_.write_report) {
      auto html = std::make_unique<AtomicFile>(options_.run_dir / "report.html");
      html->stream() << RenderRunReport(options_.title, options_.input_description, records_,
                                        engine, notes);
      files.push_back(std::move(html));
    }
  }
  // Everything is written; rename into place.
  if (frames_csv_) frames_csv_->Commit();
  if (trajectory_) trajectory_->Commit();
  for (auto& f : files) f->Commit();
  committed_ = true;
}

bool StderrIsTerminal() { return ::isatty(STDERR_FILENO) == 1; }

RunSummary RunEngineOverSource(std::unique_ptr<CmlEngine>& engine, FrameSource& source,
                               RunRecorder* recorder, const ProgressOptions& progress,
                               const SessionEndHook& on_session_end) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  auto last_draw = start;
  RunSummary summary;
  int current_session = -1;
  double error_sum = 0;
  std::int64_t error_count = 0, session_frames = 0;
  const std::string prefix = progress.label.empty() ? "" : progress.label + ": ";
  auto elapsed = [&] { return std::chrono::duration<double>(Clock::now() - start).count(); };
  auto status = [&](const FrameResult& r) {
    const double t = elapsed();
    const double fps = t > 0 ? static_cast<double>(summary.frames) / t : 0.0;
    std::ostringstream os;
    os << summary.frames;
    if (progress.total_frames) os << "/" << *progress.total_frames;
    os << " frames, day " << current_session + 1 << ", " << Fixed(fps, 1) << " frames/s, "
       << r.stats.num_views << " views";
    if (error_count > 0)
      os << ", mean error " << Fixed(error_sum / static_cast<double>(error_count), 2) << " m";
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
           << " frames, " << last->stats.num_views << " views, "
           << engine->model().NumComponents() << " components";
      if (error_count > 0)
        line << ", mean error so far " << Fixed(error_sum / static_cast<double>(error_count), 3)
             << " m";
      line << "\n";
      std::cerr << line.str();
    }
  };
  Frame frame;
  FrameResult last;
  bool have_last = false;
  while (source.Next(&frame)) {
    if (frame.session_index != current_session) {
      if (current_session >= 0) {
        end_session(have_last ? &last : nullptr);
        if (on_session_end) {
          if (auto replacement = on_session_end(*engine, current_session))
            engine = std::move(replacement);
        }
      }
      current_session = frame.session_index;
      session_frames = 0;
      engine->BeginSession(source.Session(current_session));
      ++summary.sessions;
    }
    last = engine->ProcessFrame(frame);
    have_last = true;
    ++summary.frames;
    ++session_frames;
    if (recorder != nullptr) recorder->Record(frame, last);
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
                Fixed(f * 100, 0) + "% ";
        }
        std::cerr << "\r\033[K" << prefix << bar << status(last) << std::flush;
      }
    } else if (progress.log_every_frames > 0 && summary.frames % progress.log_every_frames == 0) {
      std::cerr << (prefix + status(last) + "\n");
    }
  }
  if (current_session >= 0) end_session(have_last ? &last : nullptr);
  summary.wall_s = elapsed();
  return summary;
}

std::unique_ptr<CmlEngine> RebuildEngineWithOptions(const CmlEngine& engine,
                                                    const CmlEngineOptions& options) {
  CmlEngineOptions allowed = engine.options();
  allowed.threads = options.threads;
  allowed.model.forgetting = options.model.forgetting;
  if (!SameEngineOptions(allowed, options)) {
    throw Error(
        "a saved engine's options can only change in threads and model.forgetting (the rest is "
        "part of its "
        "state); drop --config, --e-max, --update-delay and --descriptor with --map-in");
  }
  options.Validate();
  // The engine file's payload starts with the options (engine_io.h); replace them and
  // re-checksum. EncodeEngine/DecodeEngine are bit-exact, so the state is unchanged.
  const std::vector<std::uint8_t> bytes = EncodeEngine(engine);
  constexpr std::size_t kHeader = 8 + 4 + 8, kTrailer = 4;
  BinaryWriter old_options, new_options;
  WriteEngineOptions(old_options, engine.options());
  WriteEngineOptions(new_options, options);
  const auto& old_bytes = old_options.bytes();
  OMNICML_CHECK(bytes.size() >= kHeader + old_bytes.size() + kTrailer &&
                std::equal(old_bytes.begin(), old_bytes.end(), bytes.begin() + kHeader))
      << "engine file layout: the payload does not start with the options";
  std::vector<std::uint8_t> payload(new_options.bytes());
  payload.insert(payload.end(),
                 bytes.begin() + static_cast<std::ptrdiff_t>(kHeader + old_bytes.size()),
                 bytes.end() - static_cast<std::ptrdiff_t>(kTrailer));
  BinaryWriter file;
  for (char ch : kEngineMagic) file.Write<std::uint8_t>(static_cast<std::uint8_t>(ch));
  file.Write<std::uint32_t>(kEngineFormatVersion);
  file.Write<std::uint64_t>(payload.size());
  file.WriteBytes(payload);
  file.Write<std::uint32_t>(Crc32(payload));
  return DecodeEngine(file.Release(), "rebuilt engine");
}

}  // namespace omnicml
