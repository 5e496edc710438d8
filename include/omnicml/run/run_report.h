// Reporting of a CML run: the files of a run directory that describe the engine's final
// state and the recorded frames (run_recorder.h writes frames.csv while the run goes on
// and calls these at Commit):
//   config.yaml  RunConfigYaml: the effective engine configuration (run_config.h format,
//                loadable with --config) preceded by comment lines naming the input
//   days.csv     WriteRunDaysCsv: one row per session (evaluation.h WriteDaysCsv) plus the
//                map events of the day (views inserted / removed, components removed)
//   events.csv   WriteEventsCsv: the map's event log (environment_model.h MapEvent)
//   report.html  RenderRunReport: summary, per-day table, plots of error and map growth,
//                stage timings, the map over the trajectory, the configuration
// Every function is a pure function of its arguments (same inputs, same bytes), so a run
// reproduced with other threads or in parallel with other runs writes the same files
// (report.html also shows the measured timings, which vary).
//
// Thread-safety: thread-safe (no shared state).
#ifndef OMNICML_RUN_RUN_REPORT_H_
#define OMNICML_RUN_RUN_REPORT_H_

#include <cstdint>
#include <map>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

#include "omnicml/engine/cml_engine.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/mapping/environment_model.h"

namespace omnicml {

// Names of the per-frame stage timings (FrameStats fields without "_us"), in the order
// of the time_<stage>_us columns of frames.csv.
const std::vector<std::string>& StageNames();
// The FrameStats timings in StageNames() order.
std::vector<double> StageTimes(const FrameStats& stats);

// Map events of one session (engine session index), from the model's exact per-session
// counts (EnvironmentModel::event_counts, not limited by the event ring).
struct SessionEventCounts {
  int views_inserted = 0;
  int views_removed = 0;
  int components_removed = 0;
};
// Sessions without any event are absent.
std::map<int, SessionEventCounts> EventCountsBySession(const EnvironmentModel& model);

// config.yaml: "# omnicml effective configuration (load with --config)", "# input: ..."
// and EngineOptionsToYaml(options).
std::string RunConfigYaml(const std::string& input_description, const CmlEngineOptions& options);

// days.csv of `records` (stage columns in StageNames() order) with the event columns
// views_inserted, views_removed, components_removed of `model`, and the coverage
// columns of WriteDaysCsv (frames_skipped from `skipped_frames`, by engine session).
void WriteRunDaysCsv(std::ostream& out, const std::vector<FrameRecord>& records,
                     const EnvironmentModel& model,
                     const std::map<int, std::int64_t>& skipped_frames = {});

// events.csv: header "type,frame,session,view_id,component_id,x_m,y_m,phi_rad,weight,reason"
// and one row per event, doubles in shortest round-trip form, reasons quoted when they
// hold a comma, quote or newline. WriteEventsCsv writes the events the model still holds
// (its ring, model.events.max_events); the run recorder streams every event with the header
// and row functions as the run goes.
void WriteEventsCsv(std::ostream& out, const EnvironmentModel& model);
void WriteEventsCsvHeader(std::ostream& out);
void WriteEventsCsvRow(std::ostream& out, const MapEvent& e);

// The self-contained HTML report of a run. `notes` are extra (key, value) lines of the
// summary (e.g. wall time, threads). Every error is shown next to the coverage
// (localized frames / frames) and the count of skipped unreadable frames.
std::string RenderRunReport(const std::string& title, const std::string& input_description,
                            const std::vector<FrameRecord>& records, const CmlEngine& engine,
                            const std::vector<std::pair<std::string, std::string>>& notes,
                            const std::map<int, std::int64_t>& skipped_frames = {});

// "297 of 300 (99.0 %)": localized frames of `day` and the coverage, for tables.
std::string CoverageText(const DayEvaluation& day);

// printf("%.*f") of v, "-" when v is not finite (tables of reports and printed results).
std::string FormatFixed(double v, int decimals);

}  // namespace omnicml

#endif  // OMNICML_RUN_RUN_REPORT_H_
