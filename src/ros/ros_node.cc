#include "omnicml/ros/ros_node.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <sstream>
#include <thread>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/options.h"
#include "omnicml/engine/calibration.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/ros/rosbag_io.h"
#include "omnicml/run/run_config.h"
#include "ros/ros1.h"

namespace omnicml {
namespace {

std::atomic<bool> g_stop_requested{false};
void OnSignal(int) { g_stop_requested = true; }

template <class T>
void Param(const std::string& name, T* value) {
  try {
    ros1::GetParam(name, value);
  } catch (const std::runtime_error& e) {
    throw Error(e.what());
  }
}

RosNodeParameters ReadParameters() {
  RosNodeParameters p;
  Param("image_topic", &p.image_topic);
  Param("compressed", &p.compressed);
  Param("odom_topic", &p.odom_topic);
  Param("session_topic", &p.session_topic);
  Param("map_frame", &p.map_frame);
  Param("odom_frame", &p.odom_frame);
  Param("config", &p.config);
  Param("forgetting", &p.forgetting);
  Param("threads", &p.threads);
  Param("map_in", &p.map_in);
  Param("map_out", &p.map_out);
  Param("calibration", &p.calibration);
  Param("start_mode", &p.start_mode);
  Param("start_pose", &p.start_pose);
  Param("new_session_start", &p.new_session_start);
  Param("queue_size", &p.queue_size);
  Param("odometry_wait_s", &p.odometry_wait_s);
  Param("session_gap_s", &p.session_gap_s);
  Param("views_every_frames", &p.views_every_frames);
  Param("latency_csv", &p.latency_csv);
  Param("frame_step_frames", &p.frame_step_frames);
  if (p.frame_step_frames < 0) throw Error("~frame_step_frames must be >= 0");
  if (p.start_pose.size() != 3) throw Error("~start_pose must be [x_m, y_m, phi_rad]");
  if (p.start_mode.empty()) p.start_mode = p.map_in.empty() ? "known" : "global";
  return p;
}

// The configuration file and the forgetting and threads parameters, as `omnicml run`'s
// --config, --forgetting and --threads.
OptionOverrides Overrides(const RosNodeParameters& p) {
  OptionOverrides overrides;
  overrides.config_path = p.config;
  if (!p.forgetting.empty()) overrides.forgetting = p.forgetting;
  if (p.threads > 0) overrides.threads = p.threads;
  return overrides;
}

// The engine of a loaded map (~map_in).
std::unique_ptr<CmlEngine> LoadMapEngine(const RosNodeParameters& p) {
  std::unique_ptr<CmlEngine> engine = LoadEngine(p.map_in);
  if (!p.forgetting.empty()) engine->SetForgettingMode(ForgettingModeFromString(p.forgetting));
  if (p.threads > 0) engine->SetThreads(p.threads);
  return engine;
}

// A new map whose per-frame options (stated for frames reference_step_m apart) are
// restated for the frame step of its first frames, as `omnicml run` does from its log's
// first session (ResolveNewMapOptions).
LiveEngine::EngineFactory NewMapFactory(const RosNodeParameters& p, double reference_step_m) {
  return [overrides = Overrides(p), reference_step_m](const std::vector<Pose2>& odometry) {
    const double step = MedianOdometryStep(odometry, 0.01 * reference_step_m);
    std::string note;
    const CmlEngineOptions options = ResolveFrameStepOptions(overrides, step, &note);
    if (!odometry.empty()) {
      ros1::LogInfo(StrCat(
          "omnicml: new map, frame step measured over the first ", odometry.size(),
          " frames: ", note.empty() ? StrCat("median ", step, " m, options as configured") : note));
    }
    return std::make_unique<CmlEngine>(options);
  };
}

// What only an offline run derives from its log (the live node cannot read ahead).
void WarnOfflineOnlySources(const CmlEngineOptions& o) {
  if (o.motion_noise_source == MotionNoiseSource::kIdentified)
    ros1::LogWarn(
        "omnicml: motion_noise_source identified needs the whole first session: "
        "the configured tracker.motion is used live");
  if (o.spatial_scale_source == SpatialScaleSource::kCalibrated)
    ros1::LogWarn(
        "omnicml: spatial_scale_source calibrated needs the log: the configured "
        "spatial thresholds are used live");
  if (o.appearance_offset_source == AppearanceOffsetSource::kCalibrated)
    ros1::LogWarn(
        "omnicml: appearance_offset_source calibrated needs the log: the "
        "configured appearance_offset_curve is used live");
}

SessionInfo SessionTemplate(const RosNodeParameters& p, const std::string& mode, int number) {
  SessionInfo info;
  info.name = StrCat("live_", number);
  info.day_label = StrCat("live session ", number);
  if (!p.calibration.empty()) {
    info.camera.kind = ImageKind::kRawRing;
    info.camera.calibration = CameraCalibration::FromYamlFile(p.calibration);
  }
  info.start.mode = SessionStartModeFromString(mode);
  info.start.map_T_robot = MakePose(p.start_pose[0], p.start_pose[1], p.start_pose[2]);
  return info;
}

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1) + 0.5);
  return v[std::min(v.size() - 1, k)];
}

ros1::PlanarPose ToPlanar(const Pose2& p) { return {p.x(), p.y(), p.z()}; }

}  // namespace

struct RosNode::Impl {
  RosNodeParameters params;
  std::unique_ptr<LiveEngine> live;
  std::unique_ptr<ros1::NodeTransport> transport;
  std::atomic<int> sessions_requested{1};
  // Worker-thread data (the output callback), read after LiveEngine::Stop.
  std::int64_t dropped_published = 0;
  struct Latency {
    double stamp_s, latency_ms, engine_ms, queue_ms;
  };
  std::vector<Latency> latencies;

  void Publish(const LiveOutput& out) {
    const double latency_ms = (ros1::NowSeconds() - out.stamp_s) * 1e3;
    if (out.estimate) {
      std::array<double, 9> c;
      for (int r = 0; r < 3; ++r)
        for (int k = 0; k < 3; ++k)
          c[static_cast<std::size_t>(r * 3 + k)] = out.estimate->strongest.covariance(r, k);
      transport->PublishPose(out.stamp_s, ToPlanar(out.estimate->strongest.mean), c);
      transport->PublishMapToOdom(out.stamp_s, ToPlanar(*out.map_T_odom));
      std::vector<ros1::PlanarPose> hypotheses;
      for (const Gaussian& g : out.hypotheses) hypotheses.push_back(ToPlanar(g.mean));
      transport->PublishHypotheses(out.stamp_s, hypotheses);
    }
    if (out.dropped_frames > dropped_published) {
      transport->PublishDropped(out.dropped_frames);
      ros1::LogWarnThrottled(
          5.0, StrCat("omnicml: ", out.dropped_frames,
                      " frames dropped so far (the engine is slower than the image rate; "
                      "~queue_size ",
                      params.queue_size, ")"));
      dropped_published = out.dropped_frames;
    }
    latencies.push_back({out.stamp_s, latency_ms, out.engine_us * 1e-3, out.queue_wait_us * 1e-3});
  }

  std::pair<bool, std::string> Save() {
    if (params.map_out.empty()) return {false, "no ~map_out parameter: nowhere to save"};
    const std::string error = live->Save(params.map_out).get();
    const std::string message = error.empty() ? "saved " + params.map_out : error;
    ros1::LogInfo("omnicml: save_map: " + message);
    return {error.empty(), message};
  }
};

RosNode::RosNode() : impl_(std::make_unique<Impl>()) {
  Impl& s = *impl_;
  s.params = ReadParameters();
  const RosNodeParameters& p = s.params;
  if (!p.map_out.empty()) CheckOutputFile(p.map_out, "~map_out");
  LiveEngineOptions live_options;
  live_options.queue_capacity_frames = p.queue_size;
  live_options.odometry_wait_s = p.odometry_wait_s;
  live_options.session_gap_s = p.session_gap_s;
  live_options.reference_views_every_frames = p.views_every_frames;
  LiveEngine::Callbacks callbacks;
  callbacks.on_output = [&s](const LiveOutput& out) { s.Publish(out); };
  callbacks.on_views = [&s](const std::vector<LiveViewComponent>& components) {
    std::vector<std::array<double, 3>> views;
    for (const LiveViewComponent& c : components)
      views.push_back({c.pose.x(), c.pose.y(), c.weight});
    s.transport->PublishViews(views);
  };
  callbacks.on_error = [](const std::string& e) { ros1::LogError("omnicml: " + e); };
  const auto make_live = [&](auto engine_or_factory) {
    return std::make_unique<LiveEngine>(
        std::move(engine_or_factory), live_options, SessionTemplate(p, p.start_mode, 1),
        SessionTemplate(p, p.new_session_start, 2), std::move(callbacks));
  };
  if (!p.map_in.empty()) {
    s.live = make_live(LoadMapEngine(p));
  } else {
    const CmlEngineOptions configured = ResolveEngineOptions(Overrides(p));  // errors now
    WarnOfflineOnlySources(configured);
    if (configured.reference_frame_step_m > 0.0 && p.frame_step_frames >= 2) {
      live_options.frame_step_frames = p.frame_step_frames;
      s.live = make_live(NewMapFactory(p, configured.reference_frame_step_m));
    } else {
      s.live = make_live(std::make_unique<CmlEngine>(configured));
    }
  }

  ros1::NodeTopics topics;
  topics.image_topic = p.image_topic;
  topics.odom_topic = p.odom_topic;
  topics.session_topic = p.session_topic;
  topics.compressed = p.compressed;
  topics.image_queue = static_cast<std::uint32_t>(std::max(100, p.queue_size));
  topics.map_frame = p.map_frame;
  topics.odom_frame = p.odom_frame;
  ros1::NodeHandlers h;
  h.on_image = [&s](double stamp_s, std::function<cv::Mat()> decode) {
    s.live->AddEncodedImage(stamp_s, std::move(decode));
  };
  h.on_odometry = [&s](double stamp_s, const ros1::PlanarPose& pose) {
    if (!s.live->AddOdometry(stamp_s, MakePose(pose.x_m, pose.y_m, pose.phi_rad)))
      ros1::LogWarnThrottled(
          5.0, "omnicml: " + s.params.odom_topic +
                   ": odometry not after the previous sample (or not finite): ignored");
  };
  h.on_session = [&s](const std::string& text) {
    try {
      SessionInfo info = ParseSessionMessage(text, s.params.session_topic);
      ros1::LogInfo(StrCat("omnicml: session '", info.name, "' (", ToString(info.start.mode),
                           " start) begins with the next frame"));
      s.live->BeginSession(std::move(info));
    } catch (const Error& e) {
      ros1::LogError(StrCat("omnicml: ", e.what()));
    }
  };
  h.save_map = [&s] { return s.Save(); };
  h.new_session = [&s]() -> std::pair<bool, std::string> {
    s.live->BeginSession(
        SessionTemplate(s.params, s.params.new_session_start, ++s.sessions_requested));
    return {true, "a " + s.params.new_session_start + " session begins with the next frame"};
  };
  h.forgetting = [&s](const std::string& mode) -> std::pair<bool, std::string> {
    s.live->SetForgettingMode(ForgettingModeFromString(mode));
    return {true, "forgetting mode " + mode + " from the next frame"};
  };
  s.transport = std::make_unique<ros1::NodeTransport>(topics, std::move(h));
  ros1::LogInfo(StrCat("omnicml: listening on ", p.image_topic, " and ", p.odom_topic, " (queue ",
                       p.queue_size, " frames)", p.map_in.empty() ? "" : ", map " + p.map_in));
}

RosNode::~RosNode() {
  // The worker publishes through the transport: stop it before the transport goes.
  if (impl_ && impl_->live) impl_->live->Stop(false);
}

void RosNode::InitRos(int& argc, char** argv, const std::string& name) {
  ros1::InitNode(argc, argv, name);
}

void RosNode::Spin() {
  Impl& s = *impl_;
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  while (!g_stop_requested && ros1::Ok())
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  s.transport->StopSubscriptions();
  s.transport->StopServices();
  s.live->Stop(true);
  const LiveStats stats = s.live->stats();
  if (!s.params.map_out.empty()) {
    SaveEngine(s.live->engine(), s.params.map_out);
    ros1::LogInfo("omnicml: map saved to " + s.params.map_out);
  }
  std::vector<double> latency;
  for (const auto& l : s.latencies) latency.push_back(l.latency_ms);
  std::ostringstream summary;
  summary.precision(3);
  summary << "omnicml: " << stats.received_frames << " frames received, " << stats.processed_frames
          << " processed, " << stats.dropped_frames << " dropped, " << stats.failed_frames
          << " failed, " << stats.odometry_held_frames
          << " with held odometry; latency (image stamp to pose) p50 " << Percentile(latency, 0.5)
          << " ms, p99 " << Percentile(latency, 0.99) << " ms";
  ros1::LogInfo(summary.str());
  if (!s.params.latency_csv.empty()) {
    std::ostringstream csv;
    csv << "stamp_s,latency_ms,engine_ms,queue_wait_ms\n";
    csv.precision(17);
    for (const auto& l : s.latencies)
      csv << l.stamp_s << "," << l.latency_ms << "," << l.engine_ms << "," << l.queue_ms << "\n";
    csv << "# received " << stats.received_frames << " processed " << stats.processed_frames
        << " dropped " << stats.dropped_frames << "\n";
    WriteFileAtomic(s.params.latency_csv, csv.str());
  }
  s.transport.reset();
  ros1::Shutdown();
}

}  // namespace omnicml
