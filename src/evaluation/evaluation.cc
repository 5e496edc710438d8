#include "omnicml/evaluation/evaluation.h"
#include "omnicml/evaluation/trajectory_metrics.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>

#include <Eigen/Geometry>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/geometry/chi_square.h"
#include "omnicml/report/map_export.h"
#include "omnicml/report/report.h"
#include "omnicml/report/svg_plot.h"

namespace omnicml {
namespace fs = std::filesystem;

namespace {

const std::vector<std::string>& FixedColumns() {
  static const std::vector<std::string> kColumns = {
      "session",           "frame",         "global_frame",     "stamp_s",
      "est_x_m",           "est_y_m",       "est_phi_rad",      "mean_x_m",
      "mean_y_m",          "mean_phi_rad",  "unimodal",         "truth_x_m",
      "truth_y_m",         "truth_phi_rad", "position_error_m", "heading_error_rad",
      "odometry_error_m",  "views",         "map_components",   "hypotheses",
      "mixture_components"};
  return kColumns;
}

// Columns added after the fixed ones and the stage timings; optional when reading.
const std::vector<std::string>& LaterColumns() {
  static const std::vector<std::string> kColumns = {
      "localized", "run_stamp_s", "odom_x_m",      "odom_y_m",   "odom_phi_rad", "cov_xx_m2",
      "cov_xy_m2", "cov_yy_m2",   "var_phi_rad2",  "nees_xy",    "matches",      "best_similarity",
      "nees_phi",  "nis",         "prior_nees_xy", "fix_nees_xy"};
  return kColumns;
}

std::vector<std::string> SplitCsv(const std::string& line) {
  std::vector<std::string> cells;
  std::string cell;
  for (char c : line) {
    if (c == ',') {
      cells.push_back(cell);
      cell.clear();
    } else if (c != '\r') {
      cell += c;
    }
  }
  cells.push_back(cell);
  return cells;
}

std::string Fixed(double v, int decimals) {
  if (!std::isfinite(v)) return "-";
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

}  // namespace

void WriteFramesCsvHeader(std::ostream& os, const std::vector<std::string>& stage_names) {
  const auto& cols = FixedColumns();
  for (std::size_t i = 0; i < cols.size(); ++i) os << (i ? "," : "") << cols[i];
  for (const auto& s : stage_names) os << ",time_" << s << "_us";
  for (const auto& c : LaterColumns()) os << ',' << c;
  os << "\n";
}

void WriteFramesCsvRow(std::ostream& os, const FrameRecord& r) {
  os << r.session << ',' << r.frame << ',' << r.global_frame << ',' << ShortestDouble(r.stamp_s)
     << ',';
  if (r.has_estimate) {
    os << ShortestDouble(r.estimate.x()) << ',' << ShortestDouble(r.estimate.y()) << ','
       << ShortestDouble(r.estimate.z()) << ',' << ShortestDouble(r.mean_estimate.x()) << ','
       << ShortestDouble(r.mean_estimate.y()) << ',' << ShortestDouble(r.mean_estimate.z()) << ',';
  } else {
    os << ",,,,,,";
  }
  os << (r.unimodal ? 1 : 0) << ',';
  if (r.has_truth) {
    os << ShortestDouble(r.truth.x()) << ',' << ShortestDouble(r.truth.y()) << ','
       << ShortestDouble(r.truth.z()) << ',';
  } else {
    os << ",,,";
  }
  os << ShortestDouble(r.position_error_m) << ',' << ShortestDouble(r.heading_error_rad) << ','
     << ShortestDouble(r.odometry_error_m) << ',' << r.views << ',' << r.map_components << ','
     << r.hypotheses << ',' << r.mixture_components;
  for (double t : r.stage_times_us) os << ',' << ShortestDouble(t);
  os << ',' << (r.has_estimate ? 1 : 0) << ','
     << ShortestDouble(std::isfinite(r.run_stamp_s) ? r.run_stamp_s : r.stamp_s) << ',';
  if (r.has_odometry) {
    os << ShortestDouble(r.odometry.x()) << ',' << ShortestDouble(r.odometry.y()) << ','
       << ShortestDouble(r.odometry.z());
  } else {
    os << ",,";
  }
  // ShortestDouble writes "" for NaN, so unknown covariances and NEES stay empty.
  os << ',' << ShortestDouble(r.cov_xx_m2) << ',' << ShortestDouble(r.cov_xy_m2) << ','
     << ShortestDouble(r.cov_yy_m2) << ',' << ShortestDouble(r.var_phi_rad2) << ','
     << ShortestDouble(r.nees_xy);
  os << ',';
  if (r.matches >= 0) os << r.matches;
  os << ',' << ShortestDouble(r.best_similarity);
  os << ',' << ShortestDouble(r.nees_phi) << ',' << ShortestDouble(r.nis) << ','
     << ShortestDouble(r.prior_nees_xy) << ',' << ShortestDouble(r.fix_nees_xy);
  os << '\n';
}

FramesTable ReadFramesCsv(const fs::path& path) {
  LineReader in(path, "run frames");  // a regular file, bounded lines
  std::string line;
  if (!in.Next(&line)) throw Error(StrCat(path.string(), ":1: empty file, expected a header"));
  const std::vector<std::string> header = SplitCsv(line);
  std::map<std::string, std::size_t> col;
  for (std::size_t i = 0; i < header.size(); ++i) col[header[i]] = i;
  for (const auto& name : FixedColumns()) {
    if (!col.count(name)) {
      throw Error(StrCat(path.string(), ":1: missing column '", name, "'"));
    }
  }
  FramesTable table;
  std::vector<std::size_t> time_cols;
  for (std::size_t i = 0; i < header.size(); ++i) {
    const std::string& h = header[i];
    if (h.size() > 8 && h.rfind("time_", 0) == 0 && h.substr(h.size() - 3) == "_us") {
      table.stage_names.push_back(h.substr(5, h.size() - 8));
      time_cols.push_back(i);
    }
  }
  // Rows must hold every fixed and timing column; the later columns may be missing.
  std::size_t required_cells = 0;
  for (const auto& name : FixedColumns()) required_cells = std::max(required_cells, col[name] + 1);
  for (std::size_t c : time_cols) required_cells = std::max(required_cells, c + 1);
  const std::string kEmpty;
  int line_no = 1;
  while (in.Next(&line)) {
    ++line_no;
    if (line.empty() || line == "\r") continue;
    const std::vector<std::string> cells = SplitCsv(line);
    if (cells.size() < required_cells) {
      throw Error(StrCat(path.string(), ":", line_no, ": ", cells.size(), " cells, expected ",
                         header.size()));
    }
    auto num = [&](const std::string& name) -> double {
      const std::size_t c = col.at(name);
      const std::string& s = c < cells.size() ? cells[c] : kEmpty;
      if (s.empty()) return kNaN;
      char* end = nullptr;
      const double v = std::strtod(s.c_str(), &end);
      if (end == s.c_str() || *end != '\0') {
        throw Error(StrCat(path.string(), ":", line_no, ": column '", name, "': cannot parse '",
                           Excerpt(s), "'"));
      }
      return v;
    };
    auto integer = [&](const std::string& name) -> std::int64_t {
      const double v = num(name);
      if (!std::isfinite(v)) {
        throw Error(StrCat(path.string(), ":", line_no, ": column '", name, "' must not be empty"));
      }
      return static_cast<std::int64_t>(v);
    };
    FrameRecord r;
    r.session = static_cast<int>(integer("session"));
    r.frame = integer("frame");
    r.global_frame = integer("global_frame");
    r.stamp_s = num("stamp_s");
    if (col.count("run_stamp_s")) r.run_stamp_s = num("run_stamp_s");
    if (col.count("odom_x_m") && col.count("odom_y_m") && col.count("odom_phi_rad")) {
      const double ox = num("odom_x_m"), oy = num("odom_y_m"), ophi = num("odom_phi_rad");
      r.has_odometry = std::isfinite(ox) && std::isfinite(oy) && std::isfinite(ophi);
      if (r.has_odometry) r.odometry = Pose2(ox, oy, ophi);
    }
    if (col.count("cov_xx_m2") && col.count("cov_xy_m2") && col.count("cov_yy_m2") &&
        col.count("var_phi_rad2")) {
      r.cov_xx_m2 = num("cov_xx_m2");
      r.cov_xy_m2 = num("cov_xy_m2");
      r.cov_yy_m2 = num("cov_yy_m2");
      r.var_phi_rad2 = num("var_phi_rad2");
    }
    if (col.count("nees_xy")) r.nees_xy = num("nees_xy");
    if (col.count("matches")) {
      const double m = num("matches");
      if (std::isfinite(m)) {
        if (m < 0 || m != std::floor(m)) {
          throw Error(StrCat(path.string(), ":", line_no,
                             ": column 'matches' must be a count, got '",
                             Excerpt(cells[col.at("matches")]), "'"));
        }
        r.matches = static_cast<int>(m);
      }
    }
    if (col.count("best_similarity")) r.best_similarity = num("best_similarity");
    if (col.count("nees_phi")) r.nees_phi = num("nees_phi");
    if (col.count("nis")) r.nis = num("nis");
    if (col.count("prior_nees_xy")) r.prior_nees_xy = num("prior_nees_xy");
    if (col.count("fix_nees_xy")) r.fix_nees_xy = num("fix_nees_xy");
    const double ex = num("est_x_m"), ey = num("est_y_m"), ephi = num("est_phi_rad");
    r.has_estimate = std::isfinite(ex) && std::isfinite(ey) && std::isfinite(ephi);
    if (r.has_estimate) {
      r.estimate = Pose2(ex, ey, ephi);
      r.mean_estimate = Pose2(num("mean_x_m"), num("mean_y_m"), num("mean_phi_rad"));
    }
    r.unimodal = integer("unimodal") != 0;
    const double tx = num("truth_x_m"), ty = num("truth_y_m"), tphi = num("truth_phi_rad");
    r.has_truth = std::isfinite(tx) && std::isfinite(ty) && std::isfinite(tphi);
    if (r.has_truth) r.truth = Pose2(tx, ty, tphi);
    r.position_error_m = num("position_error_m");
    r.heading_error_rad = num("heading_error_rad");
    r.odometry_error_m = num("odometry_error_m");
    r.views = static_cast<int>(integer("views"));
    r.map_components = static_cast<int>(integer("map_components"));
    r.hypotheses = static_cast<int>(integer("hypotheses"));
    r.mixture_components = static_cast<int>(integer("mixture_components"));
    for (std::size_t k = 0; k < time_cols.size(); ++k) {
      r.stage_times_us.push_back(num(header[time_cols[k]]));
    }
    table.records.push_back(std::move(r));
  }
  return table;
}

void ReadSkippedFrames(const fs::path& days_csv, FramesTable* table) {
  table->skipped_frames.clear();
  std::error_code ec;
  if (!fs::exists(days_csv, ec)) return;
  LineReader in(days_csv, "run days");
  std::string line;
  if (!in.Next(&line)) return;
  const std::vector<std::string> header = SplitCsv(line);
  const auto session_it = std::find(header.begin(), header.end(), "session");
  const auto skipped_it = std::find(header.begin(), header.end(), "frames_skipped");
  if (session_it == header.end() || skipped_it == header.end()) return;
  const std::size_t session_col = static_cast<std::size_t>(session_it - header.begin());
  const std::size_t skipped_col = static_cast<std::size_t>(skipped_it - header.begin());
  while (in.Next(&line)) {
    const std::size_t line_no = in.line_number();
    if (line.empty()) continue;
    const std::vector<std::string> cells = SplitCsv(line);
    auto integer = [&](std::size_t c, const char* name) -> std::int64_t {
      const std::string s = c < cells.size() ? cells[c] : std::string();
      char* end = nullptr;
      const long long v = std::strtoll(s.c_str(), &end, 10);
      if (s.empty() || *end != '\0' || v < 0) {
        throw Error(StrCat(days_csv.string(), ":", line_no, ": column '", name, "': cannot parse '",
                           s, "'"));
      }
      return v;
    };
    const std::int64_t skipped = integer(skipped_col, "frames_skipped");
    const int session = static_cast<int>(integer(session_col, "session"));
    if (skipped > 0) table->skipped_frames[session] += skipped;
  }
}

double RunStampClock::Next(int session, double stamp_s) {
  if (session != session_) {
    if (session_ >= 0 && have_last_) {
      // The previous session's frame period; 1 s when it had a single frame.
      double period = 1.0;
      if (session_frames_ >= 2) {
        const double p = (session_last_stamp_s_ - session_first_stamp_s_) /
                         static_cast<double>(session_frames_ - 1);
        if (std::isfinite(p) && p > 0) period = p;
      }
      offset_s_ = stamp_s > last_run_stamp_s_ ? 0.0 : last_run_stamp_s_ + period - stamp_s;
    } else {
      offset_s_ = 0.0;
    }
    session_ = session;
    session_first_stamp_s_ = stamp_s;
    session_frames_ = 0;
  }
  session_last_stamp_s_ = stamp_s;
  ++session_frames_;
  last_run_stamp_s_ = stamp_s + offset_s_;
  have_last_ = true;
  return last_run_stamp_s_;
}

namespace {
const Pose2* TumPose(const FrameRecord& r, TumContent content) {
  if (!r.has_estimate) return nullptr;
  switch (content) {
    case TumContent::kEstimate:
      return &r.estimate;
    case TumContent::kGroundTruth:
      return r.has_truth ? &r.truth : nullptr;
    case TumContent::kOdometry:
      return r.has_odometry ? &r.odometry : nullptr;
  }
  return nullptr;
}
}  // namespace

void WriteTum(std::ostream& os, const std::vector<FrameRecord>& records, TumContent content) {
  static const char* const kWhat[] = {"estimate (strongest component)", "ground truth",
                                      "odometry (as logged)"};
  os << "# omnicml " << kWhat[static_cast<int>(content)]
     << " (TUM): stamp x y z qx qy qz qw; run-unique stamps; localized frames only\n";
  for (const FrameRecord& r : records) {
    const Pose2* pose = TumPose(r, content);
    if (pose == nullptr) continue;
    os << TumLine(std::isfinite(r.run_stamp_s) ? r.run_stamp_s : r.stamp_s, *pose) << '\n';
  }
}

bool HasTumContent(const std::vector<FrameRecord>& records, TumContent content) {
  for (const FrameRecord& r : records) {
    if (TumPose(r, content) != nullptr) return true;
  }
  return false;
}

double PositionNees(double ex, double ey, double a, double b, double d) {
  const double det = a * d - b * b;
  // Not SPD (or unknown: NaN compares false): no NEES.
  if (!(a > 0 && d > 0 && det > 0) || !std::isfinite(ex) || !std::isfinite(ey)) return kNaN;
  // e^T C^-1 e with C^-1 = [d -b; -b a] / det.
  return (d * ex * ex - 2 * b * ex * ey + a * ey * ey) / det;
}

double PositionNees(const FrameRecord& r) {
  if (!(r.has_estimate && r.has_truth)) return kNaN;
  const Eigen::Vector2d e = r.estimate.head<2>() - r.truth.head<2>();
  return PositionNees(e.x(), e.y(), r.cov_xx_m2, r.cov_xy_m2, r.cov_yy_m2);
}

double HeadingNees(const FrameRecord& r) {
  if (!(r.has_estimate && r.has_truth) || !(r.var_phi_rad2 > 0)) return kNaN;
  const double e = WrapAngle(r.estimate.z() - r.truth.z());
  return e * e / r.var_phi_rad2;
}

double FractionInChiSquareBand(const std::vector<double>& values, int dof) {
  const ChiSquareBand band = ChiSquareTwoSidedBand(0.95, dof);
  int finite = 0, inside = 0;
  for (double v : values) {
    if (!std::isfinite(v)) continue;
    ++finite;
    if (v >= band.lower && v <= band.upper) ++inside;
  }
  return finite > 0 ? static_cast<double>(inside) / finite : kNaN;
}

void ComputeErrors(FrameRecord* record) {
  FrameRecord& r = *record;
  if (r.has_estimate && r.has_truth) {
    r.position_error_m = (r.estimate.head<2>() - r.truth.head<2>()).norm();
    r.heading_error_rad = std::abs(WrapAngle(r.estimate.z() - r.truth.z()));
  } else {
    r.position_error_m = kNaN;
    r.heading_error_rad = kNaN;
  }
  r.nees_xy = PositionNees(r);
  r.nees_phi = HeadingNees(r);
}

void RecomputeErrors(std::vector<FrameRecord>* records) {
  for (FrameRecord& r : *records) ComputeErrors(&r);
}

std::string ToString(Alignment alignment) {
  switch (alignment) {
    case Alignment::kNone:
      return "none";
    case Alignment::kStart:
      return "start";
    case Alignment::kSe2:
      return "se2";
  }
  return "none";
}

Alignment AlignmentFromString(const std::string& s) {
  if (s == "none") return Alignment::kNone;
  if (s == "start") return Alignment::kStart;
  if (s == "se2") return Alignment::kSe2;
  throw Error(StrCat("unknown alignment '", s, "' (expected none, start or se2)"));
}

Pose2 Align(std::vector<FrameRecord>* records, Alignment alignment) {
  Pose2 transform = Pose2::Zero();
  auto apply = [](const Pose2& t, FrameRecord* r) {
    r->estimate = Compose(t, r->estimate);
    r->mean_estimate = Compose(t, r->mean_estimate);
    // The covariance turns with the estimate: C' = R C R^T (heading variance unchanged).
    Eigen::Matrix2d c;
    c << r->cov_xx_m2, r->cov_xy_m2, r->cov_xy_m2, r->cov_yy_m2;
    const Eigen::Matrix2d rot = Eigen::Rotation2Dd(t.z()).toRotationMatrix();
    const Eigen::Matrix2d turned = rot * c * rot.transpose();
    r->cov_xx_m2 = turned(0, 0);
    r->cov_xy_m2 = turned(0, 1);
    r->cov_yy_m2 = turned(1, 1);
    // The prior's and the fix's NEES compare their own means with the truth; the records
    // keep the statistics, not those means, so they cannot be moved with the estimate.
    // Left out rather than reported in the unaligned frame next to aligned values.
    r->prior_nees_xy = kNaN;
    r->fix_nees_xy = kNaN;
  };
  if (alignment == Alignment::kStart) {
    std::map<int, Pose2> per_session;
    for (FrameRecord& r : *records) {
      if (!r.has_estimate) continue;
      auto it = per_session.find(r.session);
      if (it == per_session.end()) {
        if (!r.has_truth) continue;
        // T such that Compose(T, estimate) == truth.
        it = per_session.emplace(r.session, Compose(r.truth, Between(r.estimate, Pose2::Zero())))
                 .first;
      }
      apply(it->second, &r);
    }
  } else if (alignment == Alignment::kSe2) {
    std::vector<const FrameRecord*> pairs;
    for (const FrameRecord& r : *records) {
      if (r.has_estimate && r.has_truth) pairs.push_back(&r);
    }
    if (pairs.size() < 2) {
      throw Error("se2 alignment needs at least two frames with estimate and ground truth");
    }
    Eigen::Matrix2Xd src(2, pairs.size()), dst(2, pairs.size());
    for (std::size_t i = 0; i < pairs.size(); ++i) {
      src.col(static_cast<Eigen::Index>(i)) = pairs[i]->estimate.head<2>();
      dst.col(static_cast<Eigen::Index>(i)) = pairs[i]->truth.head<2>();
    }
    const double spread = (src.colwise() - src.rowwise().mean()).norm();
    if (spread < 1e-9) {
      throw Error("se2 alignment needs estimates at distinct positions");
    }
    // Umeyama/Horn least-squares rigid alignment, no scale.
    const Eigen::Matrix3d t = Eigen::umeyama(src, dst, false);
    transform = Pose2(t(0, 2), t(1, 2), std::atan2(t(1, 0), t(0, 0)));
    for (FrameRecord& r : *records) {
      if (r.has_estimate) apply(transform, &r);
    }
  }
  RecomputeErrors(records);
  return transform;
}

double Quantile(const std::vector<double>& sorted, double q) {
  if (sorted.empty()) return kNaN;
  q = std::clamp(q, 0.0, 1.0);
  const double pos = q * static_cast<double>(sorted.size() - 1);
  const std::size_t lo = static_cast<std::size_t>(std::floor(pos));
  const std::size_t hi = std::min(lo + 1, sorted.size() - 1);
  const double frac = pos - static_cast<double>(lo);
  return sorted[lo] + frac * (sorted[hi] - sorted[lo]);
}

ErrorStats ComputeStats(std::vector<double> values) {
  values.erase(
      std::remove_if(values.begin(), values.end(), [](double v) { return !std::isfinite(v); }),
      values.end());
  ErrorStats s;
  s.count = static_cast<int>(values.size());
  if (values.empty()) return s;
  std::sort(values.begin(), values.end());
  double sum = 0, sum_sq = 0;
  for (double v : values) sum += v, sum_sq += v * v;
  s.mean = sum / static_cast<double>(values.size());
  s.rmse = std::sqrt(sum_sq / static_cast<double>(values.size()));
  s.median = Quantile(values, 0.5);
  s.p95 = Quantile(values, 0.95);
  s.max = values.back();
  return s;
}

std::vector<double> HistogramCounts(const std::vector<double>& values,
                                    const std::vector<double>& edges) {
  if (edges.size() < 2) return {};
  std::vector<double> counts(edges.size() - 1, 0.0);
  for (double v : values) {
    if (!std::isfinite(v) || v < edges.front()) continue;
    auto it = std::upper_bound(edges.begin(), edges.end(), v);
    std::size_t bin = static_cast<std::size_t>(it - edges.begin()) - 1;
    bin = std::min(bin, counts.size() - 1);
    counts[bin] += 1;
  }
  return counts;
}

DayEvaluation EvaluateDay(const std::vector<FrameRecord>& records, int session,
                          const std::vector<std::string>& stage_names,
                          const std::map<int, std::int64_t>& skipped_frames) {
  DayEvaluation d;
  d.session = session;
  for (const auto& [s, n] : skipped_frames) {
    if (session < 0 || s == session) d.frames_skipped += n;
  }
  std::vector<double> pos, head, odo, times, nees, nees_phi, nis, prior_nees, fix_nees;
  int unimodal = 0;
  std::size_t total_col = stage_names.size();
  for (std::size_t i = 0; i < stage_names.size(); ++i) {
    if (stage_names[i] == "total") total_col = i;
  }
  for (const FrameRecord& r : records) {
    if (session >= 0 && r.session != session) continue;
    ++d.frames;
    if (r.has_truth) ++d.frames_with_truth;
    if (r.has_estimate) ++d.frames_with_estimate;
    if (r.unimodal) ++unimodal;
    pos.push_back(r.position_error_m);
    head.push_back(r.heading_error_rad);
    odo.push_back(r.odometry_error_m);
    nees.push_back(r.nees_xy);
    nees_phi.push_back(r.nees_phi);
    nis.push_back(r.nis);
    prior_nees.push_back(r.prior_nees_xy);
    fix_nees.push_back(r.fix_nees_xy);
    if (total_col < r.stage_times_us.size()) times.push_back(r.stage_times_us[total_col]);
    d.views_at_end = r.views;
    d.map_components_at_end = r.map_components;
  }
  if (d.frames > 0) d.unimodal_fraction = static_cast<double>(unimodal) / d.frames;
  d.frames_unlocalized = d.frames - d.frames_with_estimate;
  if (d.frames > 0) d.coverage = static_cast<double>(d.frames_with_estimate) / d.frames;
  d.position_m = ComputeStats(pos);
  d.heading_rad = ComputeStats(head);
  d.odometry_m = ComputeStats(odo);
  d.nees_xy = ComputeStats(nees);
  d.nees_phi = ComputeStats(nees_phi);
  d.nis = ComputeStats(nis);
  d.prior_nees_xy = ComputeStats(prior_nees);
  d.fix_nees_xy = ComputeStats(fix_nees);
  d.nees_xy_in_band = FractionInChiSquareBand(nees, 2);
  d.nees_phi_in_band = FractionInChiSquareBand(nees_phi, 1);
  d.nis_in_band = FractionInChiSquareBand(nis, 3);
  d.mean_frame_time_us = ComputeStats(times).mean;
  return d;
}

EvaluationResult Evaluate(const FramesTable& table, Alignment alignment, int histogram_bins) {
  EvaluationResult result;
  result.alignment = alignment;
  std::vector<FrameRecord> records = table.records;
  result.alignment_transform = Align(&records, alignment);
  std::vector<int> sessions;
  for (const FrameRecord& r : records) {
    if (sessions.empty() || sessions.back() != r.session) {
      if (std::find(sessions.begin(), sessions.end(), r.session) == sessions.end()) {
        sessions.push_back(r.session);
      }
    }
  }
  std::sort(sessions.begin(), sessions.end());
  for (int s : sessions)
    result.days.push_back(EvaluateDay(records, s, table.stage_names, table.skipped_frames));
  result.overall = EvaluateDay(records, -1, table.stage_names, table.skipped_frames);

  // Common bins: 0 .. the run's p99 (rounded up to a nice value), so outliers do not
  // squash the histogram; larger errors land in the last bin.
  histogram_bins = std::max(1, histogram_bins);
  auto make_edges = [&](const std::vector<double>& all, double fallback) {
    std::vector<double> finite;
    for (double v : all) {
      if (std::isfinite(v)) finite.push_back(v);
    }
    std::sort(finite.begin(), finite.end());
    double hi = finite.empty() ? fallback : Quantile(finite, 0.99);
    if (!(hi > 0)) hi = fallback;
    // A round bin width (1, 2, 2.5 or 5 x 10^k) giving at most histogram_bins bins.
    const double raw = hi / histogram_bins;
    const double magnitude = std::pow(10.0, std::floor(std::log10(raw)));
    double width = 10 * magnitude;
    for (double m : {1.0, 2.0, 2.5, 5.0}) {
      if (m * magnitude >= raw * (1 - 1e-9)) {
        width = m * magnitude;
        break;
      }
    }
    const int n = std::max(1, static_cast<int>(std::ceil(hi / width - 1e-9)));
    std::vector<double> edges(static_cast<std::size_t>(n) + 1);
    for (int i = 0; i <= n; ++i) edges[static_cast<std::size_t>(i)] = width * i;
    return edges;
  };
  std::vector<double> all_pos, all_head;
  for (const FrameRecord& r : records) {
    all_pos.push_back(r.position_error_m);
    all_head.push_back(r.heading_error_rad);
  }
  result.position_bin_edges_m = make_edges(all_pos, 1.0);
  result.heading_bin_edges_rad = make_edges(all_head, 0.5);
  for (int s : sessions) {
    std::vector<double> pos, head;
    for (const FrameRecord& r : records) {
      if (r.session != s) continue;
      pos.push_back(r.position_error_m);
      head.push_back(r.heading_error_rad);
    }
    result.position_histograms.push_back(HistogramCounts(pos, result.position_bin_edges_m));
    result.heading_histograms.push_back(HistogramCounts(head, result.heading_bin_edges_rad));
  }
  return result;
}

namespace {

std::vector<std::string> DayRow(const DayEvaluation& d, const DayEvaluation* previous) {
  std::string change = "-";
  if (previous != nullptr && std::isfinite(previous->position_m.mean) &&
      std::isfinite(d.position_m.mean)) {
    const double delta = d.position_m.mean - previous->position_m.mean;
    change = (delta >= 0 ? "+" : "") + Fixed(delta, 3);
  }
  return {d.session < 0 ? "all" : std::to_string(d.session + 1),
          std::to_string(d.frames),
          std::to_string(d.frames_with_estimate),
          Fixed(d.coverage * 100, 1),
          std::to_string(d.frames_skipped),
          Fixed(d.unimodal_fraction * 100, 1),
          Fixed(d.position_m.mean, 3),
          Fixed(d.position_m.rmse, 3),
          Fixed(d.position_m.median, 3),
          Fixed(d.position_m.p95, 3),
          Fixed(d.position_m.max, 3),
          Fixed(d.heading_rad.mean * 180 / kPi, 2),
          Fixed(d.heading_rad.p95 * 180 / kPi, 2),
          Fixed(d.odometry_m.mean, 3),
          change,
          std::to_string(d.views_at_end)};
}

const std::vector<std::string>& DayHeader() {
  static const std::vector<std::string> kHeader = {
      "day",          "frames",      "localized", "coverage%", "skipped", "unimodal%",
      "mean_m",       "rmse_m",      "median_m",  "p95_m",     "max_m",   "head_mean_deg",
      "head_p95_deg", "odom_mean_m", "d_mean_m",  "views"};
  return kHeader;
}

std::vector<std::string> ConsistencyRow(const std::string& name, const ErrorStats& s,
                                        double in_band, int frames, int dof) {
  const ChiSquareBand band = ChiSquareTwoSidedBand(0.95, dof);
  return {name,
          std::to_string(dof),
          std::to_string(s.count) + "/" + std::to_string(frames),
          Fixed(s.mean, 2),
          Fixed(s.median, 2),
          Fixed(s.p95, 2),
          Fixed(in_band * 100, 1),
          Fixed(static_cast<double>(dof), 2) + " / " + Fixed(ChiSquareQuantile(0.5, dof), 2) +
              " / " + Fixed(ChiSquareQuantile(0.95, dof), 2),
          "[" + Fixed(band.lower, 3) + ", " + Fixed(band.upper, 2) + "]"};
}

const std::vector<std::string>& ConsistencyHeader() {
  static const std::vector<std::string> kHeader = {
      "statistic", "dof", "frames",   "mean",
      "median",    "p95", "in_band%", "consistent mean/median/p95",
      "95% band"};
  return kHeader;
}

std::vector<std::vector<std::string>> ConsistencyRows(const DayEvaluation& d) {
  std::vector<std::vector<std::string>> rows;
  if (d.nees_xy.count > 0)
    rows.push_back(ConsistencyRow("position NEES", d.nees_xy, d.nees_xy_in_band, d.frames, 2));
  if (d.nees_phi.count > 0)
    rows.push_back(ConsistencyRow("heading NEES", d.nees_phi, d.nees_phi_in_band, d.frames, 1));
  if (d.nis.count > 0)
    rows.push_back(ConsistencyRow("NIS of fixes", d.nis, d.nis_in_band, d.frames, 3));
  if (d.prior_nees_xy.count > 0) {
    rows.push_back(ConsistencyRow("prior NEES (odometry)", d.prior_nees_xy, kNaN, d.frames, 2));
  }
  if (d.fix_nees_xy.count > 0) {
    rows.push_back(ConsistencyRow("fix NEES (map)", d.fix_nees_xy, kNaN, d.frames, 2));
  }
  return rows;
}

}  // namespace

const std::vector<std::string>& ConsistencyPerDayHeader() {
  static const std::vector<std::string> kHeader = {
      "day",           "nees_frames",    "nees_med",    "nees_p95",   "nees_in%",
      "head_nees_med", "head_nees_p95",  "head_in%",    "nis_frames", "nis_med",
      "nis_in%",       "prior_nees_med", "fix_nees_med"};
  return kHeader;
}

std::vector<std::string> ConsistencyPerDayRow(const DayEvaluation& d) {
  return {d.session < 0 ? "all" : std::to_string(d.session + 1),
          std::to_string(d.nees_xy.count),
          Fixed(d.nees_xy.median, 2),
          Fixed(d.nees_xy.p95, 2),
          Fixed(d.nees_xy_in_band * 100, 1),
          Fixed(d.nees_phi.median, 2),
          Fixed(d.nees_phi.p95, 2),
          Fixed(d.nees_phi_in_band * 100, 1),
          std::to_string(d.nis.count),
          Fixed(d.nis.median, 2),
          Fixed(d.nis_in_band * 100, 1),
          Fixed(d.prior_nees_xy.median, 2),
          Fixed(d.fix_nees_xy.median, 2)};
}

namespace {

// The consistency block of FormatEvaluation: the run's NEES / NIS table (empty when the
// frames carry no covariances).
std::string FormatConsistency(const EvaluationResult& result) {
  const std::vector<std::vector<std::string>> rows = ConsistencyRows(result.overall);
  if (rows.empty()) return "";
  std::ostringstream os;
  if (result.days.size() > 1) {
    std::vector<std::vector<std::string>> per_day;
    for (const DayEvaluation& d : result.days) per_day.push_back(ConsistencyPerDayRow(d));
    per_day.push_back(ConsistencyPerDayRow(result.overall));
    os << "consistency per day (medians; in% = inside the two-sided 95 % chi-square band)\n"
       << FormatTextTable(ConsistencyPerDayHeader(), per_day);
  }
  os << "consistency over the run (NEES = e^T C^-1 e of the strongest component, NIS = "
        "innovation of the appearance fixes; below the consistent values = under-confident, "
        "above = over-confident; in_band% = frames inside the two-sided 95 % chi-square band)\n"
     << FormatTextTable(ConsistencyHeader(), rows, /*left_align_first=*/true);
  if (result.alignment != Alignment::kNone) {
    os << "prior and fix NEES: not reported under alignment (frames.csv holds them against "
          "the unaligned truth; run evaluate with --align none for them)\n";
  }
  return os.str();
}

}  // namespace

std::string ShortestDouble(double v) {
  if (!std::isfinite(v)) return "";
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  // Prefer a shorter form when it round-trips.
  for (int precision = 6; precision < 17; ++precision) {
    char shorter[40];
    std::snprintf(shorter, sizeof shorter, "%.*g", precision, v);
    if (std::strtod(shorter, nullptr) == v) return shorter;
  }
  return buf;
}

std::string FormatTextTable(const std::vector<std::string>& header,
                            const std::vector<std::vector<std::string>>& rows,
                            bool left_align_first) {
  std::vector<std::size_t> width(header.size());
  for (std::size_t i = 0; i < header.size(); ++i) width[i] = header[i].size();
  for (const auto& row : rows) {
    for (std::size_t i = 0; i < row.size() && i < width.size(); ++i)
      width[i] = std::max(width[i], row[i].size());
  }
  std::ostringstream os;
  auto line = [&](const std::vector<std::string>& cells) {
    for (std::size_t i = 0; i < width.size(); ++i) {
      const std::string c = i < cells.size() ? cells[i] : "";
      const std::string pad(width[i] - c.size(), ' ');
      if (i > 0) os << "  ";
      if (i == 0 && left_align_first) {
        os << c << pad;
      } else {
        os << pad << c;
      }
    }
    os << "\n";
  };
  line(header);
  for (const auto& row : rows) line(row);
  return os.str();
}

std::string FormatEvaluation(const EvaluationResult& result, bool with_histogram) {
  std::ostringstream os;
  os << "alignment: " << ToString(result.alignment);
  if (result.alignment == Alignment::kSe2) {
    os << " (tx " << Fixed(result.alignment_transform.x(), 3) << " m, ty "
       << Fixed(result.alignment_transform.y(), 3) << " m, theta "
       << Fixed(result.alignment_transform.z() * 180 / kPi, 2) << " deg)";
  }
  os << "\nposition error per day (metres; heading in degrees) over the localized frames; "
        "coverage% = localized / frames; skipped = unreadable input frames left out; d_mean_m = "
        "change of the mean from the previous day\n";
  std::vector<std::vector<std::string>> rows;
  for (std::size_t i = 0; i < result.days.size(); ++i) {
    rows.push_back(DayRow(result.days[i], i > 0 ? &result.days[i - 1] : nullptr));
  }
  rows.push_back(DayRow(result.overall, nullptr));
  os << FormatTextTable(DayHeader(), rows);
  os << FormatConsistency(result);
  if (with_histogram && !result.position_histograms.empty()) {
    os << "\nposition error histogram (frames per bin and day)\n";
    std::vector<std::string> header = {"bin_m"};
    for (const auto& d : result.days) header.push_back("day" + std::to_string(d.session + 1));
    std::vector<std::vector<std::string>> hist_rows;
    const auto& edges = result.position_bin_edges_m;
    for (std::size_t b = 0; b + 1 < edges.size(); ++b) {
      std::vector<std::string> row = {b + 2 == edges.size()
                                          ? Fixed(edges[b], 2) + "+"
                                          : Fixed(edges[b], 2) + "-" + Fixed(edges[b + 1], 2)};
      for (const auto& h : result.position_histograms) row.push_back(Fixed(h[b], 0));
      hist_rows.push_back(row);
    }
    os << FormatTextTable(header, hist_rows);
  }
  return os.str();
}

void WriteDaysCsv(std::ostream& os, const std::vector<FrameRecord>& records,
                  const std::vector<std::string>& stage_names,
                  const std::vector<std::string>& extra_columns,
                  const std::function<std::vector<std::string>(int session)>& extra_values,
                  const std::map<int, std::int64_t>& skipped_frames) {
  os << "session,frames,frames_with_truth,unimodal_fraction,position_error_mean_m,"
        "position_error_median_m,position_error_p95_m,position_error_max_m,heading_error_mean_"
        "rad,odometry_error_mean_m,views_at_end,map_components_at_end,";
  for (const std::string& c : extra_columns) os << c << ',';
  os << "mean_frame_time_us,frames_localized,frames_unlocalized,coverage,frames_skipped";
  for (const char* c : {"nees_xy", "nees_phi", "nis"}) {
    os << ',' << c << "_frames," << c << "_mean," << c << "_median," << c << "_p95," << c
       << "_in_band";
  }
  os << ",prior_nees_xy_median,fix_nees_xy_median\n";
  std::vector<int> sessions;
  for (const FrameRecord& r : records) {
    if (sessions.empty() || sessions.back() != r.session) sessions.push_back(r.session);
  }
  for (int s : sessions) {
    const DayEvaluation d = EvaluateDay(records, s, stage_names, skipped_frames);
    os << s << ',' << d.frames << ',' << d.frames_with_truth << ','
       << ShortestDouble(d.unimodal_fraction) << ',' << ShortestDouble(d.position_m.mean) << ','
       << ShortestDouble(d.position_m.median) << ',' << ShortestDouble(d.position_m.p95) << ','
       << ShortestDouble(d.position_m.max) << ',' << ShortestDouble(d.heading_rad.mean) << ','
       << ShortestDouble(d.odometry_m.mean) << ',' << d.views_at_end << ','
       << d.map_components_at_end << ',';
    if (!extra_columns.empty()) {
      const std::vector<std::string> values = extra_values(s);
      OMNICML_CHECK(values.size() == extra_columns.size()) << "WriteDaysCsv: extra values";
      for (const std::string& v : values) os << v << ',';
    }
    os << ShortestDouble(d.mean_frame_time_us) << ',' << d.frames_with_estimate << ','
       << d.frames_unlocalized << ',' << ShortestDouble(d.coverage) << ',' << d.frames_skipped;
    const std::pair<const ErrorStats*, double> consistency[] = {{&d.nees_xy, d.nees_xy_in_band},
                                                                {&d.nees_phi, d.nees_phi_in_band},
                                                                {&d.nis, d.nis_in_band}};
    for (const auto& [stats, in_band] : consistency) {
      os << ',' << stats->count << ',' << ShortestDouble(stats->mean) << ','
         << ShortestDouble(stats->median) << ',' << ShortestDouble(stats->p95) << ','
         << ShortestDouble(in_band);
    }
    os << ',' << ShortestDouble(d.prior_nees_xy.median) << ','
       << ShortestDouble(d.fix_nees_xy.median) << '\n';
  }
}

namespace {
std::string DayName(const DayEvaluation& day) { return "day " + std::to_string(day.session + 1); }
}  // namespace

namespace {

// Moving median over the `window` frames ending at each frame (NaN ignored; NaN where
// the window holds no value).
std::vector<double> MovingMedian(const std::vector<double>& v, int window) {
  std::vector<double> out(v.size(), kNaN);
  std::vector<double> buffer;
  for (std::size_t i = 0; i < v.size(); ++i) {
    buffer.clear();
    const std::size_t first = i + 1 >= static_cast<std::size_t>(window) ? i + 1 - window : 0;
    for (std::size_t k = first; k <= i; ++k) {
      if (std::isfinite(v[k])) buffer.push_back(v[k]);
    }
    if (buffer.empty()) continue;
    std::sort(buffer.begin(), buffer.end());
    out[i] = Quantile(buffer, 0.5);
  }
  return out;
}

// One NEES plot: the per-frame values (every k-th frame, at most about 2000 points, values
// above the plot clipped to its top), the moving median, the band and the consistent median.
std::string NeesPlot(const std::string& title, const std::vector<double>& x,
                     const std::vector<double>& nees, int dof, int window) {
  const ChiSquareBand band = ChiSquareTwoSidedBand(0.95, dof);
  const double top = 3.0 * band.upper;
  SvgPlot plot(title, "frame", "NEES", 960, 300);
  plot.SetYRange(0.0, top);
  const std::size_t step = std::max<std::size_t>(1, x.size() / 2000);
  std::vector<double> px, py;
  for (std::size_t i = 0; i < x.size(); i += step) {
    if (!std::isfinite(nees[i])) continue;
    px.push_back(x[i]);
    py.push_back(std::min(nees[i], top));
  }
  if (!px.empty()) plot.AddScatter("per frame (clipped at " + Fixed(top, 1) + ")", px, py);
  std::vector<double> median = MovingMedian(nees, window);
  for (double& m : median) {
    if (std::isfinite(m)) m = std::min(m, top);
  }
  plot.AddLine("moving median (" + std::to_string(window) + " frames)", x, median);
  if (!x.empty()) {
    const std::vector<double> ends = {x.front(), x.back()};
    plot.AddLine("95 % band, upper " + Fixed(band.upper, 2), ends, {band.upper, band.upper});
    plot.AddLine("95 % band, lower " + Fixed(band.lower, 3), ends, {band.lower, band.lower});
    const double median_consistent = ChiSquareQuantile(0.5, dof);
    plot.AddLine("consistent median " + Fixed(median_consistent, 2), ends,
                 {median_consistent, median_consistent});
  }
  return plot.Render();
}

}  // namespace

std::string RenderNeesOverTimeSvg(const std::vector<FrameRecord>& records, int window) {
  window = std::max(1, window);
  std::vector<double> x, pos, head;
  for (const FrameRecord& r : records) {
    x.push_back(static_cast<double>(r.global_frame));
    pos.push_back(r.nees_xy);
    head.push_back(r.nees_phi);
  }
  return NeesPlot("Position NEES over the run (2 dof)", x, pos, 2, window) +
         NeesPlot("Heading NEES over the run (1 dof)", x, head, 1, window);
}

std::string RenderPositionHistogramSvg(const EvaluationResult& result, const std::string& title) {
  SvgPlot plot(title, "error [m]", "frames");
  for (std::size_t i = 0; i < result.days.size(); ++i) {
    plot.AddHistogram(DayName(result.days[i]), result.position_bin_edges_m,
                      result.position_histograms[i], result.days.size() > 1);
  }
  return plot.Render();
}

std::vector<std::pair<std::int64_t, int>> DayStarts(const std::vector<FrameRecord>& records) {
  std::vector<std::pair<std::int64_t, int>> out;
  for (std::size_t i = 1; i < records.size(); ++i) {
    if (records[i].session != records[i - 1].session)
      out.emplace_back(records[i].global_frame, records[i].session);
  }
  return out;
}

void AddDayMarkers(SvgPlot* plot, const std::vector<FrameRecord>& records, double x_offset) {
  for (const auto& [frame, session] : DayStarts(records))
    plot->AddVerticalMarker(x_offset + static_cast<double>(frame), StrCat("day ", session + 1));
}

std::string RenderEvaluationHtml(const EvaluationResult& result, const FramesTable& table,
                                 const std::string& title, const TrajectoryMetrics* metrics) {
  HtmlReport report(title);
  if (metrics != nullptr) {
    report.AddHeading("Trajectory error as evo reports it (APE, RPE)");
    report.AddParagraph(
        "APE: position error after the alignment below, over " +
        std::to_string(metrics->frames_evaluated) + " of " + std::to_string(metrics->frames) +
        " frames (localized with ground truth); RMSE is evo_ape's headline figure. RPE: "
        "relative error over pairs of frames " +
        Fixed(metrics->rpe_delta_m, 2) +
        " m of ground-truth path apart (evo_rpe --delta_unit m), pairs within a day: " +
        std::to_string(metrics->rpe_pairs) + " pairs, drift " + Fixed(metrics->drift_percent, 2) +
        " % (translation RMSE per metre), " + Fixed(metrics->rotation_drift_deg_per_m, 3) +
        " deg/m.");
    const auto [header, rows] = TrajectoryMetricsTable(*metrics);
    report.AddTable(header, rows);
  }
  report.AddParagraph(
      "Alignment of the estimate to ground truth: " + ToString(result.alignment) +
      ". Errors of the strongest hypothesis over the localized frames (frames with an "
      "estimate); coverage% = localized / frames, so read every error with its coverage; "
      "skipped = unreadable input frames the log reader left out (not counted in frames); "
      "d_mean_m is the change of the mean position error from the previous day.");
  std::vector<std::vector<std::string>> rows;
  for (std::size_t i = 0; i < result.days.size(); ++i) {
    rows.push_back(DayRow(result.days[i], i > 0 ? &result.days[i - 1] : nullptr));
  }
  rows.push_back(DayRow(result.overall, nullptr));
  report.AddHeading("Error per day");
  report.AddTable(DayHeader(), rows);

  report.AddHeading("Error histograms (cf. [G] Fig. 5 and 6)");
  SvgPlot head_plot("Heading error", "error [deg]", "frames");
  std::vector<double> head_edges_deg;
  for (double e : result.heading_bin_edges_rad) head_edges_deg.push_back(e * 180 / kPi);
  for (std::size_t i = 0; i < result.days.size(); ++i) {
    head_plot.AddHistogram(DayName(result.days[i]), head_edges_deg, result.heading_histograms[i],
                           result.days.size() > 1);
  }
  report.AddSvg(RenderPositionHistogramSvg(result, "Position error"));
  report.AddSvg(head_plot.Render());

  // Error over the run, estimate versus dead reckoning (re-aligned the same way).
  std::vector<FrameRecord> records = table.records;
  Align(&records, result.alignment);
  std::vector<double> x, err, odo, views;
  for (const FrameRecord& r : records) {
    x.push_back(static_cast<double>(r.global_frame));
    err.push_back(r.position_error_m);
    odo.push_back(r.odometry_error_m);
    views.push_back(r.views);
  }
  SvgPlot over_time("Position error over the run", "frame", "error [m]", 960, 320);
  over_time.AddLine("estimate", x, err);
  over_time.AddLine("odometry only", x, odo);
  AddDayMarkers(&over_time, records);
  report.AddSvg(over_time.Render());
  if (result.overall.nees_xy.count > 0 || result.overall.nees_phi.count > 0) {
    report.AddHeading("Consistency: NEES over the run against the 95 % chi-square band");
    report.AddParagraph(
        "NEES = e^T C^-1 e of the strongest component against ground truth. A consistent "
        "estimator keeps 95 % of its frames inside the band and its moving median on the "
        "consistent median; a median below it means the reported covariance is wider than "
        "the errors (under-confident), above it narrower (over-confident).");
    report.AddTable(ConsistencyHeader(), ConsistencyRows(result.overall));
    std::vector<std::vector<std::string>> per_day;
    for (const DayEvaluation& d : result.days) per_day.push_back(ConsistencyPerDayRow(d));
    per_day.push_back(ConsistencyPerDayRow(result.overall));
    report.AddTable(ConsistencyPerDayHeader(), per_day);
    report.AddSvg(RenderNeesOverTimeSvg(records));
  }
  SvgPlot map_plot("Map size", "frame", "reference views", 960, 260);
  map_plot.AddLine("views", x, views);
  AddDayMarkers(&map_plot, records);
  report.AddSvg(map_plot.Render());
  report.AddHeading("Text summary");
  report.AddPreformatted(FormatEvaluation(result));
  return report.Render();
}

}  // namespace omnicml
