#include "omnicml/sim/simulator.h"

#include <algorithm>
#include <cmath>

#include "omnicml/common/common.h"
#include "omnicml/common/limits.h"
#include "omnicml/common/options.h"

namespace omnicml {
namespace {

// Sub-seed domains (arbitrary distinct constants).
constexpr std::uint64_t kOdometryDomain = 0x0D0ULL;
constexpr std::uint64_t kPeopleDomain = 0x9E0ULL;
constexpr std::uint64_t kSensorDomain = 0x5E5ULL;
constexpr std::uint64_t kStartDomain = 0x57AULL;

std::uint64_t FrameKey(int day, std::int64_t frame) {
  return (static_cast<std::uint64_t>(day) << 40) ^ static_cast<std::uint64_t>(frame);
}

double Uniform(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * 0x1.0p-53; }

}  // namespace

void SimulatorOptions::Validate() const {
  if (world.empty())
    throw Error("SimulatorOptions.world: empty (a built-in world name or a file path)");
  if (days < 1) throw Error(StrCat("SimulatorOptions.days: ", days, " (must be >= 1)"));
  if (frames_per_day < 1)
    throw Error(StrCat("SimulatorOptions.frames_per_day: ", frames_per_day, " (must be >= 1)"));
  CheckLimit("SimulatorOptions.days", days, 1, kMaxDays);
  CheckLimit("SimulatorOptions.frames_per_day", frames_per_day, 1, kMaxFramesPerDay);
  if (static_cast<std::int64_t>(days) * frames_per_day > kMaxSimulatedFrames) {
    throw Error(StrCat("SimulatorOptions: days x frames_per_day = ", days, " x ", frames_per_day,
                       " exceeds the limit of ", kMaxSimulatedFrames, " frames"));
  }
  if (!(step_m > 0) || !std::isfinite(step_m) || step_m > 100) {
    throw Error(StrCat("SimulatorOptions.step_m: ", step_m, " (must lie in (0, 100] m)"));
  }
  // The sessions' start covariance is diag(sigma^2) and goes into every written log, whose
  // reader and writer take positive variances up to kMaxPositionVarianceM2 and
  // kMaxHeadingVarianceRad2 (common/limits.h): checked here, before any frame is made.
  const auto check_sigma = [](const char* name, double sigma, double max_variance,
                              const char* unit) {
    const double max_sigma = std::sqrt(max_variance);
    if (!(sigma > 0) || !(sigma <= max_sigma) || !std::isfinite(sigma * sigma) ||
        !(sigma * sigma > 0)) {
      throw Error(StrCat("SimulatorOptions.", name, ": ", sigma, " (must lie in (0, ", max_sigma,
                         "] ", unit, ")"));
    }
  };
  check_sigma("start_sigma_xy_m", start_sigma_xy_m, kMaxPositionVarianceM2, "m");
  check_sigma("start_sigma_phi_rad", start_sigma_phi_rad, kMaxHeadingVarianceRad2, "rad");
}

// ---------------------------------------------------------------------------------------
// Route.

RoutePath::RoutePath(const std::vector<Eigen::Vector2d>& waypoints_m, double turn_radius_m) {
  std::vector<Eigen::Vector2d> w;
  for (const auto& p : waypoints_m) {
    if (w.empty() || (p - w.back()).norm() > 1e-6) w.push_back(p);
  }
  while (w.size() > 1 && (w.front() - w.back()).norm() <= 1e-6) w.pop_back();
  if (w.size() < 3) throw Error("route: a loop needs at least 3 distinct waypoints");
  const std::size_t n = w.size();
  // Leg i runs from w[i] to w[i+1]; corner i sits at w[i] between leg i-1 and leg i.
  std::vector<Eigen::Vector2d> dir(n);
  std::vector<double> len(n);
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector2d d = w[(i + 1) % n] - w[i];
    len[i] = d.norm();
    dir[i] = d / len[i];
  }
  std::vector<double> tangent(n), radius(n), turn(n);
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t prev = (i + n - 1) % n;
    turn[i] =
        WrapAngle(std::atan2(dir[i].y(), dir[i].x()) - std::atan2(dir[prev].y(), dir[prev].x()));
    const double half = std::abs(turn[i]) / 2;
    if (half < 1e-9 || turn_radius_m <= 0) {
      tangent[i] = 0;
      radius[i] = 0;
      continue;
    }
    const double tan_half = std::tan(std::min(half, kPi / 2 - 1e-6));
    tangent[i] = std::min(turn_radius_m * tan_half, 0.5 * std::min(len[i], len[prev]));
    radius[i] = tangent[i] / tan_half;
  }
  double s = 0;
  for (std::size_t i = 0; i < n; ++i) {
    // Line of leg i, from the end of corner i's arc to the start of corner i+1's arc.
    const std::size_t next = (i + 1) % n;
    Piece line;
    line.arc = false;
    line.start = w[i] + tangent[i] * dir[i];
    line.heading_rad = std::atan2(dir[i].y(), dir[i].x());
    line.length_m = std::max(0.0, len[i] - tangent[i] - tangent[next]);
    line.s0_m = s;
    s += line.length_m;
    pieces_.push_back(line);
    // Arc of corner next (an in-place turn when its radius is 0).
    Piece arc;
    arc.arc = true;
    arc.heading_rad = line.heading_rad;
    arc.turn_sign = turn[next] >= 0 ? 1.0 : -1.0;
    arc.radius_m = radius[next];
    const Eigen::Vector2d tangent_point = w[next] - tangent[next] * dir[i];
    const Eigen::Vector2d left(-dir[i].y(), dir[i].x());
    arc.start = tangent_point + arc.turn_sign * arc.radius_m * left;  // centre
    arc.length_m = arc.radius_m * std::abs(turn[next]);
    arc.s0_m = s;
    // A zero-radius corner has zero length: the heading jumps there (PoseAt skips it).
    s += arc.length_m;
    pieces_.push_back(arc);
  }
  length_m_ = s;
  if (!(length_m_ > 0)) throw Error("route: the loop has zero length");
}

Pose2 RoutePath::PoseAt(double s_m) const {
  double s = std::fmod(s_m, length_m_);
  if (s < 0) s += length_m_;
  // Binary search for the piece containing s (the last piece whose s0 <= s, with
  // non-zero length preferred).
  auto it = std::upper_bound(pieces_.begin(), pieces_.end(), s,
                             [](double v, const Piece& p) { return v < p.s0_m; });
  std::size_t idx = it == pieces_.begin() ? 0 : static_cast<std::size_t>(it - pieces_.begin() - 1);
  while (idx > 0 && pieces_[idx].length_m <= 0) --idx;
  const Piece& p = pieces_[idx];
  const double a = std::clamp(s - p.s0_m, 0.0, p.length_m);
  if (!p.arc) {
    return MakePose(p.start.x() + a * std::cos(p.heading_rad),
                    p.start.y() + a * std::sin(p.heading_rad), p.heading_rad);
  }
  const double h = p.heading_rad + p.turn_sign * a / p.radius_m;
  return MakePose(p.start.x() + p.turn_sign * p.radius_m * std::sin(h),
                  p.start.y() - p.turn_sign * p.radius_m * std::cos(h), h);
}

std::vector<Eigen::Vector2d> RoutePath::Sample(double step_m) const {
  std::vector<Eigen::Vector2d> out;
  const int n = std::max(2, static_cast<int>(std::ceil(length_m_ / step_m)));
  for (int i = 0; i <= n; ++i) out.push_back(PoseAt(length_m_ * i / n).head<2>());
  return out;
}

// ---------------------------------------------------------------------------------------
// Frame source.

struct WalkingPerson {
  Person person;
  Eigen::Vector2d target = Eigen::Vector2d::Zero();
};

struct SimulatedFrameSource::Impl {
  SimulatorOptions options;
  World world;
  RoutePath route;
  Renderer renderer;
  std::unique_ptr<RawCameraRenderer> raw_camera;  // raw images of a kind other than kRing
  std::vector<SessionInfo> sessions;
  std::vector<double> day_start_s;  // arc length of each day's first frame

  int day = 0;  // 1-based day of the last frame; 0 before the first
  std::int64_t frame_in_day = -1;
  std::int64_t global_index = 0;
  WorldState state;
  std::vector<WalkingPerson> people;
  std::vector<Person> people_now;
  std::mt19937_64 people_rng;
  Pose2 truth = Pose2::Zero();
  Pose2 odom = Pose2::Zero();
  cv::Mat panorama;

  Impl(const SimulatorOptions& o, const World& w)
      : options(o),
        world(w),
        route(w.route.waypoints_m, w.route.turn_radius_m),
        renderer(w, o.seed) {
    if (options.output == ImageKind::kRawRing && options.camera != SimulatedCamera::kRing)
      raw_camera = std::make_unique<RawCameraRenderer>(world, options.camera);
    for (int d = 1; d <= options.days; ++d) {
      double s0 = 0;
      SessionStartMode mode = d == 1 ? SessionStartMode::kKnownPose : options.later_days_start;
      if (mode == SessionStartMode::kContinue) {
        s0 = static_cast<double>(d - 1) * options.frames_per_day * options.step_m;
      } else if (mode == SessionStartMode::kGlobal) {
        std::mt19937_64 rng(
            MixSeed(MixSeed(options.seed, kStartDomain), static_cast<std::uint64_t>(d)));
        s0 = Uniform(rng) * route.length_m();
      }
      day_start_s.push_back(s0);
      SessionInfo info;
      char name[32];
      std::snprintf(name, sizeof(name), "day_%03d", d);
      info.name = name;
      info.day_label = StrCat("day ", d, " of ", world.name);
      info.start_time_s = (d - 1) * world.days_between_sessions * 86400.0;
      info.camera.kind = options.output;
      if (options.output == ImageKind::kRawRing) {
        info.camera.image_width = world.camera.ring_width_px;
        info.camera.image_height = world.camera.ring_height_px;
      } else {
        info.camera.image_width = world.camera.panorama_width_px;
        info.camera.image_height = world.camera.panorama_height_px;
      }
      info.camera.calibration = SimulatedCalibration(world.camera);
      if (raw_camera != nullptr) {
        const RawCameraSetup& setup = raw_camera->setup();
        info.camera.image_width = setup.image_width;
        info.camera.image_height = setup.image_height;
        info.camera.calibration = setup.calibration;
      }
      info.start.mode = mode;
      info.start.map_T_robot = route.PoseAt(s0);
      const double sxy = options.start_sigma_xy_m, sphi = options.start_sigma_phi_rad;
      info.start.covariance = Eigen::Vector3d(sxy * sxy, sxy * sxy, sphi * sphi).asDiagonal();
      sessions.push_back(info);
    }
  }

  double dt_s() const { return options.step_m / world.route.speed_mps; }

  Eigen::Vector2d RandomFreePoint(double radius) {
    for (int attempt = 0; attempt < 500; ++attempt) {
      const Eigen::Vector2d p(Uniform(people_rng) * world.size_m.x(),
                              Uniform(people_rng) * world.size_m.y());
      if (IsFree(world, state, p, radius)) return p;
    }
    return Eigen::Vector2d(-1, -1);  // none found
  }

  void SetRendererState() {
    renderer.SetState(state);
    if (raw_camera != nullptr) raw_camera->SetState(state);
  }

  void StartDay(int d) {
    day = d;
    frame_in_day = -1;
    state = StateAtDayStart(world, d, options.seed);
    SetRendererState();
    people.clear();
    people_rng.seed(MixSeed(MixSeed(options.seed, kPeopleDomain), static_cast<std::uint64_t>(d)));
    if (options.people) {
      const PeopleSpec& spec = world.people;
      for (int i = 0; i < spec.count; ++i) {
        WalkingPerson wp;
        wp.person.radius_m = spec.radius_m;
        wp.person.height_m = spec.height_m * (0.9 + 0.2 * Uniform(people_rng));
        wp.person.seed = people_rng();
        wp.person.position_m = RandomFreePoint(spec.radius_m);
        if (wp.person.position_m.x() < 0) continue;  // no free space
        wp.target = wp.person.position_m;
        people.push_back(wp);
      }
    }
  }

  void MovePeople() {
    const double step = world.people.speed_mps * dt_s();
    for (auto& wp : people) {
      double remaining = step;
      for (int guard = 0; guard < 4 && remaining > 0; ++guard) {
        const Eigen::Vector2d to = wp.target - wp.person.position_m;
        const double dist = to.norm();
        if (dist > remaining) {
          wp.person.position_m += to * (remaining / dist);
          remaining = 0;
          break;
        }
        wp.person.position_m = wp.target;
        remaining -= dist;
        // A new target reachable in a straight line (a few tries, else wait).
        for (int attempt = 0; attempt < 20; ++attempt) {
          const Eigen::Vector2d t = RandomFreePoint(wp.person.radius_m);
          if (t.x() >= 0 && IsPathFree(world, state, wp.person.position_m, t, wp.person.radius_m)) {
            wp.target = t;
            break;
          }
        }
        if (wp.target == wp.person.position_m) break;
      }
    }
  }

  bool Next(Frame* frame) {
    if (day == 0 || frame_in_day + 1 >= options.frames_per_day) {
      if (day >= options.days) return false;
      const bool first_day = day == 0;
      const Pose2 last_truth = truth;
      const Pose2 last_odom = odom;
      StartDay(day + 1);
      frame_in_day = 0;
      const SessionInfo& info = sessions[day - 1];
      truth = route.PoseAt(day_start_s[day - 1]);
      if (!first_day && info.start.mode == SessionStartMode::kContinue) {
        odom = ApplyIncrement(last_odom, NoisyIncrement(last_truth, truth));
      } else if (info.start.mode == SessionStartMode::kGlobal) {
        odom = Pose2::Zero();
      } else {
        odom = truth;
      }
    } else {
      ++frame_in_day;
      if (ApplyStepEvents(world, day, frame_in_day, options.seed, &state).any()) SetRendererState();
      MovePeople();
      const Pose2 next_truth =
          route.PoseAt(day_start_s[day - 1] + static_cast<double>(frame_in_day) * options.step_m);
      odom = ApplyIncrement(odom, NoisyIncrement(truth, next_truth));
      truth = next_truth;
    }
    people_now.clear();
    for (const auto& wp : people) people_now.push_back(wp.person);

    frame->session_index = day - 1;
    frame->index_in_session = frame_in_day;
    frame->global_index = global_index++;
    frame->stamp_s = sessions[day - 1].start_time_s + static_cast<double>(frame_in_day) * dt_s();
    frame->odom_T_robot = odom;
    frame->map_T_robot_truth = truth;
    if (options.render_images) {
      renderer.RenderPanorama(truth, people_now, &panorama);
      cv::Mat image = options.output == ImageKind::kPanorama ? panorama.clone()
                      : raw_camera != nullptr ? raw_camera->Render(panorama, truth, people_now)
                                              : renderer.RenderRing(panorama);
      if (options.sensor_noise) {
        renderer.AddSensorNoise(
            &image, MixSeed(MixSeed(options.seed, kSensorDomain), FrameKey(day, frame_in_day)));
      }
      frame->image = image;
    } else {
      panorama.release();
      frame->image.release();
    }
    return true;
  }

  // Noisy odometry increment for the true motion prev -> curr, from the frame's own
  // sub-seed (so it does not depend on anything drawn before).
  OdometryIncrement NoisyIncrement(const Pose2& prev, const Pose2& curr) {
    std::mt19937_64 rng(
        MixSeed(MixSeed(options.seed, kOdometryDomain), FrameKey(day, frame_in_day)));
    return SampleOdometryIncrement(ComputeIncrement(prev, curr), world.odometry_noise, rng);
  }
};

SimulatedFrameSource::SimulatedFrameSource(const SimulatorOptions& options)
    : SimulatedFrameSource(options, (options.Validate(), LoadWorld(options.world))) {}

SimulatedFrameSource::SimulatedFrameSource(const SimulatorOptions& options, const World& world) {
  options.Validate();
  impl_ = std::make_unique<Impl>(options, world);
}

SimulatedFrameSource::~SimulatedFrameSource() = default;

int SimulatedFrameSource::NumSessions() const { return static_cast<int>(impl_->sessions.size()); }
const SessionInfo& SimulatedFrameSource::Session(int index) const {
  OMNICML_CHECK(index >= 0 && index < NumSessions()) << "session " << index;
  return impl_->sessions[index];
}
bool SimulatedFrameSource::Next(Frame* frame) {
  OMNICML_CHECK(frame != nullptr);
  return impl_->Next(frame);
}
const World& SimulatedFrameSource::world() const { return impl_->world; }
const SimulatorOptions& SimulatedFrameSource::options() const { return impl_->options; }
const RoutePath& SimulatedFrameSource::route() const { return impl_->route; }
const WorldState& SimulatedFrameSource::state() const { return impl_->state; }
const std::vector<Person>& SimulatedFrameSource::people() const { return impl_->people_now; }
const cv::Mat& SimulatedFrameSource::last_panorama() const { return impl_->panorama; }
const Renderer& SimulatedFrameSource::renderer() const { return impl_->renderer; }

// ---- options (the schema of the header's VisitFields, common/options.h)

SimulatorOptions ParseSimulatorOptionsYaml(const std::string& yaml_text,
                                           const std::string& source) {
  return ParseOptionsYaml<SimulatorOptions>(yaml_text, source, SimulatorOptions{},
                                            kSimulatorRunKeys);
}
SimulatorOptions LoadSimulatorOptions(const std::string& path) {
  return ParseSimulatorOptionsYaml(ReadOptionFile(path), path);
}
std::string SimulatorOptionsToYaml(const SimulatorOptions& options) {
  return OptionsToYaml(options);
}

}  // namespace omnicml
