// `omnicml lap-bound (--world W | LOG) [--step-m M] [--noise a1,a2,a3,a4] [--config ENGINE.yaml]
//                   [--samples N] [--seed S] [--closure-sigma-m M] [--closure-sigma-rad R]
//                   [--csv FILE]`:
// how accurate a map built on dead reckoning can become once its first lap closes
// (experiments/lap_bound.h): the closed-form position standard deviation along the lap
// before and after one exact closure, and a Monte Carlo of the engine's pose graph on
// sampled odometry. The lap is the world's route sampled every --step-m (the simulator's
// day 1), or the first lap of a log's first session's ground truth. The noise is --noise,
// else the world's odometry noise (the simulator's truth), else the engine's motion model
// (tracker.motion, from --config). --csv writes the per-pose profile.
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/experiments/lap_bound.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/run/run_config.h"
#include "omnicml/sim/world.h"

namespace omnicml::app {
namespace {

struct LapBoundFlags {
  std::string world;
  std::string log;
  double step_m = 0.2;
  std::vector<double> noise;  // a1, a2, a3, a4 (empty: the world's or the engine's)
  std::string config_path;
  std::string csv;
  LapBoundOptions options;
};

// The first session's ground truth of a log, poses only.
std::vector<Pose2> LogTruth(const std::string& dir) {
  LogReaderOptions o;
  o.load_images = false;
  LogReader reader(dir, o);
  std::vector<Pose2> truth;
  Frame f;
  while (reader.Next(&f) && f.session_index == 0) {
    if (!f.map_T_robot_truth) {
      throw Error(StrCat("lap-bound: ", dir, " session 1 frame ", f.index_in_session,
                         " has no ground truth (gt_x_m, gt_y_m, gt_phi_rad)"));
    }
    truth.push_back(*f.map_T_robot_truth);
  }
  return truth;
}

const CommandRegistration kRegistration{
    "lap-bound", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand(
          "lap-bound", "How accurate one loop closure can make a lap mapped on dead reckoning");
      auto f = std::make_shared<LapBoundFlags>();
      cmd->add_option("log", f->log, "Log whose first session's ground truth gives the lap");
      cmd->add_option("--world", f->world, "Built-in world or world file: its route is the lap");
      cmd->add_option("--step-m", f->step_m, "Distance between poses on the world's route, m")
          ->capture_default_str();
      cmd->add_option("--noise", f->noise,
                      "Odometry noise a1,a2,a3,a4 (default: the world's, else the engine's)")
          ->delimiter(',')
          ->expected(4);
      cmd->add_option("--config", f->config_path,
                      "Engine configuration (its tracker.motion is the default noise for a log)");
      cmd->add_option("--samples", f->options.samples,
                      "Monte Carlo realisations (0: closed form only)")
          ->capture_default_str();
      cmd->add_option("--seed", f->options.seed, "Seed of the realisations")->capture_default_str();
      cmd->add_option("--closure-sigma-m", f->options.closure_sigma_m,
                      "Closure position std, m (0: exact)")
          ->capture_default_str();
      cmd->add_option("--closure-sigma-rad", f->options.closure_sigma_rad,
                      "Closure heading std, rad (0: exact)")
          ->capture_default_str();
      cmd->add_option("--max-iterations", f->options.max_iterations,
                      "Pose-graph iterations per realisation")
          ->capture_default_str();
      AddOutputFile(
          cmd, "--csv", &f->csv,
          "Write the per-pose standard deviations (pose, x_m, y_m, odometry_std_m, closed_std_m)");
      cmd->callback([f] {
        if (f->world.empty() == f->log.empty())
          throw Error("lap-bound: give exactly one of --world W or a LOG directory");
        std::vector<Pose2> lap;
        std::string source;
        std::string noise_source;
        if (!f->world.empty()) {
          const World w = LoadWorld(f->world);
          lap = SampleRouteLap(w.route.waypoints_m, w.route.turn_radius_m, f->step_m);
          f->options.noise = w.odometry_noise;
          source = StrCat("world ", f->world, ", its route every ", f->step_m, " m");
          noise_source = "the world's odometry_noise";
        } else {
          const std::vector<Pose2> truth = LogTruth(f->log);
          double step = 0;
          for (std::size_t i = 1; i < truth.size(); ++i)
            step = std::max(step, (truth[i].head<2>() - truth[i - 1].head<2>()).norm());
          lap = ExtractFirstLap(truth, std::max(2 * step, 1e-3),
                                StrCat("lap-bound: ", f->log, " session 1"));
          OptionOverrides overrides;
          overrides.config_path = f->config_path;
          f->options.noise = ResolveEngineOptions(overrides).tracker.motion;
          source = StrCat("log ", f->log, ", session 1's first lap of ground truth");
          noise_source = "the engine's tracker.motion";
        }
        if (!f->noise.empty()) {
          f->options.noise = MotionNoise{f->noise[0], f->noise[1], f->noise[2], f->noise[3]};
          noise_source = "--noise";
        }
        const LapBoundResult r = ComputeLapBound(lap, f->options);
        std::cout << source << "; noise: " << noise_source << "\n" << FormatLapBound(r, f->options);
        if (!f->csv.empty()) {
          std::ostringstream out;
          out << "pose,x_m,y_m,odometry_std_m,closed_std_m\n";
          for (std::size_t i = 0; i < lap.size(); ++i) {
            out << i << "," << lap[i].x() << "," << lap[i].y() << "," << r.profile.odometry_std_m[i]
                << "," << r.profile.closed_std_m[i] << "\n";
          }
          WriteFileAtomic(f->csv, out.str());
          std::cout << "written: " << f->csv << "\n";
        }
      });
    }};

}  // namespace
}  // namespace omnicml::app
