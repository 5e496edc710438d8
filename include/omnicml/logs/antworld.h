// Reader and importer for the AntWorld panoramic image database
// (../shared/datasets/antworld, see its README.md): the project's first real,
// externally produced input.
//
// Input: a CSV with the header `X [mm], Y [mm], Z [mm], Heading [degrees], Filename`
// (fields may carry spaces after the commas) and the PNG images beside it; every image is
// a 720 x 150 RGB cylindrical panorama, 0.5 degree per column.
//
// Conventions, as measured on the files (tests/antworld_test.cc checks them after
// conversion, on the route and the grid shipped with the data):
//  * Heading: the file's "Heading" is a compass angle h, clockwise from the world +y
//    axis. Over the whole route ant1_route1 the direction of travel atan2(dy, dx) equals
//    90 deg - h (circular mean of the difference -0.01 deg, resultant length 0.9998);
//    read as a counter-clockwise angle from +x, h would be off by 73 deg on average. Our
//    pose angle (counter-clockwise from world +x) is therefore phi = 90 deg - h, wrapped
//    to (-pi, pi].
//  * Images: an AntWorld panorama looks along the heading at its centre column W/2 and
//    its columns run clockwise (a "human" panorama: the left of the picture is to the
//    left of forward). Found from the optical flow between neighbouring grid views (all
//    heading 0, i.e. facing world +y; 40 pairs): for a step along world +x the focus of
//    expansion is at column 3W/4, for a step along +y at column W/2. Ours looks forward
//    at column 0 and runs counter-clockwise (omni_unwrapper.h), so the reader delivers
//      ours[c] = antworld[(W/2 - c) mod W]   (a reflection about the centre column),
//    after which the focus lies at robot azimuth -87.7 deg (step along +x, expected -90)
//    and 1.2 deg (step along +y, expected 0).
//  * Both together: a route frame equals the nearest grid view rolled by
//    (phi_route - phi_grid) / (2 pi / W) columns, as our convention requires. On every
//    8th route frame (102 frames) the roll measured by circular cross-correlation agrees
//    with the converted heading difference to a median of 2.8 deg, 87 % within 15 deg
//    (grass parallax, the grid view being up to 140 mm away, spoils the rest); the
//    opposite sign gives a median of 32 deg. This relative test alone cannot tell "both
//    mirrored" from "neither", hence the travel-direction and optical-flow checks.
//
// Poses: ground truth map_T_robot = (X / 1000, Y / 1000, phi) in metres and radians; the
// map frame is the AntWorld world frame. Odometry is derived from consecutive
// ground-truth poses with seeded noise: the increment between two delivered frames is
// ComputeIncrement(truth_prev, truth_curr) and the odometry pose is advanced by that
// increment perturbed as in Thrun et al.'s sample_motion_model_odometry with the
// variances of docs/design.md "Motion model" (SampleOdometryIncrement, geometry/motion_model.h).
// The odometry frame starts at the first frame's ground truth pose.
#ifndef OMNICML_LOGS_ANTWORLD_H_
#define OMNICML_LOGS_ANTWORLD_H_

#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "omnicml/geometry/motion_model.h"
#include "omnicml/geometry/pose.h"
#include "omnicml/sensor/frame.h"

namespace omnicml {

struct AntWorldOptions {
  // Odometry error model (docs/design.md "Motion model"): variances of rot1, trans, rot2 are
  // a1 rot1^2 + a2 trans^2, a3 trans^2 + a4 (rot1^2 + rot2^2), a1 rot2^2 + a2 trans^2.
  // a1: rad^2/rad^2, a2: rad^2/m^2, a3: m^2/m^2, a4: m^2/rad^2. Small by default (about
  // 3 % of a rotation or a translation, 1 degree per metre).
  MotionNoise odometry_noise{.a1 = 1e-3, .a2 = 3e-4, .a3 = 1e-3, .a4 = 1e-4};
  // Seed of the odometry noise (std::mt19937_64). Same seed, same odometry.
  std::uint64_t seed = 1;
  // Use every stride-th row of the CSV (1 = all). Odometry increments are taken between
  // the used rows.
  int stride = 1;
  // Time between two consecutive CSV rows, seconds (AntWorld has no time stamps):
  // frame i of the file gets stamp_s = start_time_s + i * row_period_s.
  double row_period_s = 0.1;
  // Session start time, seconds.
  double start_time_s = 0.0;
  // How the session starts. With mode known and start_pose_from_truth, the start pose is
  // the first delivered frame's ground truth (the covariance is kept).
  SessionStart start;
  bool start_pose_from_truth = true;
  // Session name and day label; an empty name means the CSV's file stem.
  std::string session_name;
  std::string day_label = "antworld";

  // Throws omnicml::Error naming the field (negative or non-finite a1..a4, stride < 1,
  // row_period_s <= 0, non-positive start covariance).
  void Validate() const;
};

// One row of an AntWorld CSV, converted to our conventions.
struct AntWorldRow {
  std::int64_t line = 0;   // 1-based line in the CSV
  std::string image_path;  // absolute or relative to the working directory
  Pose2 map_T_robot;       // (X / 1000, Y / 1000, 90 deg - heading) in m, m, rad
};

// Parses an AntWorld CSV (all rows; poses are small, images are not read). Throws
// omnicml::Error "csv:line: what" on a missing file, a wrong header, a wrong column
// count or an unparsable or non-finite number.
std::vector<AntWorldRow> ReadAntWorldCsv(const std::string& csv);

// Converts an AntWorld panorama (column W/2 forward, clockwise columns) to our convention
// (column 0 forward, counter-clockwise): out[c] = in[(W/2 - c) mod W]. Any type; W even.
cv::Mat AntWorldToOurPanorama(const cv::Mat& antworld_panorama);

// Converts an AntWorld heading (degrees, compass: clockwise from world +y) to our phi
// (radians, counter-clockwise from world +x), wrapped to (-pi, pi].
double AntWorldHeadingToPhi(double heading_deg);

// A FrameSource over one AntWorld CSV: one session, ground truth on every frame, images
// read lazily in Next() and converted to our panorama convention (BGR, CV_8UC3). The CSV
// is parsed and the odometry computed at construction (a few bytes per row); the first
// image is read to learn the image size. Not thread-safe: one consumer.
class AntWorldReader : public FrameSource {
 public:
  // Throws omnicml::Error for invalid options, a bad CSV (file and line), no rows, or an
  // unreadable first image.
  AntWorldReader(const std::string& csv, const AntWorldOptions& options = {});

  int NumSessions() const override { return 1; }
  const SessionInfo& Session(int index) const override;
  // Throws omnicml::Error "csv:line: what" (naming the image) when an image is missing, does not
  // decode, or has another size than the first one.
  bool Next(Frame* frame) override;

  // Number of frames the reader delivers (after the stride).
  std::int64_t NumFrames() const { return static_cast<std::int64_t>(rows_.size()); }

 private:
  SessionInfo session_;
  std::string csv_path_;
  std::vector<AntWorldRow> rows_;  // the used rows (after the stride)
  std::vector<double> stamps_s_;
  std::vector<Pose2> odometry_;  // odom_T_robot per used row
  std::int64_t next_ = 0;
};

// Writes the frames of an AntWorld CSV as a one-session log to out_dir with LogWriter
// (so out_dir must not exist; nothing is left behind on failure). Returns the number of
// frames written. Throws omnicml::Error.
std::int64_t ImportAntWorld(const std::string& csv, const std::string& out_dir,
                            const AntWorldOptions& options);

}  // namespace omnicml

#endif  // OMNICML_LOGS_ANTWORLD_H_
