#include "omnicml/run/run_report.h"

#include <cmath>
#include <cstdio>

#include "omnicml/common/common.h"
#include "omnicml/report/map_export.h"
#include "omnicml/report/report.h"
#include "omnicml/report/svg_plot.h"
#include "omnicml/run/floor_plan.h"
#include "omnicml/run/run_config.h"

namespace omnicml {
namespace {

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

}  // namespace

const std::vector<std::string>& StageNames() {
  static const std::vector<std::string> kNames = {"unwrap", "describe", "update",      "apply",
                                                  "match",  "fuse",     "reconstruct", "total"};
  return kNames;
}

std::vector<double> StageTimes(const FrameStats& s) {
  return {s.unwrap_us, s.describe_us, s.update_us,      s.apply_us,
          s.match_us,  s.fuse_us,     s.reconstruct_us, s.total_us};
}

std::string FormatFixed(double v, int decimals) {
  if (!std::isfinite(v)) return "-";
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

std::map<int, SessionEventCounts> EventCountsBySession(const EnvironmentModel& model) {
  std::map<int, SessionEventCounts> out;
  for (const auto& [session, n] : model.event_counts()) {  // exact, not limited by the ring
    SessionEventCounts& s = out[session];
    s.views_inserted = static_cast<int>(n.views_inserted);
    s.views_removed = static_cast<int>(n.views_removed);
    s.components_removed = static_cast<int>(n.components_removed);
  }
  return out;
}

std::string RunConfigYaml(const std::string& input_description, const CmlEngineOptions& options) {
  return "# omnicml effective configuration (load with --config)\n# input: " + input_description +
         "\n" + EngineOptionsToYaml(options);
}

std::string CoverageText(const DayEvaluation& day) {
  return std::to_string(day.frames_with_estimate) + " of " + std::to_string(day.frames) + " (" +
         FormatFixed(day.coverage * 100, 1) + " %)";
}

void WriteRunDaysCsv(std::ostream& out, const std::vector<FrameRecord>& records,
                     const EnvironmentModel& model,
                     const std::map<int, std::int64_t>& skipped_frames) {
  const auto events = EventCountsBySession(model);
  WriteDaysCsv(
      out, records, StageNames(), {"views_inserted", "views_removed", "components_removed"},
      [&](int session) {
        const auto it = events.find(session);
        const SessionEventCounts ev = it == events.end() ? SessionEventCounts{} : it->second;
        return std::vector<std::string>{std::to_string(ev.views_inserted),
                                        std::to_string(ev.views_removed),
                                        std::to_string(ev.components_removed)};
      },
      skipped_frames);
}

void WriteEventsCsvHeader(std::ostream& out) {
  out << "type,frame,session,view_id,component_id,x_m,y_m,phi_rad,weight,reason\n";
}

void WriteEventsCsvRow(std::ostream& out, const MapEvent& e) {
  out << ToString(e.type) << ',' << e.frame << ',' << e.session << ',' << e.view_id << ','
      << e.component_id << ',' << ShortestDouble(e.position.x()) << ','
      << ShortestDouble(e.position.y()) << ',' << ShortestDouble(e.position.z()) << ','
      << ShortestDouble(e.weight) << ',' << CsvText(e.reason) << '\n';
}

void WriteEventsCsv(std::ostream& out, const EnvironmentModel& model) {
  WriteEventsCsvHeader(out);
  for (const MapEvent& e : model.events()) WriteEventsCsvRow(out, e);
}

std::string RenderRunReport(const std::string& title, const std::string& input,
                            const std::vector<FrameRecord>& records, const CmlEngine& engine,
                            const std::vector<std::pair<std::string, std::string>>& notes,
                            const std::map<int, std::int64_t>& skipped_frames) {
  HtmlReport report(title);
  FramesTable table;
  table.stage_names = StageNames();
  table.records = records;
  table.skipped_frames = skipped_frames;
  const EvaluationResult eval = Evaluate(table, Alignment::kNone);
  const EnvironmentModel& model = engine.model();
  std::vector<std::pair<std::string, std::string>> summary = {
      {"input", input},
      {"frames", std::to_string(records.size())},
      {"localized frames (coverage)", CoverageText(eval.overall)},
      {"unreadable frames skipped", std::to_string(eval.overall.frames_skipped)},
      {"sessions (days)", std::to_string(eval.days.size())},
      {"descriptor", ToString(engine.options().descriptor.kind)},
      {"forgetting", ToString(model.options().forgetting.mode)},
      {"reference views at the end", std::to_string(model.NumViews())},
      {"map components at the end", std::to_string(model.NumComponents())},
      {"map memory", FormatFixed(model.MemoryBytes() / 1024.0, 1) + " KiB"},
      {"unimodal frames", FormatFixed(eval.overall.unimodal_fraction * 100, 1) + " %"},
      {"position error mean / p95 / max (localized frames)",
       FormatFixed(eval.overall.position_m.mean, 3) + " / " +
           FormatFixed(eval.overall.position_m.p95, 3) + " / " +
           FormatFixed(eval.overall.position_m.max, 3) + " m"},
      {"odometry-only error mean", FormatFixed(eval.overall.odometry_m.mean, 3) + " m"},
      {"position NEES median / p95 / in 95 % band (consistent: 1.39 / 5.99 / 95 %)",
       FormatFixed(eval.overall.nees_xy.median, 2) + " / " +
           FormatFixed(eval.overall.nees_xy.p95, 2) + " / " +
           FormatFixed(eval.overall.nees_xy_in_band * 100, 1) + " % over " +
           std::to_string(eval.overall.nees_xy.count) + " frames"},
      {"heading NEES median / p95 / in 95 % band (consistent: 0.45 / 3.84 / 95 %)",
       FormatFixed(eval.overall.nees_phi.median, 2) + " / " +
           FormatFixed(eval.overall.nees_phi.p95, 2) + " / " +
           FormatFixed(eval.overall.nees_phi_in_band * 100, 1) + " %"},
      {"mean time per frame", FormatFixed(eval.overall.mean_frame_time_us / 1000.0, 2) + " ms"},
  };
  for (const auto& n : notes) summary.push_back(n);
  report.AddHeading("Summary");
  report.AddKeyValues(summary);

  report.AddHeading("Per day");
  report.AddParagraph(
      "Errors are over the localized frames (the engine produced a pose); coverage % = "
      "localized / frames. Skipped = unreadable input frames left out "
      "(--skip-unreadable-frames), not counted in frames.");
  const auto events = EventCountsBySession(model);
  std::vector<std::vector<std::string>> rows;
  for (const DayEvaluation& d : eval.days) {
    const auto it = events.find(d.session);
    const SessionEventCounts ev = it == events.end() ? SessionEventCounts{} : it->second;
    rows.push_back({std::to_string(d.session + 1), std::to_string(d.frames),
                    std::to_string(d.frames_with_estimate), FormatFixed(d.coverage * 100, 1),
                    std::to_string(d.frames_skipped), FormatFixed(d.unimodal_fraction * 100, 1),
                    FormatFixed(d.position_m.mean, 3), FormatFixed(d.position_m.median, 3),
                    FormatFixed(d.position_m.p95, 3), FormatFixed(d.position_m.max, 3),
                    FormatFixed(d.heading_rad.mean * 180 / kPi, 2),
                    FormatFixed(d.odometry_m.mean, 3), std::to_string(d.views_at_end),
                    std::to_string(ev.views_inserted), std::to_string(ev.views_removed),
                    std::to_string(ev.components_removed)});
  }
  report.AddTable({"day", "frames", "localized", "coverage %", "skipped", "unimodal %", "mean m",
                   "median m", "p95 m", "max m", "heading mean deg", "odometry mean m",
                   "views at end", "views inserted", "views removed", "components removed"},
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
  AddDayMarkers(&err_plot, records);
  report.AddSvg(err_plot.Render());
  SvgPlot map_plot("Map growth", "frame", "count", 960, 260);
  map_plot.AddLine("reference views", x, views);
  map_plot.AddLine("components", x, comps);
  AddDayMarkers(&map_plot, records);
  report.AddSvg(map_plot.Render());
  report.AddSvg(RenderPositionHistogramSvg(eval));

  if (eval.overall.nees_xy.count > 0) {
    report.AddHeading("Consistency (NEES, NIS)");
    report.AddParagraph(
        "NEES = e^T C^-1 e of the strongest component against ground truth (position 2 dof, "
        "heading 1 dof); NIS = innovation of the appearance fix against the prior (3 dof); "
        "prior / fix = the NEES of the odometry prior and of the map's observation alone. "
        "A consistent estimator has medians 1.39 (position), 0.45 (heading), 2.37 (NIS) "
        "and 95 % of its frames inside the two-sided 95 % band; lower values mean the "
        "reported covariance is wider than the errors.");
    std::vector<std::vector<std::string>> consistency;
    for (const DayEvaluation& d : eval.days) consistency.push_back(ConsistencyPerDayRow(d));
    consistency.push_back(ConsistencyPerDayRow(eval.overall));
    report.AddTable(ConsistencyPerDayHeader(), consistency);
    report.AddSvg(RenderNeesOverTimeSvg(records));
  }

  report.AddHeading("Time per stage (mean over frames)");
  std::vector<std::vector<std::string>> stage_rows;
  for (std::size_t s = 0; s < StageNames().size(); ++s) {
    std::vector<double> v;
    for (const FrameRecord& r : records) {
      if (s < r.stage_times_us.size()) v.push_back(r.stage_times_us[s]);
    }
    const ErrorStats st = ComputeStats(v);
    stage_rows.push_back({StageNames()[s], FormatFixed(st.mean, 1), FormatFixed(st.median, 1),
                          FormatFixed(st.p95, 1), FormatFixed(st.max, 1)});
  }
  report.AddTable({"stage", "mean us", "median us", "p95 us", "max us"}, stage_rows);

  report.AddHeading("Map over the estimated trajectory");
  MapPictureOptions pic;
  pic.width_px = 900;
  pic.floor_plan = FloorPlanForRunInput(input);
  for (const FrameRecord& r : records) {
    if (r.has_truth) pic.ground_truth.push_back(r.truth);
  }
  report.AddSvg(MapToSvg(model, trajectory, pic));

  report.AddHeading("Effective configuration");
  report.AddPreformatted(EngineOptionsToYaml(engine.options()));
  return report.Render();
}

}  // namespace omnicml
