#include "omnicml/unwrap/camera_model.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <initializer_list>
#include <map>
#include <numbers>
#include <sstream>
#include <utility>

#include <yaml-cpp/yaml.h>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/limits.h"
#include "omnicml/common/yaml_io.h"

namespace omnicml {
namespace {

constexpr double kDegToRad = std::numbers::pi / 180.0;
constexpr double kHalfPi = 0.5 * std::numbers::pi;

void Require(bool ok, const std::string& what) {
  if (!ok) throw Error(what);
}

// Image-plane angle theta of panorama column c (docs/design.md "Camera models"):
//   theta = azimuth0 - 2 pi c / W (counter-clockwise on screen), azimuth0 + 2 pi c / W
//   (clockwise).
double Sign(RingDirection d) { return d == RingDirection::kCounterClockwise ? -1.0 : 1.0; }

double ColumnOfAngle(double angle, double azimuth0, double sign, int width) {
  double alpha = std::fmod(sign * (angle - azimuth0), kTwoPi);
  if (alpha < 0.0) alpha += kTwoPi;
  double column = alpha * width / kTwoPi;
  if (column >= width) column -= width;
  return column;
}

// Elevation (radians) of the centre of panorama row `row` for a band [lo, hi] (degrees):
// rows tile the band, row 0 at the top.
double ElevationOfRow(double row, double lo_deg, double hi_deg, int height) {
  return (hi_deg - (row + 0.5) * (hi_deg - lo_deg) / height) * kDegToRad;
}
double RowOfElevation(double elevation_rad, double lo_deg, double hi_deg, int height) {
  return (hi_deg - elevation_rad / kDegToRad) * height / (hi_deg - lo_deg) - 0.5;
}

// Fisheye: image radius of a ray at angle psi from the optical axis.
double FisheyeFocalPx(const FisheyeCalibration& f) {
  const double psi_max = 0.5 * f.field_of_view_deg * kDegToRad;
  return f.projection == FisheyeProjection::kEquidistant
             ? f.circle_radius_px / psi_max
             : f.circle_radius_px / (2.0 * std::sin(0.5 * psi_max));
}
double FisheyeRadius(const FisheyeCalibration& f, double psi) {
  const double focal = FisheyeFocalPx(f);
  return f.projection == FisheyeProjection::kEquidistant ? focal * psi
                                                         : 2.0 * focal * std::sin(0.5 * psi);
}
// Inverse of FisheyeRadius; NaN beyond the projection's range.
double FisheyePsi(const FisheyeCalibration& f, double rho) {
  const double focal = FisheyeFocalPx(f);
  if (f.projection == FisheyeProjection::kEquidistant) return rho / focal;
  const double s = rho / (2.0 * focal);
  return s <= 1.0 ? 2.0 * std::asin(s) : std::nan("");
}

// Equirectangular: image x of longitude lambda, y of latitude phi (pixel centres).
double EquirectX(double lambda, int image_width) {
  double u = std::fmod((lambda + std::numbers::pi) / kTwoPi, 1.0);
  if (u < 0.0) u += 1.0;
  return u * image_width - 0.5;
}
double EquirectY(double phi, int image_height) {
  return (kHalfPi - phi) / std::numbers::pi * image_height - 0.5;
}
// Longitude of panorama azimuth alpha: lambda = azimuth0 - alpha for kClockwise (x grows
// clockwise seen from above), azimuth0 + alpha for kCounterClockwise.
double EquirectLongitude(const EquirectangularCalibration& e, double alpha) {
  return e.azimuth0_rad + (e.direction == RingDirection::kClockwise ? -alpha : alpha);
}

std::string DirectionName(RingDirection d) {
  return d == RingDirection::kCounterClockwise ? "counter_clockwise" : "clockwise";
}

// ---- YAML -----------------------------------------------------------------------------

class FieldParser {
 public:
  FieldParser(const std::string& path, const YAML::Node& node, const std::string& where)
      : path_(path), node_(node), where_(where) {}

  [[noreturn]] void Fail(const YAML::Node& at, const std::string& what) const {
    const int line = at.IsDefined() ? at.Mark().line + 1 : 0;
    if (line > 0) throw Error(StrCat(path_, ":", line, ": ", what));
    throw Error(StrCat(path_, ": ", what));
  }

  void Double(const char* key, double& out) {
    Field(key, [&](const YAML::Node& v) { out = Scalar<double>(v, key, "a number"); });
  }
  void Int(const char* key, int& out) {
    Field(key, [&](const YAML::Node& v) { out = Scalar<int>(v, key, "an integer"); });
  }
  // A string field naming one of `names`; any other text fails with the choices listed.
  template <class E>
  void Enum(const char* key, E& out, std::initializer_list<std::pair<E, const char*>> names) {
    Field(key, [&](const YAML::Node& v) {
      const std::string s = Scalar<std::string>(v, key, "a string");
      std::string choices;
      for (const auto& [value, name] : names) {
        if (s == name) {
          out = value;
          return;
        }
        choices += choices.empty() ? name : StrCat(" or ", name);
      }
      Fail(v, StrCat(where_, ".", key, ": '", s, "' is not ", choices));
    });
  }
  void Direction(const char* key, RingDirection& out) {
    Enum(key, out,
         {{RingDirection::kCounterClockwise, "counter_clockwise"},
          {RingDirection::kClockwise, "clockwise"}});
  }
  void Elevation(const char* key, ElevationMapping& out) {
    Enum(key, out,
         {{ElevationMapping::kLinear, "linear"},
          {ElevationMapping::kLinearInverted, "linear_inverted"}});
  }
  void Projection(const char* key, FisheyeProjection& out) {
    Enum(key, out,
         {{FisheyeProjection::kEquidistant, "equidistant"},
          {FisheyeProjection::kEquisolid, "equisolid"}});
  }

  // After all fields: unknown keys are an error; with require_all, missing ones too.
  void Finish(bool require_all, const std::vector<std::string>& also_allowed = {}) const {
    if (!node_.IsMap()) Fail(node_, StrCat("'", where_, "' must be a map"));
    for (const auto& kv : node_) {
      const std::string key = kv.first.Scalar();
      if (std::find(known_.begin(), known_.end(), key) == known_.end() &&
          std::find(also_allowed.begin(), also_allowed.end(), key) == also_allowed.end()) {
        Fail(kv.first, StrCat("unknown key '", key, "' in '", where_, "'"));
      }
    }
    if (!require_all) return;
    for (const std::string& key : known_) {
      if (!node_[key]) Fail(node_, StrCat("missing key '", key, "' in '", where_, "'"));
    }
  }

 private:
  template <typename T>
  T Scalar(const YAML::Node& v, const char* key, const char* kind) const {
    if (!v.IsScalar()) Fail(v, StrCat(where_, ".", key, " must be ", kind));
    try {
      return v.as<T>();
    } catch (const YAML::Exception&) {
      Fail(v, StrCat(where_, ".", key, ": '", v.Scalar(), "' is not ", kind));
    }
  }
  void Field(const char* key, const std::function<void(const YAML::Node&)>& read) {
    known_.emplace_back(key);
    if (!node_.IsMap()) return;
    const YAML::Node v = node_[key];
    if (v) read(v);
  }

  std::string path_;
  YAML::Node node_;
  std::string where_;
  std::vector<std::string> known_;
};

void ParseRing(FieldParser& p, OmniCalibration& c) {
  p.Double("center_x_px", c.center_x_px);
  p.Double("center_y_px", c.center_y_px);
  p.Double("inner_radius_px", c.inner_radius_px);
  p.Double("outer_radius_px", c.outer_radius_px);
  p.Double("azimuth0_rad", c.azimuth0_rad);
  p.Direction("direction", c.direction);
  p.Elevation("elevation", c.elevation);
  p.Int("panorama_width", c.panorama_width);
  p.Int("panorama_height", c.panorama_height);
}
void ParseFisheye(FieldParser& p, FisheyeCalibration& c) {
  p.Double("center_x_px", c.center_x_px);
  p.Double("center_y_px", c.center_y_px);
  p.Double("circle_radius_px", c.circle_radius_px);
  p.Double("field_of_view_deg", c.field_of_view_deg);
  p.Projection("projection", c.projection);
  p.Double("min_elevation_deg", c.min_elevation_deg);
  p.Double("max_elevation_deg", c.max_elevation_deg);
  p.Double("azimuth0_rad", c.azimuth0_rad);
  p.Direction("direction", c.direction);
  p.Int("panorama_width", c.panorama_width);
  p.Int("panorama_height", c.panorama_height);
}
void ParseEquirect(FieldParser& p, EquirectangularCalibration& c) {
  p.Double("min_elevation_deg", c.min_elevation_deg);
  p.Double("max_elevation_deg", c.max_elevation_deg);
  p.Double("azimuth0_rad", c.azimuth0_rad);
  p.Direction("direction", c.direction);
  p.Int("panorama_width", c.panorama_width);
  p.Int("panorama_height", c.panorama_height);
}

std::string Num(double v) {
  std::ostringstream os;
  os.precision(17);
  os << v;
  return os.str();
}

void CheckPanoramaSize(int width, int height, const char* model) {
  Require(width >= 2 && width <= 65536,
          StrCat(model, ": panorama_width = ", width, " must be in [2, 65536]"));
  Require(height >= 1 && height <= 65536,
          StrCat(model, ": panorama_height = ", height, " must be in [1, 65536]"));
}

void CheckBand(double lo, double hi, const char* model) {
  Require(std::isfinite(lo) && lo >= -90.0 && lo < 90.0,
          StrCat(model, ": min_elevation_deg = ", lo, " must be in [-90, 90)"));
  Require(std::isfinite(hi) && hi > lo && hi <= 90.0,
          StrCat(model, ": max_elevation_deg = ", hi, " must be in (min_elevation_deg = ", lo,
                 ", 90]"));
}

}  // namespace

// ---------------------------------------------------------------------------------------

std::string ToString(CameraModelType type) {
  switch (type) {
    case CameraModelType::kRing:
      return "omni_ring";
    case CameraModelType::kFisheye:
      return "fisheye";
    case CameraModelType::kEquirectangular:
      return "equirectangular";
  }
  return "?";
}

CameraModelType CameraModelTypeFromString(const std::string& name) {
  if (name == "omni_ring") return CameraModelType::kRing;
  if (name == "fisheye") return CameraModelType::kFisheye;
  if (name == "equirectangular") return CameraModelType::kEquirectangular;
  throw Error(
      StrCat("unknown camera model '", name, "' (expected omni_ring, fisheye or equirectangular)"));
}

std::string ToString(FisheyeProjection projection) {
  return projection == FisheyeProjection::kEquidistant ? "equidistant" : "equisolid";
}

void FisheyeCalibration::Validate() const {
  const char* m = "fisheye calibration";
  Require(std::isfinite(center_x_px), StrCat(m, ": center_x_px = ", center_x_px, " is not finite"));
  Require(std::isfinite(center_y_px), StrCat(m, ": center_y_px = ", center_y_px, " is not finite"));
  Require(std::isfinite(circle_radius_px) && circle_radius_px > 0.0,
          StrCat(m, ": circle_radius_px = ", circle_radius_px, " must be finite and > 0"));
  Require(std::isfinite(field_of_view_deg) && field_of_view_deg > 0.0 && field_of_view_deg < 360.0,
          StrCat(m, ": field_of_view_deg = ", field_of_view_deg, " must be in (0, 360)"));
  CheckBand(min_elevation_deg, max_elevation_deg, m);
  const double lowest = 90.0 - 0.5 * field_of_view_deg;
  Require(min_elevation_deg >= lowest - 1e-9,
          StrCat(m, ": min_elevation_deg = ", min_elevation_deg,
                 " lies outside the field of view (field_of_view_deg = ", field_of_view_deg,
                 " sees down to ", lowest, " deg)"));
  Require(projection != FisheyeProjection::kEquisolid || field_of_view_deg <= 359.0,
          StrCat(m, ": field_of_view_deg = ", field_of_view_deg, " is too wide for equisolid"));
  Require(std::isfinite(azimuth0_rad), StrCat(m, ": azimuth0_rad is not finite"));
  CheckPanoramaSize(panorama_width, panorama_height, m);
}

void EquirectangularCalibration::Validate() const {
  const char* m = "equirectangular calibration";
  CheckBand(min_elevation_deg, max_elevation_deg, m);
  Require(std::isfinite(azimuth0_rad), StrCat(m, ": azimuth0_rad is not finite"));
  CheckPanoramaSize(panorama_width, panorama_height, m);
}

int CameraCalibration::panorama_width() const {
  switch (model) {
    case CameraModelType::kRing:
      return ring.panorama_width;
    case CameraModelType::kFisheye:
      return fisheye.panorama_width;
    case CameraModelType::kEquirectangular:
      return equirectangular.panorama_width;
  }
  return 0;
}

int CameraCalibration::panorama_height() const {
  switch (model) {
    case CameraModelType::kRing:
      return ring.panorama_height;
    case CameraModelType::kFisheye:
      return fisheye.panorama_height;
    case CameraModelType::kEquirectangular:
      return equirectangular.panorama_height;
  }
  return 0;
}

void CameraCalibration::SetPanoramaSize(int width, int height) {
  ring.panorama_width = fisheye.panorama_width = equirectangular.panorama_width = width;
  ring.panorama_height = fisheye.panorama_height = equirectangular.panorama_height = height;
}

void CameraCalibration::Validate() const {
  switch (model) {
    case CameraModelType::kRing:
      ring.Validate();
      return;
    case CameraModelType::kFisheye:
      fisheye.Validate();
      return;
    case CameraModelType::kEquirectangular:
      equirectangular.Validate();
      return;
  }
}

void CameraCalibration::ValidateFor(int image_width, int image_height) const {
  Validate();
  Require(image_width >= 2 && image_height >= 2,
          StrCat("calibration: image size ", image_width, "x", image_height, " is too small"));
  if (model == CameraModelType::kEquirectangular) return;  // covers the whole image
  const double cx = model == CameraModelType::kRing ? ring.center_x_px : fisheye.center_x_px;
  const double cy = model == CameraModelType::kRing ? ring.center_y_px : fisheye.center_y_px;
  const bool centre_inside =
      cx >= -0.5 && cx <= image_width - 0.5 && cy >= -0.5 && cy <= image_height - 0.5;
  // Fraction of panorama samples inside the image, on a coarse grid of columns and rows.
  const int w = panorama_width(), h = panorama_height();
  const int step_c = std::max(1, w / 360), step_r = std::max(1, h / 60);
  int inside = 0, total = 0;
  for (int r = 0; r < h; r += step_r) {
    for (int c = 0; c < w; c += step_c) {
      const cv::Point2d p = PanoramaToImage(*this, c, r, image_width, image_height);
      ++total;
      if (p.x >= -0.5 && p.x <= image_width - 0.5 && p.y >= -0.5 && p.y <= image_height - 0.5)
        ++inside;
    }
  }
  const double fraction = static_cast<double>(inside) / total;
  const double radius =
      model == CameraModelType::kRing ? ring.outer_radius_px : fisheye.circle_radius_px;
  Require(
      centre_inside && fraction >= kMinVisibleFraction,
      StrCat("calibration leaves the image: ", ToString(model), " of radius ", radius,
             " px around (", cx, ", ", cy, ") has ", static_cast<int>(std::round(100.0 * fraction)),
             " % of its panorama inside a ", image_width, "x", image_height, " image (at least ",
             static_cast<int>(100.0 * kMinVisibleFraction), " % and the centre must be inside)"));
}

bool CameraCalibration::operator==(const CameraCalibration& o) const {
  if (model != o.model) return false;
  return YamlFields("") == o.YamlFields("");
}

std::string CameraCalibration::YamlFields(const std::string& indent) const {
  std::ostringstream os;
  const auto line = [&](const char* key, const std::string& value) {
    os << indent << key << ": " << value << "\n";
  };
  switch (model) {
    case CameraModelType::kRing:
      line("center_x_px", Num(ring.center_x_px));
      line("center_y_px", Num(ring.center_y_px));
      line("inner_radius_px", Num(ring.inner_radius_px));
      line("outer_radius_px", Num(ring.outer_radius_px));
      line("azimuth0_rad", Num(ring.azimuth0_rad));
      line("direction", DirectionName(ring.direction));
      line("elevation",
           ring.elevation == ElevationMapping::kLinearInverted ? "linear_inverted" : "linear");
      break;
    case CameraModelType::kFisheye:
      line("center_x_px", Num(fisheye.center_x_px));
      line("center_y_px", Num(fisheye.center_y_px));
      line("circle_radius_px", Num(fisheye.circle_radius_px));
      line("field_of_view_deg", Num(fisheye.field_of_view_deg));
      line("projection", ToString(fisheye.projection));
      line("min_elevation_deg", Num(fisheye.min_elevation_deg));
      line("max_elevation_deg", Num(fisheye.max_elevation_deg));
      line("azimuth0_rad", Num(fisheye.azimuth0_rad));
      line("direction", DirectionName(fisheye.direction));
      break;
    case CameraModelType::kEquirectangular:
      line("min_elevation_deg", Num(equirectangular.min_elevation_deg));
      line("max_elevation_deg", Num(equirectangular.max_elevation_deg));
      line("azimuth0_rad", Num(equirectangular.azimuth0_rad));
      line("direction", DirectionName(equirectangular.direction));
      break;
  }
  line("panorama_width", std::to_string(panorama_width()));
  line("panorama_height", std::to_string(panorama_height()));
  return os.str();
}

void CameraCalibration::ToYamlFile(const std::string& path, int image_width,
                                   int image_height) const {
  Validate();
  const std::string text =
      StrCat("camera:\n  model: ", ToString(model), "\n  image_width: ", image_width,
             "\n  image_height: ", image_height, "\n  calibration:\n", YamlFields("    "));
  WriteFileAtomic(path, text);
}

CameraCalibration ParseCameraCalibration(CameraModelType model, const std::string& path,
                                         const YAML::Node& node, const std::string& where,
                                         bool require_all) {
  CameraCalibration c;
  c.model = model;
  FieldParser p(path, node, where);
  if (!node.IsMap()) p.Fail(node, StrCat("'", where, "' must be a map"));
  switch (model) {
    case CameraModelType::kRing:
      ParseRing(p, c.ring);
      break;
    case CameraModelType::kFisheye:
      ParseFisheye(p, c.fisheye);
      break;
    case CameraModelType::kEquirectangular:
      ParseEquirect(p, c.equirectangular);
      break;
  }
  p.Finish(require_all,
           require_all ? std::vector<std::string>{} : std::vector<std::string>{"model"});
  return c;
}

CameraCalibration CameraCalibration::FromYamlFile(const std::string& path) {
  const std::string text = ReadTextFile(path, kMaxTextFileBytes, "calibration file");
  YAML::Node root;
  try {
    root = LoadYaml(text, path);
  } catch (const YAML::ParserException& e) {
    throw Error(StrCat(path, ":", e.mark.line + 1, ": YAML syntax error: ", e.msg));
  } catch (const YAML::Exception& e) {
    throw Error(StrCat("cannot read calibration file '", path, "': ", e.what()));
  }
  if (!root.IsMap()) throw Error(StrCat(path, ": calibration must be a YAML map"));
  CameraCalibration c;
  try {
    YAML::Node fields = root;
    std::string where = "calibration";
    YAML::Node model_node = root["model"];
    if (root["camera"]) {
      const YAML::Node camera = root["camera"];
      if (root.size() != 1 || !camera.IsMap()) {
        throw Error(StrCat(path, ": a 'camera:' calibration file holds only the camera map"));
      }
      for (const auto& kv : camera) {
        const std::string key = kv.first.Scalar();
        if (key != "model" && key != "image_width" && key != "image_height" &&
            key != "calibration") {
          throw Error(
              StrCat(path, ":", kv.first.Mark().line + 1, ": unknown key '", key, "' in 'camera'"));
        }
      }
      model_node = camera["model"];
      fields = camera["calibration"];
      where = "camera.calibration";
      if (!fields) throw Error(StrCat(path, ": missing key 'calibration' in 'camera'"));
    }
    CameraModelType model = CameraModelType::kRing;
    if (model_node) {
      try {
        model = CameraModelTypeFromString(model_node.Scalar());
      } catch (const Error& e) {
        throw Error(StrCat(path, ":", model_node.Mark().line + 1, ": model: ", e.what()));
      }
    }
    c = ParseCameraCalibration(model, path, fields, where, false);
  } catch (const YAML::Exception& e) {
    throw Error(StrCat(path, ":", e.mark.line + 1, ": bad calibration entry: ", e.msg));
  }
  try {
    c.Validate();
  } catch (const Error& e) {
    throw Error(StrCat(path, ": ", e.what()));
  }
  return c;
}

// ---- Projections ------------------------------------------------------------------------

cv::Point2d PanoramaToImage(const CameraCalibration& c, double column, double row, int image_width,
                            int image_height) {
  switch (c.model) {
    case CameraModelType::kRing: {
      const OmniCalibration& r = c.ring;
      const double dr = (r.outer_radius_px - r.inner_radius_px) / r.panorama_height;
      const double radius = r.elevation == ElevationMapping::kLinearInverted
                                ? r.inner_radius_px + (row + 0.5) * dr
                                : r.outer_radius_px - (row + 0.5) * dr;
      const double theta = r.azimuth0_rad + Sign(r.direction) * kTwoPi * column / r.panorama_width;
      return {r.center_x_px + radius * std::cos(theta), r.center_y_px + radius * std::sin(theta)};
    }
    case CameraModelType::kFisheye: {
      const FisheyeCalibration& f = c.fisheye;
      const double elevation =
          ElevationOfRow(row, f.min_elevation_deg, f.max_elevation_deg, f.panorama_height);
      const double rho = FisheyeRadius(f, kHalfPi - elevation);
      const double theta = f.azimuth0_rad + Sign(f.direction) * kTwoPi * column / f.panorama_width;
      return {f.center_x_px + rho * std::cos(theta), f.center_y_px + rho * std::sin(theta)};
    }
    case CameraModelType::kEquirectangular: {
      const EquirectangularCalibration& e = c.equirectangular;
      const double alpha = kTwoPi * column / e.panorama_width;
      const double elevation =
          ElevationOfRow(row, e.min_elevation_deg, e.max_elevation_deg, e.panorama_height);
      return {EquirectX(EquirectLongitude(e, alpha), image_width),
              EquirectY(elevation, image_height)};
    }
  }
  return {};
}

std::optional<cv::Point2d> ImageToPanorama(const CameraCalibration& c, cv::Point2d xy,
                                           int image_width, int image_height, double margin_rows) {
  switch (c.model) {
    case CameraModelType::kRing: {
      const OmniCalibration& r = c.ring;
      const double dx = xy.x - r.center_x_px, dy = xy.y - r.center_y_px;
      const double radius = std::hypot(dx, dy);
      const double dr = (r.outer_radius_px - r.inner_radius_px) / r.panorama_height;
      const double row = r.elevation == ElevationMapping::kLinearInverted
                             ? (radius - r.inner_radius_px) / dr - 0.5
                             : (r.outer_radius_px - radius) / dr - 0.5;
      if (row < -0.5 - margin_rows || row > r.panorama_height - 0.5 + margin_rows)
        return std::nullopt;
      return cv::Point2d(
          ColumnOfAngle(std::atan2(dy, dx), r.azimuth0_rad, Sign(r.direction), r.panorama_width),
          row);
    }
    case CameraModelType::kFisheye: {
      const FisheyeCalibration& f = c.fisheye;
      const double dx = xy.x - f.center_x_px, dy = xy.y - f.center_y_px;
      const double psi = FisheyePsi(f, std::hypot(dx, dy));
      if (!std::isfinite(psi)) return std::nullopt;
      const double row = RowOfElevation(kHalfPi - psi, f.min_elevation_deg, f.max_elevation_deg,
                                        f.panorama_height);
      if (row < -0.5 - margin_rows || row > f.panorama_height - 0.5 + margin_rows)
        return std::nullopt;
      return cv::Point2d(
          ColumnOfAngle(std::atan2(dy, dx), f.azimuth0_rad, Sign(f.direction), f.panorama_width),
          row);
    }
    case CameraModelType::kEquirectangular:
      break;
  }
  const EquirectangularCalibration& e = c.equirectangular;
  const double lambda = kTwoPi * (xy.x + 0.5) / image_width - std::numbers::pi;
  const double phi = kHalfPi - std::numbers::pi * (xy.y + 0.5) / image_height;
  const double row =
      RowOfElevation(phi, e.min_elevation_deg, e.max_elevation_deg, e.panorama_height);
  if (row < -0.5 - margin_rows || row > e.panorama_height - 0.5 + margin_rows) return std::nullopt;
  const double sign = e.direction == RingDirection::kClockwise ? -1.0 : 1.0;
  return cv::Point2d(ColumnOfAngle(lambda, e.azimuth0_rad, sign, e.panorama_width), row);
}

cv::Point2d DirectionToImage(const CameraCalibration& c, double azimuth_rad, double elevation_rad,
                             int image_width, int image_height) {
  switch (c.model) {
    case CameraModelType::kRing:
      break;
    case CameraModelType::kFisheye: {
      // Unit direction in the robot frame (x forward, y left, z up); the optical axis is z.
      const double x = std::cos(elevation_rad) * std::cos(azimuth_rad);
      const double y = std::cos(elevation_rad) * std::sin(azimuth_rad);
      const double z = std::sin(elevation_rad);
      const double psi = std::acos(std::clamp(z, -1.0, 1.0));
      const double alpha = std::atan2(y, x);
      const FisheyeCalibration& f = c.fisheye;
      const double theta = f.azimuth0_rad + Sign(f.direction) * alpha;
      const double rho = FisheyeRadius(f, psi);
      return {f.center_x_px + rho * std::cos(theta), f.center_y_px + rho * std::sin(theta)};
    }
    case CameraModelType::kEquirectangular: {
      const double x = std::cos(elevation_rad) * std::cos(azimuth_rad);
      const double y = std::cos(elevation_rad) * std::sin(azimuth_rad);
      const double z = std::sin(elevation_rad);
      const double lambda = EquirectLongitude(c.equirectangular, std::atan2(y, x));
      const double phi = std::atan2(z, std::hypot(x, y));
      return {EquirectX(lambda, image_width), EquirectY(phi, image_height)};
    }
  }
  throw Error("DirectionToImage: the omni_ring model has no elevation model");
}

cv::Point2d DirectionToPanorama(const CameraCalibration& c, double azimuth_rad,
                                double elevation_rad) {
  double lo = 0, hi = 0;
  if (c.model == CameraModelType::kFisheye) {
    lo = c.fisheye.min_elevation_deg;
    hi = c.fisheye.max_elevation_deg;
  } else if (c.model == CameraModelType::kEquirectangular) {
    lo = c.equirectangular.min_elevation_deg;
    hi = c.equirectangular.max_elevation_deg;
  } else {
    throw Error("DirectionToPanorama: the omni_ring model has no elevation model");
  }
  double alpha = std::fmod(azimuth_rad, kTwoPi);
  if (alpha < 0) alpha += kTwoPi;
  double column = alpha * c.panorama_width() / kTwoPi;
  if (column >= c.panorama_width()) column -= c.panorama_width();
  return {column, RowOfElevation(elevation_rad, lo, hi, c.panorama_height())};
}

}  // namespace omnicml
