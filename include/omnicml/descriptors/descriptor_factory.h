// Builds the configured descriptor extractor, so the engine, the baselines and the CLI
// choose a descriptor by configuration only (docs/design.md "Descriptors").
#ifndef OMNICML_DESCRIPTORS_DESCRIPTOR_FACTORY_H_
#define OMNICML_DESCRIPTORS_DESCRIPTOR_FACTORY_H_

#include <memory>

#include "omnicml/descriptors/color_histogram.h"
#include "omnicml/descriptors/descriptor.h"
#include "omnicml/descriptors/fourier_signature.h"
#include "omnicml/descriptors/invariant_feature_histogram.h"

namespace omnicml {

struct DescriptorOptions {
  // Which descriptor; only the matching options struct below is used.
  DescriptorKind kind = DescriptorKind::kFourier;
  FourierOptions fourier;
  IfhOptions ifh;
  ColorHistogramOptions color;

  // Validates the options of the selected kind; throws omnicml::Error naming the field
  // (prefixed "fourier.", "ifh." or "color.") or an unknown kind.
  void Validate() const;
};

// The options schema (common/options.h): YAML keys, dump, binary codec.
template <class V>
void VisitFields(V& v, DescriptorOptions& o) {
  v.Enum("kind", o.kind,
         {DescriptorKind::kFourier, DescriptorKind::kInvariantFeatureHistogram,
          DescriptorKind::kColorHistogram});
  v.Section("fourier", o.fourier);
  v.Section("ifh", o.ifh);
  v.Section("color", o.color);
}

// A new extractor of options.kind. Throws omnicml::Error on invalid options. The
// result is immutable and thread-safe (descriptor.h).
std::unique_ptr<DescriptorExtractor> MakeDescriptorExtractor(const DescriptorOptions& options);

}  // namespace omnicml

#endif  // OMNICML_DESCRIPTORS_DESCRIPTOR_FACTORY_H_
