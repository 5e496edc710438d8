#include "omnicml/report/map_export.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iomanip>
#include <limits>
#include <map>
#include <set>
#include <sstream>

#include <Eigen/Eigenvalues>
#include <opencv2/imgproc.hpp>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/report/svg_plot.h"

namespace omnicml {
namespace fs = std::filesystem;

namespace {

std::string Shortest(double v) {
  char buf[64];
  auto res = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, res.ptr);
}

std::string Px(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f", v);
  return buf;
}

// World (m) -> picture (px) transform fitted to the map and the trajectory.
struct Canvas {
  double min_x = 0, min_y = 0, scale = 1;  // px per metre
  int width = 0, height = 0;
  double margin = 30;
  double top = 30;  // extra room for the title
  double X(double x) const { return margin + (x - min_x) * scale; }
  double Y(double y) const { return height - margin - (y - min_y) * scale; }
};

Canvas MakeCanvas(const EnvironmentModel& model, const std::vector<Pose2>& trajectory, int width_px,
                  double sigma) {
  double lo_x = std::numeric_limits<double>::infinity(), lo_y = lo_x, hi_x = -lo_x, hi_y = -lo_x;
  auto extend = [&](double x, double y, double r) {
    lo_x = std::min(lo_x, x - r);
    hi_x = std::max(hi_x, x + r);
    lo_y = std::min(lo_y, y - r);
    hi_y = std::max(hi_y, y + r);
  };
  for (const auto& view : model.views()) {
    for (const auto& c : view.components) {
      const Ellipse2 e = CovarianceEllipse(c.covariance);
      extend(c.mean.x(), c.mean.y(), std::min(sigma * e.major_m, 2.0));
    }
  }
  for (const Pose2& p : trajectory) extend(p.x(), p.y(), 0.0);
  if (!std::isfinite(lo_x)) lo_x = 0, hi_x = 1, lo_y = 0, hi_y = 1;
  if (hi_x - lo_x < 1) hi_x = lo_x + 1;
  if (hi_y - lo_y < 1) hi_y = lo_y + 1;
  Canvas c;
  c.width = std::max(200, width_px);
  c.scale = (c.width - 2 * c.margin) / (hi_x - lo_x);
  c.height = static_cast<int>(std::ceil((hi_y - lo_y) * c.scale + 2 * c.margin + c.top));
  c.height = std::min(c.height, 4 * c.width);  // very thin maps: cap the height
  c.min_x = lo_x;
  c.min_y = lo_y;
  return c;
}

// A round scale-bar length (1, 2, 5 x 10^k metres) of about a fifth of the width.
double ScaleBarMetres(const Canvas& c) {
  const double target = (c.width - 2 * c.margin) / c.scale / 5;
  const double mag = std::pow(10.0, std::floor(std::log10(target)));
  for (double m : {5.0, 2.0, 1.0}) {
    if (m * mag <= target) return m * mag;
  }
  return mag;
}

std::string DescribeSession(int session) { return session < 0 ? "-" : std::to_string(session + 1); }

}  // namespace

std::vector<TimedPose> ReadTumTrajectory(const fs::path& path) {
  // A regular file with lines of at most kMaxCsvLineBytes (no FIFO or device).
  LineReader in(path, "trajectory", kMaxCsvLineBytes);
  std::vector<TimedPose> out;
  std::string line;
  int line_no = 0;
  while (in.Next(&line)) {
    ++line_no;
    const auto first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream is(line);
    double v[8];
    for (double& x : v) {
      if (!(is >> x)) {
        throw Error(
            StrCat(path.string(), ":", line_no, ": expected 8 numbers: stamp x y z qx qy qz qw"));
      }
      if (!std::isfinite(x))
        throw Error(StrCat(path.string(), ":", line_no, ": non-finite number"));
    }
    std::string rest;
    if (is >> rest) throw Error(StrCat(path.string(), ":", line_no, ": more than 8 values"));
    const double qx = v[4], qy = v[5], qz = v[6], qw = v[7];
    const double norm = std::sqrt(qx * qx + qy * qy + qz * qz + qw * qw);
    if (norm < 1e-9) throw Error(StrCat(path.string(), ":", line_no, ": zero quaternion"));
    // Yaw of the rotation (ZYX convention).
    const double yaw = std::atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz));
    out.push_back({v[0], MakePose(v[1], v[2], yaw)});
  }
  return out;
}

std::string TumLine(double stamp_s, const Pose2& pose) {
  const double half = 0.5 * pose.z();
  return StrCat(Shortest(stamp_s), " ", Shortest(pose.x()), " ", Shortest(pose.y()), " 0 0 0 ",
                Shortest(std::sin(half)), " ", Shortest(std::cos(half)));
}

Ellipse2 CovarianceEllipse(const Eigen::Matrix3d& covariance) {
  Eigen::Matrix2d c = covariance.topLeftCorner<2, 2>();
  c = 0.5 * (c + c.transpose());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> solver(c);
  const Eigen::Vector2d values = solver.eigenvalues().cwiseMax(0.0);
  const Eigen::Vector2d major = solver.eigenvectors().col(1);
  Ellipse2 e;
  e.major_m = std::sqrt(values(1));
  e.minor_m = std::sqrt(values(0));
  e.angle_rad = std::atan2(major.y(), major.x());
  return e;
}

nlohmann::ordered_json MapToJson(const CmlEngine& engine, const MapExportOptions& options) {
  using json = nlohmann::ordered_json;
  const EnvironmentModel& model = engine.model();
  const EnvironmentModelOptions& mo = model.options();
  const EngineCounters& counters = engine.counters();
  json j;
  j["schema"] = "omnicml.map";
  j["schema_version"] = kMapSchemaVersion;
  j["engine"] = {{"frames", engine.next_frame()},
                 {"sessions", engine.session_state().session + 1},
                 {"counters",
                  {{"frames", counters.frames},
                   {"unimodal_frames", counters.unimodal_frames},
                   {"multimodal_frames", counters.multimodal_frames},
                   {"unknown_frames", counters.unknown_frames},
                   {"reconstructed_frames", counters.reconstructed_frames},
                   {"dropped_pending_frames", counters.dropped_pending_frames},
                   {"updates_queued", counters.updates_queued},
                   {"global_seeds", counters.global_seeds},
                   {"global_fallbacks", counters.global_fallbacks}}}};
  j["model"] = {{"views", model.NumViews()},
                {"components", model.NumComponents()},
                {"memory_bytes", model.MemoryBytes()},
                {"next_view_id", model.next_view_id()},
                {"next_component_id", model.next_component_id()},
                {"options",
                 {{"e_max", mo.e_max},
                  {"top_k", mo.top_k},
                  {"beta", mo.beta},
                  {"d_max", mo.d_max},
                  {"d_for_m", mo.d_for_m},
                  {"beta_for", mo.beta_for},
                  {"d_gain_m", mo.d_gain_m},
                  {"w_min", mo.w_min},
                  {"merge_delta", mo.merge_delta},
                  {"forgetting", ToString(mo.forgetting)},
                  {"spatial_cell_m", mo.spatial_cell_m}}}};
  j["descriptor"] = {{"kind", ToString(model.extractor().kind())},
                     {"feature_size", model.extractor().FeatureSize()}};
  json views = json::array();
  for (const ReferenceView& view : model.views()) {
    const auto& f = view.descriptor.features;
    double norm = 0, mn = 0, mx = 0, mean = 0;
    if (!f.empty()) {
      mn = mx = f[0];
      for (float x : f) {
        norm += static_cast<double>(x) * x;
        mn = std::min<double>(mn, x);
        mx = std::max<double>(mx, x);
        mean += x;
      }
      norm = std::sqrt(norm);
      mean /= static_cast<double>(f.size());
    }
    json d = {{"kind", ToString(view.descriptor.kind)},
              {"length", f.size()},
              {"panorama_width", view.descriptor.panorama_width},
              {"norm", norm},
              {"min", mn},
              {"max", mx},
              {"mean", mean}};
    if (options.include_features) d["features"] = f;
    json components = json::array();
    for (const ViewComponent& c : view.components) {
      const Ellipse2 e = CovarianceEllipse(c.covariance);
      json cov = json::array();
      for (int r = 0; r < 3; ++r)
        cov.push_back({c.covariance(r, 0), c.covariance(r, 1), c.covariance(r, 2)});
      components.push_back(
          {{"id", c.id},
           {"weight", c.weight},
           {"eta", c.eta},
           {"mean", {c.mean.x(), c.mean.y(), c.mean.z()}},
           {"covariance", cov},
           {"ellipse",
            {{"major_m", e.major_m}, {"minor_m", e.minor_m}, {"angle_rad", e.angle_rad}}}});
    }
    views.push_back({{"id", view.id},
                     {"total_weight", view.TotalWeight()},
                     {"stats",
                      {{"created_frame", view.stats.created_frame},
                       {"created_session", view.stats.created_session},
                       {"observations", view.stats.observations},
                       {"last_seen_frame", view.stats.last_seen_frame},
                       {"last_seen_session", view.stats.last_seen_session}}},
                     {"descriptor", d},
                     {"components", components}});
  }
  j["views"] = views;
  if (options.include_events) {
    json events = json::array();
    for (const MapEvent& e : model.events()) {
      events.push_back({{"type", ToString(e.type)},
                        {"frame", e.frame},
                        {"session", e.session},
                        {"view_id", e.view_id},
                        {"component_id", e.component_id},
                        {"position", {e.position.x(), e.position.y(), e.position.z()}},
                        {"weight", e.weight},
                        {"reason", e.reason}});
    }
    j["events"] = events;
  }
  return j;
}

std::string MapToCsv(const EnvironmentModel& model) {
  std::ostringstream os;
  os << "view_id,view_total_weight,created_frame,created_session,observations,last_seen_frame,"
        "last_seen_session,component_id,weight,eta,x_m,y_m,phi_rad,cxx,cxy,cxphi,cyy,cyphi,cphiphi,"
        "ellipse_major_m,ellipse_minor_m,ellipse_angle_rad\n";
  for (const ReferenceView& view : model.views()) {
    for (const ViewComponent& c : view.components) {
      const Ellipse2 e = CovarianceEllipse(c.covariance);
      const auto& s = view.stats;
      os << view.id << ',' << Shortest(view.TotalWeight()) << ',' << s.created_frame << ','
         << s.created_session << ',' << s.observations << ',' << s.last_seen_frame << ','
         << s.last_seen_session << ',' << c.id << ',' << Shortest(c.weight) << ','
         << Shortest(c.eta) << ',' << Shortest(c.mean.x()) << ',' << Shortest(c.mean.y()) << ','
         << Shortest(c.mean.z()) << ',' << Shortest(c.covariance(0, 0)) << ','
         << Shortest(c.covariance(0, 1)) << ',' << Shortest(c.covariance(0, 2)) << ','
         << Shortest(c.covariance(1, 1)) << ',' << Shortest(c.covariance(1, 2)) << ','
         << Shortest(c.covariance(2, 2)) << ',' << Shortest(e.major_m) << ',' << Shortest(e.minor_m)
         << ',' << Shortest(e.angle_rad) << '\n';
    }
  }
  return os.str();
}

std::string MapToSvg(const EnvironmentModel& model, const std::vector<Pose2>& trajectory,
                     const MapPictureOptions& options) {
  const Canvas c = MakeCanvas(model, trajectory, options.width_px, options.ellipse_sigma);
  std::ostringstream os;
  os << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << c.width << "\" height=\""
     << c.height << "\" viewBox=\"0 0 " << c.width << " " << c.height
     << "\" font-family=\"sans-serif\" font-size=\"11\">\n";
  os << "<rect x=\"0\" y=\"0\" width=\"" << c.width << "\" height=\"" << c.height
     << "\" fill=\"white\"/>\n";
  if (!options.title.empty()) {
    os << "<text x=\"" << c.width / 2
       << "\" y=\"18\" text-anchor=\"middle\" font-size=\"13\" font-weight=\"bold\">"
       << XmlEscape(options.title) << "</text>\n";
  }
  os << "<g fill=\"#0072B2\" stroke=\"#0072B2\" stroke-width=\"0.5\">\n";
  for (const ReferenceView& view : model.views()) {
    for (const ViewComponent& comp : view.components) {
      const Ellipse2 e = CovarianceEllipse(comp.covariance);
      const double rx = std::max(0.5, options.ellipse_sigma * e.major_m * c.scale);
      const double ry = std::max(0.5, options.ellipse_sigma * e.minor_m * c.scale);
      const double opacity = std::clamp(comp.weight, 0.02, 1.0);
      // SVG's y axis points down: the angle flips sign.
      os << "<ellipse cx=\"" << Px(c.X(comp.mean.x())) << "\" cy=\"" << Px(c.Y(comp.mean.y()))
         << "\" rx=\"" << Px(rx) << "\" ry=\"" << Px(ry) << "\" transform=\"rotate("
         << Px(-e.angle_rad * 180 / kPi) << " " << Px(c.X(comp.mean.x())) << " "
         << Px(c.Y(comp.mean.y())) << ")\" fill-opacity=\"" << Px(opacity * 0.5)
         << "\" stroke-opacity=\"" << Px(opacity) << "\"/>\n";
    }
  }
  os << "</g>\n";
  // The trajectory over the ellipses, then the component centres.
  if (trajectory.size() >= 2) {
    os << "<polyline fill=\"none\" stroke=\"#D55E00\" stroke-width=\"1\" stroke-opacity=\"0.8\" "
          "points=\"";
    for (const Pose2& p : trajectory) os << Px(c.X(p.x())) << "," << Px(c.Y(p.y())) << " ";
    os << "\"/>\n";
  }
  os << "<g fill=\"#003f66\">\n";
  for (const ReferenceView& view : model.views()) {
    for (const ViewComponent& comp : view.components) {
      os << "<circle cx=\"" << Px(c.X(comp.mean.x())) << "\" cy=\"" << Px(c.Y(comp.mean.y()))
         << "\" r=\"1.5\"/>\n";
    }
  }
  os << "</g>\n";
  // Scale bar.
  const double bar_m = ScaleBarMetres(c);
  const double y = c.height - 10.0;
  os << "<line x1=\"" << Px(c.margin) << "\" y1=\"" << Px(y) << "\" x2=\""
     << Px(c.margin + bar_m * c.scale) << "\" y2=\"" << Px(y)
     << "\" stroke=\"black\" stroke-width=\"2\"/>\n";
  os << "<text x=\"" << Px(c.margin + bar_m * c.scale + 6) << "\" y=\"" << Px(y + 4) << "\">"
     << FormatTick(bar_m) << " m</text>\n";
  os << "<text x=\"" << c.width - 8 << "\" y=\"" << Px(y + 4) << "\" text-anchor=\"end\">"
     << model.NumViews() << " views, " << model.NumComponents() << " components</text>\n";
  os << "</svg>\n";
  return os.str();
}

cv::Mat MapToImage(const EnvironmentModel& model, const std::vector<Pose2>& trajectory,
                   const MapPictureOptions& options) {
  const Canvas c = MakeCanvas(model, trajectory, options.width_px, options.ellipse_sigma);
  cv::Mat image(c.height, c.width, CV_8UC3, cv::Scalar(255, 255, 255));
  constexpr int kShift = 4;  // sub-pixel bits for OpenCV drawing
  const double f = 1 << kShift;
  // Components, weakest first so strong ones stay visible; colour blended towards the
  // background by (1 - weight).
  std::vector<const ViewComponent*> comps;
  for (const auto& view : model.views()) {
    for (const auto& comp : view.components) comps.push_back(&comp);
  }
  std::stable_sort(comps.begin(), comps.end(), [](const ViewComponent* a, const ViewComponent* b) {
    return a->weight < b->weight;
  });
  const cv::Vec3d blue(178, 114, 0), white(255, 255, 255);
  for (const ViewComponent* comp : comps) {
    const Ellipse2 e = CovarianceEllipse(comp->covariance);
    const double alpha = std::clamp(comp->weight, 0.05, 1.0);
    const cv::Vec3d fill = white * (1 - 0.5 * alpha) + blue * (0.5 * alpha);
    const cv::Vec3d edge = white * (1 - alpha) + blue * alpha;
    const cv::Point center(cvRound(c.X(comp->mean.x()) * f), cvRound(c.Y(comp->mean.y()) * f));
    const cv::Size axes(std::max(1, cvRound(options.ellipse_sigma * e.major_m * c.scale * f)),
                        std::max(1, cvRound(options.ellipse_sigma * e.minor_m * c.scale * f)));
    const double angle_deg = -e.angle_rad * 180 / kPi;
    cv::ellipse(image, center, axes, angle_deg, 0, 360, cv::Scalar(fill[0], fill[1], fill[2]),
                cv::FILLED, cv::LINE_AA, kShift);
    cv::ellipse(image, center, axes, angle_deg, 0, 360, cv::Scalar(edge[0], edge[1], edge[2]), 1,
                cv::LINE_AA, kShift);
  }
  // The trajectory over the ellipses, then the component centres.
  if (trajectory.size() >= 2) {
    std::vector<cv::Point> pts;
    for (const Pose2& p : trajectory)
      pts.emplace_back(cvRound(c.X(p.x()) * f), cvRound(c.Y(p.y()) * f));
    cv::polylines(image, pts, false, cv::Scalar(0, 94, 213), 1, cv::LINE_AA, kShift);
  }
  for (const ViewComponent* comp : comps) {
    const cv::Point center(cvRound(c.X(comp->mean.x()) * f), cvRound(c.Y(comp->mean.y()) * f));
    cv::circle(image, center, 2 << kShift, cv::Scalar(102, 63, 0), cv::FILLED, cv::LINE_AA, kShift);
  }
  const double bar_m = ScaleBarMetres(c);
  const int y = c.height - 10;
  cv::line(image, cv::Point(static_cast<int>(c.margin), y),
           cv::Point(static_cast<int>(c.margin + bar_m * c.scale), y), cv::Scalar(0, 0, 0), 2);
  cv::putText(image, FormatTick(bar_m) + " m",
              cv::Point(static_cast<int>(c.margin + bar_m * c.scale + 6), y + 4),
              cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  if (!options.title.empty()) {
    cv::putText(image, options.title, cv::Point(10, 18), cv::FONT_HERSHEY_SIMPLEX, 0.5,
                cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  }
  return image;
}

std::string ToString(CellHealth health) {
  switch (health) {
    case CellHealth::kOk:
      return "ok";
    case CellHealth::kStale:
      return "stale";
    case CellHealth::kChanged:
      return "changed";
    case CellHealth::kNew:
      return "new";
  }
  return "ok";
}

MapHealth ComputeMapHealth(const EnvironmentModel& model, int latest_session,
                           const MapHealthOptions& options) {
  if (!(options.cell_m > 0)) throw Error("map health: cell_m must be > 0");
  if (options.stale_sessions < 1) throw Error("map health: stale_sessions must be >= 1");
  MapHealth health;
  health.latest_session = latest_session;
  struct Acc {
    MapCell cell;
    std::set<std::uint64_t> views;
    bool all_created_latest = true;
  };
  std::map<std::pair<int, int>, Acc> cells;  // key (iy, ix)
  auto key_of = [&](double x, double y) {
    return std::make_pair(static_cast<int>(std::floor(y / options.cell_m)),
                          static_cast<int>(std::floor(x / options.cell_m)));
  };
  for (const ReferenceView& view : model.views()) {
    if (health.first_session < 0 || view.stats.created_session < health.first_session) {
      health.first_session = view.stats.created_session;
    }
    for (const ViewComponent& c : view.components) {
      const auto key = key_of(c.mean.x(), c.mean.y());
      Acc& acc = cells[key];
      acc.cell.iy = key.first;
      acc.cell.ix = key.second;
      acc.cell.components += 1;
      acc.cell.total_weight += c.weight;
      if (acc.views.insert(view.id).second) {
        acc.cell.views += 1;
        acc.cell.last_seen_session =
            std::max(acc.cell.last_seen_session, view.stats.last_seen_session);
        if (view.stats.created_session != latest_session) acc.all_created_latest = false;
      }
    }
  }
  for (const MapEvent& e : model.events()) {
    if (e.session != latest_session) continue;
    const auto key = key_of(e.position.x(), e.position.y());
    auto it = cells.find(key);
    if (it == cells.end()) {
      // Everything there was removed: a changed area without views left.
      Acc& acc = cells[key];
      acc.cell.iy = key.first;
      acc.cell.ix = key.second;
      acc.all_created_latest = false;
      it = cells.find(key);
    }
    if (e.type == MapEventType::kViewInserted) it->second.cell.insertions_recent += 1;
    if (e.type == MapEventType::kViewRemoved || e.type == MapEventType::kComponentRemoved) {
      it->second.cell.removals_recent += 1;
    }
  }
  for (auto& [key, acc] : cells) {
    MapCell& cell = acc.cell;
    if (cell.views > 0 && acc.all_created_latest && latest_session > health.first_session) {
      cell.health = CellHealth::kNew;
      ++health.fresh;
    } else if (cell.insertions_recent > 0 || cell.removals_recent > 0) {
      cell.health = CellHealth::kChanged;
      ++health.changed;
    } else if (cell.last_seen_session <= latest_session - options.stale_sessions) {
      cell.health = CellHealth::kStale;
      ++health.stale;
    } else {
      cell.health = CellHealth::kOk;
      ++health.ok;
    }
    health.cells.push_back(cell);
  }
  return health;
}

std::string InspectText(const CmlEngine& engine, const MapHealthOptions& options) {
  const EnvironmentModel& model = engine.model();
  const int latest = engine.session_state().session;
  const MapHealth health = ComputeMapHealth(model, latest, options);
  std::ostringstream os;
  os << "map: " << model.NumViews() << " views, " << model.NumComponents() << " components, "
     << StrCat(std::fixed, std::setprecision(1), model.MemoryBytes() / 1024.0) << " KiB\n";
  os << "descriptor: " << ToString(model.extractor().kind()) << " ("
     << model.extractor().FeatureSize()
     << " features); forgetting: " << ToString(model.options().forgetting) << "; e_max "
     << model.options().e_max << "\n";
  const EngineCounters& k = engine.counters();
  os << "engine: " << engine.next_frame() << " frames over " << latest + 1 << " sessions; unimodal "
     << k.unimodal_frames << ", multimodal " << k.multimodal_frames << ", unknown "
     << k.unknown_frames << ", reconstructed " << k.reconstructed_frames << ", queued updates "
     << engine.queued_updates().size() << "\n";
  // Per session: views created / still alive, events.
  std::map<int, std::array<int, 4>>
      per_session;  // created alive, inserted, removed views, removed comps
  for (const auto& view : model.views()) per_session[view.stats.created_session][0] += 1;
  for (const auto& e : model.events()) {
    if (e.type == MapEventType::kViewInserted) per_session[e.session][1] += 1;
    if (e.type == MapEventType::kViewRemoved) per_session[e.session][2] += 1;
    if (e.type == MapEventType::kComponentRemoved) per_session[e.session][3] += 1;
  }
  os << "sessions covered: " << DescribeSession(health.first_session) << " .. "
     << DescribeSession(latest) << "\n";
  os << "session  views_alive_created_then  views_inserted  views_removed  components_removed\n";
  for (const auto& [s, v] : per_session) {
    char buf[128];
    std::snprintf(buf, sizeof buf, "%7s  %24d  %14d  %13d  %18d\n", DescribeSession(s).c_str(),
                  v[0], v[1], v[2], v[3]);
    os << buf;
  }
  os << "health by area (" << options.cell_m << " m cells; latest session "
     << DescribeSession(latest) << "): " << health.ok << " ok, " << health.changed << " changed, "
     << health.fresh << " new, " << health.stale << " stale\n";
  if (!health.cells.empty()) {
    int min_ix = health.cells.front().ix, max_ix = min_ix, min_iy = health.cells.front().iy,
        max_iy = min_iy;
    std::map<std::pair<int, int>, CellHealth> grid;
    for (const MapCell& c : health.cells) {
      min_ix = std::min(min_ix, c.ix);
      max_ix = std::max(max_ix, c.ix);
      min_iy = std::min(min_iy, c.iy);
      max_iy = std::max(max_iy, c.iy);
      grid[{c.iy, c.ix}] = c.health;
    }
    if (max_ix - min_ix < 120 && max_iy - min_iy < 80) {
      os << "legend: o ok, c changed, n new, s stale, . no view; x to the right, y up; origin cell "
            "("
         << min_ix * options.cell_m << ", " << min_iy * options.cell_m << ") m\n";
      for (int iy = max_iy; iy >= min_iy; --iy) {
        os << "  ";
        for (int ix = min_ix; ix <= max_ix; ++ix) {
          auto it = grid.find({iy, ix});
          char ch = '.';
          if (it != grid.end()) {
            switch (it->second) {
              case CellHealth::kOk:
                ch = 'o';
                break;
              case CellHealth::kChanged:
                ch = 'c';
                break;
              case CellHealth::kNew:
                ch = 'n';
                break;
              case CellHealth::kStale:
                ch = 's';
                break;
            }
          }
          os << ch;
        }
        os << "\n";
      }
    }
    os << "cells (x_m, y_m = lower-left corner):\n";
    os << "   x_m     y_m  views  components  weight  last_seen  inserted  removed  health\n";
    for (const MapCell& c : health.cells) {
      char buf[160];
      std::snprintf(buf, sizeof buf, "%6.1f  %6.1f  %5d  %10d  %6.2f  %9s  %8d  %7d  %s\n",
                    c.ix * options.cell_m, c.iy * options.cell_m, c.views, c.components,
                    c.total_weight, DescribeSession(c.last_seen_session).c_str(),
                    c.insertions_recent, c.removals_recent, ToString(c.health).c_str());
      os << buf;
    }
  }
  return os.str();
}

}  // namespace omnicml
