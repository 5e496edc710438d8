#include "omnicml/experiments/lap_bound.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <random>
#include <sstream>

#include <Eigen/QR>

#include "omnicml/common/common.h"
#include "omnicml/engine/pose_graph.h"
#include "omnicml/logs/antworld.h"
#include "omnicml/sim/simulator.h"
#include "omnicml/sim/world.h"

namespace omnicml {
namespace {

// sqrt(tr) of the xy block.
double PositionStd(const Eigen::Matrix3d& c) { return std::sqrt(std::max(0.0, c(0, 0) + c(1, 1))); }

// A p = (-y, x, 0): the lever of a unit turn about the origin at p (see the header).
Eigen::Vector3d Lever(const Pose2& p) { return Eigen::Vector3d(-p.y(), p.x(), 0.0); }

// b(q) = (q_y, -q_x, 1): a unit turn at pivot q moves pose t by Lever(p_t) + b(q).
Eigen::Vector3d PivotTerm(const Pose2& q) { return Eigen::Vector3d(q.y(), -q.x(), 1.0); }

double RootMeanSquare(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x * x;
  return v.empty() ? 0.0 : std::sqrt(s / static_cast<double>(v.size()));
}

LapBoundProfile ClosedForm(const std::vector<Pose2>& lap, const LapBoundOptions& options) {
  const std::size_t n = lap.size();
  const Pose2& end = lap.back();
  // Running sums over the steps j < t (header): S_tt = Q0 L L^T + L Q1^T + Q1 L^T + Q2 and
  // S_tT = L R1^T + R2 with L = Lever(p_t).
  double q0 = 0;
  Eigen::Vector3d q1 = Eigen::Vector3d::Zero();
  Eigen::Matrix3d q2 = Eigen::Matrix3d::Zero();
  Eigen::Vector3d r1 = Eigen::Vector3d::Zero();
  Eigen::Matrix3d r2 = Eigen::Matrix3d::Zero();
  std::vector<Eigen::Matrix3d> s_tt(n);
  std::vector<Eigen::Matrix3d> s_tend(n);
  const Eigen::Vector3d lever_end = Lever(end);
  for (std::size_t t = 0; t < n; ++t) {
    const Eigen::Vector3d l = Lever(lap[t]);
    s_tt[t] = q0 * l * l.transpose() + l * q1.transpose() + q1 * l.transpose() + q2;
    s_tend[t] = l * r1.transpose() + r2;
    if (t + 1 == n) break;
    const OdometryIncrement u = ComputeIncrement(lap[t], lap[t + 1]);
    const Eigen::Matrix3d m = MotionNoiseCovariance(u, options.noise);  // diag(rot1, trans, rot2)
    const double dir = lap[t].z() + u.rot1_rad;
    const Eigen::Vector3d d(std::cos(dir), std::sin(dir), 0.0);
    // rot1 turns about p_t, rot2 about p_t+1.
    for (const auto& [var, pivot] : {std::pair{m(0, 0), lap[t]}, std::pair{m(2, 2), lap[t + 1]}}) {
      const Eigen::Vector3d b = PivotTerm(pivot);
      q0 += var;
      q1 += var * b;
      q2 += var * b * b.transpose();
      const Eigen::Vector3d a_end = lever_end + b;  // per unit standard deviation squared
      r1 += var * a_end;
      r2 += var * b * a_end.transpose();
    }
    q2 += m(1, 1) * d * d.transpose();
    r2 += m(1, 1) * d * d.transpose();
  }
  LapBoundProfile p;
  p.odometry_std_m.resize(n);
  p.closed_std_m.resize(n);
  Eigen::Matrix3d innovation = s_tt.back();
  innovation(0, 0) += options.closure_sigma_m * options.closure_sigma_m;
  innovation(1, 1) += options.closure_sigma_m * options.closure_sigma_m;
  innovation(2, 2) += options.closure_sigma_rad * options.closure_sigma_rad;
  // A pseudo-inverse: with an exact closure and a direction the odometry cannot err in
  // (e.g. no translation noise on a straight lap), S_TT is singular, and S_tT lies in its
  // range, so conditioning on the observable part is what the pseudo-inverse does.
  Eigen::CompleteOrthogonalDecomposition<Eigen::Matrix3d> cod(innovation);
  cod.setThreshold(1e-12);
  for (std::size_t t = 0; t < n; ++t) {
    p.odometry_std_m[t] = PositionStd(s_tt[t]);
    const Eigen::Matrix3d c = s_tt[t] - s_tend[t] * cod.solve(s_tend[t].transpose());
    p.closed_std_m[t] = PositionStd(c);
  }
  return p;
}

LapBoundSample MonteCarlo(const std::vector<Pose2>& lap, const LapBoundOptions& options,
                          int sample) {
  PoseGraphOptions g;
  g.enabled = true;
  g.min_loop_frames = 1;
  g.closure_every_frames = 1;
  g.optimize_every_frames = 1;
  g.window_nodes = static_cast<int>(lap.size()) + 1;
  // PoseGraph adds these to the closure's covariance and requires them > 0. At least 1 cm
  // and 1 mrad: a stiffer closure (1e-4 m) made Levenberg-Marquardt fold the lap on some
  // realisations (store_large: 1 of 20 ended 49 m off; 5.5 m with 1 cm), and 1 cm is
  // nothing against metres of drift.
  g.closure_sigma_m = std::max(options.closure_sigma_m, 1e-2);
  g.closure_sigma_rad = std::max(options.closure_sigma_rad, 1e-3);
  g.loss_scale = 1e9;  // a trusted closure: no robust loss
  g.reject_chi2 = std::numeric_limits<double>::infinity();
  g.max_iterations = options.max_iterations;
  PoseGraph graph(g, options.noise, 1e-9, 1e-9, lap.size() + 1);
  std::mt19937_64 rng(MixSeed(options.seed, static_cast<std::uint64_t>(sample)));
  Gaussian start;
  start.mean = lap.front();
  start.covariance = Eigen::Vector3d(1e-8, 1e-8, 1e-10).asDiagonal();
  graph.BeginSession(false, 0, start);
  std::vector<Pose2> dead_reckoned;
  dead_reckoned.reserve(lap.size());
  Pose2 odom = lap.front();
  for (std::size_t i = 0; i < lap.size(); ++i) {
    OdometryIncrement u;
    if (i > 0) {
      u = SampleOdometryIncrement(ComputeIncrement(lap[i - 1], lap[i]), options.noise, rng);
      odom = ApplyIncrement(odom, u);
    }
    graph.AddFrameOdometry(static_cast<std::int64_t>(i), u);
    graph.AddNode(static_cast<std::int64_t>(i), odom, std::nullopt);
    dead_reckoned.push_back(odom);
  }
  const auto last = static_cast<std::int64_t>(lap.size() - 1);
  if (!graph.AddClosure(0, last, lap.back(), Eigen::Matrix3d::Zero())) {
    throw Error("ComputeLapBound: the pose graph refused the lap closure (internal error)");
  }
  graph.Optimize(last);
  LapBoundSample s;
  for (std::size_t i = 0; i < lap.size(); ++i) {
    const double odometry = (dead_reckoned[i].head<2>() - lap[i].head<2>()).norm();
    const double graph_error = (graph.nodes()[i].pose.head<2>() - lap[i].head<2>()).norm();
    s.odometry_mean_error_m += odometry;
    s.graph_mean_error_m += graph_error;
    s.odometry_rms_error_m += odometry * odometry;
    s.graph_rms_error_m += graph_error * graph_error;
  }
  const auto k = static_cast<double>(lap.size());
  s.odometry_mean_error_m /= k;
  s.graph_mean_error_m /= k;
  s.odometry_rms_error_m = std::sqrt(s.odometry_rms_error_m / k);
  s.graph_rms_error_m = std::sqrt(s.graph_rms_error_m / k);
  s.odometry_end_error_m = (dead_reckoned.back().head<2>() - lap.back().head<2>()).norm();
  return s;
}

}  // namespace

void LapBoundOptions::Validate() const {
  noise.Validate();
  auto fail = [](const char* field, const char* rule, auto value) {
    throw Error(StrCat("LapBoundOptions.", field, " must be ", rule, ", got ", value));
  };
  if (!(closure_sigma_m >= 0) || !std::isfinite(closure_sigma_m))
    fail("closure_sigma_m", "finite and >= 0", closure_sigma_m);
  if (!(closure_sigma_rad >= 0) || !std::isfinite(closure_sigma_rad))
    fail("closure_sigma_rad", "finite and >= 0", closure_sigma_rad);
  if (samples < 0) fail("samples", ">= 0", samples);
  if (max_iterations < 1) fail("max_iterations", ">= 1", max_iterations);
}

LapBoundResult ComputeLapBound(const std::vector<Pose2>& lap, const LapBoundOptions& options) {
  options.Validate();
  if (lap.size() < 3)
    throw Error(StrCat("ComputeLapBound: a lap needs at least 3 poses, got ", lap.size()));
  LapBoundResult r;
  r.poses = static_cast<int>(lap.size());
  for (std::size_t i = 1; i < lap.size(); ++i)
    r.length_m += (lap[i].head<2>() - lap[i - 1].head<2>()).norm();
  r.profile = ClosedForm(lap, options);
  r.odometry_rms_std_m = RootMeanSquare(r.profile.odometry_std_m);
  r.odometry_end_std_m = r.profile.odometry_std_m.back();
  r.closed_rms_std_m = RootMeanSquare(r.profile.closed_std_m);
  r.closed_max_std_m =
      *std::max_element(r.profile.closed_std_m.begin(), r.profile.closed_std_m.end());
  for (int s = 0; s < options.samples; ++s) {
    r.samples.push_back(MonteCarlo(lap, options, s));
    r.odometry_rms_error_m +=
        r.samples.back().odometry_rms_error_m * r.samples.back().odometry_rms_error_m;
    r.graph_rms_error_m += r.samples.back().graph_rms_error_m * r.samples.back().graph_rms_error_m;
  }
  if (!r.samples.empty()) {
    r.odometry_rms_error_m =
        std::sqrt(r.odometry_rms_error_m / static_cast<double>(r.samples.size()));
    r.graph_rms_error_m = std::sqrt(r.graph_rms_error_m / static_cast<double>(r.samples.size()));
  }
  return r;
}

std::vector<Pose2> ExtractFirstLap(const std::vector<Pose2>& trajectory, double tolerance_m,
                                   const std::string& what) {
  if (trajectory.size() < 3)
    throw Error(StrCat(what, ": a lap needs at least 3 poses, got ", trajectory.size()));
  const auto dist = [&](std::size_t i) {
    return (trajectory[i].head<2>() - trajectory[0].head<2>()).norm();
  };
  std::size_t far = 0;
  for (std::size_t i = 1; i < trajectory.size(); ++i) {
    if (dist(i) > dist(far)) far = i;
  }
  std::size_t back = far;
  for (std::size_t i = far; i < trajectory.size(); ++i) {
    if (dist(i) < dist(back)) back = i;
  }
  if (back < 2 || dist(back) > tolerance_m) {
    throw Error(StrCat(what, ": the trajectory does not come back to its start (nearest return ",
                       dist(back), " m after being ", dist(far), " m away; tolerance ", tolerance_m,
                       " m)"));
  }
  return {trajectory.begin(), trajectory.begin() + static_cast<std::ptrdiff_t>(back) + 1};
}

std::vector<Pose2> SampleRouteLap(const std::vector<Eigen::Vector2d>& waypoints_m,
                                  double turn_radius_m, double step_m) {
  if (!(step_m > 0) || !std::isfinite(step_m))
    throw Error(StrCat("SampleRouteLap: step_m must be > 0, got ", step_m));
  const RoutePath route(waypoints_m, turn_radius_m);
  const auto n = static_cast<long long>(std::llround(route.length_m() / step_m));
  if (n < 2)
    throw Error(
        StrCat("SampleRouteLap: the route (", route.length_m(), " m) is shorter than 2 steps"));
  std::vector<Pose2> lap;
  lap.reserve(static_cast<std::size_t>(n) + 1);
  for (long long i = 0; i <= n; ++i) lap.push_back(route.PoseAt(static_cast<double>(i) * step_m));
  return lap;
}

std::string FormatLapBound(const LapBoundResult& r, const LapBoundOptions& o) {
  std::ostringstream out;
  out.setf(std::ios::fixed);
  out.precision(2);
  out << "lap: " << r.length_m << " m, " << r.poses << " poses; odometry noise a1 "
      << StrCat(o.noise.a1) << " a2 " << StrCat(o.noise.a2) << " a3 " << StrCat(o.noise.a3)
      << " a4 " << StrCat(o.noise.a4) << "; closure sigma " << StrCat(o.closure_sigma_m) << " m, "
      << StrCat(o.closure_sigma_rad) << " rad\n";
  out << "closed form (linearised about the lap; position std sqrt(tr C_xy), metres):\n"
      << "  dead reckoning:           rms over the lap " << r.odometry_rms_std_m << ", at its end "
      << r.odometry_end_std_m << "\n"
      << "  after the lap's closure:  rms over the lap " << r.closed_rms_std_m << ", largest "
      << r.closed_max_std_m << "\n";
  if (!r.samples.empty()) {
    std::vector<double> odo, graph;
    int worse = 0;
    for (const LapBoundSample& s : r.samples) {
      odo.push_back(s.odometry_mean_error_m);
      graph.push_back(s.graph_mean_error_m);
      if (s.graph_mean_error_m > s.odometry_mean_error_m) ++worse;
    }
    const double k = static_cast<double>(r.samples.size());
    const auto row = [&](const char* name, std::vector<double> v, double rms) {
      std::sort(v.begin(), v.end());
      double sum = 0;
      for (double x : v) sum += x;
      out << name << sum / k << " / " << v[v.size() / 2] << " / " << v.back() << "    " << rms
          << "\n";
    };
    out << "Monte Carlo (" << r.samples.size() << " realisations, seed " << o.seed
        << "; position error over the lap's poses, metres):\n"
        << "  mean error per realisation: mean / median / worst; then rms over all realisations\n";
    row("  dead reckoning:          ", odo, r.odometry_rms_error_m);
    row("  pose graph, lap closed:  ", graph, r.graph_rms_error_m);
    if (worse > 0) {
      out << "  in " << worse << " of " << r.samples.size()
          << " realisations the closed lap's mean error exceeds dead reckoning's\n";
    }
  }
  return out.str();
}

}  // namespace omnicml
