#include "omnicml/evaluation/trajectory_metrics.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

std::string Num(double v, int decimals) {
  if (!std::isfinite(v)) return "-";
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

}  // namespace

EvoStats ComputeEvoStats(const std::vector<double>& values) {
  std::vector<double> v;
  v.reserve(values.size());
  for (double x : values) {
    if (std::isfinite(x)) v.push_back(x);
  }
  EvoStats s;
  s.count = static_cast<int>(v.size());
  if (v.empty()) return s;
  std::sort(v.begin(), v.end());
  const double n = static_cast<double>(v.size());
  double sum = 0, sum_sq = 0;
  for (double x : v) sum += x, sum_sq += x * x;
  s.mean = sum / n;
  s.rmse = std::sqrt(sum_sq / n);
  double var = 0;
  for (double x : v) var += (x - s.mean) * (x - s.mean);
  s.std = std::sqrt(var / n);
  s.median = Quantile(v, 0.5);
  s.min = v.front();
  s.max = v.back();
  return s;
}

void TrajectoryMetricsOptions::Validate() const {
  if (!(rpe_delta_m > 0) || !std::isfinite(rpe_delta_m))
    throw Error(StrCat("rpe_delta_m must be a positive number of metres (got ", rpe_delta_m, ")"));
}

std::vector<std::pair<std::size_t, std::size_t>> RpePairsByPath(
    const std::vector<Eigen::Vector2d>& positions, double delta_m) {
  // evo filters.filter_pairs_by_path (all_pairs=False).
  std::vector<std::size_t> ids;
  double path = 0;
  for (std::size_t i = 0; i < positions.size(); ++i) {
    if (i > 0) path += (positions[i] - positions[i - 1]).norm();
    if (path >= delta_m) {
      ids.push_back(i);
      path = 0;
    }
  }
  std::vector<std::pair<std::size_t, std::size_t>> pairs;
  for (std::size_t k = 1; k < ids.size(); ++k) pairs.emplace_back(ids[k - 1], ids[k]);
  return pairs;
}

TrajectoryMetrics ComputeTrajectoryMetrics(const std::vector<FrameRecord>& records,
                                           const TrajectoryMetricsOptions& options, int session) {
  options.Validate();
  TrajectoryMetrics m;
  m.rpe_delta_m = options.rpe_delta_m;
  std::vector<double> ape, heading, rpe_t, rpe_r;
  // Per session: the localized frames with ground truth, in order.
  std::vector<const FrameRecord*> sequence;
  auto flush_session = [&] {
    std::vector<Eigen::Vector2d> positions;
    positions.reserve(sequence.size());
    for (const FrameRecord* r : sequence) positions.push_back(r->truth.head<2>());
    for (const auto& [i, j] : RpePairsByPath(positions, options.rpe_delta_m)) {
      const Pose2 truth_rel = Between(sequence[i]->truth, sequence[j]->truth);
      const Pose2 est_rel = Between(sequence[i]->estimate, sequence[j]->estimate);
      const Pose2 e = Between(truth_rel, est_rel);
      rpe_t.push_back(e.head<2>().norm());
      rpe_r.push_back(std::abs(WrapAngle(e.z())) * 180.0 / kPi);
    }
    sequence.clear();
  };
  int current = -1;
  for (const FrameRecord& r : records) {
    if (session >= 0 && r.session != session) continue;
    if (r.session != current) {
      flush_session();
      current = r.session;
    }
    ++m.frames;
    if (!r.has_estimate || !r.has_truth) continue;
    ++m.frames_evaluated;
    ape.push_back((r.estimate.head<2>() - r.truth.head<2>()).norm());
    heading.push_back(std::abs(WrapAngle(r.estimate.z() - r.truth.z())) * 180.0 / kPi);
    sequence.push_back(&r);
  }
  flush_session();
  m.ape_m = ComputeEvoStats(ape);
  m.ape_heading_deg = ComputeEvoStats(heading);
  m.rpe_translation_m = ComputeEvoStats(rpe_t);
  m.rpe_rotation_deg = ComputeEvoStats(rpe_r);
  m.rpe_pairs = m.rpe_translation_m.count;
  m.drift_percent = 100.0 * m.rpe_translation_m.rmse / options.rpe_delta_m;
  m.rotation_drift_deg_per_m = m.rpe_rotation_deg.rmse / options.rpe_delta_m;
  return m;
}

int AssociateGroundTruth(std::vector<FrameRecord>* records, const std::vector<TimedPose>& reference,
                         double max_time_diff_s) {
  if (!(max_time_diff_s >= 0) || !std::isfinite(max_time_diff_s))
    throw Error(StrCat("--max-time-diff must be >= 0 seconds (got ", max_time_diff_s, ")"));
  std::vector<TimedPose> ref = reference;
  std::stable_sort(ref.begin(), ref.end(),
                   [](const TimedPose& a, const TimedPose& b) { return a.stamp_s < b.stamp_s; });
  int matched = 0;
  for (FrameRecord& r : *records) {
    const double t = std::isfinite(r.run_stamp_s) ? r.run_stamp_s : r.stamp_s;
    r.has_truth = false;
    r.truth = Pose2::Zero();
    r.odometry_error_m = kNaN;
    if (ref.empty()) continue;
    auto it = std::lower_bound(ref.begin(), ref.end(), t,
                               [](const TimedPose& p, double s) { return p.stamp_s < s; });
    const TimedPose* best = nullptr;
    if (it != ref.end()) best = &*it;
    if (it != ref.begin()) {
      const TimedPose* before = &*(it - 1);
      // Ties go to the earlier reference pose (numpy.argmin returns the first minimum).
      if (best == nullptr || std::abs(t - before->stamp_s) <= std::abs(best->stamp_s - t))
        best = before;
    }
    if (std::abs(best->stamp_s - t) <= max_time_diff_s) {
      r.has_truth = true;
      r.truth = best->pose;
      ++matched;
    }
  }
  RecomputeErrors(records);
  return matched;
}

std::vector<FrameRecord> RecordsFromTum(const std::vector<TimedPose>& estimate) {
  std::vector<FrameRecord> out;
  out.reserve(estimate.size());
  for (std::size_t i = 0; i < estimate.size(); ++i) {
    FrameRecord r;
    r.frame = static_cast<std::int64_t>(i);
    r.global_frame = static_cast<std::int64_t>(i);
    r.stamp_s = estimate[i].stamp_s;
    r.run_stamp_s = estimate[i].stamp_s;
    r.has_estimate = true;
    r.estimate = estimate[i].pose;
    r.mean_estimate = estimate[i].pose;
    out.push_back(r);
  }
  return out;
}

std::pair<std::vector<std::string>, std::vector<std::vector<std::string>>> TrajectoryMetricsTable(
    const TrajectoryMetrics& m) {
  std::vector<std::string> header = {"figure", "unit", "count", "rmse", "mean",
                                     "median", "std",  "min",   "max"};
  std::vector<std::vector<std::string>> rows;
  auto row = [&](const std::string& name, const std::string& unit, const EvoStats& s, int dec) {
    rows.push_back({name, unit, std::to_string(s.count), Num(s.rmse, dec), Num(s.mean, dec),
                    Num(s.median, dec), Num(s.std, dec), Num(s.min, dec), Num(s.max, dec)});
  };
  const std::string per = "per " + Num(m.rpe_delta_m, 2) + " m";
  row("APE position", "m", m.ape_m, 3);
  row("APE heading", "deg", m.ape_heading_deg, 2);
  row("RPE translation", "m " + per, m.rpe_translation_m, 3);
  row("RPE rotation", "deg " + per, m.rpe_rotation_deg, 2);
  return {header, rows};
}

std::string FormatTrajectoryMetrics(const TrajectoryMetrics& m) {
  std::ostringstream os;
  os << "APE (evo_ape, translation): over " << m.frames_evaluated << " of " << m.frames
     << " frames (localized with ground truth)\n";
  os << "RPE (evo_rpe --delta " << Num(m.rpe_delta_m, 2)
     << " --delta_unit m, pairs within a day): " << m.rpe_pairs << " pairs; drift "
     << Num(m.drift_percent, 2) << " % (m per m), " << Num(m.rotation_drift_deg_per_m, 3)
     << " deg/m (RMSE / delta)\n";
  const auto [header, rows] = TrajectoryMetricsTable(m);
  os << FormatTextTable(header, rows, /*left_align_first=*/true);
  return os.str();
}

}  // namespace omnicml
