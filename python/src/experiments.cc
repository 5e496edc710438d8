// Bindings of the run layer and the experiments, both in memory: run (`omnicml run`:
// CML over logs or a simulated world, the map carried from day to day) through the
// in-memory run API (run/cml_run.h: options as a value, records and engine returned in
// memory, a run directory only with out_dir) and compare (`omnicml compare`: the [G]
// Table 1 experiment, passive / active / static forgetting on the same input) through
// RunCompare (experiments/compare_experiment.h: the same, its directory only with
// out_dir), so Python gets exactly the commands' results without temporary files; their
// tables come back as numpy arrays. evaluate: the statistics of a run directory.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <pybind11/stl.h>

#include "convert.h"
#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/experiments/change_detection.h"
#include "omnicml/experiments/compare_experiment.h"
#include "omnicml/experiments/run_experiment.h"
#include "omnicml/run/cml_run.h"
#include "omnicml/run/run_config.h"

namespace omnicml::python {

CmlEngineOptions OptionsFromObject(const py::object& obj);  // engine.cc

namespace {

// What Python gets of one run.
struct RunResult {
  std::string label;
  std::string run_dir;  // "" when no run directory was kept
  py::dict frames;
  py::list days;
  py::dict overall;
  double wall_s = 0;
  std::int64_t num_frames = 0;
  int num_sessions = 0;
  std::int64_t views = 0;  // map at the end, after Finish
  std::int64_t components = 0;
  py::object engine = py::none();
};

struct CompareResult {
  py::dict table;
  std::string table_text;
  std::vector<std::int64_t> steps;
  py::dict runs;
  std::string out_dir;
};

py::dict StatsDict(const ErrorStats& s) {
  py::dict d;
  d["count"] = s.count;
  d["mean"] = s.mean;
  d["median"] = s.median;
  d["p95"] = s.p95;
  d["max"] = s.max;
  return d;
}

py::dict DayDict(const DayEvaluation& e) {
  py::dict d;
  d["session"] = e.session;
  d["frames"] = e.frames;
  d["frames_with_truth"] = e.frames_with_truth;
  d["frames_with_estimate"] = e.frames_with_estimate;
  d["unimodal_fraction"] = e.unimodal_fraction;
  d["position_m"] = StatsDict(e.position_m);
  d["heading_rad"] = StatsDict(e.heading_rad);
  d["odometry_m"] = StatsDict(e.odometry_m);
  d["views_at_end"] = e.views_at_end;
  d["map_components_at_end"] = e.map_components_at_end;
  d["mean_frame_time_us"] = e.mean_frame_time_us;
  d["nees_xy"] = StatsDict(e.nees_xy);
  d["nees_phi"] = StatsDict(e.nees_phi);
  d["nis"] = StatsDict(e.nis);
  d["nees_xy_in_band"] = e.nees_xy_in_band;
  d["nees_phi_in_band"] = e.nees_phi_in_band;
  d["nis_in_band"] = e.nis_in_band;
  return d;
}

template <typename T, typename F>
py::array_t<T> Column(const std::vector<FrameRecord>& r, F get) {
  py::array_t<T> out(static_cast<py::ssize_t>(r.size()));
  for (std::size_t i = 0; i < r.size(); ++i) out.mutable_at(i) = static_cast<T>(get(r[i]));
  return out;
}

template <typename F>
py::array_t<double> PoseColumn(const std::vector<FrameRecord>& r, F get) {
  py::array_t<double> out({static_cast<py::ssize_t>(r.size()), py::ssize_t{3}});
  for (std::size_t i = 0; i < r.size(); ++i) {
    const Pose2 p = get(r[i]);
    for (int k = 0; k < 3; ++k) out.mutable_at(i, k) = p[k];
  }
  return out;
}

py::dict FramesDict(const std::vector<FrameRecord>& r) {
  py::dict d;
  d["session"] = Column<std::int32_t>(r, [](const FrameRecord& x) { return x.session; });
  d["frame"] = Column<std::int64_t>(r, [](const FrameRecord& x) { return x.frame; });
  d["global_frame"] = Column<std::int64_t>(r, [](const FrameRecord& x) { return x.global_frame; });
  d["stamp_s"] = Column<double>(r, [](const FrameRecord& x) { return x.stamp_s; });
  d["has_estimate"] = Column<bool>(r, [](const FrameRecord& x) { return x.has_estimate; });
  d["estimate"] = PoseColumn(r, [](const FrameRecord& x) { return x.estimate; });
  d["mean_estimate"] = PoseColumn(r, [](const FrameRecord& x) { return x.mean_estimate; });
  d["unimodal"] = Column<bool>(r, [](const FrameRecord& x) { return x.unimodal; });
  d["has_truth"] = Column<bool>(r, [](const FrameRecord& x) { return x.has_truth; });
  d["truth"] = PoseColumn(r, [](const FrameRecord& x) { return x.truth; });
  d["position_error_m"] =
      Column<double>(r, [](const FrameRecord& x) { return x.position_error_m; });
  d["heading_error_rad"] =
      Column<double>(r, [](const FrameRecord& x) { return x.heading_error_rad; });
  d["odometry_error_m"] =
      Column<double>(r, [](const FrameRecord& x) { return x.odometry_error_m; });
  d["views"] = Column<std::int32_t>(r, [](const FrameRecord& x) { return x.views; });
  d["map_components"] =
      Column<std::int32_t>(r, [](const FrameRecord& x) { return x.map_components; });
  d["hypotheses"] = Column<std::int32_t>(r, [](const FrameRecord& x) { return x.hypotheses; });
  d["mixture_components"] =
      Column<std::int32_t>(r, [](const FrameRecord& x) { return x.mixture_components; });
  d["cov_xx_m2"] = Column<double>(r, [](const FrameRecord& x) { return x.cov_xx_m2; });
  d["cov_xy_m2"] = Column<double>(r, [](const FrameRecord& x) { return x.cov_xy_m2; });
  d["cov_yy_m2"] = Column<double>(r, [](const FrameRecord& x) { return x.cov_yy_m2; });
  d["var_phi_rad2"] = Column<double>(r, [](const FrameRecord& x) { return x.var_phi_rad2; });
  d["nees_xy"] = Column<double>(r, [](const FrameRecord& x) { return x.nees_xy; });
  d["nees_phi"] = Column<double>(r, [](const FrameRecord& x) { return x.nees_phi; });
  d["nis"] = Column<double>(r, [](const FrameRecord& x) { return x.nis; });
  d["prior_nees_xy"] = Column<double>(r, [](const FrameRecord& x) { return x.prior_nees_xy; });
  d["fix_nees_xy"] = Column<double>(r, [](const FrameRecord& x) { return x.fix_nees_xy; });
  d["matches"] = Column<std::int32_t>(r, [](const FrameRecord& x) { return x.matches; });
  d["best_similarity"] = Column<double>(r, [](const FrameRecord& x) { return x.best_similarity; });
  return d;
}

void FillEvaluation(const EvaluationResult& e, RunResult* r) {
  for (const DayEvaluation& d : e.days) r->days.append(DayDict(d));
  r->overall = DayDict(e.overall);
}

// The input of a run from the Python arguments.
RunInput MakeInput(const py::object& logs, const std::string& world, int days, int first_day,
                   int frames_per_day, std::uint64_t seed) {
  RunInput in;
  if (!logs.is_none()) {
    if (py::isinstance<py::str>(logs) || py::hasattr(logs, "__fspath__")) {
      in.log_dirs.push_back(py::str(logs));
    } else {
      for (const auto& d : logs) in.log_dirs.push_back(py::str(d));
    }
  }
  in.world = world;
  in.days = days;
  in.first_day = first_day;
  in.frames_per_day = frames_per_day;
  in.seed = seed;
  return in;
}

// Engine options (a value under the threads and forgetting overrides). Without options,
// threads default as for the command (WithDefaultThreads); with options, their threads.
OptionOverrides MakeOverrides(const std::optional<CmlEngineOptions>& base,
                              std::optional<int> threads, std::optional<std::string> forgetting) {
  OptionOverrides o;
  o.threads = threads;
  o.forgetting = std::move(forgetting);
  if (base) {
    if (!o.threads) o.threads = base->threads;
    return o;
  }
  return WithDefaultThreads(o);
}

}  // namespace

void BindExperiments(py::module_& m) {
  py::class_<RunResult>(
      m, "RunResult",
      "A finished run: frames (dict of per-frame numpy arrays, the columns of frames.csv: session, "
      "frame, global_frame, stamp_s, has_estimate, estimate (N, 3), mean_estimate, unimodal, "
      "has_truth, truth (N, 3), position_error_m, heading_error_rad, odometry_error_m, views, "
      "map_components, hypotheses, mixture_components, cov_xx_m2, cov_xy_m2, cov_yy_m2, "
      "var_phi_rad2, nees_xy, nees_phi, nis, prior_nees_xy, fix_nees_xy (NaN where unknown), "
      "matches (-1 unknown), best_similarity (NaN "
      "unknown)), days (per-day statistics dicts), "
      "overall (the same over all days), the map size after finish, wall time, run_dir (\"\" "
      "when none was kept) and, for run(), the engine as saved at the end (before finish(): "
      "resumable, as `omnicml run --map-out`); None for compare().")
      .def_readonly("label", &RunResult::label)
      .def_readonly("run_dir", &RunResult::run_dir)
      .def_readonly("frames", &RunResult::frames)
      .def_readonly("days", &RunResult::days)
      .def_readonly("overall", &RunResult::overall)
      .def_readonly("wall_s", &RunResult::wall_s)
      .def_readonly("num_frames", &RunResult::num_frames)
      .def_readonly("num_sessions", &RunResult::num_sessions)
      .def_readonly("views", &RunResult::views, "Views in the map at the end (after finish).")
      .def_readonly("components", &RunResult::components)
      .def_readonly("engine", &RunResult::engine)
      .def_property_readonly(
          "mean_error_m", [](const RunResult& r) { return r.overall["position_m"]["mean"]; },
          "Mean position error over all frames with truth (m).")
      .def("__repr__", [](const RunResult& r) {
        return StrCat("<omnicml.RunResult ", r.label, " frames=", r.num_frames,
                      " sessions=", r.num_sessions, " views=", r.views, ">");
      });

  py::class_<CompareResult>(
      m, "CompareResult",
      "The [G] Table 1 experiment: table (dict of columns: forgetting, views_at (modes x "
      "steps; -1 beyond the run), views_end, mean_err_m, max_err_m, head_mean_deg, "
      "unimodal_pct, odom_err_m), the same as text (table.txt), runs (mode -> RunResult) and "
      "out_dir (\"\" when none was written).")
      .def_readonly("table", &CompareResult::table)
      .def_readonly("table_text", &CompareResult::table_text)
      .def_readonly("steps", &CompareResult::steps)
      .def_readonly("runs", &CompareResult::runs)
      .def_readonly("out_dir", &CompareResult::out_dir)
      .def("__repr__", [](const CompareResult& r) { return r.table_text; });

  m.def(
      "run",
      [](const py::object& logs, const std::string& world, int days, int first_day,
         int frames_per_day, std::uint64_t seed, const py::object& options,
         std::optional<int> threads, std::optional<std::string> forgetting,
         const std::string& out_dir, const std::string& map_in, const std::string& map_out,
         const std::string& trajectory_out, bool quiet) {
        if (!map_in.empty() && !options.is_none()) {
          throw Error(StrCat("run: map_in '", map_in,
                             "': the saved engine's options are used; only threads and "
                             "forgetting may change (drop options)"));
        }
        const RunInput input = MakeInput(logs, world, days, first_day, frames_per_day, seed);
        std::optional<CmlEngineOptions> base;
        if (!options.is_none()) base = OptionsFromObject(options);
        // Resuming a saved engine changes only what is asked (MakeRunEngine).
        OptionOverrides overrides;
        if (map_in.empty()) {
          overrides = MakeOverrides(base, threads, forgetting);
        } else {
          overrides.threads = threads;
          overrides.forgetting = forgetting;
        }
        CmlRunSettings s;
        s.outputs.run_dir = out_dir;
        s.outputs.map_path = map_out;
        s.outputs.trajectory_path = trajectory_out;
        s.outputs.input_description = input.Describe() + (map_in.empty() ? "" : ", map " + map_in);
        s.progress.quiet = quiet;
        s.progress.label = "run";
        s.keep_resumable_engine = true;
        // A run directory of simulated input has the command's change detection files.
        std::optional<ChangeDetectionObserver> changes;
        if (!input.world.empty() && !out_dir.empty()) {
          changes.emplace(input.world, input.first_day, input.seed);
          s.observers.push_back(&*changes);
        }
        CmlRunResult r;
        {
          py::gil_scoped_release release;
          input.Validate();
          // A new map's options: spatial thresholds and motion noise derived from the input
          // first when the options ask, as `omnicml run` does (ResolveNewMapOptions).
          std::string note;
          std::unique_ptr<CmlEngine> engine =
              MakeRunEngine(overrides, map_in, input, &note, base.value_or(CmlEngineOptions{}));
          if (!note.empty()) s.outputs.input_description += "; " + note;
          r = RunCml(std::move(engine), input, s);
        }
        RunResult out;
        out.label = "run";
        out.run_dir = out_dir;
        out.frames = FramesDict(r.records);
        FillEvaluation(r.evaluation, &out);
        out.wall_s = r.summary.wall_s;
        out.num_frames = r.summary.frames;
        out.num_sessions = r.summary.sessions;
        out.views = static_cast<std::int64_t>(r.engine->model().NumViews());
        out.components = static_cast<std::int64_t>(r.engine->model().NumComponents());
        out.engine = py::cast(std::move(r.resumable_engine));
        return out;
      },
      py::arg("logs") = py::none(), py::arg("world") = "", py::arg("days") = 1,
      py::arg("first_day") = 0, py::arg("frames_per_day") = 0, py::arg("seed") = 1,
      py::arg("options") = py::none(), py::arg("threads") = py::none(),
      py::arg("forgetting") = py::none(), py::arg("out_dir") = "", py::arg("map_in") = "",
      py::arg("map_out") = "", py::arg("trajectory_out") = "", py::arg("quiet") = true,
      "CML over the days in order, the map carried from day to day: `omnicml run` "
      "(the in-memory run API). Input: logs (a path or list) or world (built-in name or YAML) with "
      "days, first_day, frames_per_day (0 = 300) and seed. options: None, a dict, a YAML path "
      "or EngineOptions; threads, forgetting ('active', 'passive', 'static'): overrides, the "
      "only ones allowed with map_in (resume a saved engine). out_dir: keep the run "
      "directory (config, frames.csv, days.csv, events.csv, report.html) there; map_out, "
      "trajectory_out (TUM) as the command's flags. Returns a RunResult.");

  m.def(
      "compare",
      [](const py::object& logs, const std::string& world, int days, int first_day,
         int frames_per_day, std::uint64_t seed, const py::object& options,
         std::optional<int> threads, const std::vector<std::int64_t>& steps,
         const std::string& out_dir, int jobs, bool quiet) {
        const RunInput input = MakeInput(logs, world, days, first_day, frames_per_day, seed);
        std::optional<CmlEngineOptions> base;
        if (!options.is_none()) base = OptionsFromObject(options);
        CompareSettings s;
        s.steps = steps;
        s.jobs = jobs;
        s.progress.quiet = quiet;
        s.outputs.out_dir = out_dir;
        CompareExperimentResult r;
        {
          py::gil_scoped_release release;
          // The command's engine options: the value under the threads override (modes
          // set forgetting).
          r = RunCompare(ResolveNewMapOptions(MakeOverrides(base, threads, std::nullopt), input,
                                              &s.input_note, base.value_or(CmlEngineOptions{})),
                         input, s);
        }
        CompareResult result;
        result.steps = steps;
        result.table_text = r.table_text;
        result.out_dir = r.out_dir;
        const auto n = static_cast<py::ssize_t>(r.modes.size());
        py::list names;
        py::array_t<std::int64_t> views_at({n, static_cast<py::ssize_t>(steps.size())});
        std::vector<std::int64_t> views_end;
        std::vector<double> mean_err, max_err, head_deg, unimodal_pct, odom_err;
        for (py::ssize_t i = 0; i < n; ++i) {
          const CompareModeResult& mr = r.modes[static_cast<std::size_t>(i)];
          names.append(mr.mode);
          for (std::size_t k = 0; k < steps.size(); ++k) {
            views_at.mutable_at(i, static_cast<py::ssize_t>(k)) = mr.views_at_steps[k];
          }
          const DayEvaluation& ov = mr.evaluation.overall;
          views_end.push_back(mr.final_views);
          mean_err.push_back(ov.position_m.mean);
          max_err.push_back(ov.position_m.max);
          head_deg.push_back(ov.heading_rad.mean * 180 / kPi);
          unimodal_pct.push_back(ov.unimodal_fraction * 100);
          odom_err.push_back(ov.odometry_m.mean);
          RunResult run;
          run.label = mr.mode;
          run.run_dir =
              r.out_dir.empty() ? "" : (std::filesystem::path(r.out_dir) / mr.mode).string();
          run.frames = FramesDict(mr.records);
          FillEvaluation(mr.evaluation, &run);
          run.wall_s = mr.wall_s;
          run.num_frames = static_cast<std::int64_t>(mr.records.size());
          run.num_sessions = static_cast<int>(mr.evaluation.days.size());
          run.views = mr.final_views;
          run.components = mr.final_components;
          result.runs[py::str(mr.mode)] = run;
        }
        result.table["forgetting"] = names;
        result.table["views_at"] = views_at;
        result.table["views_end"] = py::array(py::cast(views_end));
        result.table["mean_err_m"] = py::array(py::cast(mean_err));
        result.table["max_err_m"] = py::array(py::cast(max_err));
        result.table["head_mean_deg"] = py::array(py::cast(head_deg));
        result.table["unimodal_pct"] = py::array(py::cast(unimodal_pct));
        result.table["odom_err_m"] = py::array(py::cast(odom_err));
        return result;
      },
      py::arg("logs") = py::none(), py::arg("world") = "", py::arg("days") = 1,
      py::arg("first_day") = 0, py::arg("frames_per_day") = 0, py::arg("seed") = 1,
      py::arg("options") = py::none(), py::arg("threads") = py::none(),
      py::arg("steps") = std::vector<std::int64_t>{2000, 4000, 6000, 8000}, py::arg("out_dir") = "",
      py::arg("jobs") = 1, py::arg("quiet") = true,
      "The [G] Table 1 experiment: `omnicml compare` (RunCompare, in memory). The same input "
      "under passive, active and static forgetting (static learns day 1 actively, then is "
      "frozen); reference views at `steps` (frames) and errors. jobs: modes in parallel "
      "threads (0 = one per core; same results). out_dir: keep each mode's run directory, "
      "table.txt and report.html there. Returns a CompareResult.");

  m.def(
      "evaluate",
      [](const std::string& run_dir, const std::string& align) {
        FramesTable table = ReadFramesCsv(std::filesystem::path(run_dir) / "frames.csv");
        const EvaluationResult e = Evaluate(table, AlignmentFromString(align));
        py::dict d;
        py::list days;
        for (const auto& x : e.days) days.append(DayDict(x));
        d["days"] = days;
        d["overall"] = DayDict(e.overall);
        d["alignment"] = ToString(e.alignment);
        d["alignment_transform"] = ArrayFromPose(e.alignment_transform);
        d["frames"] = FramesDict(table.records);
        return d;
      },
      py::arg("run_dir"), py::arg("align") = "none",
      "Per-day error statistics of a run directory (`omnicml evaluate`); align: 'none', "
      "'start' or 'se2'. Returns a dict with days, overall, alignment, frames.");
}

}  // namespace omnicml::python
