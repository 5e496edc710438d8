// Identification of the odometry noise a1..a4 (geometry/motion_model.h) from the data:
// maximum likelihood on the innovations of appearance loop closures against odometry
// (docs/design.md "Motion noise identified from loop innovations").
//
// Input: the dead-reckoned odometry poses p_0..p_{n-1} of one session (odometry frame)
// and loop pairs (s, t), s < t: frames that the descriptors say were taken at the same
// place. The innovation of a pair is the odometry displacement r = p_t,xy - p_s,xy, which
// for a true revisit is zero up to odometry drift and the appearance offset:
//   r ~ N(0, S(a, rho)),  S = sum_j a_j B_j(s, t) + rho I_2,
// where B_j(s, t) is the xy covariance of the dead-reckoning error accumulated from s to
// t with unit noise in parameter j (linear in a: the propagation C' = G C G^T + V M V^T
// is linear in M, and M is linear in a), and rho (m^2) the variance, per axis, of the
// position offset between two frames that match. B_j comes from prefix sums in O(1) per
// pair.
//
// Several sessions (OdometrySession): a pair within one session is as above; a pair
// across two sessions that both start at a known pose compares their dead-reckoned map
// poses, whose errors are independent: S = F + sum_j a_j (B_j(0, s) + B_j(0, t)) + rho I_2
// with F the two start covariances carried to s and t (Phi C_0 Phi^T, xy block). The estimate
// maximises sum_k -(ln det S_k + r_k^T S_k^-1 r_k) over ln a_j and ln rho (cyclic golden-section
// search in bounds); pairs whose NIS r^T S^-1 r exceeds the chi-square quantile of
// `outlier_confidence` (2 dof) at the current estimate are perceptual aliases and are dropped, and
// the fit repeated until the set is stable.
//
// Pure function; thread-safe.
#ifndef OMNICML_TRACKING_MOTION_NOISE_IDENTIFICATION_H_
#define OMNICML_TRACKING_MOTION_NOISE_IDENTIFICATION_H_

#include <array>
#include <vector>

#include <Eigen/Core>

#include "omnicml/geometry/motion_model.h"
#include "omnicml/geometry/pose.h"

namespace omnicml {

// Two frames of one session seen at the same place: indices into the odometry poses,
// first < second.
struct LoopPair {
  int first = 0;
  int second = 0;
};

struct MotionNoiseIdentificationOptions {
  // Search bounds of each a_j (the units of MotionNoise). 0 < min < max.
  double min_parameter = 1e-7;
  double max_parameter = 1.0;
  // Search bounds of rho, m^2. 0 < min < max.
  double min_appearance_variance_m2 = 1e-6;
  double max_appearance_variance_m2 = 100.0;
  // Pairs whose NIS exceeds the chi-square quantile (2 dof) of this confidence at the
  // current estimate are rejected as aliases. In (0, 1).
  double outlier_confidence = 0.999;
  // Fewer pairs than this (after rejection) leave the noise unidentified. >= 1.
  int min_pairs = 20;
  // Cycles of the coordinate search per fit, and fits (rejection rounds). >= 1.
  int sweeps = 12;
  int max_rounds = 8;
  // Throws omnicml::Error naming the first invalid field.
  void Validate() const;
};

struct MotionNoiseIdentification {
  bool identified = false;  // false: too few pairs; noise and rho are then meaningless
  MotionNoise noise;
  double appearance_variance_m2 = 0.0;  // rho
  int pairs = 0;                        // pairs given
  int pairs_used = 0;                   // after alias rejection
  double median_nis = 0.0;              // of the pairs used at the estimate (consistent: 1.39)
  double mean_nis = 0.0;                // (consistent: about 2, less after the rejection)
};

// One session's dead reckoning in the map frame: poses[0] is the session's start pose,
// poses[i] = ApplyIncrement(poses[i-1], u_i) with the log's odometry increments.
struct OdometrySession {
  std::vector<Pose2> poses;
  // The start is known (map frame) with this covariance (m^2, rad^2); pairs across
  // sessions need both starts known. false: within-session pairs only.
  bool known_start = false;
  Eigen::Matrix3d start_covariance = Eigen::Matrix3d::Zero();
};

// Two frames seen at the same place, possibly in two sessions: (session, index) each;
// (first_session, first) comes before (second_session, second).
struct SessionLoopPair {
  int first_session = 0;
  int first = 0;
  int second_session = 0;
  int second = 0;
};

// The xy covariance of the dead-reckoning error accumulated between poses s and t
// (s <= t) per unit noise parameter, for every pair: B[k][j] (2x2) for parameter a_{j+1}.
// `odometry` are the session's poses in the odometry frame; increments are computed
// between consecutive poses (ComputeIncrement). Throws omnicml::Error on a pair out of
// range or not ordered.
std::vector<std::array<Eigen::Matrix2d, 4>> LoopDriftBases(const std::vector<Pose2>& odometry,
                                                           const std::vector<LoopPair>& pairs);

// The maximum-likelihood a1..a4 and rho (file comment). Throws omnicml::Error on invalid
// options or pairs.
MotionNoiseIdentification IdentifyMotionNoise(const std::vector<Pose2>& odometry,
                                              const std::vector<LoopPair>& pairs,
                                              const MotionNoiseIdentificationOptions& options = {});
// The same over several sessions (pairs within a session, or across two sessions with
// known starts). Throws omnicml::Error on a pair out of range, not ordered, or across
// sessions without known starts.
MotionNoiseIdentification IdentifyMotionNoise(const std::vector<OdometrySession>& sessions,
                                              const std::vector<SessionLoopPair>& pairs,
                                              const MotionNoiseIdentificationOptions& options = {});

}  // namespace omnicml

#endif  // OMNICML_TRACKING_MOTION_NOISE_IDENTIFICATION_H_
