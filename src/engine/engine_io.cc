#include "omnicml/engine/engine_io.h"

#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <utility>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/options.h"
#include "omnicml/geometry/pose_io.h"

namespace omnicml {

// Restores the private state of a CmlEngine (friend of CmlEngine).
class EngineStateAccess {
 public:
  static void Write(BinaryWriter& out, const CmlEngine& e);
  static std::unique_ptr<CmlEngine> Read(BinaryReader& in);
};

namespace {

constexpr std::size_t kHeaderBytes = 8 + 4 + 8;
constexpr std::size_t kTrailerBytes = 4;

// ---- small value types -------------------------------------------------------------

using internal::ReadMatrix3;
using internal::ReadPose;
using internal::WriteMatrix3;
using internal::WritePose;

void WriteGaussian(BinaryWriter& out, const Gaussian& g) {
  WritePose(out, g.mean);
  WriteMatrix3(out, g.covariance);
  out.Write<double>(g.weight);
}
Gaussian ReadGaussian(BinaryReader& in, const char* what) {
  Gaussian g;
  g.mean = ReadPose(in, what);
  g.covariance = ReadMatrix3(in, what);
  g.weight = in.Read<double>(what);
  return g;
}
void WriteIncrement(BinaryWriter& out, const OdometryIncrement& u) {
  out.Write<double>(u.rot1_rad);
  out.Write<double>(u.trans_m);
  out.Write<double>(u.rot2_rad);
}
OdometryIncrement ReadIncrement(BinaryReader& in, const char* what) {
  OdometryIncrement u;
  u.rot1_rad = in.Read<double>(what);
  u.trans_m = in.Read<double>(what);
  u.rot2_rad = in.Read<double>(what);
  return u;
}
// Descriptors of pending frames and queued updates use the descriptor record encoding
// (descriptor.h), as the map's views do; they must fit the engine's extractor.
Descriptor ReadDescriptor(BinaryReader& in, const char* what,
                          const DescriptorExtractor& extractor) {
  Descriptor d = ReadDescriptorRecord(in);
  if (d.kind != extractor.kind() || d.features.size() != extractor.FeatureSize()) {
    in.Fail(what, StrCat("a ", ToString(d.kind), " descriptor with ", d.features.size(),
                         " features, the engine's extractor gives ", ToString(extractor.kind()),
                         " with ", extractor.FeatureSize()));
  }
  return d;
}

// Reads an enum stored as its underlying integer and checks it against [lo, hi].
template <typename E>
E ReadEnum(BinaryReader& in, const char* what, int lo, int hi) {
  using U = std::underlying_type_t<E>;
  const auto v = static_cast<long long>(in.Read<U>(what));
  if (v < lo || v > hi) in.Fail(what, StrCat("invalid value ", v));
  return static_cast<E>(v);
}

void WriteCalibration(BinaryWriter& out, const OmniCalibration& c) {
  out.Write<double>(c.center_x_px);
  out.Write<double>(c.center_y_px);
  out.Write<double>(c.inner_radius_px);
  out.Write<double>(c.outer_radius_px);
  out.Write<double>(c.azimuth0_rad);
  out.Write<std::int32_t>(static_cast<std::int32_t>(c.direction));
  out.Write<std::int32_t>(static_cast<std::int32_t>(c.elevation));
  out.Write<std::int32_t>(c.panorama_width);
  out.Write<std::int32_t>(c.panorama_height);
}

OmniCalibration ReadCalibration(BinaryReader& in) {
  OmniCalibration c;
  c.center_x_px = in.Read<double>("camera.calibration.center_x_px");
  c.center_y_px = in.Read<double>("camera.calibration.center_y_px");
  c.inner_radius_px = in.Read<double>("camera.calibration.inner_radius_px");
  c.outer_radius_px = in.Read<double>("camera.calibration.outer_radius_px");
  c.azimuth0_rad = in.Read<double>("camera.calibration.azimuth0_rad");
  c.direction = ReadEnum<RingDirection>(in, "camera.calibration.direction", 0, 1);
  c.elevation = ReadEnum<ElevationMapping>(in, "camera.calibration.elevation", 0, 1);
  c.panorama_width = in.Read<std::int32_t>("camera.calibration.panorama_width");
  c.panorama_height = in.Read<std::int32_t>("camera.calibration.panorama_height");
  return c;
}

// The camera model's fields after the ring calibration (format 14): model, fisheye,
// equirectangular, then the user mask (rows, cols, bytes; 0 x 0 when none).
void WriteCamera(BinaryWriter& out, const CameraModel& camera) {
  const CameraCalibration& c = camera.calibration;
  WriteCalibration(out, c.ring);
  out.Write<std::int32_t>(static_cast<std::int32_t>(c.model));
  const FisheyeCalibration& f = c.fisheye;
  for (const double v : {f.center_x_px, f.center_y_px, f.circle_radius_px, f.field_of_view_deg,
                         f.min_elevation_deg, f.max_elevation_deg, f.azimuth0_rad}) {
    out.Write<double>(v);
  }
  out.Write<std::int32_t>(static_cast<std::int32_t>(f.projection));
  out.Write<std::int32_t>(static_cast<std::int32_t>(f.direction));
  out.Write<std::int32_t>(f.panorama_width);
  out.Write<std::int32_t>(f.panorama_height);
  const EquirectangularCalibration& q = c.equirectangular;
  for (const double v : {q.min_elevation_deg, q.max_elevation_deg, q.azimuth0_rad})
    out.Write<double>(v);
  out.Write<std::int32_t>(static_cast<std::int32_t>(q.direction));
  out.Write<std::int32_t>(q.panorama_width);
  out.Write<std::int32_t>(q.panorama_height);
  const cv::Mat mask = camera.mask.empty() ? cv::Mat() : camera.mask.clone();  // continuous
  out.Write<std::int32_t>(mask.rows);
  out.Write<std::int32_t>(mask.cols);
  if (!mask.empty()) out.WriteBytes(std::span<const std::uint8_t>(mask.data, mask.total()));
}

void ReadCamera(BinaryReader& in, CameraModel& camera) {
  CameraCalibration& c = camera.calibration;
  c.ring = ReadCalibration(in);
  c.model = ReadEnum<CameraModelType>(in, "camera.model", 0, 2);
  FisheyeCalibration& f = c.fisheye;
  for (double* v : {&f.center_x_px, &f.center_y_px, &f.circle_radius_px, &f.field_of_view_deg,
                    &f.min_elevation_deg, &f.max_elevation_deg, &f.azimuth0_rad}) {
    *v = in.Read<double>("camera.fisheye");
  }
  f.projection = ReadEnum<FisheyeProjection>(in, "camera.fisheye.projection", 0, 1);
  f.direction = ReadEnum<RingDirection>(in, "camera.fisheye.direction", 0, 1);
  f.panorama_width = in.Read<std::int32_t>("camera.fisheye.panorama_width");
  f.panorama_height = in.Read<std::int32_t>("camera.fisheye.panorama_height");
  EquirectangularCalibration& q = c.equirectangular;
  for (double* v : {&q.min_elevation_deg, &q.max_elevation_deg, &q.azimuth0_rad}) {
    *v = in.Read<double>("camera.equirectangular");
  }
  q.direction = ReadEnum<RingDirection>(in, "camera.equirectangular.direction", 0, 1);
  q.panorama_width = in.Read<std::int32_t>("camera.equirectangular.panorama_width");
  q.panorama_height = in.Read<std::int32_t>("camera.equirectangular.panorama_height");
  const auto rows = in.Read<std::int32_t>("camera.mask.rows");
  const auto cols = in.Read<std::int32_t>("camera.mask.cols");
  if (rows < 0 || cols < 0 || rows > 65536 || cols > 65536) in.Fail("camera.mask", "invalid size");
  camera.mask = cv::Mat();
  if (rows > 0 && cols > 0) {
    const std::vector<std::uint8_t> bytes = in.ReadBytes(
        static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols), "camera.mask");
    camera.mask = cv::Mat(rows, cols, CV_8UC1);
    std::copy(bytes.begin(), bytes.end(), camera.mask.data);
  }
}

[[noreturn]] void FailFile(const std::string& path, const std::string& message) {
  throw Error(StrCat(path, ": ", message));
}

}  // namespace

// The options section is the schema's tree of every field (cml_engine.h VisitFields,
// common/options.h EncodeOptionValue): names and values, so reading checks that every
// field is present and none is unknown. The model's options are stored in the flat
// layout the file has always had (environment_model_options.h FlatModelOptionsValue), so files keep
// their bytes across the grouping of those options into sections. Fields added after the
// file's format version (Since in VisitFields, e.g. tracker.fusion) are written only when
// they differ from their defaults and read as defaults when absent.
void WriteEngineOptions(BinaryWriter& out, const CmlEngineOptions& o) {
  OptionValue tree = OptionsToFileValue(o, kEngineFormatVersion);
  for (auto& [key, value] : tree.members) {
    if (key == "model") value = FlatModelOptionsValue(value);
  }
  EncodeOptionValue(out, tree);
}

CmlEngineOptions ReadEngineOptions(BinaryReader& in, std::uint32_t format_version) {
  OptionValue tree = DecodeOptionValue(in, "options");
  for (auto& [key, value] : tree.members) {
    if (key == "model") value = GroupedModelOptionsValue(value);
  }
  CmlEngineOptions o;
  OptionsFromValue(tree, OptionSource{"options", true, {}, format_version}, &o);
  o.reconstruction.motion = o.tracker.motion;
  return o;
}

void EngineStateAccess::Write(BinaryWriter& out, const CmlEngine& e) {
  WriteEngineOptions(out, e.options_);
  // Counters.
  const EngineCounters& c = e.counters_;
  for (std::int64_t v :
       {c.frames, c.unimodal_frames, c.multimodal_frames, c.unknown_frames, c.reconstructed_frames,
        c.dropped_pending_frames, c.updates_queued, c.global_seeds, c.global_fallbacks}) {
    out.Write<std::int64_t>(v);
  }
  // Session state.
  const EngineSessionState& s = e.session_;
  out.Write<std::int32_t>(s.session);
  out.Write<bool>(s.in_session);
  out.Write<std::int32_t>(static_cast<std::int32_t>(s.camera.kind));
  out.Write<std::int32_t>(s.camera.image_width);
  out.Write<std::int32_t>(s.camera.image_height);
  WriteCamera(out, s.camera);
  out.Write<std::int32_t>(static_cast<std::int32_t>(s.start_mode));
  out.Write<bool>(s.has_prev_odom);
  WritePose(out, s.prev_odom);
  out.Write<bool>(s.awaiting_global_seed);
  out.Write<std::int64_t>(e.next_frame_);
  // The last map update's place, only with map_update_spacing_m (an option stored only when
  // not the default, so files without it keep their layout).
  if (e.options_.map_update_spacing_m > 0.0) {
    out.Write<bool>(e.last_map_update_.has_value());
    if (e.last_map_update_) {
      out.Write<std::int32_t>(e.last_map_update_->session);
      out.Write<double>(e.last_map_update_->x_m);
      out.Write<double>(e.last_map_update_->y_m);
    }
  }
  // The frames behind the smoothing of the queued updates, only with smooth_map_updates
  // (stored only when set).
  if (e.options_.smooth_map_updates) {
    out.Write<std::uint64_t>(e.smoothing_history_.size());
    for (const CmlEngine::SmoothingFrame& s : e.smoothing_history_) {
      out.Write<std::int64_t>(s.frame);
      out.Write<std::int32_t>(s.session);
      WriteIncrement(out, s.increment);
      out.Write<bool>(s.filtered.has_value());
      if (s.filtered) WriteGaussian(out, *s.filtered);
    }
  }
  // Tracker mixture.
  const Mixture& m = e.tracker_.state();
  out.Write<std::uint64_t>(m.size());
  for (const Gaussian& g : m) WriteGaussian(out, g);
  // Pending multimodal frames and their anchor.
  out.Write<std::uint64_t>(e.pending_.size());
  for (const PendingFrame& p : e.pending_) {
    out.Write<std::int64_t>(p.frame);
    out.Write<std::int32_t>(p.session);
    WriteDescriptorRecord(out, p.descriptor);
    WriteIncrement(out, p.increment);
    out.Write<bool>(p.filtered.has_value());
    if (p.filtered) WriteGaussian(out, *p.filtered);
  }
  out.Write<bool>(e.anchor_.has_value());
  if (e.anchor_) {
    out.Write<std::int64_t>(e.anchor_->first);
    WriteGaussian(out, e.anchor_->second);
  }
  // Queued map updates (the worker is idle between frames).
  const std::deque<MapUpdate>& q = e.updater_->queued();
  out.Write<std::uint64_t>(q.size());
  for (const MapUpdate& u : q) {
    out.Write<std::int64_t>(u.frame);
    out.Write<std::int64_t>(u.due_frame);
    out.Write<std::int32_t>(u.session_index);
    WriteDescriptorRecord(out, u.descriptor);
    WriteGaussian(out, u.state);
    out.Write<bool>(u.reconstructed);
  }
  // The map.
  e.model_->Serialize(out);
  // The global pose graph (format 7; empty when disabled).
  e.pose_graph_->Write(out);
}

std::unique_ptr<CmlEngine> EngineStateAccess::Read(BinaryReader& in) {
  const CmlEngineOptions options = ReadEngineOptions(in);
  std::unique_ptr<CmlEngine> e;
  try {
    e = std::make_unique<CmlEngine>(options);
  } catch (const Error& err) {
    in.Fail("options", StrCat("invalid stored options: ", err.what()));
  }
  EngineCounters& c = e->counters_;
  for (std::int64_t* v : {&c.frames, &c.unimodal_frames, &c.multimodal_frames, &c.unknown_frames,
                          &c.reconstructed_frames, &c.dropped_pending_frames, &c.updates_queued,
                          &c.global_seeds, &c.global_fallbacks}) {
    *v = in.Read<std::int64_t>("counters");
  }
  EngineSessionState& s = e->session_;
  s.session = in.Read<std::int32_t>("session.index");
  s.in_session = in.Read<bool>("session.in_session");
  s.camera.kind = ReadEnum<ImageKind>(in, "session.camera.kind", 0, 1);
  s.camera.image_width = in.Read<std::int32_t>("session.camera.image_width");
  s.camera.image_height = in.Read<std::int32_t>("session.camera.image_height");
  ReadCamera(in, s.camera);
  s.start_mode = ReadEnum<SessionStartMode>(in, "session.start_mode", 0, 2);
  s.has_prev_odom = in.Read<bool>("session.has_prev_odom");
  s.prev_odom = ReadPose(in, "session.prev_odom");
  s.awaiting_global_seed = in.Read<bool>("session.awaiting_global_seed");
  e->next_frame_ = in.Read<std::int64_t>("next_frame");
  if (e->next_frame_ < 0) in.Fail("next_frame", "negative frame index");
  if (e->options_.map_update_spacing_m > 0.0 && in.Read<bool>("last_map_update")) {
    CmlEngine::LastMapUpdate last;
    last.session = in.Read<std::int32_t>("last_map_update.session");
    last.x_m = in.Read<double>("last_map_update.x_m");
    last.y_m = in.Read<double>("last_map_update.y_m");
    if (!std::isfinite(last.x_m) || !std::isfinite(last.y_m))
      in.Fail("last_map_update", "position is not finite");
    e->last_map_update_ = last;
  }
  if (e->options_.smooth_map_updates) {
    const std::size_t frames = in.ReadCount("smoothing_history", 8 + 4 + 24 + 1);
    if (frames > static_cast<std::size_t>(e->options_.update_delay_frames) + 1)
      in.Fail("smoothing_history", "more frames than update_delay_frames + 1");
    for (std::size_t i = 0; i < frames; ++i) {
      CmlEngine::SmoothingFrame s;
      s.frame = in.Read<std::int64_t>("smoothing_history.frame");
      s.session = in.Read<std::int32_t>("smoothing_history.session");
      s.increment = ReadIncrement(in, "smoothing_history.increment");
      if (in.Read<bool>("smoothing_history.filtered"))
        s.filtered = ReadGaussian(in, "smoothing_history.filtered");
      if (!e->smoothing_history_.empty() && s.frame <= e->smoothing_history_.back().frame)
        in.Fail("smoothing_history.frame", "frames do not increase");
      e->smoothing_history_.push_back(std::move(s));
    }
  }

  const std::size_t components = in.ReadCount("tracker.state", 13 * 8);
  Mixture m;
  for (std::size_t i = 0; i < components; ++i) m.push_back(ReadGaussian(in, "tracker.state"));
  e->tracker_.set_state(std::move(m));

  const std::size_t pending = in.ReadCount("pending", 8 + 4 + 21 + 24 + 1);
  for (std::size_t i = 0; i < pending; ++i) {
    PendingFrame p;
    p.frame = in.Read<std::int64_t>("pending.frame");
    p.session = in.Read<std::int32_t>("pending.session");
    p.descriptor = ReadDescriptor(in, "pending.descriptor", *e->extractor_);
    p.increment = ReadIncrement(in, "pending.increment");
    if (in.Read<bool>("pending.filtered")) p.filtered = ReadGaussian(in, "pending.filtered");
    e->pending_.push_back(std::move(p));
  }
  if (in.Read<bool>("anchor")) {
    const std::int64_t frame = in.Read<std::int64_t>("anchor.frame");
    e->anchor_ = std::make_pair(frame, ReadGaussian(in, "anchor.state"));
  }

  const std::size_t queued = in.ReadCount("queued_updates", 8 + 8 + 4 + 21 + 13 * 8 + 1);
  std::int64_t last_due = INT64_MIN;
  for (std::size_t i = 0; i < queued; ++i) {
    MapUpdate u;
    u.frame = in.Read<std::int64_t>("queued_updates.frame");
    u.due_frame = in.Read<std::int64_t>("queued_updates.due_frame");
    u.session_index = in.Read<std::int32_t>("queued_updates.session");
    u.descriptor = ReadDescriptor(in, "queued_updates.descriptor", *e->extractor_);
    u.state = ReadGaussian(in, "queued_updates.state");
    u.reconstructed = in.Read<bool>("queued_updates.reconstructed");
    if (u.due_frame < last_due) in.Fail("queued_updates.due_frame", "due frames decrease");
    last_due = u.due_frame;
    e->updater_->PushRaw(std::move(u));
  }

  // This engine format embeds exactly the model section version Serialize writes; any
  // other is refused by version, before its bytes are misread as something else.
  e->model_ = std::make_unique<EnvironmentModel>(EnvironmentModel::Deserialize(
      in, e->options_.model, e->extractor_, EnvironmentModel::kFormatVersion));
  e->pose_graph_->Read(in);
  in.ExpectEnd("engine payload");
  if (s.in_session) e->MakeUnwrapper();
  return e;
}

std::vector<std::uint8_t> EncodeEngine(const CmlEngine& engine) {
  BinaryWriter payload;
  EngineStateAccess::Write(payload, engine);
  BinaryWriter file;
  for (char ch : kEngineMagic) file.Write<std::uint8_t>(static_cast<std::uint8_t>(ch));
  file.Write<std::uint32_t>(kEngineFormatVersion);
  file.Write<std::uint64_t>(payload.size());
  file.WriteBytes(payload.bytes());
  file.Write<std::uint32_t>(Crc32(payload.bytes()));
  return file.Release();
}

std::unique_ptr<CmlEngine> DecodeEngine(const std::vector<std::uint8_t>& bytes,
                                        const std::string& source) {
  if (bytes.size() < 8 || std::memcmp(bytes.data(), kEngineMagic, 8) != 0) {
    FailFile(source, bytes.size() < 8 ? "not an omnicml engine file (shorter than the magic bytes)"
                                      : "not an omnicml engine file (bad magic bytes)");
  }
  BinaryReader header(std::span<const std::uint8_t>(bytes.data(), bytes.size()), source);
  header.ReadBytes(8, "magic");
  if (bytes.size() < kHeaderBytes)
    FailFile(source, StrCat("truncated header (", bytes.size(), " bytes)"));
  const auto version = header.Read<std::uint32_t>("format version");
  if (version != kEngineFormatVersion) {
    FailFile(source, StrCat("unsupported engine format version ", version, " (this build reads ",
                            kEngineFormatVersion, "..", kEngineFormatVersion, ")"));
  }
  const auto length = header.Read<std::uint64_t>("payload length");
  const std::uint64_t available = bytes.size() - kHeaderBytes;
  if (available < kTrailerBytes || length > available - kTrailerBytes) {
    FailFile(source,
             StrCat("truncated: header announces ", length, " payload bytes + 4 checksum bytes, ",
                    available, " bytes follow the header"));
  }
  if (length + kTrailerBytes != available) {
    FailFile(source, StrCat("corrupted: ", available - length - kTrailerBytes,
                            " unexpected bytes after the checksum"));
  }
  const std::span<const std::uint8_t> payload(bytes.data() + kHeaderBytes, length);
  BinaryReader trailer(
      std::span<const std::uint8_t>(bytes.data() + kHeaderBytes + length, kTrailerBytes), source);
  const auto stored = trailer.Read<std::uint32_t>("checksum");
  const std::uint32_t actual = Crc32(payload);
  if (stored != actual) {
    FailFile(source, StrCat("corrupted: checksum mismatch (stored 0x", std::hex, stored,
                            ", computed 0x", actual, ")"));
  }
  BinaryReader in(payload, source);
  return EngineStateAccess::Read(in);
}

void SaveEngine(const CmlEngine& engine, const std::string& path) {
  WriteFileAtomic(path, EncodeEngine(engine));
}

std::unique_ptr<CmlEngine> LoadEngine(const std::string& path) {
  // A regular file no larger than kMaxMapFileBytes, checked before allocating.
  return DecodeEngine(ReadBinaryFile(path, kMaxMapFileBytes, "engine file"), path);
}

}  // namespace omnicml
