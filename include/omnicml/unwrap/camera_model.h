// Camera models: how a raw camera image maps to the engine's cylindrical panorama
// (docs/design.md "Camera models").
//
// Every model produces the same panorama convention (omni_unwrapper.h): W columns, column
// c looks along the robot-frame azimuth alpha_c = 2 pi c / W counter-clockwise from the
// robot's forward axis; row 0 is the highest elevation. Three models:
//   - kRing: a catadioptric (mirror) camera's ring image (OmniCalibration); rows are
//     linear in the ring's radius between inner_radius_px and outer_radius_px.
//   - kFisheye: one circular fisheye lens whose optical axis points up (to the zenith);
//     equidistant (rho = f psi) or equisolid (rho = 2 f sin(psi / 2)) projection of the
//     angle psi from the axis; rows are linear in elevation over
//     [min_elevation_deg, max_elevation_deg].
//   - kEquirectangular: a full-sphere equirectangular image (the output of dual-fisheye
//     360 cameras): image x linear in longitude over 360 deg, image y linear in latitude
//     from +90 deg (top row) to -90 deg; rows of the panorama are linear in elevation
//     over [min_elevation_deg, max_elevation_deg].
// Pixel coordinates: x to the right, y down, origin at the centre of the top-left pixel
// (cv::remap's convention). Image-plane angles are measured from +x towards +y
// (clockwise on screen).
//
// Plain values; the free functions are pure and thread-safe.
#ifndef OMNICML_UNWRAP_CAMERA_MODEL_H_
#define OMNICML_UNWRAP_CAMERA_MODEL_H_

#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace YAML {
class Node;
}

namespace omnicml {

// How the ring's azimuth runs in the raw image as panorama columns increase.
enum class RingDirection { kCounterClockwise, kClockwise };

// How panorama rows map to ring radius.
//  kLinear: radius linear in row, row 0 at the outer radius (the usual upward-looking
//           mirror whose outer ring sees the highest elevation).
//  kLinearInverted: row 0 at the inner radius.
enum class ElevationMapping { kLinear, kLinearInverted };

// Intrinsic calibration of a catadioptric ring image. Pixel coordinates have x to the
// right and y downwards, origin at the centre of the top-left pixel.
struct OmniCalibration {
  double center_x_px = 320.0;
  double center_y_px = 240.0;
  double inner_radius_px = 40.0;   // radius of panorama's lowest/highest row edge
  double outer_radius_px = 220.0;  // must exceed inner_radius_px
  // Image-plane angle of panorama column 0, measured from the image x axis towards the
  // image y axis (i.e. clockwise on screen), radians.
  double azimuth0_rad = 0.0;
  RingDirection direction = RingDirection::kCounterClockwise;
  ElevationMapping elevation = ElevationMapping::kLinear;
  int panorama_width = 720;   // azimuth bins (columns)
  int panorama_height = 120;  // rows

  // Throws omnicml::Error naming the field when a value is invalid (radii, sizes).
  void Validate() const;
  // Throws omnicml::Error when the ring does not fit inside an image of this size.
  void ValidateFor(int image_width, int image_height) const;

  // YAML round trip (keys equal member names; direction: counter_clockwise|clockwise;
  // elevation: linear|linear_inverted). Unknown keys are an error naming the key.
  static OmniCalibration FromYamlFile(const std::string& path);
  void ToYamlFile(const std::string& path) const;
};

enum class CameraModelType { kRing, kFisheye, kEquirectangular };
// "omni_ring", "fisheye", "equirectangular" (the names of session.yaml's camera.model).
std::string ToString(CameraModelType type);
// Throws omnicml::Error naming the unknown name and the known ones.
CameraModelType CameraModelTypeFromString(const std::string& name);

// Radial projection of a fisheye lens: image radius rho of a ray at angle psi (radians)
// from the optical axis, with f = circle_radius_px / psi_max (equidistant) or
// circle_radius_px / (2 sin(psi_max / 2)) (equisolid), psi_max = field_of_view_deg / 2.
enum class FisheyeProjection { kEquidistant, kEquisolid };
std::string ToString(FisheyeProjection projection);  // "equidistant", "equisolid"

// A circular fisheye image, optical axis up. The image circle (the edge of the field of
// view) has radius circle_radius_px around the centre.
struct FisheyeCalibration {
  double center_x_px = 720.0;  // image position of the optical axis (zenith)
  double center_y_px = 720.0;
  double circle_radius_px = 700.0;   // image radius of the field of view's edge, > 0
  double field_of_view_deg = 180.0;  // full angle of the image circle, (0, 360)
  FisheyeProjection projection = FisheyeProjection::kEquidistant;
  // Elevation band of the panorama (0 = horizontal, +90 = zenith), degrees; row 0 is
  // max_elevation_deg. The band must lie inside the field of view:
  // min_elevation_deg >= 90 - field_of_view_deg / 2.
  double min_elevation_deg = -20.0;
  double max_elevation_deg = 60.0;
  // Image-plane angle of panorama column 0 and how azimuth runs on screen (as the ring).
  double azimuth0_rad = 0.0;
  RingDirection direction = RingDirection::kCounterClockwise;
  int panorama_width = 720;
  int panorama_height = 120;

  // Throws omnicml::Error naming the field when a value is invalid.
  void Validate() const;
};

// A full equirectangular (longitude x latitude) image.
struct EquirectangularCalibration {
  // Elevation band of the panorama, degrees in [-90, 90]; row 0 is max_elevation_deg.
  double min_elevation_deg = -30.0;
  double max_elevation_deg = 60.0;
  // Image longitude of panorama column 0 (the robot's forward axis), radians; image
  // longitude is 0 at the image's middle column and grows with x.
  double azimuth0_rad = 0.0;
  // How the robot's azimuth runs as image x grows: kClockwise (the usual 360-camera output:
  // x to the right is turning right, seen from above) or kCounterClockwise.
  RingDirection direction = RingDirection::kClockwise;
  int panorama_width = 720;
  int panorama_height = 120;

  void Validate() const;
};

// One camera's calibration: the model and its own fields (only the member of `model`
// is meaningful). Converts implicitly from an OmniCalibration (a ring), so code and
// files written for the ring keep working.
struct CameraCalibration {
  CameraModelType model = CameraModelType::kRing;
  OmniCalibration ring;
  FisheyeCalibration fisheye;
  EquirectangularCalibration equirectangular;

  CameraCalibration() = default;
  CameraCalibration(const OmniCalibration& ring_calibration)  // NOLINT: implicit on purpose
      : ring(ring_calibration) {}
  CameraCalibration(const FisheyeCalibration& f)  // NOLINT
      : model(CameraModelType::kFisheye), fisheye(f) {}
  CameraCalibration(const EquirectangularCalibration& e)  // NOLINT
      : model(CameraModelType::kEquirectangular), equirectangular(e) {}

  int panorama_width() const;
  int panorama_height() const;
  void SetPanoramaSize(int width, int height);

  // Throws omnicml::Error naming the field when the active model's values are invalid.
  void Validate() const;
  // Also checks the model against an image size: a ring or fisheye centre must lie in
  // the image and at least kMinVisibleFraction of the panorama's pixels must sample
  // inside it (the rest is marked invalid, OmniUnwrapper::valid_mask); the message says
  // "leaves the image" otherwise.
  void ValidateFor(int image_width, int image_height) const;

  // Reads a calibration file: either a flat map of one model's keys with an optional
  // `model:` key (default omni_ring, so old ring files load unchanged), or a session.yaml
  // style `camera:` section (model, image_width, image_height, calibration), as written by
  // ToYamlFile. Unknown keys are an error naming file, line and key.
  static CameraCalibration FromYamlFile(const std::string& path);
  // Writes the `camera:` section session.yaml takes (atomically).
  void ToYamlFile(const std::string& path, int image_width, int image_height) const;
  // The calibration's keys as YAML lines, each prefixed by `indent` (session.yaml writer).
  std::string YamlFields(const std::string& indent) const;
  bool operator==(const CameraCalibration& other) const;
};

// Minimum fraction of panorama pixels that must sample inside the image.
inline constexpr double kMinVisibleFraction = 0.5;

// Parses the calibration map of `model` (session.yaml's camera.calibration). Keys equal
// the member names; `require_all` makes every key mandatory. Errors name
// "path:line: <where>.<key>". Does not validate values.
CameraCalibration ParseCameraCalibration(CameraModelType model, const std::string& path,
                                         const YAML::Node& node, const std::string& where,
                                         bool require_all);

// Raw-image position (x, y) sampled for panorama position (column, row) (continuous;
// pixel centres at integers) in an image of image_width x image_height (the size matters
// for the equirectangular model only). May lie outside the image (clipped ring).
cv::Point2d PanoramaToImage(const CameraCalibration& c, double column, double row, int image_width,
                            int image_height);
// Inverse: (column in [0, W), row) of a raw-image point, or std::nullopt when the point
// lies outside the model's ring or elevation band widened by `margin_rows` rows.
std::optional<cv::Point2d> ImageToPanorama(const CameraCalibration& c, cv::Point2d xy,
                                           int image_width, int image_height,
                                           double margin_rows = 0.0);
// Fisheye and equirectangular only: raw-image point of the direction at robot azimuth
// alpha (counter-clockwise from forward) and elevation (up from horizontal), radians,
// computed from the projection equations directly. Throws omnicml::Error for the ring
// (which has no elevation model).
cv::Point2d DirectionToImage(const CameraCalibration& c, double azimuth_rad, double elevation_rad,
                             int image_width, int image_height);
// Panorama (column, row) of a direction by the convention alone: column = alpha W / 2 pi
// (in [0, W)), row = (max_elev - elev) / (max_elev - min_elev) H - 0.5. Fisheye and
// equirectangular only.
cv::Point2d DirectionToPanorama(const CameraCalibration& c, double azimuth_rad,
                                double elevation_rad);

}  // namespace omnicml

#endif  // OMNICML_UNWRAP_CAMERA_MODEL_H_
