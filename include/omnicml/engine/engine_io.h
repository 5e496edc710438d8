// Saving and loading the whole CmlEngine state, so a multi-day run can stop after any
// day and go on later with exactly the result of one uninterrupted run.
//
// File layout (all integers little-endian, binary_io.h encoding):
//   magic            8 bytes  "OMNICML\0"
//   format version   u32      kEngineFormatVersion
//   payload length   u64      bytes of the payload
//   payload                   options: every field of CmlEngineOptions and its sections, as
//                             the named tree of common/options.h (EncodeOptions), so a load
//                             restores every field or fails naming the missing one;
//                             counters, session state, next frame index, the tracker's
//                             mixture, the pending multimodal frames and their anchor, the
//                             queued map updates, the environment model
//                             (EnvironmentModel::Serialize: views, counters, next ids, events)
//                             and the global pose graph (PoseGraph::Write)
//   checksum         u32      CRC-32 (binary_io.h Crc32) of the payload
// Doubles are stored bit for bit, so SaveEngine -> LoadEngine restores bit-identical
// state: running day 1, saving, loading and running day 2 gives exactly the estimates and
// map of one run over both days (the descriptor extractor and the session's unwrapper
// are rebuilt from the stored options and camera).
//
// Writing is atomic: the bytes go to a temporary file in the same directory, which is
// fsync'ed and then renamed over `path` (and the directory fsync'ed), so a crash leaves
// either the old file or the new one, never a torn one.
//
// Failures: omnicml::Error whose message starts with the path and says what is wrong
// (cannot open/write, not an omnicml engine file (magic), unsupported format version,
// truncated, checksum mismatch, malformed payload).
//
// Thread-safety: call between ProcessFrame calls, from the engine's thread.
#ifndef OMNICML_ENGINE_ENGINE_IO_H_
#define OMNICML_ENGINE_ENGINE_IO_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "omnicml/common/binary_io.h"
#include "omnicml/engine/cml_engine.h"

namespace omnicml {

// Version of the payload layout written by SaveEngine. Bump on any change.
// 4: the options section is the schema's tree of named fields (common/options.h).
// 5: descriptors of pending frames and queued updates in the descriptor record encoding
//    (descriptor.h WriteDescriptorRecord), as the map's views.
// 6: the bounded event log: option model.max_events; the model section (version 3) holds
//    the number of events logged, per-session event counts and the ring of recent events.
// 7: options model.index_min_views, model.index_max_bounded_fraction and model.index_dims
//    (place retrieval); the global pose graph: options section
//    pose_graph; after the model, the graph's nodes, closures, recent frame odometry and
//    its state (pose_graph.h Write). Files of version 6 are rejected with both versions
//    named (re-run to rebuild them).
// 8: option section gated_matching (pose-gated matching).
// 9: options model.ann_min_views, ann_m, ann_ef_construction, ann_ef, ann_k (approximate
//    retrieval; the graph is rebuilt on load, not stored); descriptor.color's
//    illumination options.
// 10: option model.merge_precision_weighted. 11: option model.look_back_frames and the
//    model section's version 4 (its recent updates).
// 12: option model.forget_unconfirmed_views.
// 13: option descriptor.ifh.normalize_columns.
// 14: the session camera's model (ring, fisheye, equirectangular), its fields and the
//    user mask after the ring calibration.
// 15: the model section's version 5 (each component's spread) and the options declared
//    Since(15) in their VisitFields (tracker.fusion, gate_confidence, the motion noise and
//    spatial scale sources, the pose graph's closure model and marginals, the appearance
//    offsets, ...). Options added after 15 without a format bump were declared Since(16):
//    map_update_spacing_m (when it is set, the session state after next_frame also holds
//    the last map update's session and position), reference_frame_step_m and
//    hypothesis_evidence_scale (the first read only when a run starts a new map).
// 16: the model section's version 6 (the view persistence counts and belief) and the
//    options declared Since(16), now part of the format (model.forgetting.
//    persistence_min_probability added with it).
// 17: option smooth_map_updates, declared Since(17) (when it is set, the session state
//    after next_frame also holds the frames behind the smoothing); the defaults of
//    smooth_map_updates (true) and model.merge_fusion (convex_combination) changed with it.
//    Options added after 17 without a bump are declared Since(18): stored only when not
//    default.
// The model's options keep these flat names in the file (model.e_max, model.forgetting,
// ...) although YAML and C++ group them in sections (environment_model_options.h
// FlatModelOptionsValue), so files of every version keep their bytes and load as before.
inline constexpr std::uint32_t kEngineFormatVersion = 17;
// The 8 magic bytes (including the terminating NUL).
inline constexpr char kEngineMagic[8] = {'O', 'M', 'N', 'I', 'C', 'M', 'L', '\0'};

// Writes the engine state to `path` atomically. Throws omnicml::Error on I/O failure.
void SaveEngine(const CmlEngine& engine, const std::string& path);

// Reads an engine written by SaveEngine. Throws omnicml::Error naming `path` and the
// problem (see the file comment).
std::unique_ptr<CmlEngine> LoadEngine(const std::string& path);

// The file bytes SaveEngine writes (header, payload, checksum); exposed for tests.
std::vector<std::uint8_t> EncodeEngine(const CmlEngine& engine);
// Parses bytes produced by EncodeEngine; `source` names them in errors.
std::unique_ptr<CmlEngine> DecodeEngine(const std::vector<std::uint8_t>& bytes,
                                        const std::string& source);

// Option encoding, shared with anything else that stores an engine configuration. Written
// for the current format; fields added in a later format than `format_version` (the
// file's) may be absent and take their defaults (common/options.h Since).
void WriteEngineOptions(BinaryWriter& out, const CmlEngineOptions& options);
CmlEngineOptions ReadEngineOptions(BinaryReader& in,
                                   std::uint32_t format_version = kEngineFormatVersion);

}  // namespace omnicml

#endif  // OMNICML_ENGINE_ENGINE_IO_H_
