#include "omnicml/unwrap/omni_unwrapper.h"

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string_view>
#include <system_error>
#include <vector>

#include <unistd.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "omnicml/common/binary_io.h"
#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/limits.h"
#include "unwrap/internal/png_decode.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

// Render paints raw pixels whose centre lies up to half a pixel outside [inner, outer]:
// Unwrap's bilinear samples of the first and last panorama rows (half a radial bin inside
// the ring) then never blend in background, so Unwrap(Render(p)) reproduces p up to
// rounding even on its edge rows (measured: without the margin the edge rows were off by
// 6 grey levels on average, up to 50). The visible ring of a rendered image is thus about
// 0.5 px wider on each side than the calibration's radii.
constexpr double kRenderMarginPx = 0.5;

// Shifts a panorama by `shift` columns around azimuth: out(c) = in(c + shift), wrapping;
// integer shifts are exact, fractional ones bilinear.
cv::Mat ShiftColumnsWrapped(const cv::Mat& in, double shift) {
  const double rounded = std::round(shift);
  if (std::abs(shift - rounded) < 1e-9) {
    const int k = ((static_cast<int>(rounded) % in.cols) + in.cols) % in.cols;
    if (k == 0) return in;
    cv::Mat out;
    cv::hconcat(in.colRange(k, in.cols), in.colRange(0, k), out);
    return out;
  }
  const cv::Matx23d out_to_in(1.0, 0.0, shift, 0.0, 1.0, 0.0);
  cv::Mat out;
  cv::warpAffine(in, out, out_to_in, in.size(), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP,
                 cv::BORDER_WRAP);
  return out;
}

// Resamples a panorama to `size` keeping the convention: output column c looks along the
// same azimuth 2 pi c / W as input column c W_in / W (columns are centred on their azimuth,
// and wrap around). Rows are elevation bins (pixel-area convention, as cv::resize).
// Shrinking both axes averages (INTER_AREA); otherwise bilinear.
cv::Mat ResizePanorama(const cv::Mat& in, cv::Size size) {
  if (in.size() == size) return in;
  const double s = static_cast<double>(in.cols) / size.width;  // input columns per output column
  if (in.cols >= size.width && in.rows >= size.height) {
    // cv::resize centres output column c on input column (c + 0.5) s - 0.5, but the
    // convention wants c s: pre-shift the input by 0.5 - 0.5 s columns (exact for odd s).
    cv::Mat out;
    cv::resize(ShiftColumnsWrapped(in, 0.5 - 0.5 * s), out, size, 0, 0, cv::INTER_AREA);
    return out;
  }
  // Bilinear from a copy padded by one wrapped column on each side: output (c, r) samples
  // input column c s and row (r + 0.5) s_rows - 0.5 (clamped).
  cv::Mat padded;
  cv::copyMakeBorder(in, padded, 0, 0, 1, 1, cv::BORDER_WRAP);
  const double s_rows = static_cast<double>(in.rows) / size.height;
  cv::Mat map_x(size, CV_32FC1), map_y(size, CV_32FC1);
  for (int r = 0; r < size.height; ++r) {
    const float y = static_cast<float>(std::clamp((r + 0.5) * s_rows - 0.5, 0.0, in.rows - 1.0));
    float* mx = map_x.ptr<float>(r);
    float* my = map_y.ptr<float>(r);
    for (int c = 0; c < size.width; ++c) {
      mx[c] = static_cast<float>(c * s + 1.0);
      my[c] = y;
    }
  }
  cv::Mat out;
  cv::remap(padded, out, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  return out;
}

void Require(bool ok, const std::string& what) {
  if (!ok) throw Error(what);
}

std::string TypeName(const cv::Mat& image) {
  return StrCat(image.cols, "x", image.rows, ", ", image.channels(), " channel(s), depth ",
                cv::depthToString(image.depth()));
}

// Checks the chunk structure of a PNG file (lengths within the file, CRC of every chunk,
// IHDR first, IEND present) so that a truncated or corrupted file is reported here in
// one line instead of by libpng's default error handler, which prints its own line to
// stderr before OpenCV returns an empty image. Returns "" when the structure is sound or
// the bytes are not a PNG file.
std::string PngStructureProblem(const std::vector<std::uint8_t>& b) {
  static constexpr std::uint8_t kPng[8] = {0x89, 'P', 'N', 'G', 0x0D, 0x0A, 0x1A, 0x0A};
  if (b.size() < 8 || !std::equal(kPng, kPng + 8, b.begin())) return "";
  const auto be32 = [&](std::size_t i) {
    return (std::uint32_t{b[i]} << 24) | (std::uint32_t{b[i + 1]} << 16) |
           (std::uint32_t{b[i + 2]} << 8) | std::uint32_t{b[i + 3]};
  };
  std::size_t i = 8;
  for (int chunk = 0;; ++chunk) {
    if (i + 12 > b.size()) return StrCat("truncated PNG (no IEND chunk; ", b.size(), " bytes)");
    const std::uint64_t length = be32(i);
    if (length > b.size() - i - 12) {
      return StrCat("truncated PNG (chunk at byte ", i, " runs past the end of the file)");
    }
    const std::string type(b.begin() + static_cast<std::ptrdiff_t>(i + 4),
                           b.begin() + static_cast<std::ptrdiff_t>(i + 8));
    if (chunk == 0 && type != "IHDR") return "corrupted PNG (the first chunk is not IHDR)";
    const std::span<const std::uint8_t> covered(b.data() + i + 4, length + 4);
    if (Crc32(covered) != be32(i + 8 + length)) {
      return StrCat("corrupted PNG (CRC mismatch in the chunk at byte ", i, ")");
    }
    if (type == "IEND") return "";
    i += 12 + length;
  }
}

// The image formats ReadImage decodes, by the signature OpenCV's own decoder checks
// (imgcodecs grfmt_*.cpp checkSignature): PNG, JPEG, BMP, TIFF (classic and BigTIFF),
// PBM/PGM/PPM/PAM and WebP. OpenCV tries its decoders in order and hands bytes no earlier
// decoder claims to later ones; the DICOM decoder (GDCM) then aborts the process on a
// malformed file (fuzz_image found it), so other formats are refused before decoding.
// Returns the format's name, or "" when the bytes start like none of them.
std::string SupportedImageFormat(const std::vector<std::uint8_t>& b) {
  const auto starts_with = [&](std::string_view magic, std::size_t at = 0) {
    return b.size() >= at + magic.size() &&
           std::equal(magic.begin(), magic.end(), b.begin() + static_cast<std::ptrdiff_t>(at),
                      [](char m, std::uint8_t v) { return static_cast<std::uint8_t>(m) == v; });
  };
  using namespace std::string_view_literals;
  if (starts_with("\x89PNG\r\n\x1a\n"sv)) return "PNG";
  if (starts_with("\xFF\xD8\xFF"sv)) return "JPEG";
  if (starts_with("BM"sv)) return "BMP";
  if (starts_with("II\x2A\x00"sv) || starts_with("MM\x00\x2A"sv) || starts_with("II\x2B\x00"sv) ||
      starts_with("MM\x00\x2B"sv)) {
    return "TIFF";
  }
  if (b.size() >= 3 && b[0] == 'P' && b[1] >= '1' && b[1] <= '7' && std::isspace(b[2])) {
    return b[1] == '7' ? "PAM" : "PNM";
  }
  if (starts_with("RIFF"sv) && starts_with("WEBP"sv, 8)) return "WebP";
  return "";
}

// Width and height declared by a PNG (IHDR) or baseline/progressive JPEG (SOFn) header;
// {0, 0} for other formats or a header too short to tell. Lets ReadImage refuse a huge
// image before the decoder allocates it.
std::pair<std::uint64_t, std::uint64_t> DeclaredImageSize(const std::vector<std::uint8_t>& b) {
  const auto be16 = [&](std::size_t i) { return (std::uint64_t{b[i]} << 8) | b[i + 1]; };
  const auto be32 = [&](std::size_t i) { return (be16(i) << 16) | be16(i + 2); };
  static constexpr std::uint8_t kPng[8] = {0x89, 'P', 'N', 'G', 0x0D, 0x0A, 0x1A, 0x0A};
  if (b.size() >= 24 && std::equal(kPng, kPng + 8, b.begin()) &&
      std::equal(b.begin() + 12, b.begin() + 16, "IHDR")) {
    return {be32(16), be32(20)};
  }
  if (b.size() < 4 || b[0] != 0xFF || b[1] != 0xD8) return {0, 0};
  std::size_t i = 2;  // at the 0xFF of a marker
  while (i + 3 < b.size()) {
    if (b[i] != 0xFF) return {0, 0};
    const std::uint8_t m = b[i + 1];
    if (m == 0xFF) {  // fill byte
      ++i;
      continue;
    }
    if (m == 0x01 || (m >= 0xD0 && m <= 0xD8)) {  // markers without a length
      i += 2;
      continue;
    }
    if (m == 0xD9 || m == 0xDA) return {0, 0};  // end of image / start of scan
    const std::uint64_t length = be16(i + 2);
    const bool sof = m >= 0xC0 && m <= 0xCF && m != 0xC4 && m != 0xC8 && m != 0xCC;
    if (sof && i + 8 < b.size()) return {be16(i + 7), be16(i + 5)};  // width, height
    i += 2 + length;
  }
  return {0, 0};
}

}  // namespace

// ---------------------------------------------------------------------------------------
// OmniCalibration

void OmniCalibration::Validate() const {
  auto finite = [](double v) { return std::isfinite(v); };
  Require(finite(center_x_px),
          StrCat("calibration: center_x_px = ", center_x_px, " is not finite"));
  Require(finite(center_y_px),
          StrCat("calibration: center_y_px = ", center_y_px, " is not finite"));
  Require(finite(inner_radius_px) && inner_radius_px >= 0.0,
          StrCat("calibration: inner_radius_px = ", inner_radius_px, " must be finite and >= 0"));
  Require(finite(outer_radius_px) && outer_radius_px > inner_radius_px,
          StrCat("calibration: outer_radius_px = ", outer_radius_px,
                 " must be finite and exceed inner_radius_px = ", inner_radius_px));
  Require(finite(azimuth0_rad),
          StrCat("calibration: azimuth0_rad = ", azimuth0_rad, " is not finite"));
  Require(panorama_width >= 2 && panorama_width <= kMaxPanoramaSidePx,
          StrCat("calibration: panorama_width = ", panorama_width, " must be in [2, ",
                 kMaxPanoramaSidePx, "]"));
  Require(panorama_height >= 1 && panorama_height <= kMaxPanoramaSidePx,
          StrCat("calibration: panorama_height = ", panorama_height, " must be in [1, ",
                 kMaxPanoramaSidePx, "]"));
  Require(
      static_cast<std::uint64_t>(panorama_width) * static_cast<std::uint64_t>(panorama_height) <=
          kMaxImagePixels,
      StrCat("calibration: panorama_width x panorama_height = ", panorama_width, " x ",
             panorama_height, " exceeds ", kMaxImagePixels, " pixels"));
}

void OmniCalibration::ValidateFor(int image_width, int image_height) const {
  CameraCalibration(*this).ValidateFor(image_width, image_height);
}

OmniCalibration OmniCalibration::FromYamlFile(const std::string& path) {
  // One parser for every camera model (CameraCalibration::FromYamlFile); this one only
  // insists on the ring.
  const CameraCalibration c = CameraCalibration::FromYamlFile(path);
  if (c.model != CameraModelType::kRing) {
    throw Error(StrCat(path, ": model ", ToString(c.model), " is not omni_ring"));
  }
  return c.ring;
}

void OmniCalibration::ToYamlFile(const std::string& path) const {
  Validate();
  WriteFileAtomic(path, CameraCalibration(*this).YamlFields(""));
}

// ---------------------------------------------------------------------------------------
// OmniUnwrapper

OmniUnwrapper::OmniUnwrapper(const CameraCalibration& calibration, int image_width,
                             int image_height, const cv::Mat& user_mask)
    : camera_(calibration), image_width_(image_width), image_height_(image_height) {
  camera_.ValidateFor(image_width, image_height);
  if (!user_mask.empty() && (user_mask.type() != CV_8UC1 || user_mask.cols != image_width ||
                             user_mask.rows != image_height)) {
    throw Error(StrCat("mask image is ", TypeName(user_mask),
                       " but the camera needs 8-bit grey of ", image_width, "x", image_height));
  }
  const int width = camera_.panorama_width(), height = camera_.panorama_height();
  const bool equirect = camera_.model == CameraModelType::kEquirectangular;
  border_mode_ = equirect ? cv::BORDER_WRAP : cv::BORDER_REPLICATE;

  // Forward maps: panorama pixel (r, c) -> raw (x, y); a pixel is valid when its sample
  // lies inside the image (always for the equirectangular model, which wraps around in x)
  // and on a non-zero pixel of the user mask.
  map_x_.create(height, width, CV_32FC1);
  map_y_.create(height, width, CV_32FC1);
  valid_mask_.create(height, width, CV_8UC1);
  int valid = 0;
  for (int r = 0; r < height; ++r) {
    float* mx = map_x_.ptr<float>(r);
    float* my = map_y_.ptr<float>(r);
    std::uint8_t* v = valid_mask_.ptr<std::uint8_t>(r);
    for (int c = 0; c < width; ++c) {
      const cv::Point2d p = PanoramaToImage(camera_, c, r, image_width, image_height);
      mx[c] = static_cast<float>(p.x);
      my[c] = static_cast<float>(p.y);
      bool ok = equirect || (p.x >= -0.5 && p.x <= image_width - 0.5 && p.y >= -0.5 &&
                             p.y <= image_height - 0.5);
      if (ok && !user_mask.empty()) {
        // Every pixel the bilinear sample reads must be unmasked, so masked pixels have
        // no influence at all on the valid panorama pixels.
        const int x0 = static_cast<int>(std::floor(p.x)), y0 = static_cast<int>(std::floor(p.y));
        for (int dy = 0; dy < 2 && ok; ++dy) {
          for (int dx = 0; dx < 2 && ok; ++dx) {
            const int xi = std::clamp(x0 + dx, 0, image_width - 1);
            const int yi = std::clamp(y0 + dy, 0, image_height - 1);
            ok = user_mask.at<std::uint8_t>(yi, xi) != 0;
          }
        }
      }
      v[c] = ok ? 255 : 0;
      valid += ok ? 1 : 0;
    }
  }
  valid_fraction_ = static_cast<double>(valid) / (static_cast<double>(width) * height);
  if (valid == 0) throw Error("the mask image leaves no valid panorama pixel");

  // Inverse maps: raw (x, y) -> coordinates in the panorama padded by one wrapped column on
  // each side (Render), so bilinear sampling wraps around azimuth. Rows are clamped to
  // [0, H-1] (replicating the first and last row up to the band's edges). A raw pixel is
  // painted when it lies within about kRenderMarginPx of the ring or band; the others
  // point far outside the padded panorama and get the background.
  // kRenderMarginPx in rows at the band's first and last row (the larger of the two).
  const auto rows_per_px = [&](double row) {
    const cv::Point2d a = PanoramaToImage(camera_, 0, row - 0.5, image_width, image_height);
    const cv::Point2d b = PanoramaToImage(camera_, 0, row + 0.5, image_width, image_height);
    return 1.0 / std::max(1e-9, std::hypot(a.x - b.x, a.y - b.y));
  };
  const double margin_rows =
      kRenderMarginPx * std::max(rows_per_px(0.0), rows_per_px(height - 1.0));
  constexpr float kOutside = -1000.0f;
  inv_map_x_.create(image_height, image_width, CV_32FC1);
  inv_map_y_.create(image_height, image_width, CV_32FC1);
  for (int y = 0; y < image_height; ++y) {
    float* ix = inv_map_x_.ptr<float>(y);
    float* iy = inv_map_y_.ptr<float>(y);
    for (int x = 0; x < image_width; ++x) {
      const std::optional<cv::Point2d> q =
          ImageToPanorama(camera_, cv::Point2d(x, y), image_width, image_height, margin_rows);
      if (!q) {
        ix[x] = kOutside;
        iy[x] = kOutside;
        continue;
      }
      ix[x] = static_cast<float>(q->x + 1.0);
      iy[x] = static_cast<float>(std::clamp(q->y, 0.0, static_cast<double>(height - 1)));
    }
  }

  // Render's rectangles: bands of kBandRows rows over the painted pixels' columns; a band
  // whose rows all have a hole (unpainted pixels between painted ones) is split around
  // the columns unpainted in all its rows. cv::remap is pointwise, so remapping these
  // rectangles paints the same bytes as remapping the whole bounding box, without the
  // slow border path over the ~25 % of the box outside the ring and in the hole.
  constexpr int kBandRows = 16;
  for (int y0 = 0; y0 < image_height; y0 += kBandRows) {
    const int y1 = std::min(image_height, y0 + kBandRows);
    int xmin = image_width, xmax = -1;       // painted columns of the band
    int hole_lo = 0, hole_hi = image_width;  // columns unpainted in every row (in a hole)
    bool all_rows_have_hole = true;
    for (int y = y0; y < y1; ++y) {
      const float* ix = inv_map_x_.ptr<float>(y);
      int first = -1, last = -1;
      for (int x = 0; x < image_width; ++x) {
        if (ix[x] == kOutside) continue;
        if (first < 0) first = x;
        last = x;
      }
      if (first < 0) continue;
      xmin = std::min(xmin, first);
      xmax = std::max(xmax, last);
      // The hole of this row: the longest unpainted run between first and last.
      int best_lo = 0, best_hi = -1;
      for (int x = first; x <= last;) {
        if (ix[x] != kOutside) {
          ++x;
          continue;
        }
        int e = x;
        while (e + 1 <= last && ix[e + 1] == kOutside) ++e;
        if (e - x > best_hi - best_lo) {
          best_lo = x;
          best_hi = e;
        }
        x = e + 1;
      }
      if (best_hi < best_lo) {
        all_rows_have_hole = false;
      } else {
        hole_lo = std::max(hole_lo, best_lo);
        hole_hi = std::min(hole_hi, best_hi);
      }
    }
    if (xmax < 0) continue;  // nothing painted in this band
    if (all_rows_have_hole && hole_lo <= hole_hi && hole_lo > xmin && hole_hi < xmax) {
      render_rects_.emplace_back(xmin, y0, hole_lo - xmin, y1 - y0);
      render_rects_.emplace_back(hole_hi + 1, y0, xmax - hole_hi, y1 - y0);
    } else {
      render_rects_.emplace_back(xmin, y0, xmax - xmin + 1, y1 - y0);
    }
  }

  // Fixed-point maps (1/32 pixel; OpenCV's fastest remap path): map_x_ holds the integer
  // positions (CV_16SC2), map_y_ the interpolation table indices (CV_16UC1).
  cv::Mat fixed_xy, fixed_table;
  cv::convertMaps(map_x_, map_y_, fixed_xy, fixed_table, CV_16SC2);
  map_x_ = fixed_xy;
  map_y_ = fixed_table;
  cv::convertMaps(inv_map_x_, inv_map_y_, fixed_xy, fixed_table, CV_16SC2);
  inv_map_x_ = fixed_xy;
  inv_map_y_ = fixed_table;
}

cv::Mat OmniUnwrapper::Unwrap(const cv::Mat& raw) const {
  cv::Mat panorama;
  Unwrap(raw, &panorama);
  return panorama;
}

void OmniUnwrapper::Unwrap(const cv::Mat& raw, cv::Mat* panorama) const {
  OMNICML_CHECK(panorama != nullptr);
  if (raw.empty()) throw Error("Unwrap: the raw image is empty");
  if (raw.cols != image_width_ || raw.rows != image_height_) {
    throw Error(StrCat("Unwrap: raw image is ", raw.cols, "x", raw.rows,
                       " but the unwrapper was made for ", image_width_, "x", image_height_));
  }
  if (raw.type() != CV_8UC1 && raw.type() != CV_8UC3) {
    throw Error(StrCat("Unwrap: unsupported raw image type (", TypeName(raw),
                       "); expected 8-bit grey or BGR"));
  }
  cv::remap(raw, *panorama, map_x_, map_y_, cv::INTER_LINEAR, border_mode_);
}

cv::Mat OmniUnwrapper::Render(const cv::Mat& panorama, const cv::Scalar& background) const {
  if (panorama.empty()) throw Error("Render: the panorama is empty");
  if (panorama.channels() > 4)
    throw Error(StrCat("Render: unsupported panorama (", TypeName(panorama), ")"));
  const cv::Size size(camera_.panorama_width(), camera_.panorama_height());
  const cv::Mat resized = ResizePanorama(panorama, size);
  cv::Mat padded;
  cv::copyMakeBorder(resized, padded, 0, 0, 1, 1, cv::BORDER_WRAP);
  // Only the ring's rectangles need sampling; the rest is background.
  cv::Mat raw(image_height_, image_width_, panorama.type(), background);
  for (const cv::Rect& rect : render_rects_) {
    cv::Mat raw_rect = raw(rect);
    cv::remap(padded, raw_rect, inv_map_x_(rect), inv_map_y_(rect), cv::INTER_LINEAR,
              cv::BORDER_CONSTANT, background);
    OMNICML_CHECK(raw_rect.data == raw(rect).data) << "remap reallocated its output";
  }
  return raw;
}

// ---------------------------------------------------------------------------------------
// Images

cv::Mat PreparePanorama(const cv::Mat& panorama, int width, int height) {
  if (panorama.empty()) throw Error("PreparePanorama: the panorama is empty");
  if (panorama.cols <= 1 && panorama.rows <= 1) {
    throw Error(StrCat("PreparePanorama: the panorama is ", panorama.cols, "x", panorama.rows,
                       " (too small)"));
  }
  if (width < 0 || height < 0) {
    throw Error(StrCat("PreparePanorama: requested size ", width, "x", height, " is negative"));
  }
  if (width == 0 || height == 0 || (width == panorama.cols && height == panorama.rows))
    return panorama;
  return ResizePanorama(panorama, cv::Size(width, height));
}

cv::Mat OmniUnwrapper::MaskFor(int width, int height) const {
  if (valid_fraction_ >= 1.0) return cv::Mat();
  return PrepareMask(valid_mask_, width, height);
}

cv::Mat PrepareMask(const cv::Mat& valid_mask, int width, int height) {
  if (valid_mask.cols == width && valid_mask.rows == height) return valid_mask;
  cv::Mat resized = PreparePanorama(valid_mask, width, height);
  cv::Mat out;
  cv::threshold(resized, out, 127, 255, cv::THRESH_BINARY);
  return out;
}

cv::Mat ReadImage(const std::string& path) {
  // Only a regular file (not a FIFO or device), read once: decoding from memory checks
  // the same bytes that were checked here.
  const std::vector<std::uint8_t> bytes = ReadBinaryFile(path, kMaxImageFileBytes, "image file");
  if (bytes.empty()) throw Error(StrCat("image file '", path, "' is empty (0 bytes)"));
  const auto [declared_width, declared_height] = DeclaredImageSize(bytes);
  if (declared_width * declared_height > kMaxImagePixels) {
    throw Error(StrCat("image file '", path, "' declares ", declared_width, "x", declared_height,
                       " pixels (more than the limit of ", kMaxImagePixels, ")"));
  }
  if (SupportedImageFormat(bytes).empty()) {
    throw Error(StrCat("image file '", path,
                       "' is unreadable: not a PNG, JPEG, BMP, TIFF, PBM/PGM/PPM/PAM or WebP "
                       "image (unknown signature)"));
  }
  if (const std::string problem = PngStructureProblem(bytes); !problem.empty()) {
    throw Error(StrCat("image file '", path, "' is unreadable: ", problem));
  }
  cv::Mat image;
  if (SupportedImageFormat(bytes) == "PNG") {
    // libpng directly: its messages go into the one-line error, never to stderr.
    std::string problem;
    image = internal::DecodePng(bytes, &problem);
    if (image.empty()) {
      throw Error(StrCat("image file '", path, "' is unreadable: PNG: ", Excerpt(problem, 200)));
    }
  } else {
    try {
      // Decoder warnings (libjpeg) go to OpenCV's logger, which stays quiet below its error
      // level; failures surface here as an empty image.
      image = cv::imdecode(bytes, cv::IMREAD_UNCHANGED);
    } catch (const cv::Exception& e) {
      throw Error(StrCat("image file '", path, "' is unreadable: ", e.what()));
    }
  }
  if (image.empty()) {
    throw Error(
        StrCat("image file '", path, "' is unreadable (not an image or an unsupported format)"));
  }
  if (image.cols <= 1 && image.rows <= 1) {
    throw Error(StrCat("image file '", path, "' is ", image.cols, "x", image.rows,
                       " (too small to be an image)"));
  }
  const int channels = image.channels();
  if (channels != 1 && channels != 3 && channels != 4) {
    throw Error(StrCat("image file '", path, "' has ", channels, " channels (expected 1, 3 or 4)"));
  }
  if (image.depth() == CV_16U) {
    image.convertTo(image, CV_8U, 255.0 / 65535.0);
  } else if (image.depth() != CV_8U) {
    throw Error(StrCat("image file '", path, "' has unsupported pixel depth ",
                       cv::depthToString(image.depth()), " (expected 8 or 16 bit)"));
  }
  if (channels == 4) cv::cvtColor(image, image, cv::COLOR_BGRA2BGR);
  return image;
}

void WriteImage(const std::string& path, const cv::Mat& image) {
  if (image.empty()) throw Error(StrCat("cannot write image '", path, "': the image is empty"));
  const fs::path target(path);
  if (target.extension().empty()) {
    throw Error(StrCat("cannot write image '", path, "': no file extension to choose the format"));
  }
  std::vector<std::uint8_t> encoded;
  bool ok = false;
  std::string reason;
  try {
    ok = cv::imencode(target.extension().string(), image, encoded);
  } catch (const cv::Exception& e) {
    reason = StrCat(": ", e.what());
  }
  if (!ok) {
    throw Error(StrCat("cannot write image '", path, "' (", TypeName(image), ")",
                       reason.empty() ? " (format unable to store the image)" : reason));
  }
  WriteFileAtomic(target, encoded);  // temporary file, fsync, rename; names the path
}

}  // namespace omnicml
