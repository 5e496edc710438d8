// Bindings of frames, sessions and the frame sources: LogReader (logs on disk), the
// simulator (SimulatedFrameSource) and LogWriter.
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <pybind11/stl.h>

#include "convert.h"
#include "omnicml/common/common.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/sensor/frame.h"
#include "omnicml/sim/simulator.h"
#include "omnicml/sim/world.h"

namespace omnicml::python {
namespace {

std::string ToString(ImageKind k) { return k == ImageKind::kRawRing ? "raw_ring" : "panorama"; }
ImageKind ImageKindFrom(const std::string& s) {
  if (s == "raw_ring") return ImageKind::kRawRing;
  if (s == "panorama") return ImageKind::kPanorama;
  throw Error(StrCat("image kind '", s, "': expected raw_ring or panorama"));
}

Frame NextFrame(FrameSource& source) {
  Frame f;
  bool ok = false;
  {
    py::gil_scoped_release release;
    ok = source.Next(&f);
  }
  if (!ok) throw py::stop_iteration();
  return f;
}

}  // namespace

void BindLogs(py::module_& m) {
  py::class_<SessionInfo>(
      m, "SessionInfo",
      "One session (day) of a log: name, camera, and how it starts ('known' pose with "
      "covariance, 'continue' from the previous session, or 'global' without prior).")
      .def(py::init([](const std::string& name, const std::string& day_label, double start_time_s,
                       const std::string& image_kind, int image_width, int image_height,
                       const std::optional<OmniCalibration>& calibration,
                       const std::string& start_mode, const py::object& start_pose,
                       const py::object& start_covariance) {
             SessionInfo s;
             s.name = name;
             s.day_label = day_label;
             s.start_time_s = start_time_s;
             s.camera.kind = ImageKindFrom(image_kind);
             s.camera.image_width = image_width;
             s.camera.image_height = image_height;
             if (calibration) s.camera.calibration = *calibration;
             s.start.mode = SessionStartModeFromString(start_mode);
             if (!start_pose.is_none())
               s.start.map_T_robot = PoseFromObject(start_pose, "start_pose");
             if (!start_covariance.is_none())
               s.start.covariance = Matrix3FromObject(start_covariance, "start_covariance");
             return s;
           }),
           py::arg("name") = "session", py::arg("day_label") = "", py::arg("start_time_s") = 0.0,
           py::arg("image_kind") = "panorama", py::arg("image_width") = 0,
           py::arg("image_height") = 0, py::arg("calibration") = py::none(),
           py::arg("start_mode") = "known", py::arg("start_pose") = py::none(),
           py::arg("start_covariance") = py::none(),
           "image_kind: 'panorama' or 'raw_ring' (then calibration is used); start_mode: "
           "'known', 'continue' or 'global'; start_pose (x_m, y_m, phi_rad), default 0; "
           "start_covariance 3x3 (m^2, rad^2), default diag(0.01, 0.01, 0.001).")
      .def_readwrite("name", &SessionInfo::name)
      .def_readwrite("day_label", &SessionInfo::day_label)
      .def_readwrite("start_time_s", &SessionInfo::start_time_s)
      .def_property(
          "image_kind", [](const SessionInfo& s) { return ToString(s.camera.kind); },
          [](SessionInfo& s, const std::string& k) { s.camera.kind = ImageKindFrom(k); })
      .def_property(
          "image_width", [](const SessionInfo& s) { return s.camera.image_width; },
          [](SessionInfo& s, int v) { s.camera.image_width = v; })
      .def_property(
          "image_height", [](const SessionInfo& s) { return s.camera.image_height; },
          [](SessionInfo& s, int v) { s.camera.image_height = v; })
      .def_property(
          "calibration", [](const SessionInfo& s) { return s.camera.calibration.ring; },
          [](SessionInfo& s, const OmniCalibration& c) { s.camera.calibration = c; })
      .def_property(
          "start_mode", [](const SessionInfo& s) { return omnicml::ToString(s.start.mode); },
          [](SessionInfo& s, const std::string& v) {
            s.start.mode = SessionStartModeFromString(v);
          })
      .def_property(
          "start_pose", [](const SessionInfo& s) { return ArrayFromPose(s.start.map_T_robot); },
          [](SessionInfo& s, const py::object& p) {
            s.start.map_T_robot = PoseFromObject(p, "start_pose");
          })
      .def_property(
          "start_covariance",
          [](const SessionInfo& s) { return ArrayFromMatrix3(s.start.covariance); },
          [](SessionInfo& s, const py::object& c) {
            s.start.covariance = Matrix3FromObject(c, "start_covariance");
          })
      .def("__repr__", [](const SessionInfo& s) {
        return StrCat("<omnicml.SessionInfo '", s.name, "' ", ToString(s.camera.kind), " ",
                      s.camera.image_width, "x", s.camera.image_height,
                      " start=", omnicml::ToString(s.start.mode), ">");
      });

  py::class_<Frame>(m, "Frame",
                    "One frame: stamp, image (numpy uint8, raw ring or panorama, BGR), odometry "
                    "pose and optional ground truth (map frame).")
      .def(py::init([](const py::object& image, const py::object& odom_pose, double stamp_s,
                       const py::object& truth, int session_index, std::int64_t index_in_session,
                       std::int64_t global_index) {
             Frame f;
             f.image = ImageFromArray(image, "image").clone();
             f.odom_T_robot = PoseFromObject(odom_pose, "odom_pose");
             f.stamp_s = stamp_s;
             if (!truth.is_none()) f.map_T_robot_truth = PoseFromObject(truth, "truth");
             f.session_index = session_index;
             f.index_in_session = index_in_session;
             f.global_index = global_index;
             return f;
           }),
           py::arg("image"), py::arg("odom_pose"), py::arg("stamp_s"),
           py::arg("truth") = py::none(), py::arg("session_index") = 0,
           py::arg("index_in_session") = 0, py::arg("global_index") = 0)
      .def_readwrite("session_index", &Frame::session_index, "0-based session (day) index.")
      .def_readwrite("index_in_session", &Frame::index_in_session)
      .def_readwrite("global_index", &Frame::global_index, "0-based over all sessions.")
      .def_readwrite("stamp_s", &Frame::stamp_s)
      .def_property(
          "image", [](const Frame& f) { return ArrayFromImage(f.image); },
          [](Frame& f, const py::object& a) { f.image = ImageFromArray(a, "image").clone(); },
          "The image as a numpy uint8 array (a copy).")
      .def_property(
          "odom_pose", [](const Frame& f) { return ArrayFromPose(f.odom_T_robot); },
          [](Frame& f, const py::object& p) { f.odom_T_robot = PoseFromObject(p, "odom_pose"); },
          "Odometry pose odom_T_robot (x_m, y_m, phi_rad).")
      .def_property(
          "truth",
          [](const Frame& f) -> py::object {
            if (!f.map_T_robot_truth) return py::none();
            return ArrayFromPose(*f.map_T_robot_truth);
          },
          [](Frame& f, const py::object& p) {
            if (p.is_none())
              f.map_T_robot_truth.reset();
            else
              f.map_T_robot_truth = PoseFromObject(p, "truth");
          },
          "Ground truth map_T_robot (x_m, y_m, phi_rad), or None.")
      .def("__repr__", [](const Frame& f) {
        return StrCat("<omnicml.Frame session=", f.session_index, " index=", f.index_in_session,
                      " stamp_s=", f.stamp_s, " image=", f.image.cols, "x", f.image.rows, ">");
      });

  py::class_<FrameSource, std::shared_ptr<FrameSource>>(
      m, "FrameSource",
      "A stream of frames over one or more sessions, read lazily; iterate it for Frames. One "
      "consumer; not restartable.")
      .def_property_readonly("num_sessions", &FrameSource::NumSessions)
      .def("session", &FrameSource::Session, py::arg("index"), "SessionInfo of session `index`.")
      .def_property_readonly("sessions",
                             [](const FrameSource& s) {
                               std::vector<SessionInfo> out;
                               for (int i = 0; i < s.NumSessions(); ++i)
                                 out.push_back(s.Session(i));
                               return out;
                             })
      .def("__iter__", [](py::object self) { return self; })
      .def("__next__", &NextFrame,
           "The next frame; raises omnicml.Error naming file and line on a bad frame.");

  py::class_<LogReader, FrameSource, std::shared_ptr<LogReader>>(
      m, "LogReader",
      "Reads an omnicml log (one session directory, or a multi-day log of session "
      "directories) frame by frame.")
      .def(py::init([](const py::object& log_dirs, bool load_images, bool skip_unreadable_frames,
                       bool allow_images_outside_log) {
             LogReaderOptions o;
             o.load_images = load_images;
             o.skip_unreadable_frames = skip_unreadable_frames;
             o.allow_images_outside_log = allow_images_outside_log;
             std::vector<std::string> dirs;
             if (py::isinstance<py::str>(log_dirs) || py::hasattr(log_dirs, "__fspath__")) {
               dirs.push_back(py::str(log_dirs));
             } else {
               for (const auto& d : log_dirs) dirs.push_back(py::str(d));
             }
             return std::make_shared<LogReader>(dirs, o);
           }),
           py::arg("log_dirs"), py::arg("load_images") = true,
           py::arg("skip_unreadable_frames") = false, py::arg("allow_images_outside_log") = false,
           "log_dirs: a path or a list of paths, read in order. Raises omnicml.Error naming the "
           "file and line of the first problem. Images named outside the log directory "
           "(absolute, '..', links leading out) are refused unless allow_images_outside_log.")
      .def("session_directory", &LogReader::SessionDirectory, py::arg("index"))
      .def_property_readonly("num_skipped_frames", static_cast<std::int64_t (LogReader::*)() const>(
                                                       &LogReader::NumSkippedFrames));

  const SimulatorOptions sd;
  py::class_<SimulatedFrameSource, FrameSource, std::shared_ptr<SimulatedFrameSource>>(
      m, "Simulator",
      "Renders a simulated multi-day log of a built-in world (or a world YAML file) with "
      "ground truth: frames over `days` sessions, the world changing between and during "
      "days.")
      .def(py::init([](const std::string& world, int days, int frames_per_day, std::uint64_t seed,
                       bool panorama, double step_m, bool render_images, bool sensor_noise,
                       bool people) {
             SimulatorOptions o;
             o.world = world;
             o.days = days;
             o.frames_per_day = frames_per_day;
             o.seed = seed;
             o.output = panorama ? ImageKind::kPanorama : ImageKind::kRawRing;
             o.step_m = step_m;
             o.render_images = render_images;
             o.sensor_noise = sensor_noise;
             o.people = people;
             py::gil_scoped_release release;
             return std::make_shared<SimulatedFrameSource>(o);
           }),
           py::arg("world") = sd.world, py::arg("days") = sd.days,
           py::arg("frames_per_day") = sd.frames_per_day, py::arg("seed") = sd.seed,
           py::arg("panorama") = false, py::arg("step_m") = sd.step_m,
           py::arg("render_images") = sd.render_images, py::arg("sensor_noise") = sd.sensor_noise,
           py::arg("people") = sd.people,
           "world: 'home_store', 'institute', 'store_large' (world_names()) or a YAML path; "
           "panorama: deliver panoramas instead of raw ring images; step_m: distance between "
           "frames. Raises omnicml.Error naming the field.")
      .def_property_readonly("world_name",
                             [](const SimulatedFrameSource& s) { return s.options().world; })
      .def(
          "route",
          [](const SimulatedFrameSource& s, double step_m) {
            const auto pts = s.route().Sample(step_m);
            py::array_t<double> out({static_cast<py::ssize_t>(pts.size()), py::ssize_t{2}});
            for (std::size_t i = 0; i < pts.size(); ++i) {
              out.mutable_at(i, 0) = pts[i].x();
              out.mutable_at(i, 1) = pts[i].y();
            }
            return out;
          },
          py::arg("step_m") = 0.5, "Points of the closed route every step_m, (N, 2) metres.")
      .def_property_readonly("route_length_m",
                             [](const SimulatedFrameSource& s) { return s.route().length_m(); });
  m.def("world_names", &BuiltinWorldNames, "Names of the built-in simulated worlds.");

  py::class_<LogWriter>(m, "LogWriter",
                        "Writes an omnicml log directory: begin_session(info), write(frame)..., "
                        "finish(). Without finish() the partial directory is removed.")
      .def(py::init<const std::string&, bool>(), py::arg("log_dir"), py::arg("overwrite") = false)
      .def("begin_session", &LogWriter::BeginSession, py::arg("info"))
      .def("write", &LogWriter::Write, py::arg("frame"))
      .def("finish", &LogWriter::Finish)
      .def("__enter__", [](py::object self) { return self; })
      .def("__exit__",
           [](LogWriter& w, const py::object& type, const py::object&, const py::object&) {
             if (type.is_none()) w.Finish();
             return false;
           });

  m.def(
      "validate_log",
      [](const std::string& log_dir) {
        const LogSummary s = ValidateLog(log_dir);
        py::list sessions;
        for (const auto& x : s.sessions) {
          py::dict d;
          d["name"] = x.name;
          d["directory"] = x.directory;
          d["day_label"] = x.day_label;
          d["frames"] = x.frames;
          d["frames_with_truth"] = x.frames_with_truth;
          d["first_stamp_s"] = x.first_stamp_s;
          d["last_stamp_s"] = x.last_stamp_s;
          sessions.append(d);
        }
        py::dict out;
        out["sessions"] = sessions;
        out["total_frames"] = s.total_frames;
        return out;
      },
      py::arg("log_dir"),
      "Checks every row and image of a log; returns a summary dict, raises omnicml.Error on "
      "the first problem (file and line).");
}

}  // namespace omnicml::python
