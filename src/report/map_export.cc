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

// ---- The map picture: one list of drawing primitives, two back ends (SVG, OpenCV). ----

// A drawing primitive in picture pixels (y down).
struct Prim {
  enum class Type { kPolyline, kPolygon, kCircle, kEllipse, kText, kRect };
  Type type = Type::kPolyline;
  std::vector<cv::Point2d> pts;  // polyline/polygon vertices; circle/ellipse/text/rect origin
  double rx = 0, ry = 0;         // circle radius (rx), ellipse semi-axes, rect size
  double angle_deg = 0;          // ellipse rotation, clockwise on the page
  std::string stroke;            // "" = none
  double stroke_width = 1;
  std::string fill;  // "" = none
  double opacity = 1;
  std::string text;
  double font_px = 11;
  int anchor = -1;  // text: -1 start, 0 middle, 1 end
  bool bold = false;
};

struct Scene {
  int width = 0, height = 0;
  std::vector<Prim> prims;
  Prim& Add(Prim::Type type) {
    prims.emplace_back();
    prims.back().type = type;
    return prims.back();
  }
  void Line(std::vector<cv::Point2d> pts, const std::string& color, double width,
            double opacity = 1) {
    Prim& p = Add(Prim::Type::kPolyline);
    p.pts = std::move(pts);
    p.stroke = color;
    p.stroke_width = width;
    p.opacity = opacity;
  }
  void Text(double x, double y, std::string text, double font_px = 11, int anchor = -1,
            bool bold = false) {
    Prim& p = Add(Prim::Type::kText);
    p.pts = {{x, y}};
    p.text = std::move(text);
    p.font_px = font_px;
    p.anchor = anchor;
    p.bold = bold;
  }
};

// Text metrics shared by both back ends: OpenCV's Hershey simplex at this scale per
// pixel of font size is a little wider than an SVG sans-serif, so layouts measured with it
// fit in both.
constexpr double kHersheyScalePerPx = 1.0 / 30.0;
double TextWidthPx(const std::string& text, double font_px = 11) {
  int baseline = 0;
  return cv::getTextSize(text, cv::FONT_HERSHEY_SIMPLEX, font_px * kHersheyScalePerPx, 1, &baseline)
      .width;
}

// World (m) -> picture (px) transform.
struct Canvas {
  double min_x = 0, min_y = 0, scale = 1;  // px per metre
  double left = 0, bottom = 0;             // pixel of (min_x, min_y)
  double X(double x) const { return left + (x - min_x) * scale; }
  double Y(double y) const { return bottom - (y - min_y) * scale; }
  cv::Point2d P(double x, double y) const { return {X(x), Y(y)}; }
};

// A round scale-bar length (1, 2, 5 x 10^k metres) of at most `target_m`.
double RoundMetres(double target_m) {
  const double mag = std::pow(10.0, std::floor(std::log10(target_m)));
  for (double m : {5.0, 2.0, 1.0}) {
    if (m * mag <= target_m) return m * mag;
  }
  return mag;
}

std::string Hex(int r, int g, int b) {
  char buf[8];
  std::snprintf(buf, sizeof buf, "#%02x%02x%02x", std::clamp(r, 0, 255), std::clamp(g, 0, 255),
                std::clamp(b, 0, 255));
  return buf;
}

// Component weight 0..1 -> pale blue .. dark navy (sequential, readable on white).
std::string WeightColor(double w) {
  static const double stops[3][3] = {{198, 219, 239}, {66, 146, 198}, {8, 48, 107}};
  const double t = std::clamp(w, 0.0, 1.0) * 2;
  const int i = std::min(1, static_cast<int>(t));
  const double f = t - i;
  auto mix = [&](int k) {
    return static_cast<int>(std::lround(stops[i][k] * (1 - f) + stops[i + 1][k] * f));
  };
  return Hex(mix(0), mix(1), mix(2));
}

const char* HealthColor(CellHealth h) {
  switch (h) {
    case CellHealth::kOk:
      return "#1b7837";
    case CellHealth::kChanged:
      return "#e7298a";
    case CellHealth::kNew:
      return "#7570b3";
    case CellHealth::kStale:
      return "#999999";
  }
  return "#1b7837";
}

constexpr const char* kWallColor = "#404040";
constexpr const char* kShelfFill = "#d9d9d9";
constexpr const char* kShelfEdge = "#a0a0a0";
constexpr const char* kBoxFill = "#e8dcc8";
constexpr const char* kTruthColor = "#222222";
constexpr const char* kEstimateColor = "#d55e00";
constexpr const char* kRemovedColor = "#c0102a";

Scene BuildMapScene(const EnvironmentModel& model, const std::vector<Pose2>& trajectory,
                    const MapPictureOptions& options) {
  // Extent: floor plan, trajectories and component means (not the ellipses: one
  // uncertain component must not shrink the whole map).
  double lo_x = std::numeric_limits<double>::infinity(), lo_y = lo_x, hi_x = -lo_x, hi_y = -lo_x;
  auto extend = [&](double x, double y) {
    if (!std::isfinite(x) || !std::isfinite(y)) return;
    lo_x = std::min(lo_x, x);
    hi_x = std::max(hi_x, x);
    lo_y = std::min(lo_y, y);
    hi_y = std::max(hi_y, y);
  };
  const FloorPlan& plan = options.floor_plan;
  if (!plan.empty()) {
    if ((plan.max_m.array() > plan.min_m.array()).all()) {
      extend(plan.min_m.x(), plan.min_m.y());
      extend(plan.max_m.x(), plan.max_m.y());
    }
    for (const auto& shape : plan.shapes) {
      for (const auto& p : shape.points_m) extend(p.x(), p.y());
    }
  }
  for (const auto& view : model.views()) {
    for (const auto& c : view.components) extend(c.mean.x(), c.mean.y());
  }
  for (const Pose2& p : trajectory) extend(p.x(), p.y());
  for (const Pose2& p : options.ground_truth) extend(p.x(), p.y());
  for (const Eigen::Vector2d& p : options.removed_m) extend(p.x(), p.y());
  if (!std::isfinite(lo_x)) lo_x = 0, hi_x = 1, lo_y = 0, hi_y = 1;
  const double pad_m = 0.03 * std::max(hi_x - lo_x, hi_y - lo_y);
  lo_x -= pad_m, hi_x += pad_m, lo_y -= pad_m, hi_y += pad_m;
  if (hi_x - lo_x < 1) hi_x = lo_x + 1;
  if (hi_y - lo_y < 1) hi_y = lo_y + 1;

  Scene s;
  s.width = std::max(400, options.width_px);
  const double margin = 12;
  const double top = options.title.empty() ? margin : 30;
  const double legend_h = 64;
  Canvas c;
  c.scale = (s.width - 2 * margin) / (hi_x - lo_x);
  const double map_h = std::min((hi_y - lo_y) * c.scale, 3.0 * s.width);
  c.min_x = lo_x;
  c.min_y = lo_y;
  c.left = margin;
  c.bottom = top + map_h;
  s.height = static_cast<int>(std::ceil(top + map_h + legend_h));

  Prim& bg = s.Add(Prim::Type::kRect);
  bg.pts = {{0, 0}};
  bg.rx = s.width;
  bg.ry = s.height;
  bg.fill = "#ffffff";
  if (!options.title.empty()) s.Text(s.width / 2.0, 19, options.title, 13, 0, true);

  // Floor plan: blocks first, walls over them.
  for (int pass = 0; pass < 2; ++pass) {
    for (const auto& shape : plan.shapes) {
      const bool wall = shape.kind == FloorPlanShape::Kind::kWall;
      if (wall != (pass == 1) || shape.points_m.size() < 2) continue;
      std::vector<cv::Point2d> pts;
      for (const auto& p : shape.points_m) pts.push_back(c.P(p.x(), p.y()));
      if (wall) {
        if (shape.closed) pts.push_back(pts.front());
        s.Line(std::move(pts), kWallColor, 2.5);
      } else {
        Prim& p = s.Add(shape.closed ? Prim::Type::kPolygon : Prim::Type::kPolyline);
        p.pts = std::move(pts);
        p.fill =
            shape.closed ? (shape.kind == FloorPlanShape::Kind::kBox ? kBoxFill : kShelfFill) : "";
        p.stroke = kShelfEdge;
        p.stroke_width = 1;
      }
    }
  }

  // Components, weakest first so the strong ones stay on top.
  struct Comp {
    const ViewComponent* comp;
    std::string color;
  };
  std::vector<Comp> comps;
  std::map<std::pair<int, int>, CellHealth> health_of_cell;
  if (options.coloring == MapColoring::kHealth) {
    int latest = options.latest_session;
    if (latest < 0) {
      for (const auto& view : model.views()) {
        latest = std::max({latest, view.stats.created_session, view.stats.last_seen_session});
      }
    }
    MapHealthOptions ho;
    ho.cell_m = options.health_cell_m;
    for (const MapCell& cell : ComputeMapHealth(model, latest, ho).cells) {
      health_of_cell[{cell.ix, cell.iy}] = cell.health;
    }
  }
  for (const auto& view : model.views()) {
    for (const auto& comp : view.components) {
      std::string color;
      if (options.coloring == MapColoring::kHealth) {
        const int ix = static_cast<int>(std::floor(comp.mean.x() / options.health_cell_m));
        const int iy = static_cast<int>(std::floor(comp.mean.y() / options.health_cell_m));
        const auto it = health_of_cell.find({ix, iy});
        color = HealthColor(it == health_of_cell.end() ? CellHealth::kOk : it->second);
      } else {
        color = WeightColor(comp.weight);
      }
      comps.push_back({&comp, color});
    }
  }
  std::stable_sort(comps.begin(), comps.end(),
                   [](const Comp& a, const Comp& b) { return a.comp->weight < b.comp->weight; });

  // Readable ellipses: strongest first, within the size limits on the page.
  std::vector<const Comp*> by_strength;
  for (const Comp& k : comps) by_strength.push_back(&k);
  std::reverse(by_strength.begin(), by_strength.end());
  // An ellipse is left out when it would mostly overlap a stronger one already drawn
  // (centres closer than 0.75 x the sum of the major semi-axes): neighbouring views along
  // the path have near-identical ellipses, and a chain of them reads as one blob.
  const double max_px = options.max_ellipse_fraction * s.width;
  std::vector<std::pair<cv::Point2d, double>> drawn;  // centre, major semi-axis (px)
  int ellipses = 0;
  for (const Comp* k : by_strength) {
    if (ellipses >= options.max_ellipses || k->comp->weight < options.min_ellipse_weight) break;
    const Ellipse2 e = CovarianceEllipse(k->comp->covariance);
    const double rx = options.ellipse_sigma * e.major_m * c.scale;
    const double ry = options.ellipse_sigma * e.minor_m * c.scale;
    if (rx < options.min_ellipse_px || rx > max_px) continue;
    const cv::Point2d centre = c.P(k->comp->mean.x(), k->comp->mean.y());
    const bool crowded = std::any_of(drawn.begin(), drawn.end(), [&](const auto& d) {
      return cv::norm(d.first - centre) < 0.75 * (d.second + rx);
    });
    if (crowded) continue;
    drawn.emplace_back(centre, rx);
    Prim& p = s.Add(Prim::Type::kEllipse);
    p.pts = {centre};
    p.rx = rx;
    p.ry = std::max(ry, 0.5);
    p.angle_deg = -e.angle_rad * 180 / kPi;  // the page's y axis points down
    p.stroke = k->color;
    p.stroke_width = 1;
    p.opacity = 0.7;
    ++ellipses;
  }

  // Trajectories: ground truth under the estimate.
  auto path = [&](const std::vector<Pose2>& poses, const char* color, double width,
                  double opacity) {
    if (poses.size() < 2) return;
    std::vector<cv::Point2d> pts;
    pts.reserve(poses.size());
    for (const Pose2& p : poses) pts.push_back(c.P(p.x(), p.y()));
    s.Line(std::move(pts), color, width, opacity);
  };
  path(options.ground_truth, kTruthColor, 1.0, 0.55);
  path(trajectory, kEstimateColor, 1.2, 0.85);

  // Component dots: radius grows with the weight.
  for (const Comp& k : comps) {
    Prim& p = s.Add(Prim::Type::kCircle);
    p.pts = {c.P(k.comp->mean.x(), k.comp->mean.y())};
    p.rx = 1.6 + 1.6 * std::clamp(k.comp->weight, 0.0, 1.0);
    p.fill = k.color;
  }
  auto cross = [&](const cv::Point2d& q) {
    s.Line({{q.x - 3, q.y - 3}, {q.x + 3, q.y + 3}}, kRemovedColor, 1.3, 0.8);
    s.Line({{q.x - 3, q.y + 3}, {q.x + 3, q.y - 3}}, kRemovedColor, 1.3, 0.8);
  };
  for (const Eigen::Vector2d& r : options.removed_m) cross(c.P(r.x(), r.y()));

  // Legend: two rows under the map.
  const double y1 = top + map_h + 20, y2 = y1 + 24;
  double x = margin;
  auto swatch_line = [&](const char* color, double width, const std::string& label) {
    s.Line({{x, y1 - 4}, {x + 22, y1 - 4}}, color, width);
    s.Text(x + 27, y1, label);
    x += 27 + TextWidthPx(label) + 18;
  };
  if (!plan.empty()) {
    swatch_line(kWallColor, 2.5, "walls");
    Prim& r = s.Add(Prim::Type::kRect);
    r.pts = {{x, y1 - 10}};
    r.rx = 22;
    r.ry = 11;
    r.fill = kShelfFill;
    r.stroke = kShelfEdge;
    const std::string label =
        plan.name.empty() ? "shelves, boxes" : "shelves, boxes (" + plan.name + ")";
    s.Text(x + 27, y1, label);
    x += 27 + TextWidthPx(label) + 18;
  }
  if (options.ground_truth.size() >= 2) swatch_line(kTruthColor, 1.5, "ground truth");
  if (trajectory.size() >= 2) swatch_line(kEstimateColor, 1.5, "estimate");
  if (!options.removed_m.empty()) {
    cross({x + 8, y1 - 4});
    const std::string label = StrCat("view removed (", options.removed_m.size(), ")");
    s.Text(x + 20, y1, label);
    x += 20 + TextWidthPx(label) + 18;
  }
  {
    Prim& e = s.Add(Prim::Type::kEllipse);
    e.pts = {{x + 11, y1 - 4}};
    e.rx = 10;
    e.ry = 5;
    e.stroke = WeightColor(0.8);
    const std::string label =
        StrCat(FormatTick(options.ellipse_sigma), "-sigma ellipses: ", ellipses,
               " strongest that do not overlap");
    s.Text(x + 27, y1, label);
  }
  // Row 2: the dot colours, counts, the scale bar on the right.
  x = margin;
  if (options.coloring == MapColoring::kWeight) {
    const std::string label = "view components by weight:";
    s.Text(x, y2, label);
    x += TextWidthPx(label) + 12;
    for (double w : {0.0, 0.25, 0.5, 0.75, 1.0}) {
      Prim& p = s.Add(Prim::Type::kCircle);
      p.pts = {{x + 4, y2 - 4}};
      p.rx = 1.6 + 1.6 * w;
      p.fill = WeightColor(w);
      s.Text(x + 10, y2, FormatTick(w));
      x += 10 + TextWidthPx(FormatTick(w)) + 14;
    }
  } else {
    const std::string label = "view components by area health:";
    s.Text(x, y2, label);
    x += TextWidthPx(label) + 12;
    for (CellHealth h :
         {CellHealth::kOk, CellHealth::kChanged, CellHealth::kNew, CellHealth::kStale}) {
      Prim& p = s.Add(Prim::Type::kCircle);
      p.pts = {{x + 4, y2 - 4}};
      p.rx = 3.5;
      p.fill = HealthColor(h);
      s.Text(x + 11, y2, ToString(h));
      x += 11 + TextWidthPx(ToString(h)) + 14;
    }
  }
  s.Text(x + 10, y2, StrCat(model.NumViews(), " views, ", model.NumComponents(), " components"));
  const double bar_m = RoundMetres((s.width - 2 * margin) / c.scale / 6);
  const double bar_px = bar_m * c.scale;
  const double bar_x1 = s.width - margin - 50, bar_x0 = bar_x1 - bar_px;
  s.Line({{bar_x0, y2 - 8}, {bar_x0, y2 - 2}, {bar_x1, y2 - 2}, {bar_x1, y2 - 8}}, "#000000", 2);
  s.Text(bar_x1 + 6, y2, FormatTick(bar_m) + " m");
  return s;
}

std::string RenderSvg(const Scene& s) {
  std::ostringstream os;
  os << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << s.width << "\" height=\""
     << s.height << "\" viewBox=\"0 0 " << s.width << " " << s.height
     << "\" font-family=\"sans-serif\" font-size=\"11\">\n";
  for (const Prim& p : s.prims) {
    std::string paint;
    paint += " fill=\"" + (p.fill.empty() ? std::string("none") : p.fill) + "\"";
    if (!p.stroke.empty()) {
      paint += " stroke=\"" + p.stroke + "\" stroke-width=\"" + Px(p.stroke_width) +
               "\" stroke-linejoin=\"round\"";
    }
    if (p.opacity < 1) paint += " opacity=\"" + Px(p.opacity) + "\"";
    switch (p.type) {
      case Prim::Type::kPolyline:
      case Prim::Type::kPolygon:
        os << (p.type == Prim::Type::kPolygon ? "<polygon" : "<polyline") << paint << " points=\"";
        for (const auto& q : p.pts) os << Px(q.x) << "," << Px(q.y) << " ";
        os << "\"/>\n";
        break;
      case Prim::Type::kCircle:
        os << "<circle cx=\"" << Px(p.pts[0].x) << "\" cy=\"" << Px(p.pts[0].y) << "\" r=\""
           << Px(p.rx) << "\"" << paint << "/>\n";
        break;
      case Prim::Type::kEllipse:
        os << "<ellipse cx=\"" << Px(p.pts[0].x) << "\" cy=\"" << Px(p.pts[0].y) << "\" rx=\""
           << Px(p.rx) << "\" ry=\"" << Px(p.ry) << "\" transform=\"rotate(" << Px(p.angle_deg)
           << " " << Px(p.pts[0].x) << " " << Px(p.pts[0].y) << ")\"" << paint << "/>\n";
        break;
      case Prim::Type::kRect:
        os << "<rect x=\"" << Px(p.pts[0].x) << "\" y=\"" << Px(p.pts[0].y) << "\" width=\""
           << Px(p.rx) << "\" height=\"" << Px(p.ry) << "\"" << paint << "/>\n";
        break;
      case Prim::Type::kText:
        os << "<text x=\"" << Px(p.pts[0].x) << "\" y=\"" << Px(p.pts[0].y) << "\"";
        if (p.anchor == 0) os << " text-anchor=\"middle\"";
        if (p.anchor == 1) os << " text-anchor=\"end\"";
        if (p.font_px != 11) os << " font-size=\"" << Px(p.font_px) << "\"";
        if (p.bold) os << " font-weight=\"bold\"";
        os << ">" << XmlEscape(p.text) << "</text>\n";
        break;
    }
  }
  os << "</svg>\n";
  return os.str();
}

cv::Scalar Bgr(const std::string& hex) {
  unsigned r = 0, g = 0, b = 0;
  if (hex.size() == 7) std::sscanf(hex.c_str() + 1, "%02x%02x%02x", &r, &g, &b);
  return cv::Scalar(b, g, r);
}

cv::Mat RenderImage(const Scene& s) {
  cv::Mat image(s.height, s.width, CV_8UC3, cv::Scalar(255, 255, 255));
  constexpr int kShift = 4;  // sub-pixel bits for OpenCV drawing
  const double f = 1 << kShift;
  auto fix = [&](const cv::Point2d& q) { return cv::Point(cvRound(q.x * f), cvRound(q.y * f)); };
  const cv::Rect whole(0, 0, s.width, s.height);
  for (const Prim& p : s.prims) {
    // Translucent primitives: drawn, then blended with what was there within their box.
    cv::Rect box = whole;
    cv::Mat before;
    if (p.opacity < 1) {
      double x0 = 1e18, y0 = 1e18, x1 = -1e18, y1 = -1e18;
      for (const auto& q : p.pts) {
        x0 = std::min(x0, q.x), y0 = std::min(y0, q.y), x1 = std::max(x1, q.x),
        y1 = std::max(y1, q.y);
      }
      const double r = std::max(p.rx, p.ry) + p.stroke_width + 2;
      box = cv::Rect(cv::Point(static_cast<int>(x0 - r), static_cast<int>(y0 - r)),
                     cv::Point(static_cast<int>(x1 + r) + 1, static_cast<int>(y1 + r) + 1)) &
            whole;
      if (box.empty()) continue;
      before = image(box).clone();
    }
    const int thick = std::max(1, static_cast<int>(std::lround(p.stroke_width)));
    switch (p.type) {
      case Prim::Type::kPolyline:
      case Prim::Type::kPolygon: {
        std::vector<cv::Point> pts;
        for (const auto& q : p.pts) pts.push_back(fix(q));
        if (!p.fill.empty() && p.type == Prim::Type::kPolygon) {
          cv::fillPoly(image, std::vector<std::vector<cv::Point>>{pts}, Bgr(p.fill), cv::LINE_AA,
                       kShift);
        }
        if (!p.stroke.empty()) {
          cv::polylines(image, pts, p.type == Prim::Type::kPolygon, Bgr(p.stroke), thick,
                        cv::LINE_AA, kShift);
        }
        break;
      }
      case Prim::Type::kCircle:
        if (!p.fill.empty()) {
          cv::circle(image, fix(p.pts[0]), cvRound(p.rx * f), Bgr(p.fill), cv::FILLED, cv::LINE_AA,
                     kShift);
        }
        if (!p.stroke.empty()) {
          cv::circle(image, fix(p.pts[0]), cvRound(p.rx * f), Bgr(p.stroke), thick, cv::LINE_AA,
                     kShift);
        }
        break;
      case Prim::Type::kEllipse: {
        const cv::Size axes(std::max(1, cvRound(p.rx * f)), std::max(1, cvRound(p.ry * f)));
        if (!p.fill.empty()) {
          cv::ellipse(image, fix(p.pts[0]), axes, p.angle_deg, 0, 360, Bgr(p.fill), cv::FILLED,
                      cv::LINE_AA, kShift);
        }
        if (!p.stroke.empty()) {
          cv::ellipse(image, fix(p.pts[0]), axes, p.angle_deg, 0, 360, Bgr(p.stroke), thick,
                      cv::LINE_AA, kShift);
        }
        break;
      }
      case Prim::Type::kRect: {
        const cv::Rect r(cvRound(p.pts[0].x), cvRound(p.pts[0].y), cvRound(p.rx), cvRound(p.ry));
        if (!p.fill.empty()) cv::rectangle(image, r, Bgr(p.fill), cv::FILLED);
        if (!p.stroke.empty()) cv::rectangle(image, r, Bgr(p.stroke), thick);
        break;
      }
      case Prim::Type::kText: {
        const int face = cv::FONT_HERSHEY_SIMPLEX;
        const double font_scale = p.font_px * kHersheyScalePerPx * (p.bold ? 1.1 : 1.0);
        const int weight = 1;
        int baseline = 0;
        const cv::Size size = cv::getTextSize(p.text, face, font_scale, weight, &baseline);
        double x = p.pts[0].x;
        if (p.anchor == 0) x -= size.width / 2.0;
        if (p.anchor == 1) x -= size.width;
        cv::putText(image, p.text, cv::Point(cvRound(x), cvRound(p.pts[0].y)), face, font_scale,
                    cv::Scalar(0, 0, 0), weight, cv::LINE_AA);
        break;
      }
    }
    if (p.opacity < 1) {
      cv::Mat roi = image(box);
      cv::addWeighted(roi, p.opacity, before, 1 - p.opacity, 0, roi);
    }
  }
  return image;
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
                 {{"e_max", mo.retrieval.e_max},
                  {"top_k", mo.retrieval.top_k},
                  {"beta", mo.update.beta},
                  {"d_max", mo.update.d_max},
                  {"d_for_m", mo.forgetting.d_for_m},
                  {"beta_for", mo.forgetting.beta_for},
                  {"d_gain_m", mo.forgetting.d_gain_m},
                  {"w_min", mo.update.w_min},
                  {"merge_delta", mo.update.merge_delta},
                  {"forgetting", ToString(mo.forgetting.mode)},
                  {"spatial_cell_m", mo.index.spatial_cell_m}}}};
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
           {"spread", {{c.spread(0, 0), c.spread(0, 1)}, {c.spread(1, 0), c.spread(1, 1)}}},
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

std::string ToString(MapColoring coloring) {
  return coloring == MapColoring::kHealth ? "health" : "weight";
}

MapColoring MapColoringFromString(const std::string& text) {
  if (text == "weight") return MapColoring::kWeight;
  if (text == "health") return MapColoring::kHealth;
  throw Error(StrCat("map colouring '", text, "': expected weight or health"));
}

std::string MapToSvg(const EnvironmentModel& model, const std::vector<Pose2>& trajectory,
                     const MapPictureOptions& options) {
  return RenderSvg(BuildMapScene(model, trajectory, options));
}

cv::Mat MapToImage(const EnvironmentModel& model, const std::vector<Pose2>& trajectory,
                   const MapPictureOptions& options) {
  return RenderImage(BuildMapScene(model, trajectory, options));
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
  if (options.min_changed_neighbours < 0 || options.min_changed_neighbours > 8) {
    throw Error("map health: min_changed_neighbours must be in 0..8");
  }
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
        const ViewFootprint& f = view.footprint;
        if (view.stats.created_session < latest_session && f.last_expected_frame >= 0 &&
            f.last_expected_session == latest_session) {
          acc.cell.expected_recent += 1;
          if (view.stats.last_seen_session < latest_session) acc.cell.missed_recent += 1;
        }
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
    if (e.type == MapEventType::kComponentRemoved && IsActiveForgettingReason(e.reason)) {
      it->second.cell.forgotten_recent += 1;
    }
  }
  // Evidence of its own: every view new, or what says the appearance changed there:
  // nothing matched (insertion), or views the robot confidently passed through no longer
  // matched. Removals alone are the map's bookkeeping (passive forgetting (17), merges)
  // and happen where nothing changed.
  auto is_new = [&](const Acc& acc) {
    return acc.cell.views > 0 && acc.all_created_latest && latest_session > health.first_session;
  };
  auto own_evidence = [&](const Acc& acc) {
    const MapCell& c = acc.cell;
    return is_new(acc) || c.insertions_recent > 0 || c.missed_recent > 0 || c.forgotten_recent > 0;
  };
  for (auto& [key, acc] : cells) {
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) {
        if (dx == 0 && dy == 0) continue;
        const auto it = cells.find({key.first + dy, key.second + dx});
        if (it != cells.end() && own_evidence(it->second)) acc.cell.changed_neighbours += 1;
      }
    }
  }
  for (auto& [key, acc] : cells) {
    MapCell& cell = acc.cell;
    if (is_new(acc)) {
      cell.health = CellHealth::kNew;
      ++health.fresh;
    } else if (own_evidence(acc)) {
      cell.health = CellHealth::kChanged;
      ++health.changed;
    } else if (cell.last_seen_session <= latest_session - options.stale_sessions) {
      cell.health = CellHealth::kStale;
      ++health.stale;
    } else if (options.min_changed_neighbours > 0 &&
               cell.changed_neighbours >= options.min_changed_neighbours) {
      cell.health = CellHealth::kChanged;
      ++health.changed;
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
     << " features); forgetting: " << ToString(model.options().forgetting.mode) << "; e_max "
     << model.options().retrieval.e_max << "\n";
  const EngineCounters& k = engine.counters();
  os << "engine: " << engine.next_frame() << " frames over " << latest + 1 << " sessions; unimodal "
     << k.unimodal_frames << ", multimodal " << k.multimodal_frames << ", unknown "
     << k.unknown_frames << ", reconstructed " << k.reconstructed_frames << ", queued updates "
     << engine.queued_updates().size() << "\n";
  // Per session: views created / still alive, events.
  std::map<int, std::array<int, 4>>
      per_session;  // created alive, inserted, removed views, removed comps
  for (const auto& view : model.views()) per_session[view.stats.created_session][0] += 1;
  for (const auto& [session, n] : model.event_counts()) {  // exact, not limited by the ring
    per_session[session][1] = static_cast<int>(n.views_inserted);
    per_session[session][2] = static_cast<int>(n.views_removed);
    per_session[session][3] = static_cast<int>(n.components_removed);
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
  // Health reads the latest session's events from the ring (model.events.max_events).
  if (const auto it = model.event_counts().find(latest); it != model.event_counts().end()) {
    const MapEventCounts& n = it->second;
    const std::int64_t logged = n.views_inserted + n.views_removed + n.components_added +
                                n.components_merged + n.components_removed;
    std::int64_t held = 0;
    for (const MapEvent& e : model.events()) held += e.session == latest ? 1 : 0;
    if (held < logged) {
      os << "note: the map's event ring (model.events.max_events "
         << model.options().events.max_events << ") holds " << held << " of the " << logged
         << " events of session " << DescribeSession(latest) << "; the health counts only those\n";
    }
  }
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
    os << "   x_m     y_m  views  components  weight  last_seen  inserted  removed  expected  "
          "missed  forgotten  neighbours  health\n";
    for (const MapCell& c : health.cells) {
      char buf[200];
      std::snprintf(buf, sizeof buf,
                    "%6.1f  %6.1f  %5d  %10d  %6.2f  %9s  %8d  %7d  %8d  %6d  %9d  %10d  %s\n",
                    c.ix * options.cell_m, c.iy * options.cell_m, c.views, c.components,
                    c.total_weight, DescribeSession(c.last_seen_session).c_str(),
                    c.insertions_recent, c.removals_recent, c.expected_recent, c.missed_recent,
                    c.forgotten_recent, c.changed_neighbours, ToString(c.health).c_str());
      os << buf;
    }
  }
  return os.str();
}

}  // namespace omnicml
