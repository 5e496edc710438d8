// Omniview camera model: raw catadioptric ring image <-> cylindrical panorama.
//
// Panorama convention used by the whole engine (descriptors, simulator, environment
// model): a panorama is W columns by H rows; column c looks along the robot-frame
// azimuth alpha_c = 2 pi c / W, counter-clockwise from the robot's forward axis (x);
// row 0 is the highest elevation. Turning the robot counter-clockwise by k * 2 pi / W
// therefore rolls the panorama by k columns towards lower indices:
//   after[c] = before[(c + k) mod W].
//
// OmniUnwrapper computes its sampling maps once at construction (cv::remap, bilinear)
// and is then immutable: Unwrap and Render are safe to call from several threads.
#ifndef OMNICML_UNWRAP_OMNI_UNWRAPPER_H_
#define OMNICML_UNWRAP_OMNI_UNWRAPPER_H_

#include <string>

#include <vector>

#include <opencv2/core.hpp>

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

// Result of estimating centre and radii of the ring from an image.
struct AutoCalibrationResult {
  OmniCalibration calibration;  // the input template with centre and radii replaced
  double inner_residual_px = 0; // RMS distance of inner-circle inliers to the fitted circle
  double outer_residual_px = 0; // RMS distance of outer-circle inliers to the fitted circle
  int inner_inliers = 0;
  int outer_inliers = 0;
};

class OmniUnwrapper {
 public:
  // Precomputes the maps for raw images of image_width x image_height pixels.
  // Throws omnicml::Error if the calibration is invalid or leaves the image.
  OmniUnwrapper(const OmniCalibration& calibration, int image_width, int image_height);

  // Raw ring (CV_8UC1 or CV_8UC3 of the construction size) -> panorama of the same type.
  // Throws omnicml::Error on an empty image, a wrong size or an unsupported type.
  cv::Mat Unwrap(const cv::Mat& raw) const;

  // Inverse mapping: panorama (any size; resampled to the calibration's width/height)
  // -> raw ring image of the construction size and the panorama's type; pixels outside
  // the ring are `background`. A raw pixel belongs to the ring when its centre lies within
  // half a pixel of [inner_radius_px, outer_radius_px] (it touches the ring), so that
  // Unwrap(Render(p)) reproduces p up to interpolation, edge rows included; the visible
  // ring of a rendered image is therefore ~0.5 px wider on each side than the radii.
  // Cost: cv::remap over a few rectangles covering the ring (render_rects_), not the
  // pixels of the bounding box's corners or the hole (under 1 ms for 640x480).
  // Throws omnicml::Error on an empty panorama or more than 4 channels.
  cv::Mat Render(const cv::Mat& panorama, const cv::Scalar& background = cv::Scalar::all(0)) const;

  const OmniCalibration& calibration() const { return calibration_; }

 private:
  OmniCalibration calibration_;
  int image_width_;
  int image_height_;
  // Sampling maps in OpenCV's fixed-point form (cv::convertMaps: CV_16SC2 positions in the
  // *_x_ member, CV_16UC1 interpolation indices in the *_y_ member; 1/32 pixel).
  cv::Mat map_x_, map_y_;            // panorama pixel -> raw pixel
  cv::Mat inv_map_x_, inv_map_y_;    // raw pixel -> panorama pixel (padded by one column)
  // Rectangles of the raw image, together holding every pixel Render paints (bands of
  // rows, split around the hole); the pixels outside them keep the background.
  std::vector<cv::Rect> render_rects_;
};

// Estimates centre and radii of the ring: edge points, then a robust circle fit (Ceres,
// Huber loss) for the inner and the outer boundary. `initial` gives sizes, direction and
// the other fields carried over. Throws omnicml::Error if no ring can be found.
// Method: Gaussian blur; Otsu split into dark (outside, hole) and bright (ring) levels; a
// crossing threshold a third of the way from dark to bright; rays from the bright
// region's centroid: the first dark->bright crossing from the centre is an inner edge
// point, the first coming in from the image border an outer one, each refined to the
// sub-pixel peak of the radial gradient; per boundary a Cauchy-loss circle fit marks
// inliers (|residual| <= max(2 px, 3 robust sigma)); the rays are cast again from the
// fitted centre; finally one concentric fit (shared centre, Huber loss) of both
// boundaries' inliers. Needs a ring brighter than a dark outside and a dark hole; the
// outer circle may be cut by the image border (those rays are skipped). Deterministic;
// about 10 ms of CPU for 640x480. Accepts CV_8UC1 or CV_8UC3 images.
AutoCalibrationResult AutoCalibrate(const cv::Mat& raw, const OmniCalibration& initial = {});

// Panoramic input (already unwrapped): returned as is, or resized (bilinear, INTER_AREA
// when shrinking) to width x height when both are positive. Throws omnicml::Error on
// an empty or 1x1 image or a negative size. Resizing keeps the column convention: output
// column c looks along the azimuth of input column c * W_in / W (columns are centred on
// their azimuth and wrap around; plain cv::resize would shift them by a fraction of a
// column). Render resamples panoramas of another size the same way.
cv::Mat PreparePanorama(const cv::Mat& panorama, int width = 0, int height = 0);

// Reads an image file as 8-bit grey or BGR: PNG, JPEG, BMP, TIFF, PBM/PGM/PPM/PAM or WebP,
// recognised by their signature before any decoder runs (OpenCV's other decoders, DICOM
// among them, are not offered untrusted bytes). Throws omnicml::Error naming the file when
// it is missing, not a regular file (directory, FIFO, device), larger than
// kMaxImageFileBytes, of another format, declares more than kMaxImagePixels in its
// PNG/JPEG header (checked before decoding), unreadable, empty, 1x1, or has a channel
// count other than 1, 3 or 4 (4 is converted to 3). 16-bit images are scaled to 8 bit
// (v * 255 / 65535); other depths are an error.
cv::Mat ReadImage(const std::string& path);

// Writes an image atomically: encodes it in memory in the format of the extension, then
// WriteFileAtomic (common/file_io.h: temporary file, fsync, rename over `path`); readers
// never see a partial file. Throws omnicml::Error naming the file on an
// empty image, a path without extension or a failed write (missing directory, no
// permission, format unable to store the image); no temporary file is left behind.
void WriteImage(const std::string& path, const cv::Mat& image);

}  // namespace omnicml

#endif  // OMNICML_UNWRAP_OMNI_UNWRAPPER_H_
