// PNG decoding with libpng directly, so that libpng's own messages (errors such as
// "IDAT: invalid distance too far back", warnings such as "iCCP: known incorrect sRGB
// profile") are captured instead of printed on stderr: a bad PNG gives one line, the
// error naming the file, and a good one prints nothing.
//
// Thread-safety: DecodePng is reentrant (no shared state).
#ifndef OMNICML_UNWRAP_INTERNAL_PNG_DECODE_H_
#define OMNICML_UNWRAP_INTERNAL_PNG_DECODE_H_

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace omnicml::internal {

// Decodes PNG `bytes` the way cv::imdecode(IMREAD_UNCHANGED) does: 8 or 16 bits per
// channel, 1 (grey), 3 (BGR) or 4 (BGRA) channels; palettes and bit depths below 8 are
// expanded, grey with alpha becomes BGRA. On a decoding error returns an empty Mat and
// stores libpng's message in *error. Warnings are dropped.
cv::Mat DecodePng(const std::vector<std::uint8_t>& bytes, std::string* error);

}  // namespace omnicml::internal

#endif  // OMNICML_UNWRAP_INTERNAL_PNG_DECODE_H_
