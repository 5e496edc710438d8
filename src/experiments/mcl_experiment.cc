#include "omnicml/experiments/mcl_experiment.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <numeric>
#include <random>
#include <sstream>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/limits.h"
#include "omnicml/descriptors/descriptor_factory.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/report/report.h"
#include "omnicml/report/svg_plot.h"
#include "omnicml/run/run_directory.h"
#include "omnicml/sim/simulator.h"
#include "omnicml/sim/world.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

double Deg(double rad) { return rad * 180.0 / kPi; }

std::string F(double v, int prec = 3) {
  std::ostringstream os;
  os << std::fixed << std::setprecision(prec) << v;
  return os.str();
}

MclOptions MakeOptions(const MclExperimentOptions& a) {
  MclOptions o = a.filter;
  o.num_particles = a.particles;
  o.random_samples_per_step = a.random_samples;
  o.heading_independent = a.heading_gate_deg <= 0;
  // Degrees to radians only when they differ (a gate loaded with --config stays bit-exact).
  if (a.heading_gate_deg > 0 && a.heading_gate_deg != Deg(o.heading_gate_half_width_rad)) {
    o.heading_gate_half_width_rad = a.heading_gate_deg * kPi / 180;
  }
  o.top_k = a.top_k;
  o.prior_fraction = a.prior_fraction;
  o.min_likelihood = a.min_likelihood;
  o.visibility.max_distance_from_reference_m = a.max_distance_from_reference_m;
  o.seed = a.mcl_seed;
  o.Validate();
  return o;
}

MclPrepared PrepareMcl(const MclExperimentOptions& a) {
  const auto t0 = std::chrono::steady_clock::now();
  MclPrepared p;
  p.options = MakeOptions(a);
  DescriptorOptions dopt;
  dopt.kind = DescriptorKindFromString(a.descriptor);
  dopt.ifh.normalize_columns = a.ifh_normalize_columns;
  p.extractor = MakeDescriptorExtractor(dopt);
  if (a.train_day < 1 || a.test_day < 1) throw Error("mcl: --train-day and --test-day are 1-based");
  const std::vector<int> sessions = {a.train_day - 1, a.test_day - 1};
  std::vector<MclFrame> frames;
  // Heading descriptors only when the filter uses them (MclOptions::relative_heading).
  const std::shared_ptr<const DescriptorExtractor> heading =
      p.options.relative_heading ? MakeMclHeadingExtractor() : nullptr;
  if (!a.log_dirs.empty()) {
    if (a.map_yaml.empty()) throw Error("mcl: a LOGDIR input needs --map map.yaml (map_server)");
    p.grid = LoadOccupancyGrid(a.map_yaml);
    LogReader reader(a.log_dirs);
    if (std::max(a.train_day, a.test_day) > reader.NumSessions()) {
      throw Error(StrCat("mcl: the log has ", reader.NumSessions(), " session(s)"));
    }
    frames = ReadMclFrames(reader, *p.extractor, sessions, 1, heading.get());
    p.input = StrCat("log ", a.log_dirs.front(), " map ", a.map_yaml);
  } else {
    if (std::max(a.train_day, a.test_day) > a.days) {
      throw Error(StrCat("mcl: --train-day/--test-day beyond --days ", a.days));
    }
    World world = LoadWorld(a.world);
    if (a.panorama_width < 16 || a.panorama_height < 8) {
      throw Error("mcl: --panorama-width >= 16 and --panorama-height >= 8 required");
    }
    world.camera.panorama_width_px = a.panorama_width;
    world.camera.panorama_height_px = a.panorama_height;
    p.world_noise = world.odometry_noise;
    SimulatorOptions so;
    so.world = a.world;
    so.days = std::max(a.train_day, a.test_day);
    so.frames_per_day = a.frames_per_day;
    so.seed = a.seed;
    so.output = ImageKind::kPanorama;
    so.people = a.people;
    so.Validate();
    SimulatedFrameSource source(so, world);
    frames = ReadMclFrames(source, *p.extractor, sessions, 1, heading.get());
    p.grid = a.map_yaml.empty()
                 ? MakeOccupancyGrid(world, StateAtDayStart(world, a.test_day, a.seed),
                                     {.resolution_m = a.grid_resolution_m})
                 : LoadOccupancyGrid(a.map_yaml);
    p.input = StrCat("world ", a.world, " seed ", a.seed, " frames/day ", a.frames_per_day);
  }
  std::vector<MclFrame> train;
  for (const auto& f : frames) {
    if (f.session == a.train_day - 1) train.push_back(f);
    if (f.session == a.test_day - 1) p.test.push_back(f);
  }
  std::vector<MclFrame> refs_frames;
  for (std::size_t i = 0; i < train.size();
       i += static_cast<std::size_t>(std::max(1, a.ref_every))) {
    refs_frames.push_back(train[i]);
  }
  // Every true position must lie on the grid; one that does not means the map is not the
  // log's (or its origin is off), and the filter would run without an error otherwise.
  const std::string map_name = a.map_yaml.empty() ? StrCat("the grid of ", a.world) : a.map_yaml;
  auto count_not_free = [&](const std::vector<MclFrame>& fs) {
    int n = 0;
    for (const MclFrame& f : fs) {
      if (!f.truth) continue;
      const CellIndex c = p.grid.CellOf(f.truth->head<2>());
      if (!p.grid.InBounds(c)) {
        const Eigen::Vector2d lo = p.grid.origin_m();
        const Eigen::Vector2d hi =
            lo + p.grid.resolution_m() * Eigen::Vector2d(p.grid.width(), p.grid.height());
        throw Error(StrCat("mcl: ", map_name, ": day ", f.session + 1, " frame ", f.index,
                           ": ground truth (", F(f.truth->x(), 2), ", ", F(f.truth->y(), 2),
                           ") m lies outside the map ([", F(lo.x(), 2), ", ", F(hi.x(), 2), "] x [",
                           F(lo.y(), 2), ", ", F(hi.y(), 2), "] m); is it the map of this log?"));
      }
      n += p.grid.IsFree(c) ? 0 : 1;
    }
    return n;
  };
  p.refs_not_free = count_not_free(refs_frames);
  p.test_not_free = count_not_free(p.test);
  p.refs = MakeReferences(refs_frames);
  if (p.refs.empty()) throw Error("mcl: no reference frame with ground truth on the training day");
  if (p.test.empty()) throw Error("mcl: no frame on the test day");
  p.reference_spacing_m = MedianReferenceSpacing(p.refs);
  p.visibility_radius_m = ComputeVisibilityAreas(p.grid, p.options, &p.refs);
  p.prepare_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return p;
}

std::string ConfigYaml(const MclExperimentOptions& a, const MclPrepared& p) {
  std::ostringstream os;
  // The inputs (kMclRunKeys, skipped by LoadMclOptions), then every MclOptions field, so
  // that `omnicml mcl --config RUNDIR/config.yaml` with the same inputs repeats the run.
  os << "# Effective configuration of `omnicml mcl` (MclOptions and inputs).\n"
     << "input: \"" << p.input << "\"\n"
     << "train_day: " << a.train_day << "\ntest_day: " << a.test_day << "\n"
     << "ref_every: " << a.ref_every << "\nreferences: " << p.refs.size() << "\n"
     << "panorama_width_px: " << a.panorama_width << "\npanorama_height_px: " << a.panorama_height
     << "\n"
     << "descriptor: " << a.descriptor << "\n"
     << "ifh_normalize_columns: " << (a.ifh_normalize_columns ? "true" : "false") << "\n"
     << "grid_resolution_m: " << FormatRoundTrip(p.grid.resolution_m()) << "\n"
     << "start: " << (a.global ? "global" : "known") << "\n"
     << MclOptionsToYaml(p.options);
  return os.str();
}

struct Stats {
  double mean = 0, median = 0, max = 0, min = 0;
  int n = 0;
};
Stats Summarise(std::vector<double> v) {
  Stats s;
  s.n = static_cast<int>(v.size());
  if (v.empty()) return s;
  std::sort(v.begin(), v.end());
  s.mean = std::accumulate(v.begin(), v.end(), 0.0) / v.size();
  s.median = v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
  s.max = v.back();
  s.min = v.front();
  return s;
}

constexpr double kUnimodalClusterWeight = 0.5;

const std::vector<std::string>& MclStageNames() {
  static const std::vector<std::string> kNames = {"correct", "total"};
  return kNames;
}

std::vector<FrameRecord> MakeFrameRecords(const MclPrepared& p,
                                          const std::vector<MclStepRecord>& rec) {
  if (rec.size() != p.test.size()) throw Error("mcl: internal: one record per test frame expected");
  const int retrieved = p.options.top_k > 0
                            ? std::min<int>(p.options.top_k, static_cast<int>(p.refs.size()))
                            : static_cast<int>(p.refs.size());
  std::vector<FrameRecord> out;
  out.reserve(rec.size());
  int session = -1;
  std::int64_t first_index = 0;
  bool have_anchor = false;
  Pose2 anchor_truth = Pose2::Zero(), anchor_odom = Pose2::Zero();
  RunStampClock clock;
  for (std::size_t i = 0; i < rec.size(); ++i) {
    const MclFrame& f = p.test[i];
    const MclStepRecord& s = rec[i];
    if (f.session != session) {
      session = f.session;
      first_index = f.index;
      have_anchor = false;
    }
    FrameRecord r;
    r.session = f.session;
    r.frame = f.index - first_index;
    r.global_frame = f.index;
    r.stamp_s = s.stamp_s;
    r.run_stamp_s = clock.Next(f.session, s.stamp_s);
    r.has_odometry = true;
    r.odometry = f.odom_T_robot;
    r.has_estimate = true;  // a particle filter always has an estimate: coverage 1
    r.estimate = s.estimate.cluster;
    r.mean_estimate = s.estimate.mean;
    r.unimodal = s.estimate.cluster_weight >= kUnimodalClusterWeight;
    if (f.truth) {
      r.has_truth = true;
      r.truth = *f.truth;
      if (!have_anchor) {
        have_anchor = true;
        anchor_truth = r.truth;
        anchor_odom = f.odom_T_robot;
      }
      const Pose2 dead_reckoning = Compose(anchor_truth, Between(anchor_odom, f.odom_T_robot));
      r.odometry_error_m = (dead_reckoning.head<2>() - r.truth.head<2>()).norm();
      r.position_error_m = (r.estimate.head<2>() - r.truth.head<2>()).norm();
      r.heading_error_rad = std::abs(WrapAngle(r.estimate.z() - r.truth.z()));
    }
    r.views = static_cast<int>(p.refs.size());
    r.map_components = static_cast<int>(p.refs.size());
    r.hypotheses = retrieved;
    r.mixture_components = p.options.num_particles;
    r.stage_times_us = {s.time_us, s.time_us};
    out.push_back(std::move(r));
  }
  return out;
}

std::string Fx(double v, int prec) { return std::isfinite(v) ? F(v, prec) : std::string("-"); }

std::string ReportHtml(const MclExperimentOptions& a, const MclPrepared& p,
                       const std::vector<FrameRecord>& records, const std::string& summary_text,
                       const std::string& config_yaml) {
  FramesTable table;
  table.stage_names = MclStageNames();
  table.records = records;
  const EvaluationResult eval = Evaluate(table, Alignment::kNone);
  HtmlReport report("omnicml mcl [W]");
  report.AddHeading("Summary");
  report.AddKeyValues({
      {"input", p.input},
      {"references",
       StrCat(p.refs.size(), " (day ", a.train_day, ", every ", a.ref_every, ". frame)")},
      {"queries", StrCat(records.size(), " (day ", a.test_day, ")")},
      {"localized queries (coverage)",
       StrCat(eval.overall.frames_with_estimate, " of ", eval.overall.frames, " (",
              Fx(eval.overall.coverage * 100, 1), " %; the filter always has an estimate)")},
      {"particles", std::to_string(p.options.num_particles)},
      {"start", a.global ? "global" : "known"},
      {"descriptor", a.descriptor == "ifh" && a.ifh_normalize_columns
                         ? std::string("ifh, columns normalised")
                         : a.descriptor},
      {"grid", StrCat(p.grid.width(), " x ", p.grid.height(), " cells of ",
                      F(p.grid.resolution_m(), 3), " m")},
      {"visibility areas cut at",
       StrCat(F(p.visibility_radius_m, 3), " m (median reference spacing ",
              F(p.reference_spacing_m, 3), " m)")},
      {"position error mean / p95 / max", Fx(eval.overall.position_m.mean, 3) + " / " +
                                              Fx(eval.overall.position_m.p95, 3) + " / " +
                                              Fx(eval.overall.position_m.max, 3) + " m"},
      {"odometry-only error mean", Fx(eval.overall.odometry_m.mean, 3) + " m"},
      {"mean time per step", Fx(eval.overall.mean_frame_time_us / 1000.0, 2) + " ms"},
      {"preparation", F(p.prepare_s, 1) + " s"},
  });
  report.AddPreformatted(summary_text);

  report.AddHeading("Per day");
  std::vector<std::vector<std::string>> rows;
  for (const DayEvaluation& d : eval.days) {
    rows.push_back({std::to_string(d.session + 1), std::to_string(d.frames),
                    std::to_string(d.frames_with_truth), std::to_string(d.frames_with_estimate),
                    Fx(d.coverage * 100, 1), Fx(d.unimodal_fraction * 100, 1),
                    Fx(d.position_m.mean, 3), Fx(d.position_m.median, 3), Fx(d.position_m.p95, 3),
                    Fx(d.position_m.max, 3), Fx(d.heading_rad.mean * 180 / kPi, 2),
                    Fx(d.odometry_m.mean, 3), std::to_string(d.views_at_end),
                    Fx(d.mean_frame_time_us / 1000.0, 2)});
  }
  report.AddTable({"day", "frames", "with truth", "localized", "coverage %",
                   "best cluster >= 50 % of weight, %", "mean m", "median m", "p95 m", "max m",
                   "heading mean deg", "odometry mean m", "references", "ms per step"},
                  rows);

  report.AddHeading("Plots");
  std::vector<double> x, err, mean_err, odo;
  for (const FrameRecord& r : records) {
    x.push_back(static_cast<double>(r.global_frame));
    err.push_back(r.position_error_m);
    odo.push_back(r.odometry_error_m);
    mean_err.push_back(r.has_truth ? (r.mean_estimate.head<2>() - r.truth.head<2>()).norm() : kNaN);
  }
  SvgPlot err_plot("Position error", "frame", "error [m]", 960, 300);
  err_plot.AddLine("MCL estimate (best cluster)", x, err);
  err_plot.AddLine("sample mean", x, mean_err);
  err_plot.AddLine("odometry only", x, odo);
  report.AddSvg(err_plot.Render());
  report.AddSvg(RenderPositionHistogramSvg(eval));

  report.AddHeading("Effective configuration");
  report.AddPreformatted(config_yaml);
  return report.Render();
}

// Fails early (before the long preparation) when --out cannot become a run directory.
// Files marking an existing directory as an earlier run directory that a new run may
// replace whole: those of `omnicml run` and mcl's own.
std::vector<std::string> MclRunDirectoryMarkers() {
  std::vector<std::string> markers = RunDirectoryMarkers();
  markers.push_back("summary.txt");
  markers.push_back("map.yaml");
  return markers;
}

void CheckRunDir(const std::string& out) {
  if (out.empty()) return;
  const fs::path dir = fs::absolute(fs::path(out)).lexically_normal();
  fs::path parent = dir.parent_path();
  if (dir.filename().empty()) parent = dir.parent_path().parent_path();
  if (!parent.empty() && !fs::is_directory(parent)) {
    throw Error(StrCat("--out '", out, "': directory '", parent.string(), "' does not exist"));
  }
  if (fs::exists(dir) && !fs::is_directory(dir)) {
    throw Error(StrCat("--out '", out, "' exists and is not a directory"));
  }
}

// The single run: the filter, then the summary text.
MclSingleResult RunSingle(const MclExperimentOptions& a, const MclPrepared& p) {
  MonteCarloLocalizer mcl(p.options, p.grid, p.refs, p.extractor);
  MclRunSpec spec;
  spec.known_start = !a.global;
  MclSingleResult result;
  result.steps = RunMcl(mcl, p.test, spec);
  const auto& rec = result.steps;
  std::vector<double> err, head, time;
  for (const auto& r : rec) {
    if (r.position_error_m >= 0) {
      err.push_back(r.position_error_m);
      head.push_back(Deg(r.heading_error_rad));
    }
    time.push_back(r.time_us / 1000.0);
  }
  // Retrieval quality alone: how far the most similar reference lies from the truth.
  std::vector<double> top1;
  for (const auto& f : p.test) {
    if (!f.truth) continue;
    const std::vector<double> xi = mcl.Similarities(f.descriptor);
    const auto best = std::max_element(xi.begin(), xi.end()) - xi.begin();
    top1.push_back((p.refs[best].map_T_robot.head<2>() - f.truth->head<2>()).norm());
  }
  const Stats r1 = Summarise(top1);
  const double within2 = top1.empty() ? 0.0 : std::count_if(top1.begin(), top1.end(), [](double d) {
                                                return d < 2.0;
                                              }) / static_cast<double>(top1.size());
  const Stats e = Summarise(err), h = Summarise(head), t = Summarise(time);
  const int conv = StepsToConverge(rec, 0, a.converge_error_m, a.success_heading_deg * kPi / 180);
  std::ostringstream sum;
  sum << "omnicml mcl [W]: " << p.input << "\n"
      << "references: " << p.refs.size() << " (day " << a.train_day << "), queries: " << rec.size()
      << " (day " << a.test_day << "), particles: " << p.options.num_particles
      << ", start: " << (a.global ? "global" : "known") << "\n"
      << "localized queries: " << rec.size() << " of " << rec.size()
      << " (coverage 100 %: the filter has an estimate at every step)\n"
      << "position error (cluster) m: mean " << F(e.mean) << " median " << F(e.median) << " max "
      << F(e.max) << "\n"
      << "heading error deg: mean " << F(h.mean, 2) << " median " << F(h.median, 2) << " max "
      << F(h.max, 2) << "\n"
      << "retrieval: most similar reference within 2 m of the truth for " << F(100 * within2, 1)
      << " % of the queries (median distance " << F(r1.median, 2) << " m)\n"
      << "steps to converge (< " << a.converge_error_m << " m, < " << a.success_heading_deg
      << " deg for 3 steps): " << conv << "\n"
      << "time per step ms: mean " << F(t.mean) << " median " << F(t.median) << " max " << F(t.max)
      << " (prediction + retrieval + weighting + resampling; descriptors excluded)\n"
      << "preparation (rendering, descriptors, grid, visibility areas) s: " << F(p.prepare_s, 1)
      << "\n";
  result.summary_text = sum.str();
  result.records = MakeFrameRecords(p, rec);
  return result;
}

MclOptions RunOptions(const MclPrepared& p, int run) {
  MclOptions o = p.options;
  o.seed = MixSeed(p.options.seed, static_cast<std::uint64_t>(run));
  return o;
}

void ExperimentTracking(const MclExperimentOptions& a, const MclPrepared& p,
                        MclExperimentResult* out) {
  std::ostringstream os;
  os << "# [W] tracking: known start, " << a.runs << " run(s), " << p.test.size() << " steps, "
     << p.options.num_particles << " particles\n"
     << "run  max_pos_err_m  max_head_err_deg  mean_pos_err_m  ms_per_step\n";
  std::vector<double> maxe, maxh, meane;
  for (int run = 0; run < a.runs; ++run) {
    MonteCarloLocalizer mcl(RunOptions(p, run), p.grid, p.refs, p.extractor);
    const auto rec = RunMcl(mcl, p.test, {.known_start = true});
    double me = 0, mh = 0, se = 0, st = 0;
    for (const auto& r : rec) {
      me = std::max(me, r.position_error_m);
      mh = std::max(mh, Deg(r.heading_error_rad));
      se += r.position_error_m;
      st += r.time_us;
    }
    maxe.push_back(me);
    maxh.push_back(mh);
    meane.push_back(se / rec.size());
    out->tracking.push_back({.max_position_error_m = me,
                             .max_heading_error_deg = mh,
                             .mean_position_error_m = se / rec.size(),
                             .ms_per_step = st / rec.size() / 1000.0});
    os << std::setw(3) << run << "  " << std::setw(13) << F(me) << "  " << std::setw(16) << F(mh, 2)
       << "  " << std::setw(14) << F(se / rec.size()) << "  " << std::setw(11)
       << F(st / rec.size() / 1000.0) << "\n";
  }
  const Stats e = Summarise(maxe), h = Summarise(maxh), m = Summarise(meane);
  os << "summary: max position error m mean " << F(e.mean) << " worst " << F(e.max)
     << "; max heading error deg mean " << F(h.mean, 2) << " worst " << F(h.max, 2)
     << "; mean position error m " << F(m.mean) << "\n";
  out->text = os.str();
}

void ExperimentGlobal(const MclExperimentOptions& a, const MclPrepared& p,
                      MclExperimentResult* out) {
  std::ostringstream os;
  os << "# [W] global localization: uniform start, " << a.runs
     << " run(s), converged = " << a.converge_error_m << " m and " << a.success_heading_deg
     << " deg for 3 steps, starting at a different frame per run\n"
     << "run  start_frame  steps_to_converge\n";
  std::vector<double> steps;
  int failures = 0;
  std::mt19937_64 rng(MixSeed(p.options.seed, 99));
  for (int run = 0; run < a.runs; ++run) {
    const int n = static_cast<int>(p.test.size());
    const int start = run == 0 ? 0 : static_cast<int>(rng() % static_cast<std::uint64_t>(n / 2));
    std::vector<MclFrame> seq(p.test.begin() + start, p.test.end());
    MonteCarloLocalizer mcl(RunOptions(p, run), p.grid, p.refs, p.extractor);
    const auto rec = RunMcl(mcl, seq, {.known_start = false});
    const int s = StepsToConverge(rec, 0, a.converge_error_m, a.success_heading_deg * kPi / 180);
    os << std::setw(3) << run << "  " << std::setw(11) << start << "  " << std::setw(17)
       << (s < 0 ? std::string("never") : std::to_string(s)) << "\n";
    out->global.push_back({.start_frame = start, .steps_to_converge = s});
    if (s < 0) {
      ++failures;
    } else {
      steps.push_back(s);
    }
  }
  const Stats s = Summarise(steps);
  os << "summary: converged " << s.n << "/" << a.runs << "; steps mean " << F(s.mean, 1)
     << " median " << F(s.median, 1) << " max " << F(s.max, 0) << "\n";
  out->text = os.str();
}

void ExperimentKidnap(const MclExperimentOptions& a, const MclPrepared& p,
                      MclExperimentResult* out) {
  std::ostringstream os;
  const int n = static_cast<int>(p.test.size());
  os << "# [W] kidnapped robot: known start, kidnapped after a random step in [20, " << n / 3
     << ") to a frame at least a quarter of the sequence ahead (and 40 before its end), no "
        "odometry; "
     << a.runs << " run(s); recovered = " << a.converge_error_m << " m and "
     << a.success_heading_deg << " deg for 3 steps\n"
     << "run  kidnap_step  to_frame  jump_m  steps_to_recover\n";
  std::vector<double> steps;
  std::mt19937_64 rng(MixSeed(p.options.seed, 77));
  for (int run = 0; run < a.runs; ++run) {
    const int k =
        20 + static_cast<int>(rng() % static_cast<std::uint64_t>(std::max(1, n / 3 - 20)));
    // At least a quarter of the sequence ahead and 40 steps before its end.
    const int lo = k + n / 4, hi = std::max(lo + 1, n - 40);
    const int to =
        std::min(n - 1, lo + static_cast<int>(rng() % static_cast<std::uint64_t>(hi - lo)));
    MclRunSpec spec;
    spec.kidnap_step = k;
    spec.kidnap_to_frame = to;
    spec.max_steps = k + 1 + std::min(n - to, 150);
    MonteCarloLocalizer mcl(RunOptions(p, run), p.grid, p.refs, p.extractor);
    const auto rec = RunMcl(mcl, p.test, spec);
    const double jump = p.test[k].truth && p.test[to].truth
                            ? (p.test[k].truth->head<2>() - p.test[to].truth->head<2>()).norm()
                            : -1;
    const int s =
        StepsToConverge(rec, k + 1, a.converge_error_m, a.success_heading_deg * kPi / 180);
    os << std::setw(3) << run << "  " << std::setw(11) << k << "  " << std::setw(8) << to << "  "
       << std::setw(6) << F(jump, 1) << "  " << std::setw(16)
       << (s < 0 ? std::string("never") : std::to_string(s)) << "\n";
    out->kidnap.push_back(
        {.kidnap_step = k, .to_frame = to, .jump_m = jump, .steps_to_recover = s});
    if (s >= 0) steps.push_back(s);
  }
  const Stats s = Summarise(steps);
  os << "summary: recovered " << s.n << "/" << a.runs << "; steps mean " << F(s.mean, 1)
     << " median " << F(s.median, 1) << " max " << F(s.max, 0) << "\n";
  out->text = os.str();
}

void ExperimentNoise(const MclExperimentOptions& a, const MclPrepared& p,
                     MclExperimentResult* out) {
  std::ostringstream os;
  std::vector<double> levels;
  {
    std::stringstream ss(a.noise_levels);
    std::string tok;
    while (std::getline(ss, tok, ',')) {
      try {
        levels.push_back(std::stod(tok));
      } catch (const std::exception&) {
        throw Error(StrCat("mcl: --noise-levels: bad number '", tok, "'"));
      }
      if (!(levels.back() >= 0)) throw Error("mcl: --noise-levels: must be >= 0");
    }
  }
  const MotionNoise& b = p.world_noise;
  os << "# [W] robustness to odometry noise: extra noise a_i = level x (" << b.a1 << ", " << b.a2
     << ", " << b.a3 << ", " << b.a4
     << ") added to the logged odometry (the filter's model unchanged), known start, " << a.runs
     << " run(s) per level; success = final error < " << a.success_error_m << " m and < "
     << a.success_heading_deg << " deg\n"
     << "level  success_rate  mean_final_err_m  mean_max_err_m\n";
  for (double level : levels) {
    int ok = 0;
    double fe = 0, me = 0;
    for (int run = 0; run < a.runs; ++run) {
      MclRunSpec spec;
      spec.extra_odometry_noise = {
          .a1 = level * b.a1, .a2 = level * b.a2, .a3 = level * b.a3, .a4 = level * b.a4};
      spec.noise_seed = MixSeed(1234, static_cast<std::uint64_t>(run));
      MonteCarloLocalizer mcl(RunOptions(p, run), p.grid, p.refs, p.extractor);
      const auto rec = RunMcl(mcl, p.test, spec);
      const auto& last = rec.back();
      if (last.position_error_m < a.success_error_m &&
          Deg(last.heading_error_rad) < a.success_heading_deg) {
        ++ok;
      }
      fe += last.position_error_m;
      double mx = 0;
      for (const auto& r : rec) mx = std::max(mx, r.position_error_m);
      me += mx;
    }
    os << std::setw(5) << level << "  " << std::setw(12)
       << StrCat(ok, "/", a.runs, " (", F(100.0 * ok / a.runs, 0), "%)") << "  " << std::setw(16)
       << F(fe / a.runs) << "  " << std::setw(14) << F(me / a.runs) << "\n";
    out->noise.push_back({.level = level,
                          .successes = ok,
                          .runs = a.runs,
                          .mean_final_error_m = fe / a.runs,
                          .mean_max_error_m = me / a.runs});
  }
  out->text = os.str();
}

}  // namespace

void SetMclFilterOptions(const MclOptions& filter, MclExperimentOptions* a) {
  a->filter = filter;
  a->particles = filter.num_particles;
  a->random_samples = filter.random_samples_per_step;
  a->heading_gate_deg = filter.heading_independent ? 0.0 : Deg(filter.heading_gate_half_width_rad);
  a->top_k = filter.top_k;
  a->prior_fraction = filter.prior_fraction;
  a->min_likelihood = filter.min_likelihood;
  a->max_distance_from_reference_m = filter.visibility.max_distance_from_reference_m;
  a->mcl_seed = filter.seed;
}

MclPrepared PrepareMclExperiment(const MclExperimentOptions& a) {
  CheckLimit("mcl: --runs", a.runs, 1, kMaxRuns);
  CheckLimit("mcl: --particles", a.particles, 1, kMaxParticles);
  CheckLimit("mcl: --random-samples", a.random_samples, 0, kMaxParticles);
  CheckLimit("mcl: --ref-every", a.ref_every, 1, kMaxFramesPerDay);
  if (a.log_dirs.empty()) {
    CheckLimit("mcl: --days", a.days, 1, kMaxDays);
    CheckLimit("mcl: --frames-per-day", a.frames_per_day, 1, kMaxFramesPerDay);
    if (static_cast<std::int64_t>(std::max(a.train_day, a.test_day)) * a.frames_per_day >
        kMaxSimulatedFrames) {
      throw Error(StrCat("mcl: simulated days x --frames-per-day exceeds the limit of ",
                         kMaxSimulatedFrames, " frames"));
    }
  }
  if (!a.experiment.empty() && a.experiment != "tracking" && a.experiment != "global" &&
      a.experiment != "kidnap" && a.experiment != "noise") {
    throw Error(
        StrCat("mcl: --experiment must be tracking|global|kidnap|noise, got '", a.experiment, "'"));
  }
  if (a.ifh_normalize_columns && a.descriptor != "ifh") {
    throw Error(
        StrCat("mcl: --ifh-normalize-columns needs --descriptor ifh, got '", a.descriptor, "'"));
  }
  if (a.experiment.empty()) CheckRunDir(a.out_dir);
  if (!a.out_dir.empty()) {
    CheckOutputDirectory(a.out_dir, "--out");
    CheckReplaceableDirectory(a.out_dir, "--out", MclRunDirectoryMarkers());
  }
  return PrepareMcl(a);
}

std::string DescribeMclPrepared(const MclPrepared& p) {
  int empty = 0;
  double cells = 0;
  for (const auto& r : p.refs) {
    empty += r.visibility.empty() ? 1 : 0;
    cells += static_cast<double>(r.visibility.size());
  }
  std::ostringstream os;
  os << "mcl: visibility areas: " << empty << " empty, mean "
     << F(cells / p.refs.size() * p.grid.resolution_m() * p.grid.resolution_m(), 2)
     << " m^2, cut at " << F(p.visibility_radius_m, 3) << " m from the reference"
     << (p.options.visibility.max_distance_from_reference_m > 0
             ? std::string(" (max_distance_from_reference_m)")
             : StrCat(" (", F(p.options.visibility_radius_spacings, 3),
                      " x median reference spacing ", F(p.reference_spacing_m, 3), " m)"))
     << "\n";
  os << "mcl: " << p.refs.size() << " references, " << p.test.size() << " queries, grid "
     << p.grid.width() << "x" << p.grid.height() << " prepared in " << F(p.prepare_s, 1) << " s\n";
  if (p.refs_not_free > 0 || p.test_not_free > 0) {
    os << "mcl: warning: the true positions of " << p.refs_not_free << " of " << p.refs.size()
       << " references and " << p.test_not_free << " of " << p.test.size()
       << " queries lie in occupied or unknown cells of the grid\n";
  }
  return os.str();
}

MclSingleResult RunMclSingle(const MclExperimentOptions& options, const MclPrepared& prepared) {
  // The run directory's lock from the start: a second writer refuses before its work.
  std::unique_ptr<OutputLock> lock;
  if (!options.out_dir.empty()) {
    lock = std::make_unique<OutputLock>(options.out_dir, "--out");
    CheckReplaceableDirectory(options.out_dir, "--out", MclRunDirectoryMarkers());
  }
  MclSingleResult result = RunSingle(options, prepared);
  if (!options.out_dir.empty()) WriteMclRunDirectory(options, prepared, result);
  return result;
}

MclExperimentResult RunMclExperiment(const MclExperimentOptions& options,
                                     const MclPrepared& prepared) {
  MclExperimentResult result;
  result.experiment = options.experiment;
  if (options.experiment == "tracking") {
    ExperimentTracking(options, prepared, &result);
  } else if (options.experiment == "global") {
    ExperimentGlobal(options, prepared, &result);
  } else if (options.experiment == "kidnap") {
    ExperimentKidnap(options, prepared, &result);
  } else if (options.experiment == "noise") {
    ExperimentNoise(options, prepared, &result);
  } else {
    throw Error(StrCat("mcl: --experiment must be tracking|global|kidnap|noise, got '",
                       options.experiment, "'"));
  }
  return result;
}

void WriteMclRunDirectory(const MclExperimentOptions& a, const MclPrepared& p,
                          const MclSingleResult& result) {
  CheckRunDir(a.out_dir);
  // Assembled in a staging directory and renamed into place whole (common/file_io.h
  // StagedDirectory): a failure or a kill leaves the old run directory or none.
  StagedDirectory staged(a.out_dir, "--out", MclRunDirectoryMarkers());
  const fs::path dir = staged.path();
  {
    const std::string config = ConfigYaml(a, p);
    std::vector<std::unique_ptr<AtomicFile>> files;
    auto add = [&](const char* name) -> std::ostream& {
      files.push_back(std::make_unique<AtomicFile>(dir / name, FileSync::kDeferred));
      return files.back()->stream();
    };
    std::ostream& csv = add("frames.csv");
    WriteFramesCsvHeader(csv, MclStageNames());
    for (const FrameRecord& r : result.records) WriteFramesCsvRow(csv, r);
    WriteDaysCsv(add("days.csv"), result.records, MclStageNames());
    // evo-ready TUM files on shared stamps (run/run_recorder.h).
    WriteTum(add("trajectory.tum"), result.records, TumContent::kEstimate);
    if (HasTumContent(result.records, TumContent::kGroundTruth))
      WriteTum(add("groundtruth.tum"), result.records, TumContent::kGroundTruth);
    if (HasTumContent(result.records, TumContent::kOdometry))
      WriteTum(add("odometry.tum"), result.records, TumContent::kOdometry);
    add("config.yaml") << config;
    add("summary.txt") << result.summary_text;
    add("report.html") << ReportHtml(a, p, result.records, result.summary_text, config);
    // The grid goes through its own writer (occupancy_grid.h), then everything else is
    // renamed into place.
    SaveOccupancyGrid(p.grid, (dir / "map.yaml").string());
    for (auto& f : files) f->Commit();
  }
  staged.Commit();
}

}  // namespace omnicml
