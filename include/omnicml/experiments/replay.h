// The interactive replay of a run or a compare: one self-contained HTML page
// (replay.html; no server, no external scripts, fonts or style sheets; all data inline)
// with a time slider over the frames. Above, one map panel per run (passive, active and
// static side by side for a compare): the floor plan when the input was a simulated
// world, ground truth and the estimate up to the slider's frame, the estimate's 2-sigma
// position covariance ellipse, and the reference views from the event log appearing
// (view_inserted), weakened (component_removed: drawn paler for every component lost,
// ringed for a moment when it happens) and disappearing (view_removed: a cross for a
// moment, red when active forgetting removed it, purple otherwise). Below, map size and position
// error over the run with day boundaries, linked to the slider (click or drag on the plots to move
// it).
//
// Limits (a long run stays fast and the page small): at most max_samples frames per run
// are kept (evenly spaced, every day's first frame and the last frame always kept), and
// at most max_weakening_events component removals (evenly thinned beyond); every view
// insertion and removal is kept. A 30-day run of 45 000 frames gives a page of a few MB
// that redraws in milliseconds (docs/results.md).
//
// "replay.html#at=0.6" opens the page 60 % of the way through the run.
// The page exposes `window.replayState` after every redraw: {index, frame, session,
// redraws, runs: [{name, views, weakened, removed_recent, removed_total, estimate}]}
// (views = reference views alive at the frame by the event log), for tests and scripts.
// Every user-controlled text (titles, run names, the input) travels as JSON with <, >
// and & escaped and is put into the page with textContent.
//
// Pure functions except the file readers and WriteReplay; thread-safe.
#ifndef OMNICML_EXPERIMENTS_REPLAY_H_
#define OMNICML_EXPERIMENTS_REPLAY_H_

#include <filesystem>
#include <string>
#include <vector>

#include "omnicml/evaluation/evaluation.h"
#include "omnicml/mapping/environment_model.h"
#include "omnicml/report/map_export.h"

namespace omnicml {

// One run of the replay: its frames (frames.csv) and map events (events.csv).
struct ReplayRun {
  std::string name;  // e.g. the forgetting mode
  std::vector<FrameRecord> records;
  std::vector<MapEvent> events;
};

struct ReplayOptions {
  std::string title = "omnicml replay";
  std::string input;                 // input description shown under the title
  FloorPlan floor_plan;              // drawn under the maps when not empty
  int max_samples = 3000;            // frames kept per run (the slider's positions), >= 2
  int max_weakening_events = 50000;  // component removals kept per run, >= 0
  // Throws omnicml::Error naming the field when out of range.
  void Validate() const;
};

// Reads an events.csv (run_report.h WriteEventsCsv format). A missing file gives no
// events; a malformed row throws omnicml::Error "<file>:<line>: ...".
std::vector<MapEvent> ReadEventsCsv(const std::filesystem::path& path);

// The page of the file comment.
std::string RenderReplayHtml(const std::vector<ReplayRun>& runs, const ReplayOptions& options);

// Reads a run directory (frames.csv, events.csv, config.yaml) or a compare directory
// (its passive/, active/, static/ run directories) and writes DIR/replay.html
// atomically; options.title, input and floor_plan are filled from the files when empty
// (floor plan: the simulated world named in config.yaml). Returns the page's path.
// Throws omnicml::Error when DIR holds neither.
std::filesystem::path WriteReplay(const std::filesystem::path& dir, ReplayOptions options = {});

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_REPLAY_H_
