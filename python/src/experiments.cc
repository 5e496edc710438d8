// Bindings of the experiments: run (CML over logs or a simulated world, the map carried
// from day to day) and compare (the [G] Table 1 experiment: passive, active and static
// forgetting on the same input), returning their tables as numpy arrays; evaluate (the
// statistics of a run directory).
//
// `omnicml compare` lives in apps/cmd_compare.cc (not yet a library function), so compare
// here drives the library's engine loop (RunEngineOverSource) itself, exactly as the
// command does: static learns the first day with active forgetting and is frozen after it.
#include <algorithm>
#include <cmath>
#include <exception>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <pybind11/stl.h>

#include "convert.h"
#include "omnicml/common/common.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/experiments/run_config.h"
#include "omnicml/experiments/run_recorder.h"

namespace omnicml::python {

CmlEngineOptions OptionsFromObject(const py::object& obj);  // engine.cc

namespace {

// One finished run, in C++ (built without the GIL).
struct RunOutput {
  std::string label;
  std::vector<FrameRecord> records;
  EvaluationResult eval;
  RunSummary summary;
  std::unique_ptr<CmlEngine> engine;
};

// What Python gets.
struct RunResult {
  std::string label;
  py::dict frames;
  py::list days;
  py::dict overall;
  double wall_s = 0;
  std::int64_t num_frames = 0;
  int num_sessions = 0;
  py::object engine;
};

struct CompareResult {
  py::dict table;
  std::string table_text;
  std::vector<std::int64_t> steps;
  py::dict runs;
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
  d["position_error_m"] = Column<double>(r, [](const FrameRecord& x) { return x.position_error_m; });
  d["heading_error_rad"] = Column<double>(r, [](const FrameRecord& x) { return x.heading_error_rad; });
  d["odometry_error_m"] = Column<double>(r, [](const FrameRecord& x) { return x.odometry_error_m; });
  d["views"] = Column<std::int32_t>(r, [](const FrameRecord& x) { return x.views; });
  d["map_components"] = Column<std::int32_t>(r, [](const FrameRecord& x) { return x.map_components; });
  d["hypotheses"] = Column<std::int32_t>(r, [](const FrameRecord& x) { return x.hypotheses; });
  d["mixture_components"] =
      Column<std::int32_t>(r, [](const FrameRecord& x) { return x.mixture_components; });
  return d;
}

RunResult ToPython(RunOutput out) {
  RunResult r;
  r.label = out.label;
  r.frames = FramesDict(out.records);
  for (const DayEvaluation& d : out.eval.days) r.days.append(DayDict(d));
  r.overall = DayDict(out.eval.overall);
  r.wall_s = out.summary.wall_s;
  r.num_frames = out.summary.frames;
  r.num_sessions = out.summary.sessions;
  r.engine = py::cast(std::move(out.engine));
  return r;
}

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
  in.Validate();
  return in;
}

// The engine loop of `omnicml run` over `input` (no GIL needed). `engine` is consumed.
RunOutput RunOne(std::unique_ptr<CmlEngine> engine, const RunInput& input, const std::string& out_dir,
                 const std::string& trajectory_out, const std::string& map_out, bool quiet,
                 const std::string& label, const SessionEndHook& hook) {
  RunOutput out;
  out.label = label;
  auto source = OpenFrameSource(input);
  RunRecorderOptions ro;
  ro.run_dir = out_dir;
  ro.trajectory_path = trajectory_out;
  ro.title = label.empty() ? "omnicml run" : "omnicml run (" + label + ")";
  ro.input_description = input.Describe();
  RunRecorder recorder(ro);
  ProgressOptions progress;
  progress.quiet = quiet;
  progress.label = label.empty() ? "run" : label;
  progress.total_frames = CountFrames(input, *source);
  out.summary = RunEngineOverSource(engine, *source, &recorder, progress, hook);
  if (out.summary.frames == 0) throw Error(StrCat("the input (", input.Describe(), ") has no frames"));
  // As `omnicml run`: the saved engine is the state before Finish(), so a resumed run
  // continues exactly as one uninterrupted run.
  std::vector<std::uint8_t> map_bytes;
  if (!map_out.empty()) map_bytes = EncodeEngine(*engine);
  engine->Finish();
  recorder.Commit(*engine);
  if (!map_out.empty()) WriteFileAtomically(map_out, map_bytes);
  FramesTable table;
  table.stage_names = StageNames();
  table.records = recorder.records();
  out.eval = Evaluate(table, Alignment::kNone);
  out.records = recorder.records();
  out.engine = std::move(engine);
  return out;
}

}  // namespace

void BindExperiments(py::module_& m) {
  py::class_<RunResult>(
      m, "RunResult",
      "A finished run: frames (dict of per-frame numpy arrays: session, frame, global_frame, "
      "stamp_s, has_estimate, estimate (N, 3), mean_estimate, unimodal, has_truth, truth (N, 3), "
      "position_error_m, heading_error_rad, odometry_error_m, views, map_components, "
      "hypotheses, mixture_components), days (per-day statistics dicts), overall (the same "
      "over all days), the engine after finish(), wall time.")
      .def_readonly("label", &RunResult::label)
      .def_readonly("frames", &RunResult::frames)
      .def_readonly("days", &RunResult::days)
      .def_readonly("overall", &RunResult::overall)
      .def_readonly("wall_s", &RunResult::wall_s)
      .def_readonly("num_frames", &RunResult::num_frames)
      .def_readonly("num_sessions", &RunResult::num_sessions)
      .def_readonly("engine", &RunResult::engine)
      .def_property_readonly(
          "mean_error_m", [](const RunResult& r) { return r.overall["position_m"]["mean"]; },
          "Mean position error over all frames with truth (m).")
      .def("__repr__", [](const RunResult& r) {
        return StrCat("<omnicml.RunResult ", r.label, " frames=", r.num_frames,
                      " sessions=", r.num_sessions, ">");
      });

  py::class_<CompareResult>(
      m, "CompareResult",
      "The [G] Table 1 experiment: table (dict of columns: forgetting, views_at (modes x "
      "steps), views_end, mean_err_m, max_err_m, head_mean_deg, unimodal_pct, odom_err_m), "
      "the same as text, and runs (mode -> RunResult).")
      .def_readonly("table", &CompareResult::table)
      .def_readonly("table_text", &CompareResult::table_text)
      .def_readonly("steps", &CompareResult::steps)
      .def_readonly("runs", &CompareResult::runs)
      .def("__repr__", [](const CompareResult& r) { return r.table_text; });

  m.def("run",
        [](const py::object& logs, const std::string& world, int days, int first_day,
           int frames_per_day, std::uint64_t seed, const py::object& options,
           const std::string& out_dir, const std::string& map_in, const std::string& map_out,
           const std::string& trajectory_out, bool quiet) {
          const RunInput input = MakeInput(logs, world, days, first_day, frames_per_day, seed);
          std::unique_ptr<CmlEngine> engine;
          if (!map_in.empty()) {
            engine = LoadEngine(map_in);
            if (!options.is_none()) engine = RebuildEngineWithOptions(*engine, OptionsFromObject(options));
          } else {
            engine = std::make_unique<CmlEngine>(OptionsFromObject(options));
          }
          RunOutput out;
          {
            py::gil_scoped_release release;
            out = RunOne(std::move(engine), input, out_dir, trajectory_out, map_out, quiet, "", {});
          }
          return ToPython(std::move(out));
        },
        py::arg("logs") = py::none(), py::arg("world") = "", py::arg("days") = 1,
        py::arg("first_day") = 0, py::arg("frames_per_day") = 0, py::arg("seed") = 1,
        py::arg("options") = py::none(), py::arg("out_dir") = "", py::arg("map_in") = "",
        py::arg("map_out") = "", py::arg("trajectory_out") = "", py::arg("quiet") = true,
        "CML over the days in order, the map carried from day to day (`omnicml run`). Input: "
        "logs (a path or list) or world (built-in name) with days, frames_per_day (0 = 300), "
        "seed. options: None, dict, YAML path or EngineOptions (with map_in: only threads and "
        "model.forgetting may differ from the saved ones). out_dir: a run directory (config, "
        "frames.csv, days.csv, report) when given. Returns a RunResult.");

  m.def("compare",
        [](const py::object& logs, const std::string& world, int days, int first_day,
           int frames_per_day, std::uint64_t seed, const py::object& options,
           const std::vector<std::int64_t>& steps, const std::string& out_dir, int jobs,
           bool quiet) {
          const RunInput input = MakeInput(logs, world, days, first_day, frames_per_day, seed);
          if (steps.empty()) throw Error("steps: at least one step");
          for (std::int64_t s : steps) {
            if (s < 1) throw Error(StrCat("steps: ", s, " is not a positive integer"));
          }
          const CmlEngineOptions base = OptionsFromObject(options);
          const std::vector<ForgettingMode> modes = {ForgettingMode::kPassive, ForgettingMode::kActive,
                                                     ForgettingMode::kStatic};
          const int n_jobs = std::clamp(
              jobs > 0 ? jobs : static_cast<int>(std::thread::hardware_concurrency()), 1, 3);
          std::vector<RunOutput> outs(modes.size());
          std::vector<std::exception_ptr> errors(modes.size());
          {
            py::gil_scoped_release release;
            auto run_mode = [&](std::size_t i) {
              const ForgettingMode mode = modes[i];
              CmlEngineOptions o = base;
              o.model.forgetting = mode == ForgettingMode::kStatic ? ForgettingMode::kActive : mode;
              SessionEndHook freeze;
              if (mode == ForgettingMode::kStatic) {
                freeze = [](const CmlEngine& e, int session) -> std::unique_ptr<CmlEngine> {
                  if (session != 0) return nullptr;
                  CmlEngineOptions frozen = e.options();
                  frozen.model.forgetting = ForgettingMode::kStatic;
                  return RebuildEngineWithOptions(e, frozen);
                };
              }
              const std::string dir =
                  out_dir.empty() ? "" : (std::filesystem::path(out_dir) / ToString(mode)).string();
              outs[i] = RunOne(std::make_unique<CmlEngine>(o), input, dir, "", "", quiet,
                               ToString(mode), freeze);
            };
            auto worker = [&](int w) {
              for (std::size_t i = static_cast<std::size_t>(w); i < modes.size();
                   i += static_cast<std::size_t>(n_jobs)) {
                try {
                  run_mode(i);
                } catch (...) {
                  errors[i] = std::current_exception();
                }
              }
            };
            if (n_jobs == 1) {
              worker(0);
            } else {
              std::vector<std::thread> threads;
              for (int w = 0; w < n_jobs; ++w) threads.emplace_back(worker, w);
              for (auto& t : threads) t.join();
            }
          }
          for (const auto& e : errors) {
            if (e) std::rethrow_exception(e);
          }
          CompareResult result;
          result.steps = steps;
          py::list names;
          py::array_t<std::int64_t> views_at({static_cast<py::ssize_t>(modes.size()),
                                              static_cast<py::ssize_t>(steps.size())});
          std::vector<std::int64_t> views_end;
          std::vector<double> mean_err, max_err, head_deg, unimodal_pct, odom_err;
          std::vector<std::string> header = {"forgetting"};
          for (std::int64_t s : steps) header.push_back("views@" + std::to_string(s));
          for (const char* h : {"views_end", "mean_err_m", "max_err_m", "head_mean_deg",
                                "unimodal%", "odom_err_m"})
            header.push_back(h);
          std::vector<std::vector<std::string>> rows;
          auto fixed = [](double v, int decimals) -> std::string {
            if (!std::isfinite(v)) return "-";
            char buf[48];
            std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
            return buf;
          };
          for (std::size_t i = 0; i < outs.size(); ++i) {
            const RunOutput& o = outs[i];
            names.append(o.label);
            std::vector<std::string> row = {o.label};
            for (std::size_t k = 0; k < steps.size(); ++k) {
              const auto s = static_cast<std::size_t>(steps[k]);
              const std::int64_t v = s <= o.records.size() ? o.records[s - 1].views : -1;
              views_at.mutable_at(i, k) = v;
              row.push_back(v < 0 ? "-" : std::to_string(v));
            }
            const auto& ov = o.eval.overall;
            views_end.push_back(static_cast<std::int64_t>(o.engine->model().NumViews()));
            mean_err.push_back(ov.position_m.mean);
            max_err.push_back(ov.position_m.max);
            head_deg.push_back(ov.heading_rad.mean * 180 / kPi);
            unimodal_pct.push_back(ov.unimodal_fraction * 100);
            odom_err.push_back(ov.odometry_m.mean);
            row.push_back(std::to_string(views_end.back()));
            row.push_back(fixed(mean_err.back(), 3));
            row.push_back(fixed(max_err.back(), 3));
            row.push_back(fixed(head_deg.back(), 2));
            row.push_back(fixed(unimodal_pct.back(), 1));
            row.push_back(fixed(odom_err.back(), 3));
            rows.push_back(row);
          }
          result.table_text = FormatTextTable(header, rows, /*left_align_first=*/true);
          if (!out_dir.empty()) {
            WriteFileAtomically((std::filesystem::path(out_dir) / "table.txt").string(),
                                std::vector<std::uint8_t>(result.table_text.begin(), result.table_text.end()));
          }
          result.table["forgetting"] = names;
          result.table["views_at"] = views_at;
          result.table["views_end"] = py::array(py::cast(views_end));
          result.table["mean_err_m"] = py::array(py::cast(mean_err));
          result.table["max_err_m"] = py::array(py::cast(max_err));
          result.table["head_mean_deg"] = py::array(py::cast(head_deg));
          result.table["unimodal_pct"] = py::array(py::cast(unimodal_pct));
          result.table["odom_err_m"] = py::array(py::cast(odom_err));
          for (auto& o : outs) {
            const std::string label = o.label;
            result.runs[py::str(label)] = ToPython(std::move(o));
          }
          return result;
        },
        py::arg("logs") = py::none(), py::arg("world") = "", py::arg("days") = 1,
        py::arg("first_day") = 0, py::arg("frames_per_day") = 0, py::arg("seed") = 1,
        py::arg("options") = py::none(),
        py::arg("steps") = std::vector<std::int64_t>{2000, 4000, 6000, 8000},
        py::arg("out_dir") = "", py::arg("jobs") = 1, py::arg("quiet") = true,
        "The [G] Table 1 experiment (`omnicml compare`): the same input under passive, active "
        "and static forgetting (static learns day 1 actively, then is frozen); reference views "
        "at `steps` (frames) and errors. jobs: modes run in parallel threads (0 = one per core; "
        "same results). out_dir: each mode's run directory under it, and table.txt. Returns a "
        "CompareResult.");

  m.def("evaluate",
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
