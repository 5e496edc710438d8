// Identification of the odometry noise a1..a4 (geometry/motion_model.h) from the data:
// maximum a posteriori estimate on the innovations of appearance loop closures against
// odometry (docs/design.md "Motion noise identified from loop innovations").
//
// Input: the dead-reckoned odometry poses p_0..p_{n-1} of one session (odometry frame)
// and loop pairs (s, t), s < t: frames that the descriptors say were taken at the same
// place, optionally with the descriptor's relative heading psi = heading(t) - heading(s).
// The innovation of a pair is
//   r = (p_t,xy - p_s,xy, WrapAngle(phi_t - phi_s - psi)),
// which for a true revisit is zero up to odometry drift and the appearance offset:
//   r ~ N(0, S),  S = sum_j a_j B_j(s, t) + diag(rho, rho, rho_phi),
// where B_j(s, t) (3x3) is the covariance of the dead-reckoning error accumulated from s
// to t with unit noise in parameter j (linear in a: the propagation C' = G C G^T + V M V^T
// is linear in M, and M is linear in a), rho (m^2) the variance, per axis, of the position
// offset between two frames that match, and rho_phi (rad^2) the variance of the
// descriptor's relative heading. Pairs without psi (descriptors without heading) use the
// xy rows only (2 dof). B_j comes from prefix sums in O(1) per pair.
//
// Several sessions (OdometrySession): a pair within one session is as above; a pair
// across two sessions that both start at a known pose compares their dead-reckoned map
// poses, whose errors are independent: S = F + sum_j a_j (B_j(0, s) + B_j(0, t)) + the
// offsets, with F the two start covariances carried to s and t (Phi C_0 Phi^T).
//
// Prior (a weak one, so that a parameter the loops do not see keeps a physical value
// instead of collapsing to a bound): on the shape of a1..a4, d_j = ln(a_j / c_j) with c the
// prior shape, -2 ln p = sum_j (d_j - mean(d))^2 / sd^2 (the common scale is free: the
// data alone set it); on each offset variance, ln(rho / rho_0) ~ N(0, sd_offset^2). The
// estimate minimises -2 ln posterior = sum_k (ln det S_k + r_k^T S_k^-1 r_k) - 2 ln p over
// the logarithms of the six parameters in bounds (Fisher scoring with a damped step from
// the prior shape at its best common scale). With offset_dof nu > 0, rho comes from a
// second fit whose pair terms are the Student t's, ln det S_k + (nu + d) ln(1 + r_k^T
// S_k^-1 r_k / nu). With joint_pairs > 0, a1..a4 come from a third fit: the joint
// likelihood of the inliers' heading innovations, whose covariance holds what every two
// pairs' heading drifts share (the pairs of a log hold one realisation of the drift, not
// one per pair). Pairs whose NIS exceeds the chi-square
// quantile of `outlier_confidence` (2 or 3 dof) at the current estimate are perceptual
// aliases and are dropped, and the fit repeated until the set is stable.
//
// Pure function; deterministic; thread-safe.
#ifndef OMNICML_TRACKING_MOTION_NOISE_IDENTIFICATION_H_
#define OMNICML_TRACKING_MOTION_NOISE_IDENTIFICATION_H_

#include <array>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "omnicml/geometry/motion_model.h"
#include "omnicml/geometry/pose.h"

namespace omnicml {

// Two frames of one session seen at the same place: indices into the odometry poses,
// first < second; heading_rad, when known, is the descriptor's relative heading
// RelativeHeading(y_second, y_first): the robot's heading at `second` minus at `first`,
// radians.
struct LoopPair {
  LoopPair() = default;
  LoopPair(int first_index, int second_index, std::optional<double> heading = std::nullopt)
      : first(first_index), second(second_index), heading_rad(heading) {}
  int first = 0;
  int second = 0;
  std::optional<double> heading_rad;
};

struct MotionNoiseIdentificationOptions {
  // Search bounds of each a_j (the units of MotionNoise). 0 < min < max.
  double min_parameter = 1e-7;
  double max_parameter = 1.0;
  // Search bounds of rho, m^2. 0 < min < max.
  double min_appearance_variance_m2 = 1e-6;
  double max_appearance_variance_m2 = 100.0;
  // Search bounds of rho_phi, rad^2. 0 < min < max.
  double min_heading_variance_rad2 = 1e-8;
  double max_heading_variance_rad2 = 1.0;
  // Prior shape of a1..a4: only the ratios matter (the scale is free). Every a_j > 0. The
  // engine's default noise: translation and rotation relative variances equal (a1 = a3),
  // the cross terms a fifth of them.
  MotionNoise shape_prior{0.05, 0.01, 0.05, 0.01};
  // Standard deviation of ln a_j about the prior shape (after removing the common scale),
  // natural-log units: 0.25 lets a parameter depart from the shape by a factor 1.28 at one
  // sd, and loops that see it clearly move it much further (docs/design.md). > 0.
  double shape_prior_log_sd = 0.25;
  // Prior centre of rho, m^2 (> 0): the offset between two frames that match. Calibrate
  // sets it to (L / 4)^2 for match length L (a pair is accepted within about L / 2).
  double appearance_variance_prior_m2 = 0.0045;
  // Prior centre of rho_phi, rad^2 (> 0). Calibrate sets it to the square of one panorama
  // column's angle.
  double heading_variance_prior_rad2 = 0.0025;
  // Standard deviation of ln rho and ln rho_phi about their centres, natural-log units. > 0.
  double offset_prior_log_sd = 1.5;
  // The appearance offset rho as the core of the pairs' offsets: 0 takes rho from the
  // Gaussian fit with a1..a4 (the second moment of everything a1..a4 leave unexplained);
  // nu > 0 refits the same inliers under a multivariate Student t likelihood with nu
  // degrees of freedom and takes rho from that fit. A minority of pairs matched with a
  // large offset (a corridor whose view changes slowly, matched a few metres along itself)
  // then weighs less instead of widening rho for every pair. a1..a4 (unless joint_pairs
  // replaces them) and rho_phi stay the Gaussian fit's: the prior's covariance must cover the
  // drift's full spread, or a confidence gate rejects the true fix after a long stretch of dead
  // reckoning (docs/design.md "Motion noise identified from loop innovations"). Finite, >= 0.
  double offset_dof = 4.0;
  // a1..a4 from the joint likelihood of the heading innovations of up to this many inlier
  // pairs with heading (evenly spaced), whose covariance holds the covariance of every two
  // pairs' heading drifts over the steps of dead reckoning they share; 0 (or fewer than
  // min_pairs pairs with heading) keeps the fit that treats pairs as independent. The
  // pairs of one revisit, and of every revisit of one stretch, share most of their dead
  // reckoning, so that fit weighs one realisation of the drift as many independent ones,
  // and its a1..a4 follow that realisation from log to log. The joint fit reads the
  // heading rows only (exact: the heading is linear in the noise); a3 and a4, which only
  // the xy rows see, follow a1 and a2 through the shape prior. Cost: a dense Cholesky
  // factorisation of joint_pairs rows per evaluation. >= 0.
  int joint_pairs = 150;
  // Pairs whose NIS exceeds the chi-square quantile (2 or 3 dof) of this confidence at the
  // current estimate are rejected as aliases. In (0, 1).
  double outlier_confidence = 0.999;
  // Fewer pairs than this (after rejection) leave the noise unidentified. >= 1.
  int min_pairs = 20;
  // Fisher-scoring iterations per fit, and fits (rejection rounds). >= 1.
  int max_iterations = 60;
  int max_rounds = 8;
  // Throws omnicml::Error naming the first invalid field.
  void Validate() const;
};

// Index of each estimated parameter in MotionNoiseIdentification's per-parameter arrays.
enum class IdentifiedParameter { kA1 = 0, kA2, kA3, kA4, kAppearanceVariance, kHeadingVariance };
inline constexpr int kIdentifiedParameters = 6;

struct MotionNoiseIdentification {
  bool identified = false;  // false: too few pairs; the values below are then meaningless
  MotionNoise noise;
  double appearance_variance_m2 = 0.0;  // rho (the Student t fit's when offset_dof > 0)
  double heading_variance_rad2 = 0.0;   // rho_phi (prior centre when no pair has heading)
  int pairs = 0;                        // pairs given
  int pairs_used = 0;                   // after alias rejection
  int pairs_with_heading = 0;           // of those used, 3-dof pairs
  int joint_pairs_used = 0;             // pairs in the joint fit of a1..a4 (0: not run)
  // Of the pairs used, at the pairwise fit's estimate: the median of NIS / (the chi-square
  // median of its dof: 1.39 for 2, 2.37 for 3) and the mean of NIS / dof; both about 1
  // when consistent (the mean less after the rejection).
  double median_nis_ratio = 0.0;
  double mean_nis_per_dof = 0.0;
  // Posterior standard deviation of ln(parameter) (order: IdentifiedParameter), from the
  // curvature (Fisher information plus the prior's) at the estimate. It treats pairs as
  // independent; pairs of one revisit share their path, so it is optimistic.
  std::array<double, kIdentifiedParameters> log_sd{};
  // Share of each parameter's curvature that comes from the data: F_jj / (F_jj + P_jj)
  // (F the loops' Fisher information, P the prior's): near 1 the loops identified it, near
  // 0 the prior holds it.
  std::array<double, kIdentifiedParameters> data_share{};
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
// (first_session, first) comes before (second_session, second). heading_rad as in
// LoopPair (heading at the second frame minus at the first, map frame).
struct SessionLoopPair {
  int first_session = 0;
  int first = 0;
  int second_session = 0;
  int second = 0;
  std::optional<double> heading_rad;
};

// The covariance (x, y, phi) of the dead-reckoning error accumulated between poses s and t
// (s <= t) per unit noise parameter, for every pair: B[k][j] (3x3) for parameter a_{j+1}.
// `odometry` are the session's poses in the odometry frame; increments are computed
// between consecutive poses (ComputeIncrement). Throws omnicml::Error on a pair out of
// range or not ordered.
std::vector<std::array<Eigen::Matrix3d, 4>> LoopDriftBases(const std::vector<Pose2>& odometry,
                                                           const std::vector<LoopPair>& pairs);

// The MAP a1..a4, rho and rho_phi (file comment). Throws omnicml::Error on invalid options
// or pairs.
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
