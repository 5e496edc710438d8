#include "omnicml/descriptors/descriptor_factory.h"

#include "omnicml/common/common.h"

namespace omnicml {

void DescriptorOptions::Validate() const {
  try {
    switch (kind) {
      case DescriptorKind::kFourier:
        fourier.Validate();
        return;
      case DescriptorKind::kInvariantFeatureHistogram:
        ifh.Validate();
        return;
      case DescriptorKind::kColorHistogram:
        color.Validate();
        return;
    }
  } catch (const Error& e) {
    throw Error(StrCat("DescriptorOptions.", ToString(kind), ": ", e.what()));
  }
  throw Error(StrCat("DescriptorOptions.kind: unknown descriptor kind ", static_cast<int>(kind)));
}

std::unique_ptr<DescriptorExtractor> MakeDescriptorExtractor(const DescriptorOptions& options) {
  options.Validate();
  switch (options.kind) {
    case DescriptorKind::kFourier:
      return std::make_unique<FourierSignature>(options.fourier);
    case DescriptorKind::kInvariantFeatureHistogram:
      return std::make_unique<InvariantFeatureHistogram>(options.ifh);
    case DescriptorKind::kColorHistogram:
      return std::make_unique<ColorHistogram>(options.color);
  }
  throw Error("MakeDescriptorExtractor: unknown descriptor kind");
}

}  // namespace omnicml
