// Bindings of the engine: EngineOptions (from a dict, YAML text or a YAML file), CmlEngine
// (process_frame, sessions, save/load), its results (FrameResult, Estimate) and the map as
// numpy arrays (Map).
#include <charconv>
#include <cstring>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <pybind11/stl.h>
#include <yaml-cpp/yaml.h>

#include "convert.h"
#include "omnicml/common/common.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/report/map_export.h"
#include "omnicml/run/run_config.h"
#include "omnicml/run/run_recorder.h"

namespace omnicml::python {
namespace {

// ---- Options: Python values <-> YAML ------------------------------------------------

YAML::Node NodeFromPython(const py::handle& v, const std::string& key) {
  if (py::isinstance<py::dict>(v)) {
    YAML::Node n(YAML::NodeType::Map);
    for (const auto& item : py::reinterpret_borrow<py::dict>(v)) {
      const std::string k = py::str(item.first);
      n[k] = NodeFromPython(item.second, key.empty() ? k : key + "." + k);
    }
    return n;
  }
  if (py::isinstance<py::bool_>(v)) return YAML::Node(v.cast<bool>() ? "true" : "false");
  if (py::isinstance<py::int_>(v)) return YAML::Node(std::string(py::str(v)));
  if (py::isinstance<py::float_>(v)) return YAML::Node(std::string(py::repr(v)));
  if (py::isinstance<py::str>(v)) return YAML::Node(v.cast<std::string>());
  if (py::isinstance<py::array>(v)) {
    return NodeFromPython(v.attr("tolist")(), key);
  }
  if (py::isinstance<py::list>(v) || py::isinstance<py::tuple>(v)) {
    YAML::Node n(YAML::NodeType::Sequence);
    for (const auto& x : v) n.push_back(NodeFromPython(x, key));
    return n;
  }
  // numpy scalars and other numbers.
  if (py::hasattr(v, "item")) return NodeFromPython(v.attr("item")(), key);
  throw Error(StrCat("options: '", key, "': unsupported value of type ",
                     std::string(py::str(py::type::of(v).attr("__name__")))));
}

std::string YamlFromDict(const py::dict& d) {
  YAML::Emitter out;
  out << NodeFromPython(d, "");
  return std::string(out.c_str()) + "\n";
}

py::object PythonFromNode(const YAML::Node& n) {
  switch (n.Type()) {
    case YAML::NodeType::Map: {
      py::dict d;
      for (const auto& kv : n) d[py::str(kv.first.as<std::string>())] = PythonFromNode(kv.second);
      return d;
    }
    case YAML::NodeType::Sequence: {
      py::list l;
      for (const auto& x : n) l.append(PythonFromNode(x));
      return l;
    }
    case YAML::NodeType::Scalar: {
      const std::string s = n.Scalar();
      if (s == "true") return py::bool_(true);
      if (s == "false") return py::bool_(false);
      long long i = 0;
      auto [pi, ei] = std::from_chars(s.data(), s.data() + s.size(), i);
      if (ei == std::errc() && pi == s.data() + s.size()) return py::int_(i);
      double x = 0;
      auto [pd, ed] = std::from_chars(s.data(), s.data() + s.size(), x);
      if (ed == std::errc() && pd == s.data() + s.size()) return py::float_(x);
      return py::str(s);
    }
    default:
      return py::none();
  }
}

py::dict DictFromOptions(const CmlEngineOptions& o) {
  return PythonFromNode(YAML::Load(EngineOptionsToYaml(o)));
}

}  // namespace

// Options from None (defaults), an EngineOptions, a dict (keys as in the YAML file) or a
// path of a YAML file. Shared with experiments.cc.
CmlEngineOptions OptionsFromObject(const py::object& obj) {
  if (obj.is_none()) return CmlEngineOptions{};
  if (py::isinstance<CmlEngineOptions>(obj)) return obj.cast<CmlEngineOptions>();
  if (py::isinstance<py::dict>(obj)) {
    return ParseEngineOptionsYaml(YamlFromDict(obj.cast<py::dict>()), "options dict");
  }
  if (py::isinstance<py::str>(obj) || py::hasattr(obj, "__fspath__")) {
    return LoadEngineOptionsYaml(py::str(obj));
  }
  throw Error(
      StrCat("options: expected None, a dict, a YAML file path or omnicml.EngineOptions, got ",
             std::string(py::str(py::type::of(obj).attr("__name__")))));
}

namespace {

// The map as numpy arrays (a snapshot; later frames do not change it).
struct MapSnapshot {
  py::dict views;
  py::dict components;
  py::dict events;
  std::size_t num_views = 0;
  std::size_t num_components = 0;
  std::size_t memory_bytes = 0;
  std::uint64_t next_view_id = 0;
  std::uint64_t next_component_id = 0;
};

template <typename T>
py::array_t<T> Vec(const std::vector<T>& v) {
  py::array_t<T> out(static_cast<py::ssize_t>(v.size()));
  if (!v.empty()) std::memcpy(out.mutable_data(), v.data(), v.size() * sizeof(T));
  return out;
}

MapSnapshot Snapshot(const EnvironmentModel& model) {
  MapSnapshot s;
  const auto& views = model.views();
  const std::size_t n = views.size();
  std::vector<std::uint64_t> view_id(n);
  std::vector<std::int64_t> created_frame(n), observations(n), last_seen_frame(n);
  std::vector<std::int32_t> created_session(n), last_seen_session(n), view_components(n);
  std::vector<double> total_weight(n);
  const std::size_t f = n ? views[0].descriptor.features.size() : 0;
  py::array_t<float> features({static_cast<py::ssize_t>(n), static_cast<py::ssize_t>(f)});
  std::vector<std::int64_t> c_view_index;
  std::vector<std::uint64_t> c_view_id, c_id;
  std::vector<double> c_weight, c_eta, c_mean, c_cov, c_spread;
  for (std::size_t i = 0; i < n; ++i) {
    const ReferenceView& v = views[i];
    view_id[i] = v.id;
    created_frame[i] = v.stats.created_frame;
    created_session[i] = v.stats.created_session;
    observations[i] = v.stats.observations;
    last_seen_frame[i] = v.stats.last_seen_frame;
    last_seen_session[i] = v.stats.last_seen_session;
    view_components[i] = static_cast<std::int32_t>(v.components.size());
    total_weight[i] = v.TotalWeight();
    if (f && v.descriptor.features.size() == f) {
      std::memcpy(features.mutable_data(static_cast<py::ssize_t>(i), 0),
                  v.descriptor.features.data(), f * sizeof(float));
    }
    for (const ViewComponent& c : v.components) {
      c_view_index.push_back(static_cast<std::int64_t>(i));
      c_view_id.push_back(v.id);
      c_id.push_back(c.id);
      c_weight.push_back(c.weight);
      c_eta.push_back(c.eta);
      for (int k = 0; k < 3; ++k) c_mean.push_back(c.mean[k]);
      for (int r = 0; r < 3; ++r)
        for (int k = 0; k < 3; ++k) c_cov.push_back(c.covariance(r, k));
      for (int r = 0; r < 2; ++r)
        for (int k = 0; k < 2; ++k) c_spread.push_back(c.spread(r, k));
    }
  }
  s.views["id"] = Vec(view_id);
  s.views["created_frame"] = Vec(created_frame);
  s.views["created_session"] = Vec(created_session);
  s.views["observations"] = Vec(observations);
  s.views["last_seen_frame"] = Vec(last_seen_frame);
  s.views["last_seen_session"] = Vec(last_seen_session);
  s.views["num_components"] = Vec(view_components);
  s.views["total_weight"] = Vec(total_weight);
  s.views["features"] = features;
  const auto m = static_cast<py::ssize_t>(c_id.size());
  s.components["view_index"] = Vec(c_view_index);
  s.components["view_id"] = Vec(c_view_id);
  s.components["id"] = Vec(c_id);
  s.components["weight"] = Vec(c_weight);
  s.components["eta"] = Vec(c_eta);
  s.components["mean"] = Vec(c_mean).reshape({m, py::ssize_t{3}});
  s.components["covariance"] = Vec(c_cov).reshape({m, py::ssize_t{3}, py::ssize_t{3}});
  s.components["spread"] = Vec(c_spread).reshape({m, py::ssize_t{2}, py::ssize_t{2}});

  const auto& events = model.events();
  py::list type, reason;
  std::vector<std::int64_t> e_frame;
  std::vector<std::int32_t> e_session;
  std::vector<std::uint64_t> e_view, e_comp;
  std::vector<double> e_pos, e_weight;
  for (const MapEvent& e : events) {
    type.append(ToString(e.type));
    reason.append(e.reason);
    e_frame.push_back(e.frame);
    e_session.push_back(e.session);
    e_view.push_back(e.view_id);
    e_comp.push_back(e.component_id);
    for (int k = 0; k < 3; ++k) e_pos.push_back(e.position[k]);
    e_weight.push_back(e.weight);
  }
  s.events["type"] = type;
  s.events["frame"] = Vec(e_frame);
  s.events["session"] = Vec(e_session);
  s.events["view_id"] = Vec(e_view);
  s.events["component_id"] = Vec(e_comp);
  s.events["position"] =
      Vec(e_pos).reshape({static_cast<py::ssize_t>(events.size()), py::ssize_t{3}});
  s.events["weight"] = Vec(e_weight);
  s.events["reason"] = reason;
  s.num_views = model.NumViews();
  s.num_components = model.NumComponents();
  s.memory_bytes = model.MemoryBytes();
  s.next_view_id = model.next_view_id();
  s.next_component_id = model.next_component_id();
  return s;
}

py::dict StatsDict(const FrameStats& s) {
  py::dict d;
  d["unwrap_us"] = s.unwrap_us;
  d["describe_us"] = s.describe_us;
  d["update_us"] = s.update_us;
  d["apply_us"] = s.apply_us;
  d["match_us"] = s.match_us;
  d["fuse_us"] = s.fuse_us;
  d["reconstruct_us"] = s.reconstruct_us;
  d["total_us"] = s.total_us;
  d["num_views"] = s.num_views;
  d["num_map_components"] = s.num_map_components;
  d["num_matches"] = s.num_matches;
  d["best_similarity"] = s.best_similarity;
  d["hypothesis_components"] = s.hypothesis_components;
  d["gated_matching"] = s.gated_matching;
  d["matching_candidates"] = s.matching_candidates;
  d["mixture_components"] = s.mixture_components;
  d["updates_applied"] = s.updates_applied;
  d["updates_queued"] = s.updates_queued;
  d["pending_multimodal"] = s.pending_multimodal;
  d["dropped_pending"] = s.dropped_pending;
  return d;
}

py::dict CountersDict(const EngineCounters& c) {
  py::dict d;
  d["frames"] = c.frames;
  d["unimodal_frames"] = c.unimodal_frames;
  d["multimodal_frames"] = c.multimodal_frames;
  d["unknown_frames"] = c.unknown_frames;
  d["reconstructed_frames"] = c.reconstructed_frames;
  d["dropped_pending_frames"] = c.dropped_pending_frames;
  d["updates_queued"] = c.updates_queued;
  d["global_seeds"] = c.global_seeds;
  d["global_fallbacks"] = c.global_fallbacks;
  return d;
}

// Starts a default session when none is running: panoramic camera, known start pose 0.
void EnsureSession(CmlEngine& e) {
  if (e.session_state().in_session) return;
  SessionInfo info;
  info.name = "python";
  info.camera.kind = ImageKind::kPanorama;
  e.BeginSession(info);
}

FrameResult ProcessFrame(CmlEngine& e, Frame& frame) {
  EnsureSession(e);
  frame.global_index = e.next_frame();
  frame.session_index = e.session_state().session;
  py::gil_scoped_release release;
  return e.ProcessFrame(frame);
}

py::bytes Bytes(const std::vector<std::uint8_t>& b) {
  return py::bytes(reinterpret_cast<const char*>(b.data()), b.size());
}

}  // namespace

void BindEngine(py::module_& m) {
  py::class_<CmlEngineOptions>(
      m, "EngineOptions",
      "Every option of the engine (descriptor, tracker, model, reconstruction and the "
      "engine's own). Build it from a dict or YAML (keys equal member names, nested sections "
      "'descriptor', 'tracker', 'model', 'reconstruction'); an unknown key or an invalid value "
      "raises omnicml.Error naming it.")
      .def(py::init([](const py::object& options) { return OptionsFromObject(options); }),
           py::arg("options") = py::none(),
           "options: None (defaults), a dict, or the path of a YAML file.")
      .def_static(
          "from_yaml_text",
          [](const std::string& text, const std::string& source) {
            return ParseEngineOptionsYaml(text, source);
          },
          py::arg("text"), py::arg("source") = "yaml text",
          "Parses YAML text on top of the defaults; `source` names it in errors.")
      .def_static("from_yaml", &LoadEngineOptionsYaml, py::arg("path"),
                  "Reads a YAML file on top of the defaults.")
      .def("to_yaml", &EngineOptionsToYaml, "Every option as YAML (loadable again).")
      .def("to_dict", &DictFromOptions, "Every option as a nested dict.")
      .def(
          "updated",
          [](const CmlEngineOptions& o, const py::dict& changes) {
            return ParseEngineOptionsYaml(YamlFromDict(changes), "options dict", o);
          },
          py::arg("changes"),
          "A copy with the keys of `changes` (a nested dict) applied and validated.")
      .def("validate", &CmlEngineOptions::Validate,
           "Raises omnicml.Error naming the first invalid field.")
      .def("__eq__", [](const CmlEngineOptions& a,
                        const CmlEngineOptions& b) { return SameEngineOptions(a, b); })
      .def("__repr__", [](const CmlEngineOptions& o) {
        return "<omnicml.EngineOptions>\n" + EngineOptionsToYaml(o);
      });

  py::class_<Estimate>(m, "Estimate",
                       "Summary of p(x_t): the strongest component (pose, covariance, weight) "
                       "and the moment-matched mean of the whole mixture.")
      .def_property_readonly(
          "pose", [](const Estimate& e) { return ArrayFromPose(e.strongest.mean); },
          "Mean of the strongest component, (x_m, y_m, phi_rad), map frame.")
      .def_property_readonly(
          "covariance", [](const Estimate& e) { return ArrayFromMatrix3(e.strongest.covariance); })
      .def_property_readonly("weight", [](const Estimate& e) { return e.strongest.weight; })
      .def_property_readonly(
          "mean_pose", [](const Estimate& e) { return ArrayFromPose(e.mean.mean); },
          "Moment-matched mean of the mixture (mu_t).")
      .def_property_readonly("mean_covariance",
                             [](const Estimate& e) { return ArrayFromMatrix3(e.mean.covariance); })
      .def_readonly("unimodal", &Estimate::unimodal)
      .def_readonly("num_components", &Estimate::num_components)
      .def("__repr__", [](const Estimate& e) {
        return StrCat("<omnicml.Estimate pose=(", e.strongest.mean[0], ", ", e.strongest.mean[1],
                      ", ", e.strongest.mean[2], ") unimodal=", e.unimodal ? "True" : "False",
                      " components=", e.num_components, ">");
      });

  py::class_<FrameResult>(m, "FrameResult", "The result of one processed frame.")
      .def_readonly("frame", &FrameResult::frame, "Engine frame index (0-based over all sessions).")
      .def_readonly("session", &FrameResult::session, "Engine session index.")
      .def_readonly("estimate", &FrameResult::estimate,
                    "Estimate, or None while the state is unknown (global start not seeded).")
      .def_property_readonly(
          "pose",
          [](const FrameResult& r) -> py::object {
            if (!r.estimate) return py::none();
            return ArrayFromPose(r.estimate->strongest.mean);
          },
          "Shortcut: estimate.pose or None.")
      .def_property_readonly(
          "stats", [](const FrameResult& r) { return StatsDict(r.stats); },
          "Timings (us) and sizes of the call, as a dict.")
      .def_property_readonly(
          "reconstructed",
          [](const FrameResult& r) {
            py::list l;
            for (const auto& [frame, g] : r.reconstructed)
              l.append(py::make_tuple(frame, DictFromGaussian(g)));
            return l;
          },
          "States of earlier frames reconstructed at this frame: [(frame, {mean, covariance, "
          "weight})].")
      .def_property_readonly(
          "map_state",
          [](const FrameResult& r) -> py::object {
            if (!r.map_state) return py::none();
            return DictFromGaussian(*r.map_state);
          },
          "N(mu_t, C_t) queued for the map (unimodal frames), or None.")
      .def("__repr__", [](const FrameResult& r) {
        return StrCat("<omnicml.FrameResult frame=", r.frame, " session=", r.session,
                      r.estimate ? "" : " no estimate", ">");
      });

  py::class_<MapSnapshot>(
      m, "Map",
      "A snapshot of the adaptive appearance map as numpy arrays. views: dict of (N,) arrays "
      "(id, created_frame, created_session, observations, last_seen_frame, last_seen_session, "
      "num_components, total_weight) and features (N, F) float32; components: dict of (M,) "
      "arrays (view_index into the views, view_id, id, weight, eta), mean (M, 3), covariance "
      "(M, 3, 3) and spread (M, 2, 2), the scatter of the positions merged into each; events: the "
      "map's event log (type, frame, session, view_id, component_id, "
      "position (K, 3), weight, reason).")
      .def_readonly("views", &MapSnapshot::views)
      .def_readonly("components", &MapSnapshot::components)
      .def_readonly("events", &MapSnapshot::events)
      .def_readonly("num_views", &MapSnapshot::num_views)
      .def_readonly("num_components", &MapSnapshot::num_components)
      .def_readonly("memory_bytes", &MapSnapshot::memory_bytes)
      .def_readonly("next_view_id", &MapSnapshot::next_view_id)
      .def_readonly("next_component_id", &MapSnapshot::next_component_id)
      .def_property_readonly(
          "weights", [](const MapSnapshot& s) { return s.components["weight"]; },
          "Component weights w_ij, (M,).")
      .def_property_readonly(
          "eta", [](const MapSnapshot& s) { return s.components["eta"]; },
          "Component eta_ij, (M,).")
      .def("__repr__", [](const MapSnapshot& s) {
        return StrCat("<omnicml.Map views=", s.num_views, " components=", s.num_components, ">");
      });

  py::class_<CmlEngine>(
      m, "CmlEngine",
      "The omniview CML engine [G]: per frame, unwrap, describe, p(x|u), p(x|y), fuse, "
      "estimate, and the delayed map update. Sessions (days) start with begin_session; "
      "process_frame starts a default one (panoramic camera, known start pose 0) when none is "
      "running. Deterministic: same options and frames give identical estimates. One thread "
      "at a time.")
      .def(py::init([](const py::object& options) {
             return std::make_unique<CmlEngine>(OptionsFromObject(options));
           }),
           py::arg("options") = py::none(),
           "options: None (defaults), a dict (YAML keys, nested sections), a YAML file path, or "
           "an EngineOptions. Raises omnicml.Error naming an unknown key or invalid value.")
      .def_static("load", &LoadEngine, py::arg("path"),
                  "Loads an engine saved with save(); bit-identical state. Raises omnicml.Error "
                  "naming the path and the problem.")
      .def_static(
          "from_bytes",
          [](const py::bytes& b, const std::string& source) {
            const std::string s = b;
            return DecodeEngine(std::vector<std::uint8_t>(s.begin(), s.end()), source);
          },
          py::arg("data"), py::arg("source") = "bytes", "Decodes the bytes of to_bytes().")
      .def("save", &SaveEngine, py::arg("path"),
           "Writes the whole engine state (options, map, tracker, queues) atomically.")
      .def(
          "to_bytes", [](const CmlEngine& e) { return Bytes(EncodeEngine(e)); },
          "The bytes save() writes.")
      .def(
          "begin_session",
          [](CmlEngine& e, const std::optional<SessionInfo>& session) {
            SessionInfo info;
            if (session) {
              info = *session;
            } else {
              info.name = "python";
              info.camera.kind = ImageKind::kPanorama;
            }
            e.BeginSession(info);
          },
          py::arg("session") = py::none(),
          "Starts a session (day): a SessionInfo (e.g. from Simulator.session(i)), or None for "
          "a panoramic camera with known start pose 0. Raises omnicml.Error on a bad camera.")
      .def(
          "process_frame",
          [](CmlEngine& e, const py::object& image, const py::object& odom_pose,
             std::optional<double> stamp, const py::object& truth) {
            Frame f;
            f.image = ImageFromArray(image, "image");
            f.odom_T_robot = PoseFromObject(odom_pose, "odom_pose");
            f.stamp_s = stamp.value_or(static_cast<double>(e.next_frame()));
            if (!truth.is_none()) f.map_T_robot_truth = PoseFromObject(truth, "truth");
            return ProcessFrame(e, f);
          },
          py::arg("image"), py::arg("odom_pose"), py::arg("stamp") = py::none(),
          py::arg("truth") = py::none(),
          "Processes one frame: image (numpy uint8 raw ring of the session camera's size, or "
          "a panorama), odometry pose (x_m, y_m, phi_rad), stamp in seconds. Returns a "
          "FrameResult (estimate and stats). Raises omnicml.Error on a bad image or "
          "odometry.")
      .def(
          "process", [](CmlEngine& e, Frame frame) { return ProcessFrame(e, frame); },
          py::arg("frame"), "Processes a Frame (from a LogReader or Simulator).")
      .def("finish", &CmlEngine::Finish,
           "End of the run: queues the pending unimodal frames and applies every queued map "
           "update. Returns the number applied. Processing may continue afterwards.")
      .def_property_readonly("options", &CmlEngine::options, "The EngineOptions (a copy).")
      .def_property_readonly(
          "counters", [](const CmlEngine& e) { return CountersDict(e.counters()); },
          "Counters over the engine's life, as a dict.")
      .def_property_readonly(
          "map", [](const CmlEngine& e) { return Snapshot(e.model()); },
          "A snapshot of the map (omnicml.Map).")
      .def_property_readonly("num_views", [](const CmlEngine& e) { return e.model().NumViews(); })
      .def_property_readonly("num_components",
                             [](const CmlEngine& e) { return e.model().NumComponents(); })
      .def_property_readonly("next_frame", &CmlEngine::next_frame,
                             "The engine index the next frame will get.")
      .def_property_readonly(
          "session", [](const CmlEngine& e) { return e.session_state().session; },
          "Index of the current session, -1 before the first.")
      .def_property_readonly(
          "extractor",
          [](const CmlEngine& e) {
            return std::const_pointer_cast<DescriptorExtractor>(e.extractor_ptr());
          },
          "The engine's DescriptorExtractor.")
      .def(
          "find_matches",
          [](const CmlEngine& e, const Descriptor& y) {
            py::list out;
            for (const ViewMatch& v : e.model().FindMatches(y)) {
              py::dict d;
              d["view_index"] = v.view_index;
              d["view_id"] = v.view_id;
              d["distance"] = v.distance;
              d["similarity"] = v.similarity;
              d["relative_heading_rad"] = v.relative_heading_rad;
              out.append(d);
            }
            return out;
          },
          py::arg("descriptor"),
          "Views matching a descriptor (E < e_max), best first: dicts with view_index, "
          "view_id, distance, similarity, relative_heading_rad.")
      .def("set_threads", &CmlEngine::SetThreads, py::arg("threads"),
           "Changes options.threads between frames (1: no worker; >= 2: background map "
           "updates); results do not depend on it. Raises omnicml.Error unless threads >= 1.")
      .def(
          "set_forgetting_mode",
          [](CmlEngine& e, const std::string& mode) {
            e.SetForgettingMode(ForgettingModeFromString(mode));
          },
          py::arg("mode"),
          "Changes options.model.forgetting.mode between frames: 'active', 'passive' or 'static' "
          "(e.g. learn day 1, then freeze the map); queued updates apply under the new mode.")
      .def(
          "map_json", [](const CmlEngine& e) { return MapToJson(e).dump(); },
          "The map as JSON text (datasets/map_schema.md).");
}

}  // namespace omnicml::python
