// A simulated raw-ring frame source whose sessions carry a user mask (session.yaml's
// camera.mask_image) over the right quarter of the image, optionally with the masked
// pixels of every frame overwritten by noise: what the mask-plumbing tests of mcl, topo
// and calibrate compare (a masked region must not change their result).
#ifndef OMNICML_TESTS_TESTING_MASKED_RING_SOURCE_H_
#define OMNICML_TESTS_TESTING_MASKED_RING_SOURCE_H_

#include <cstdint>
#include <memory>
#include <vector>

#include <opencv2/core.hpp>

#include "omnicml/sensor/frame.h"
#include "omnicml/sim/simulator.h"

namespace omnicml::testing {

class MaskedRingSource : public FrameSource {
 public:
  // options.output is forced to kRawRing. `declare_mask`: the sessions carry the mask;
  // `scramble`: the pixels under the mask are replaced by noise seeded by the frame index.
  MaskedRingSource(SimulatorOptions options, bool declare_mask, bool scramble)
      : scramble_(scramble) {
    options.output = ImageKind::kRawRing;
    inner_ = std::make_unique<SimulatedFrameSource>(options);
    for (int s = 0; s < inner_->NumSessions(); ++s) {
      SessionInfo info = inner_->Session(s);
      mask_ = cv::Mat(info.camera.image_height, info.camera.image_width, CV_8UC1, cv::Scalar(255));
      mask_.colRange(mask_.cols * 3 / 4, mask_.cols).setTo(0);
      if (declare_mask) {
        info.camera.mask = mask_;
        info.camera.mask_image = "mask.png";
      }
      sessions_.push_back(info);
    }
  }

  int NumSessions() const override { return static_cast<int>(sessions_.size()); }
  const SessionInfo& Session(int index) const override {
    return sessions_[static_cast<std::size_t>(index)];
  }
  bool Next(Frame* frame) override {
    if (!inner_->Next(frame)) return false;
    if (scramble_) {
      cv::Mat noise(frame->image.size(), frame->image.type());
      cv::RNG rng(static_cast<std::uint64_t>(frame->global_index) + 7);
      rng.fill(noise, cv::RNG::UNIFORM, 0, 256);
      frame->image = frame->image.clone();
      noise.copyTo(frame->image, mask_ == 0);
    }
    return true;
  }

 private:
  bool scramble_;
  cv::Mat mask_;
  std::unique_ptr<SimulatedFrameSource> inner_;
  std::vector<SessionInfo> sessions_;
};

}  // namespace omnicml::testing

#endif  // OMNICML_TESTS_TESTING_MASKED_RING_SOURCE_H_
