#include "omnicml/run/run_recorder.h"

#include <utility>

#include "omnicml/common/common.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/report/map_export.h"
#include "omnicml/run/run_report.h"

namespace omnicml {
namespace fs = std::filesystem;

RunRecorder::RunRecorder(RunRecorderOptions options)
    : options_(std::move(options)), directory_(options_.run_dir, options_.stage) {
  if (!options_.run_dir.empty()) {
    frames_csv_ = &directory_.OpenFile("frames.csv");
    WriteFramesCsvHeader(frames_csv_->stream(), StageNames());
    events_csv_ = &directory_.OpenFile("events.csv");
    WriteEventsCsvHeader(events_csv_->stream());
  }
  if (!options_.trajectory_path.empty()) {
    trajectory_ = &directory_.OpenOutput("--trajectory-out", options_.trajectory_path);
    trajectory_->stream() << "# omnicml trajectory (TUM): stamp x y z qx qy qz qw\n";
  }
}

RunRecorder::~RunRecorder() = default;

void RunRecorder::AddOutput(const std::string& flag, const fs::path& path,
                            std::vector<std::uint8_t> bytes) {
  directory_.AddOutput(flag, path, std::move(bytes));
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
  for (std::size_t i = static_cast<std::size_t>(*next_event_ - first); i < events.size(); ++i) {
    if (events_csv_) WriteEventsCsvRow(events_csv_->stream(), events[i]);
    if (options_.keep_events) events_.push_back(events[i]);
  }
  next_event_ = model.events_logged();
}

void RunRecorder::Commit(const CmlEngine& engine,
                         const std::vector<std::pair<std::string, std::string>>& notes) {
  if (committed_) return;
  RecordEvents(engine.model());  // what Finish added
  std::vector<std::pair<std::string, std::string>> all_notes = notes;
  if (events_lost_ > 0) {
    all_notes.emplace_back(
        "map events missing from events.csv",
        StrCat(events_lost_, " (more than model.events.max_events in one frame)"));
  }
  if (!directory_.write_dir().empty()) {
    directory_.OpenFile("config.yaml").stream()
        << RunConfigYaml(options_.input_description, engine.options());
    WriteRunDaysCsv(directory_.OpenFile("days.csv").stream(), records_, engine.model(),
                    skipped_frames_);
    // evo-ready TUM files on shared run-unique stamps (see the header).
    for (const auto& [name, content] : {std::pair{"trajectory.tum", TumContent::kEstimate},
                                        std::pair{"groundtruth.tum", TumContent::kGroundTruth},
                                        std::pair{"odometry.tum", TumContent::kOdometry}}) {
      if (content != TumContent::kEstimate && !HasTumContent(records_, content)) {
        directory_.RemoveFile(name);
        continue;
      }
      WriteTum(directory_.OpenFile(name).stream(), records_, content);
    }
    for (const auto& [name, content] : extra_files_) directory_.OpenFile(name).stream() << content;
    if (options_.write_report) {
      directory_.OpenFile("report.html").stream() << RenderRunReport(
          options_.title, options_.input_description, records_, engine, all_notes, skipped_frames_);
    }
  }
  // The outputs, outputs.yaml and the renames into place (run_directory.h).
  directory_.Commit();
  committed_ = true;
}

}  // namespace omnicml
