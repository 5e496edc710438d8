#include "unwrap/internal/png_decode.h"

#include <png.h>

#include <cstring>

namespace omnicml::internal {
namespace {

struct PngSource {
  const std::uint8_t* data = nullptr;
  std::size_t size = 0;
  std::size_t pos = 0;
  char message[256] = {};
};

void OnError(png_structp png, png_const_charp message) {
  auto* source = static_cast<PngSource*>(png_get_error_ptr(png));
  std::strncpy(source->message, message, sizeof source->message - 1);
  png_longjmp(png, 1);
}

void OnWarning(png_structp, png_const_charp) {}  // not fatal; never printed

void OnRead(png_structp png, png_bytep out, png_size_t n) {
  auto* source = static_cast<PngSource*>(png_get_io_ptr(png));
  if (source->size - source->pos < n) png_error(png, "file truncated");
  std::memcpy(out, source->data + source->pos, n);
  source->pos += n;
}

// The libpng calls, in a function whose locals are all plain data (setjmp/longjmp skip
// no destructor): fills *image, or returns false with source->message set.
bool Decode(png_structp png, png_infop info, PngSource* source, cv::Mat* image) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_set_read_fn(png, source, OnRead);
  png_read_info(png, info);
  const png_byte color_type = png_get_color_type(png, info);
  const png_byte bit_depth = png_get_bit_depth(png, info);
  if (color_type == PNG_COLOR_TYPE_PALETTE) png_set_palette_to_rgb(png);
  if (color_type == PNG_COLOR_TYPE_GRAY && bit_depth < 8) png_set_expand_gray_1_2_4_to_8(png);
  if (png_get_valid(png, info, PNG_INFO_tRNS)) png_set_tRNS_to_alpha(png);
  if (color_type == PNG_COLOR_TYPE_GRAY_ALPHA) png_set_gray_to_rgb(png);
  if (bit_depth == 16) png_set_swap(png);  // PNG is big-endian; cv::Mat holds host order
  png_set_bgr(png);
  const int passes = png_set_interlace_handling(png);
  png_read_update_info(png, info);
  const png_uint_32 width = png_get_image_width(png, info);
  const png_uint_32 height = png_get_image_height(png, info);
  const int channels = png_get_channels(png, info);
  const int depth = png_get_bit_depth(png, info) == 16 ? CV_16U : CV_8U;
  if (channels == 2) png_error(png, "grey with alpha not expanded");
  image->create(static_cast<int>(height), static_cast<int>(width), CV_MAKETYPE(depth, channels));
  // Row by row (each interlace pass over all rows): nothing to free should libpng jump.
  for (int pass = 0; pass < passes; ++pass) {
    for (png_uint_32 y = 0; y < height; ++y) {
      png_read_row(png, image->ptr(static_cast<int>(y)), nullptr);
    }
  }
  png_read_end(png, nullptr);
  return true;
}

}  // namespace

cv::Mat DecodePng(const std::vector<std::uint8_t>& bytes, std::string* error) {
  PngSource source;
  source.data = bytes.data();
  source.size = bytes.size();
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &source, OnError, OnWarning);
  if (png == nullptr) {
    *error = "cannot create a PNG decoder";
    return {};
  }
  png_infop info = png_create_info_struct(png);
  cv::Mat image;
  const bool ok = info != nullptr && Decode(png, info, &source, &image);
  png_destroy_read_struct(&png, info != nullptr ? &info : nullptr, nullptr);
  if (!ok) {
    *error = source.message[0] != 0 ? source.message : "cannot decode";
    return {};
  }
  return image;
}

}  // namespace omnicml::internal
