// `omnicml mcl`: Monte Carlo localization with image retrieval and visibility areas [W]
// (include/omnicml/mcl.h) over a simulated world or a panorama log.
//
//   omnicml mcl --world home_store --days 2 --frames-per-day 300 --seed 1 --out RUNDIR
//       references: every --ref-every-th frame of --train-day (with ground truth);
//       queries: every frame of --test-day; writes the run directory described at
//       WriteRunDirectory (frames.csv in the evaluation.h schema, days.csv, config.yaml,
//       report.html, summary.txt, map.yaml + map.pgm), atomically.
//   omnicml mcl LOGDIR --map map.yaml ...   (panorama sessions with ground truth)
//   omnicml mcl --world home_store --experiment tracking|global|kidnap|noise --runs 20
//       prints the [W] experiment tables (see README "Baselines").
#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <memory>
#include <numeric>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <unistd.h>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/descriptors/descriptor_factory.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/baselines/mcl/mcl.h"
#include "omnicml/baselines/mcl/occupancy_grid.h"
#include "omnicml/report/report.h"
#include "omnicml/sim/simulator.h"
#include "omnicml/report/svg_plot.h"
#include "omnicml/sim/world.h"

namespace omnicml::app {
namespace {

namespace fs = std::filesystem;

struct MclArgs {
  std::vector<std::string> log_dirs;
  std::string map_yaml;
  std::string world = "home_store";
  int days = 2;
  int frames_per_day = 300;
  std::uint64_t seed = 1;
  int train_day = 1;
  int test_day = 2;
  int ref_every = 2;
  int panorama_width = 180;
  int panorama_height = 36;
  bool people = true;
  std::string descriptor = "ifh";
  double grid_resolution_m = 0.1;
  int particles = 5000;
  int random_samples = 50;
  double heading_gate_deg = 0.0;  // 0: heading independent (omni)
  int top_k = 10;
  double prior_fraction = 0.2;
  double min_likelihood = MclOptions{}.min_likelihood;
  double max_distance_from_reference_m = 2.5;
  bool global = false;
  std::uint64_t mcl_seed = 1;
  std::string out;
  std::string experiment;
  int runs = 20;
  std::string noise_levels = "0,1,4,16,64";
  double success_error_m = 2.0;
  double success_heading_deg = 35.0;
  double converge_error_m = 1.0;
};

double Deg(double rad) { return rad * 180.0 / kPi; }

std::string F(double v, int prec = 3) {
  std::ostringstream os;
  os << std::fixed << std::setprecision(prec) << v;
  return os.str();
}

// Everything a run needs, prepared once.
struct Prepared {
  OccupancyGrid grid;
  std::vector<MclReference> refs;  // visibility areas computed
  std::vector<MclFrame> test;
  std::shared_ptr<const DescriptorExtractor> extractor;
  MclOptions options;
  MotionNoise world_noise{.a1 = 0.01, .a2 = 0.002, .a3 = 0.005, .a4 = 0.001};
  std::string input;
  double prepare_s = 0;
};

MclOptions MakeOptions(const MclArgs& a) {
  MclOptions o;
  o.num_particles = a.particles;
  o.random_samples_per_step = a.random_samples;
  o.heading_independent = a.heading_gate_deg <= 0;
  if (a.heading_gate_deg > 0) o.heading_gate_half_width_rad = a.heading_gate_deg * kPi / 180;
  o.top_k = a.top_k;
  o.prior_fraction = a.prior_fraction;
  o.min_likelihood = a.min_likelihood;
  o.visibility.max_distance_from_reference_m = a.max_distance_from_reference_m;
  o.seed = a.mcl_seed;
  o.Validate();
  return o;
}

Prepared Prepare(const MclArgs& a) {
  const auto t0 = std::chrono::steady_clock::now();
  Prepared p;
  p.options = MakeOptions(a);
  DescriptorOptions dopt;
  dopt.kind = DescriptorKindFromString(a.descriptor);
  p.extractor = MakeDescriptorExtractor(dopt);
  if (a.train_day < 1 || a.test_day < 1) throw Error("mcl: --train-day and --test-day are 1-based");
  const std::vector<int> sessions = {a.train_day - 1, a.test_day - 1};
  std::vector<MclFrame> frames;
  if (!a.log_dirs.empty()) {
    if (a.map_yaml.empty()) throw Error("mcl: a LOGDIR input needs --map map.yaml (map_server)");
    p.grid = LoadOccupancyGrid(a.map_yaml);
    LogReader reader(a.log_dirs);
    if (std::max(a.train_day, a.test_day) > reader.NumSessions()) {
      throw Error(StrCat("mcl: the log has ", reader.NumSessions(), " session(s)"));
    }
    frames = ReadMclFrames(reader, *p.extractor, sessions);
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
    frames = ReadMclFrames(source, *p.extractor, sessions);
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
  for (std::size_t i = 0; i < train.size(); i += static_cast<std::size_t>(std::max(1, a.ref_every))) {
    refs_frames.push_back(train[i]);
  }
  p.refs = MakeReferences(refs_frames);
  if (p.refs.empty()) throw Error("mcl: no reference frame with ground truth on the training day");
  if (p.test.empty()) throw Error("mcl: no frame on the test day");
  ComputeVisibilityAreas(p.grid, p.options, &p.refs);
  p.prepare_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return p;
}

std::string ConfigYaml(const MclArgs& a, const Prepared& p) {
  const MclOptions& o = p.options;
  std::ostringstream os;
  os << "# Effective configuration of `omnicml mcl` (MclOptions and inputs).\n"
     << "input: \"" << p.input << "\"\n"
     << "train_day: " << a.train_day << "\ntest_day: " << a.test_day << "\n"
     << "ref_every: " << a.ref_every << "\nreferences: " << p.refs.size() << "\n"
     << "panorama_width_px: " << a.panorama_width << "\npanorama_height_px: " << a.panorama_height
     << "\n"
     << "descriptor: " << a.descriptor << "\n"
     << "grid_resolution_m: " << FormatRoundTrip(p.grid.resolution_m()) << "\n"
     << "start: " << (a.global ? "global" : "known") << "\n"
     << "num_particles: " << o.num_particles << "\n"
     << "random_samples_per_step: " << o.random_samples_per_step << "\n"
     << "motion: {a1: " << FormatRoundTrip(o.motion.a1) << ", a2: " << FormatRoundTrip(o.motion.a2)
     << ", a3: " << FormatRoundTrip(o.motion.a3) << ", a4: " << FormatRoundTrip(o.motion.a4) << "}\n"
     << "heading_gate_half_width_rad: " << FormatRoundTrip(o.heading_gate_half_width_rad) << "\n"
     << "heading_independent: " << (o.heading_independent ? "true" : "false") << "\n"
     << "top_k: " << o.top_k << "\n"
     << "prior_fraction: " << FormatRoundTrip(o.prior_fraction) << "\n"
     << "min_likelihood: " << FormatRoundTrip(o.min_likelihood) << "\n"
     << "axis_offset_rad: " << FormatRoundTrip(o.axis_offset_rad) << "\n"
     << "visibility: {max_ray_range_m: " << FormatRoundTrip(o.visibility.max_ray_range_m)
     << ", max_distance_m: " << FormatRoundTrip(o.visibility.max_distance_m)
     << ", max_view_angle_rad: " << FormatRoundTrip(o.visibility.max_view_angle_rad)
     << ", max_distance_from_reference_m: "
     << FormatRoundTrip(o.visibility.max_distance_from_reference_m) << "}\n"
     << "cluster_cell_m: " << FormatRoundTrip(o.cluster_cell_m) << "\n"
     << "cluster_radius_m: " << FormatRoundTrip(o.cluster_radius_m) << "\n"
     << "init_sigma_xy_m: " << FormatRoundTrip(o.init_sigma_xy_m) << "\n"
     << "init_sigma_phi_rad: " << FormatRoundTrip(o.init_sigma_phi_rad) << "\n"
     << "seed: " << o.seed << "\n";
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

// ------------------------------------------------------------ the run directory
//
// RUNDIR holds, like `omnicml run` (run_recorder.h):
//   frames.csv   evaluation.h schema (readable by `omnicml evaluate RUNDIR`):
//                  estimate        = the MCL estimate (weighted mean of the best cluster)
//                  mean_estimate   = the weighted sample mean of all particles
//                  unimodal        = the best cluster holds >= kUnimodalClusterWeight of
//                                    the weight
//                  odometry_error  = dead reckoning anchored at the session's first
//                                    ground-truth pose vs truth
//                  views, map_components = number of references (one pose each)
//                  hypotheses      = references retrieved per query (top_k, all when 0)
//                  mixture_components = particles of the filter
//                stages (time_<stage>_us): "correct" = one filter step, prediction +
//                retrieval + weighting + resampling (RunMcl measures them together), and
//                "total" = the same (descriptors are computed beforehand, excluded)
//   days.csv     per-day statistics (EvaluateDay)
//   config.yaml  the effective MclOptions and inputs
//   report.html  self-contained: summary, per-day table, error over frames (inline SVG),
//                error histogram, configuration
//   summary.txt  the text printed on stdout
//   map.yaml + map.pgm  the occupancy grid used (map_server format)
// Everything is written into a temporary sibling directory which is then renamed onto
// RUNDIR (RUNDIR missing or empty), so a failure leaves no half-written run directory;
// into an existing non-empty RUNDIR every file is renamed over its old version.

constexpr double kUnimodalClusterWeight = 0.5;

const std::vector<std::string>& MclStageNames() {
  static const std::vector<std::string> kNames = {"correct", "total"};
  return kNames;
}

std::vector<FrameRecord> MakeFrameRecords(const Prepared& p,
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
    r.has_estimate = true;
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

std::string ReportHtml(const MclArgs& a, const Prepared& p, const std::vector<FrameRecord>& records,
                       const std::string& summary_text, const std::string& config_yaml) {
  FramesTable table;
  table.stage_names = MclStageNames();
  table.records = records;
  const EvaluationResult eval = Evaluate(table, Alignment::kNone);
  HtmlReport report("omnicml mcl [W]");
  report.AddHeading("Summary");
  report.AddKeyValues({
      {"input", p.input},
      {"references", StrCat(p.refs.size(), " (day ", a.train_day, ", every ", a.ref_every,
                            ". frame)")},
      {"queries", StrCat(records.size(), " (day ", a.test_day, ")")},
      {"particles", std::to_string(p.options.num_particles)},
      {"start", a.global ? "global" : "known"},
      {"descriptor", a.descriptor},
      {"grid", StrCat(p.grid.width(), " x ", p.grid.height(), " cells of ",
                      F(p.grid.resolution_m(), 3), " m")},
      {"position error mean / p95 / max",
       Fx(eval.overall.position_m.mean, 3) + " / " + Fx(eval.overall.position_m.p95, 3) + " / " +
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
                    std::to_string(d.frames_with_truth), Fx(d.unimodal_fraction * 100, 1),
                    Fx(d.position_m.mean, 3), Fx(d.position_m.median, 3), Fx(d.position_m.p95, 3),
                    Fx(d.position_m.max, 3), Fx(d.heading_rad.mean * 180 / kPi, 2),
                    Fx(d.odometry_m.mean, 3), std::to_string(d.views_at_end),
                    Fx(d.mean_frame_time_us / 1000.0, 2)});
  }
  report.AddTable({"day", "frames", "with truth", "best cluster >= 50 % of weight, %", "mean m",
                   "median m", "p95 m", "max m", "heading mean deg", "odometry mean m",
                   "references", "ms per step"},
                  rows);

  report.AddHeading("Plots");
  std::vector<double> x, err, mean_err, odo;
  for (const FrameRecord& r : records) {
    x.push_back(static_cast<double>(r.global_frame));
    err.push_back(r.position_error_m);
    odo.push_back(r.odometry_error_m);
    mean_err.push_back(r.has_truth ? (r.mean_estimate.head<2>() - r.truth.head<2>()).norm()
                                   : kNaN);
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

// Writes `content` to `path`, throwing omnicml::Error naming the file on failure.
void WriteWhole(const fs::path& path, const std::string& content) {
  std::ofstream out(path, std::ios::binary);
  out << content;
  out.close();
  if (!out) throw Error(StrCat(path.string(), ": write failed"));
}

// Fails early (before the long preparation) when --out cannot become a run directory.
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

// A temporary sibling directory removed on destruction unless released.
class TempDir {
 public:
  explicit TempDir(fs::path path) : path_(std::move(path)) {
    std::error_code ec;
    if (!fs::create_directory(path_, ec) || ec) {
      throw Error(StrCat("cannot create '", path_.string(), "': ",
                         ec ? ec.message() : std::string("already exists")));
    }
  }
  ~TempDir() {
    if (path_.empty()) return;
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

void WriteRunDirectory(const MclArgs& a, const Prepared& p, const std::vector<MclStepRecord>& rec,
                       const std::string& summary_text) {
  CheckRunDir(a.out);
  fs::path dir = fs::absolute(fs::path(a.out)).lexically_normal();
  if (dir.filename().empty()) dir = dir.parent_path();
  const std::vector<FrameRecord> records = MakeFrameRecords(p, rec);
  const std::string config = ConfigYaml(a, p);

  static int counter = 0;
  TempDir tmp(dir.parent_path() /
              StrCat(".", dir.filename().string(), ".tmp-", ::getpid(), "-", counter++));
  {
    std::ostringstream csv;
    WriteFramesCsvHeader(csv, MclStageNames());
    for (const FrameRecord& r : records) WriteFramesCsvRow(csv, r);
    WriteWhole(tmp.path() / "frames.csv", csv.str());
  }
  {
    std::ostringstream days;
    WriteDaysCsv(days, records, MclStageNames());
    WriteWhole(tmp.path() / "days.csv", days.str());
  }
  WriteWhole(tmp.path() / "config.yaml", config);
  WriteWhole(tmp.path() / "summary.txt", summary_text);
  WriteWhole(tmp.path() / "report.html", ReportHtml(a, p, records, summary_text, config));
  SaveOccupancyGrid(p.grid, (tmp.path() / "map.yaml").string());

  std::error_code ec;
  const bool exists = fs::exists(dir, ec);
  if (exists && !fs::is_directory(dir)) {
    throw Error(StrCat("--out '", a.out, "' exists and is not a directory"));
  }
  if (!exists || fs::is_empty(dir, ec)) {
    if (exists) fs::remove(dir, ec);  // an empty directory; rename() may not replace it
    fs::rename(tmp.path(), dir, ec);
    if (ec) {
      throw Error(StrCat("cannot rename '", tmp.path().string(), "' to '", dir.string(), "': ",
                         ec.message()));
    }
  } else {
    // An existing run directory: replace each file atomically, keep unrelated files.
    for (const auto& entry : fs::directory_iterator(tmp.path())) {
      fs::rename(entry.path(), dir / entry.path().filename(), ec);
      if (ec) {
        throw Error(StrCat("cannot rename '", entry.path().string(), "' into '", dir.string(),
                           "': ", ec.message()));
      }
    }
  }
  std::cout << "wrote " << a.out
            << "/{frames.csv,days.csv,config.yaml,report.html,summary.txt,map.yaml,map.pgm}\n";
}

// A single run with a run directory.
void RunSingle(const MclArgs& a, const Prepared& p) {
  MonteCarloLocalizer mcl(p.options, p.grid, p.refs, p.extractor);
  MclRunSpec spec;
  spec.known_start = !a.global;
  const auto rec = RunMcl(mcl, p.test, spec);
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
  const double within2 =
      top1.empty() ? 0.0
                   : std::count_if(top1.begin(), top1.end(), [](double d) { return d < 2.0; }) /
                         static_cast<double>(top1.size());
  const Stats e = Summarise(err), h = Summarise(head), t = Summarise(time);
  const int conv = StepsToConverge(rec, 0, a.converge_error_m, a.success_heading_deg * kPi / 180);
  std::ostringstream sum;
  sum << "omnicml mcl [W]: " << p.input << "\n"
      << "references: " << p.refs.size() << " (day " << a.train_day << "), queries: " << rec.size()
      << " (day " << a.test_day << "), particles: " << p.options.num_particles
      << ", start: " << (a.global ? "global" : "known") << "\n"
      << "position error (cluster) m: mean " << F(e.mean) << " median " << F(e.median) << " max "
      << F(e.max) << "\n"
      << "heading error deg: mean " << F(h.mean, 2) << " median " << F(h.median, 2) << " max "
      << F(h.max, 2) << "\n"
      << "retrieval: most similar reference within 2 m of the truth for " << F(100 * within2, 1)
      << " % of the queries (median distance " << F(r1.median, 2) << " m)\n"
      << "steps to converge (< " << a.converge_error_m << " m, < " << a.success_heading_deg
      << " deg for 3 steps): " << conv << "\n"
      << "time per step ms: mean " << F(t.mean) << " median " << F(t.median) << " max "
      << F(t.max) << " (prediction + retrieval + weighting + resampling; descriptors excluded)\n"
      << "preparation (rendering, descriptors, grid, visibility areas) s: " << F(p.prepare_s, 1)
      << "\n";
  std::cout << sum.str();
  if (a.out.empty()) return;
  WriteRunDirectory(a, p, rec, sum.str());
}

MclOptions RunOptions(const Prepared& p, int run) {
  MclOptions o = p.options;
  o.seed = MixSeed(p.options.seed, static_cast<std::uint64_t>(run));
  return o;
}

void ExperimentTracking(const MclArgs& a, const Prepared& p) {
  std::cout << "# [W] tracking: known start, " << a.runs << " run(s), " << p.test.size()
            << " steps, " << p.options.num_particles << " particles\n"
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
    std::cout << std::setw(3) << run << "  " << std::setw(13) << F(me) << "  " << std::setw(16)
              << F(mh, 2) << "  " << std::setw(14) << F(se / rec.size()) << "  " << std::setw(11)
              << F(st / rec.size() / 1000.0) << "\n";
  }
  const Stats e = Summarise(maxe), h = Summarise(maxh), m = Summarise(meane);
  std::cout << "summary: max position error m mean " << F(e.mean) << " worst " << F(e.max)
            << "; max heading error deg mean " << F(h.mean, 2) << " worst " << F(h.max, 2)
            << "; mean position error m " << F(m.mean) << "\n";
}

void ExperimentGlobal(const MclArgs& a, const Prepared& p) {
  std::cout << "# [W] global localization: uniform start, " << a.runs << " run(s), converged = "
            << a.converge_error_m << " m and " << a.success_heading_deg
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
    std::cout << std::setw(3) << run << "  " << std::setw(11) << start << "  " << std::setw(17)
              << (s < 0 ? std::string("never") : std::to_string(s)) << "\n";
    if (s < 0) {
      ++failures;
    } else {
      steps.push_back(s);
    }
  }
  const Stats s = Summarise(steps);
  std::cout << "summary: converged " << s.n << "/" << a.runs << "; steps mean " << F(s.mean, 1)
            << " median " << F(s.median, 1) << " max " << F(s.max, 0) << "\n";
}

void ExperimentKidnap(const MclArgs& a, const Prepared& p) {
  const int n = static_cast<int>(p.test.size());
  std::cout << "# [W] kidnapped robot: known start, kidnapped after a random step in [20, "
            << n / 3 << ") to a frame at least a quarter of the sequence ahead (and 40 before its end), no odometry; "
            << a.runs << " run(s); recovered = " << a.converge_error_m << " m and "
            << a.success_heading_deg << " deg for 3 steps\n"
            << "run  kidnap_step  to_frame  jump_m  steps_to_recover\n";
  std::vector<double> steps;
  std::mt19937_64 rng(MixSeed(p.options.seed, 77));
  for (int run = 0; run < a.runs; ++run) {
    const int k = 20 + static_cast<int>(rng() % static_cast<std::uint64_t>(std::max(1, n / 3 - 20)));
    // At least a quarter of the sequence ahead and 40 steps before its end.
    const int lo = k + n / 4, hi = std::max(lo + 1, n - 40);
    const int to = std::min(n - 1, lo + static_cast<int>(rng() % static_cast<std::uint64_t>(hi - lo)));
    MclRunSpec spec;
    spec.kidnap_step = k;
    spec.kidnap_to_frame = to;
    spec.max_steps = k + 1 + std::min(n - to, 150);
    MonteCarloLocalizer mcl(RunOptions(p, run), p.grid, p.refs, p.extractor);
    const auto rec = RunMcl(mcl, p.test, spec);
    const double jump = p.test[k].truth && p.test[to].truth
                            ? (p.test[k].truth->head<2>() - p.test[to].truth->head<2>()).norm()
                            : -1;
    const int s = StepsToConverge(rec, k + 1, a.converge_error_m, a.success_heading_deg * kPi / 180);
    std::cout << std::setw(3) << run << "  " << std::setw(11) << k << "  " << std::setw(8) << to
              << "  " << std::setw(6) << F(jump, 1) << "  " << std::setw(16)
              << (s < 0 ? std::string("never") : std::to_string(s)) << "\n";
    if (s >= 0) steps.push_back(s);
  }
  const Stats s = Summarise(steps);
  std::cout << "summary: recovered " << s.n << "/" << a.runs << "; steps mean " << F(s.mean, 1)
            << " median " << F(s.median, 1) << " max " << F(s.max, 0) << "\n";
}

void ExperimentNoise(const MclArgs& a, const Prepared& p) {
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
  std::cout << "# [W] robustness to odometry noise: extra noise a_i = level x (" << b.a1 << ", "
            << b.a2 << ", " << b.a3 << ", " << b.a4
            << ") added to the logged odometry (the filter's model unchanged), known start, "
            << a.runs << " run(s) per level; success = final error < " << a.success_error_m
            << " m and < " << a.success_heading_deg << " deg\n"
            << "level  success_rate  mean_final_err_m  mean_max_err_m\n";
  for (double level : levels) {
    int ok = 0;
    double fe = 0, me = 0;
    for (int run = 0; run < a.runs; ++run) {
      MclRunSpec spec;
      spec.extra_odometry_noise = {.a1 = level * b.a1, .a2 = level * b.a2, .a3 = level * b.a3,
                                   .a4 = level * b.a4};
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
    std::cout << std::setw(5) << level << "  " << std::setw(12)
              << StrCat(ok, "/", a.runs, " (", F(100.0 * ok / a.runs, 0), "%)") << "  "
              << std::setw(16) << F(fe / a.runs) << "  " << std::setw(14) << F(me / a.runs) << "\n";
  }
}

void RunMclCommand(const MclArgs& a) {
  if (a.runs < 1) throw Error("mcl: --runs must be >= 1");
  if (a.experiment.empty()) CheckRunDir(a.out);
  const Prepared p = Prepare(a);
  int empty = 0;
  double cells = 0;
  for (const auto& r : p.refs) {
    empty += r.visibility.empty() ? 1 : 0;
    cells += static_cast<double>(r.visibility.size());
  }
  std::cerr << "mcl: visibility areas: " << empty << " empty, mean "
            << F(cells / p.refs.size() * p.grid.resolution_m() * p.grid.resolution_m(), 2)
            << " m^2\n";
  std::cerr << "mcl: " << p.refs.size() << " references, " << p.test.size() << " queries, grid "
            << p.grid.width() << "x" << p.grid.height() << " prepared in " << F(p.prepare_s, 1)
            << " s\n";
  if (a.experiment.empty()) {
    RunSingle(a, p);
  } else if (a.experiment == "tracking") {
    ExperimentTracking(a, p);
  } else if (a.experiment == "global") {
    ExperimentGlobal(a, p);
  } else if (a.experiment == "kidnap") {
    ExperimentKidnap(a, p);
  } else if (a.experiment == "noise") {
    ExperimentNoise(a, p);
  } else {
    throw Error(StrCat("mcl: --experiment must be tracking|global|kidnap|noise, got '",
                       a.experiment, "'"));
  }
}

const CommandRegistration kRegistration{
    "mcl", [](CLI::App& app) {
      auto a = std::make_shared<MclArgs>();
      CLI::App* cmd = app.add_subcommand(
          "mcl", "Monte Carlo localization with image retrieval and visibility areas [W]");
      cmd->add_option("logdirs", a->log_dirs, "Panorama log directories (instead of --world)");
      cmd->add_option("--map", a->map_yaml,
                      "Occupancy grid in map_server format (YAML + PGM); default: rasterised "
                      "from the world");
      cmd->add_option("--world", a->world, "Built-in world or world YAML")->capture_default_str();
      cmd->add_option("--days", a->days, "Simulated days")->capture_default_str();
      cmd->add_option("--frames-per-day", a->frames_per_day, "Simulated frames per day")
          ->capture_default_str();
      cmd->add_option("--seed", a->seed, "Simulator seed")->capture_default_str();
      cmd->add_option("--train-day", a->train_day, "Day of the reference images (1-based)")
          ->capture_default_str();
      cmd->add_option("--test-day", a->test_day, "Day localized (1-based)")->capture_default_str();
      cmd->add_option("--ref-every", a->ref_every, "Every k-th training frame is a reference")
          ->capture_default_str();
      cmd->add_option("--panorama-width", a->panorama_width, "Simulated panorama width, px")
          ->capture_default_str();
      cmd->add_option("--panorama-height", a->panorama_height, "Simulated panorama height, px")
          ->capture_default_str();
      cmd->add_flag("!--no-people", a->people, "Simulate without people");
      cmd->add_option("--descriptor", a->descriptor, "ifh | fourier | color")->capture_default_str();
      cmd->add_option("--grid-resolution", a->grid_resolution_m, "Occupancy grid cell size, m")
          ->capture_default_str();
      cmd->add_option("--particles", a->particles, "Number of particles")->capture_default_str();
      cmd->add_option("--random-samples", a->random_samples, "Random samples injected per step")
          ->capture_default_str();
      cmd->add_option("--heading-gate-deg", a->heading_gate_deg,
                      "Half width of d(psi), degrees; 0 = heading independent (omni)")
          ->capture_default_str();
      cmd->add_option("--top-k", a->top_k, "Retrieved references per query (0 = all)")
          ->capture_default_str();
      cmd->add_option("--prior-fraction", a->prior_fraction, "Prior of [W] eq. (8) / mean xi")
          ->capture_default_str();
      cmd->add_option("--min-likelihood", a->min_likelihood, "Lower bound of a particle's weight")
          ->capture_default_str();
      cmd->add_option("--visibility-radius", a->max_distance_from_reference_m,
                      "Visibility areas kept within this distance of the reference, m (0 = off)")
          ->capture_default_str();
      cmd->add_flag("--global", a->global, "Start with uniform particles (global localization)");
      cmd->add_option("--mcl-seed", a->mcl_seed, "Seed of the filter")->capture_default_str();
      cmd->add_option("--out", a->out, "Run directory (single run)");
      cmd->add_option("--experiment", a->experiment, "tracking | global | kidnap | noise");
      cmd->add_option("--runs", a->runs, "Runs per experiment (per noise level)")
          ->capture_default_str();
      cmd->add_option("--noise-levels", a->noise_levels,
                      "Noise experiment: comma-separated multiples of the world's a1..a4")
          ->capture_default_str();
      cmd->callback([a] { RunMclCommand(*a); });
    }};

}  // namespace
}  // namespace omnicml::app
