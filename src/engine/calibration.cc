#include "omnicml/engine/calibration.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <sstream>

#include "omnicml/common/common.h"
#include "omnicml/descriptors/descriptor_factory.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
namespace {

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const std::size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid), v.end());
  return v[mid];
}

}  // namespace

void CalibrationOptions::Validate() const {
  if (max_frames < 2) throw Error(StrCat("CalibrationOptions.max_frames must be > 1, got ", max_frames));
  if (max_lag_frames < 1) {
    throw Error(StrCat("CalibrationOptions.max_lag_frames must be >= 1, got ", max_lag_frames));
  }
  if (!(std::isfinite(reference_match_length_m) && reference_match_length_m > 0)) {
    throw Error(StrCat("CalibrationOptions.reference_match_length_m must be > 0, got ",
                       reference_match_length_m));
  }
  if (!(min_scale > 0 && min_scale <= max_scale && std::isfinite(max_scale))) {
    throw Error("CalibrationOptions.min_scale/max_scale must satisfy 0 < min <= max");
  }
}

Calibration Calibrate(FrameSource& source, const CmlEngineOptions& options,
                      const CalibrationOptions& calibration_options) {
  calibration_options.Validate();
  if (source.NumSessions() < 1) throw Error("calibrate: the log has no session");
  const SessionInfo& session = source.Session(0);
  const std::unique_ptr<DescriptorExtractor> extractor = MakeDescriptorExtractor(options.descriptor);
  std::unique_ptr<OmniUnwrapper> unwrapper;
  if (session.camera.kind == ImageKind::kRawRing) {
    unwrapper = std::make_unique<OmniUnwrapper>(session.camera.calibration, session.camera.image_width,
                                                session.camera.image_height, session.camera.mask);
  }
  std::vector<Descriptor> y;
  std::vector<double> path_m;  // odometry path length from the first frame
  Frame frame;
  Pose2 last = Pose2::Zero();
  while (static_cast<int>(y.size()) < calibration_options.max_frames && source.Next(&frame)) {
    if (frame.session_index != 0) break;
    const cv::Mat panorama =
        unwrapper ? PreparePanorama(unwrapper->Unwrap(frame.image), options.panorama_width,
                                    options.panorama_height)
                  : PreparePanorama(frame.image, options.panorama_width, options.panorama_height);
    // Pixels outside a clipped ring or under the user mask do not count (descriptor.h).
    y.push_back(extractor->ComputeMasked(
        panorama, unwrapper ? unwrapper->MaskFor(panorama.cols, panorama.rows) : cv::Mat()));
    const double step = path_m.empty() ? 0.0
                                       : std::hypot(frame.odom_T_robot.x() - last.x(),
                                                    frame.odom_T_robot.y() - last.y());
    path_m.push_back(path_m.empty() ? 0.0 : path_m.back() + step);
    last = frame.odom_T_robot;
  }
  const int n = static_cast<int>(y.size());
  if (n < 2) throw Error("calibrate: the first session has fewer than two frames");

  Calibration c;
  c.frames_used = n;
  c.e_max = options.model.retrieval.e_max;
  {
    std::vector<double> steps;
    for (int t = 1; t < n; ++t) steps.push_back(path_m[t] - path_m[t - 1]);
    c.median_step_m = Median(steps);
  }
  const int max_lag = std::min(calibration_options.max_lag_frames, n - 1);
  bool found = false;
  double previous_path = 0.0, previous_e = 0.0;
  for (int lag = 1; lag <= max_lag; ++lag) {
    std::vector<double> e, p;
    for (int t = 0; t + lag < n; ++t) {
      e.push_back(extractor->Distance(y[t], y[t + lag]));
      p.push_back(path_m[t + lag] - path_m[t]);
    }
    CalibrationPoint point{lag, static_cast<int>(e.size()), Median(p), Median(e)};
    c.curve.push_back(point);
    if (!found && point.median_distance >= c.e_max) {
      // Linear interpolation between the previous lag (or zero path at E = 0) and this one.
      const double de = point.median_distance - previous_e;
      const double f = de > 0 ? (c.e_max - previous_e) / de : 1.0;
      c.match_length_m = previous_path + f * (point.median_path_m - previous_path);
      found = true;
    }
    previous_path = point.median_path_m;
    previous_e = point.median_distance;
  }
  if (!found) {
    c.saturated = true;
    c.match_length_m = c.curve.back().median_path_m;
  }
  c.scale = std::clamp(c.match_length_m / calibration_options.reference_match_length_m,
                       calibration_options.min_scale, calibration_options.max_scale);
  const CmlEngineOptions defaults;
  c.appearance_sigma_m = defaults.appearance_sigma_m * c.scale;
  c.anchor_max_sigma_m = defaults.anchor_max_sigma_m * c.scale;
  c.d_for_m = defaults.model.forgetting.d_for_m * c.scale;
  c.spatial_cell_m = defaults.model.index.spatial_cell_m * c.scale;
  return c;
}

void ApplyCalibration(const Calibration& calibration, CmlEngineOptions* options) {
  options->appearance_sigma_m = calibration.appearance_sigma_m;
  options->anchor_max_sigma_m = calibration.anchor_max_sigma_m;
  options->model.forgetting.d_for_m = calibration.d_for_m;
  options->model.index.spatial_cell_m = calibration.spatial_cell_m;
}

std::string Calibration::ToYaml() const {
  std::ostringstream s;
  s.precision(6);
  s << "# omnicml calibrate: " << frames_used << " frames of the first session, median step "
    << median_step_m << " m\n";
  s << "# descriptor distance E reaches e_max " << e_max << " after " << match_length_m
    << " m of travel" << (saturated ? " (not reached: largest lag measured)" : "")
    << "; scale " << scale << "\n";
  s << "# lag_frames, median path m, median E\n";
  for (std::size_t i = 0; i < curve.size(); ++i) {
    if (i >= 20 && (i + 1) % 20 != 0 && i + 1 != curve.size()) continue;
    s << "#   " << curve[i].lag_frames << ", " << curve[i].median_path_m << ", "
      << curve[i].median_distance << "\n";
  }
  s << "appearance_sigma_m: " << appearance_sigma_m << "\n";
  s << "anchor_max_sigma_m: " << anchor_max_sigma_m << "\n";
  s << "model:\n";
  s << "  d_for_m: " << d_for_m << "\n";
  s << "  spatial_cell_m: " << spatial_cell_m << "\n";
  return s.str();
}

}  // namespace omnicml
