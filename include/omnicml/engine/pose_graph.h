// The global pose graph (docs/design.md "Global pose graph"; beyond [G], as RTAB-Map and
// Cartographer do): the poses at which the map was updated, linked by odometry and by
// appearance loop closures, optimised with Ceres under a robust loss when a loop closes,
// so that the map (views hang from the node of the update that created them) is moved
// into one consistent frame instead of keeping the first lap's dead-reckoning drift.
//
// Nodes: one per map update the engine queues (CmlEngine::PushUpdate), in frame order,
// with the pose the update carries. Factors (residuals r, whitened by W with
// W^T W = Sigma^-1; angles wrapped):
//   odometry  between consecutive nodes a, b of one odometry segment (a session, or
//             sessions joined by kContinue): r = W (Between(x_a, x_b) - z_ab), z_ab =
//             Between(o_a, o_b) of the dead-reckoned poses o (the increments composed),
//             Sigma_ab = sum of the increments' covariances (IncrementCovariance, summed
//             without rotating them into a's frame: an approximation) plus floors.
//   prior     on nodes with a pose from outside the engine: survey frames (their trusted
//             pose) and the first frame of a kKnownPose session (its start pose):
//             r = W (x - mu).
//   closure   between the node c that created the best-matching view i and the current
//             anchor node t, when t - c >= min_loop_frames. kViewFrame (default): y_i is
//             the panorama taken at x_c, so a match says x_t is at x_c's place, turned by
//             the descriptors' relative heading: z_ct = (0, 0, RelativeHeading(y_t, y_i)),
//             Sigma = diag(s^2, s^2, s_phi^2), s = closure_sigma_m (0: the engine's
//             appearance_sigma_m, the spread of a match about the view's place), s_phi =
//             closure_sigma_rad; the engine adds the match's appearance offset
//             (CmlEngineOptions::appearance_offset_curve) to s^2. kViewComponent:
//             z_ct = Between(x_c, m) with m = (x_ij, y_ij, wrap(phi_ij +
//             RelativeHeading(y_t, y_i))) from the view's strongest component j, Sigma
//             with the component's largest xy variance and its heading variance added.
//             Under a Cauchy loss rho(s) = c^2 log(1 + s / c^2) of the squared whitened
//             residual, c = loss_scale, so that a false closure (aliasing) cannot pull
//             the map apart.
// Optimisation (Optimize): Levenberg-Marquardt over the newest window_nodes nodes (older
// nodes referenced by a factor are held constant); then closures whose squared whitened
// residual exceeds reject_chi2 are removed and the window is solved again without
// them (closure verification). Single-threaded, fixed options, so
// the result depends only on the inputs (deterministic; the engine calls it on its own
// thread while the map-update worker is idle). The gauge: the constant older nodes, the
// priors, else the window's first node is held constant.
//
// Thread-safety: thread-compatible (the engine's thread only).
#ifndef OMNICML_ENGINE_POSE_GRAPH_H_
#define OMNICML_ENGINE_POSE_GRAPH_H_

#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "omnicml/common/binary_io.h"
#include "omnicml/geometry/gaussian_mixture.h"
#include "omnicml/geometry/motion_model.h"
#include "omnicml/geometry/pose.h"

namespace omnicml {

struct PoseGraphOptions {
  // Keep and optimise the graph; false: the engine behaves exactly as without it. Off by
  // default: with equal odometry noise on every day the optimum lies between two days'
  // chains over one corridor, so a later day whose odometry drifted more bends the map
  // built before it (home_store seeds 1-10: better on 7, worse by 13-18 % on 3; AntWorld
  // with a biased second day 0.020 -> 0.159 m); docs/design.md "Global pose graph".
  bool enabled = false;
  // A match with a view created at least this many frames before the current frame is a
  // loop closure (nearer matches are the odometry's business). Frames, >= 1. It must be
  // shorter than the shortest loop, or the first lap's closure never enters the graph:
  // the earlier default 300 exceeded home_store's lap (285 frames) and institute's (180),
  // and the graph then bent the reconstructed first lap back towards raw odometry. A view
  // matches within decimetres of its place, i.e. for a few frames after its creation, so
  // 50 (10 m at the simulator's 0.2 m a frame) only excludes the current pass; 20, 50,
  // 100 and 200 give identical home_store runs (docs/results.md "Global pose graph
  // with the first lap's closure").
  int min_loop_frames = 50;
  // At most one closure factor per this many frames (a revisit matches at every frame).
  // Frames, >= 1.
  int closure_every_frames = 10;
  // The graph is optimised when a closure factor was added since the last optimisation
  // and at least this many frames have passed since it. Frames, >= 1.
  int optimize_every_frames = 50;
  // Nodes optimised: the newest window_nodes (older ones are constant). Bounds the cost of
  // one optimisation. Nodes, >= 2.
  int window_nodes = 3000;
  // What a closure measures. kViewFrame: the pose of the current frame relative to the
  // frame that created the matched view (the two panoramas were taken at one place), a
  // relative measurement whose noise is how far from a view's place it still matches.
  // kViewComponent: the pose the view's strongest component says the robot is at, with
  // the component's covariance added. That covariance is the absolute uncertainty of
  // the map at the view, which the graph already holds in its nodes, so the closure
  // counts it twice and is weaker than the match; and a component merged from later
  // passes is not the creator's pose. Measured in docs/results.md "Pose graph
  // closures relative to the view's frame".
  enum class ClosureModel : std::uint8_t { kViewFrame = 0, kViewComponent = 1 };
  ClosureModel closure_model = ClosureModel::kViewFrame;
  // Closure standard deviations. Position (metres, >= 0): kViewFrame, the whole standard
  // deviation of the current position about the creator's; 0 takes the engine's
  // appearance_sigma_m (as identified from the log or configured, and scaled with the
  // spatial thresholds), the same neighbourhood a fix gets in p(x|y). kViewComponent:
  // added to the component's variance (0: nothing added). Both models also add the
  // match's appearance offset, as p(x|y) does (CmlEngineOptions::appearance_offset_curve).
  // Heading (radians, > 0): the
  // relative heading's noise, plus the component's heading variance under
  // kViewComponent. Standard deviations below 1 mm are raised to 1 mm.
  double closure_sigma_m = 0.0;
  double closure_sigma_rad = 0.05;
  // Cauchy loss scale c on the squared whitened closure residual (dimensionless, in
  // standard deviations, > 0): residuals much beyond c count logarithmically (weight
  // 1 / (1 + s / c^2)). 3.368 = sqrt(11.34), the chi-square 99 % quantile of 3 dof, so a
  // closure inside the 99 % gate keeps at least half its weight. A scale of 1 halves
  // the weight of a closure one standard deviation off: from a map that the first lap's
  // drift turned, the closures that would turn it back then look like outliers and are
  // removed by reject_chi2 (docs/results.md "Pose graph closures relative to the view's
  // frame").
  double loss_scale = 3.368;
  // Levenberg-Marquardt iterations per optimisation, >= 1.
  int max_iterations = 10;
  // Closure verification: after the robust optimisation, a closure whose squared whitened
  // residual exceeds this is removed as inconsistent (aliasing) and the window solved
  // again. Dimensionless (chi-square, 3 degrees of freedom), > 0; 25 = 5 sigma.
  double reject_chi2 = 25.0;
  // Optimise the nodes of the latest odometry segment (the current session, or the
  // sessions joined to it by kContinue) only, holding every earlier node constant: a
  // session's closures correct its own poses and the views it made (its first lap's
  // drift), and tie it to the earlier map without moving that map. Two days' chains over
  // one corridor then never pull the older map towards the newer day's odometry, which
  // the graph cannot tell apart from the older day's when both carry the same modelled
  // noise (a biased odometry day bent AntWorld's day-1 map). false: every node in the
  // window is free. With it, the engine solves a session's closures that no
  // optimisation has solved yet when the next session begins (CmlEngine::BeginSession),
  // while that session's nodes are still free.
  bool hold_earlier_sessions = false;
  // What moves the tracker (and the anchor it reconstructs from) after an optimisation at
  // an appearance fix. kMatchedView: the correction of the node that created the view the
  // frame was fixed by (the best match). The tracker's estimate was fused from that
  // view's place, so it moves with it; where the view's node did not move, the tracker
  // stays. kNewestNode: the correction of the newest node, the fixed frame's own. That
  // node's optimised pose rests on one closure to the creator's place and the odometry
  // before it, not on the fused fix (prior and up to top_k views), so where a view still
  // matches a match length from its place it pulled the tracker off a good fix
  // (docs/results.md "The tracker follows the view it was fixed by").
  enum class TrackerFollows : std::uint8_t { kMatchedView = 0, kNewestNode = 1 };
  TrackerFollows tracker_follows = TrackerFollows::kMatchedView;
  // After each optimisation, the marginal covariance of every moved node that created a
  // view still in the map (Ceres' Covariance over the window, the robust loss applied)
  // goes with its correction, and the engine gives it to the components of the node's
  // views at the node's place: the graph's knowledge of where the creator was replaces
  // what the reconstruction left. One sparse QR of the window per optimisation and one
  // back-substitution per requested node.
  bool marginal_covariances = false;

  // Throws omnicml::Error naming the first invalid field ("PoseGraphOptions.<field>").
  void Validate() const;
};

template <class V>
void VisitFields(V& v, PoseGraphOptions& o) {
  v("enabled", o.enabled);
  v("min_loop_frames", o.min_loop_frames);
  v("closure_every_frames", o.closure_every_frames);
  v("optimize_every_frames", o.optimize_every_frames);
  v("window_nodes", o.window_nodes);
  v("closure_sigma_m", o.closure_sigma_m);
  v("closure_sigma_rad", o.closure_sigma_rad);
  v("loss_scale", o.loss_scale);
  v("max_iterations", o.max_iterations);
  v("reject_chi2", o.reject_chi2);
  // After engine file format 14 (engine_io.h): stored only when not the default.
  v.Since(15, [&](auto& w) {
    w("hold_earlier_sessions", o.hold_earlier_sessions);
    w.NamedEnum("closure_model", o.closure_model,
                {{PoseGraphOptions::ClosureModel::kViewFrame, "view_frame"},
                 {PoseGraphOptions::ClosureModel::kViewComponent, "view_component"}});
    w.NamedEnum("tracker_follows", o.tracker_follows,
                {{PoseGraphOptions::TrackerFollows::kMatchedView, "matched_view"},
                 {PoseGraphOptions::TrackerFollows::kNewestNode, "newest_node"}});
    w("marginal_covariances", o.marginal_covariances);
  });
}

// One node: the pose of a map update.
struct PoseGraphNode {
  std::int64_t frame = 0;      // engine frame index (increasing over the nodes)
  std::int64_t segment = -1;   // odometry segment; -1: no odometry known for the frame
  Pose2 pose = Pose2::Zero();  // current estimate (map frame)
  Pose2 odom = Pose2::Zero();  // dead-reckoned pose in the segment's frame
  Eigen::Matrix3d odom_cov = Eigen::Matrix3d::Zero();  // summed increment covariances
  std::optional<Gaussian> prior;  // survey pose or known session start (weight unused)
  bool operator==(const PoseGraphNode& o) const {
    return frame == o.frame && segment == o.segment && pose == o.pose && odom == o.odom &&
           odom_cov == o.odom_cov && prior.has_value() == o.prior.has_value() &&
           (!prior || (prior->mean == o.prior->mean && prior->covariance == o.prior->covariance));
  }
};

// A loop closure: Between(x_from, x_to) measured as z with covariance `covariance`.
struct PoseGraphClosure {
  std::int64_t from_frame = 0;  // node of the view's creator
  std::int64_t to_frame = 0;    // the current anchor's node
  Pose2 z = Pose2::Zero();
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
  bool operator==(const PoseGraphClosure&) const = default;
};

// A node moved by an optimisation: its pose before and after.
struct NodeCorrection {
  std::int64_t frame = 0;
  Pose2 before = Pose2::Zero();
  Pose2 after = Pose2::Zero();
  // Marginal covariance of `after` (map frame; m^2, rad^2) when
  // PoseGraphOptions::marginal_covariances and Ceres could compute it.
  std::optional<Eigen::Matrix3d> covariance;
};

// The correction of node `frame` in `corrections` (sorted by frame, as Optimize returns
// them); nullptr when that node did not move.
const NodeCorrection* FindCorrection(const std::vector<NodeCorrection>& corrections,
                                     std::int64_t frame);

// The correction the tracker follows after an optimisation at an appearance fix
// (PoseGraphOptions::tracker_follows): the newest node's (the last of `corrections`), or
// that of node `fixed_by` (the creator of the view the frame was fixed by). nullptr when
// `corrections` is empty or the followed node did not move (or there is none).
// `corrections` sorted by frame, as Optimize returns them.
const NodeCorrection* TrackerCorrection(const std::vector<NodeCorrection>& corrections,
                                        PoseGraphOptions::TrackerFollows follows,
                                        std::optional<std::int64_t> fixed_by);

class PoseGraph {
 public:
  // `motion` and the variance floors (m^2, rad^2) give the odometry factors'
  // covariances (IncrementCovariance). Odometry is kept for the newest
  // max_recent_frames frames that are not nodes yet (the longest a frame can wait to
  // reach the map: max_pending_multimodal_frames plus one).
  PoseGraph(const PoseGraphOptions& options, const MotionNoise& motion,
            double min_translation_variance_m2, double min_rotation_variance_rad2,
            std::size_t max_recent_frames);

  // Session start: kContinue sessions continue the odometry segment, others start a new
  // one. `known_start` (kKnownPose) becomes the prior of the node of `first_frame`
  // (the session's first frame) if that frame becomes a node.
  void BeginSession(bool continue_segment, std::int64_t first_frame,
                    const std::optional<Gaussian>& known_start);
  // The odometry increment u_t of frame t (every processed frame, in order).
  void AddFrameOdometry(std::int64_t frame, const OdometryIncrement& u);
  // A map update of `frame` at `pose` (frames increasing; a frame not after the last
  // node's is ignored). `prior`: a pose from outside the engine (survey).
  void AddNode(std::int64_t frame, const Pose2& pose, const std::optional<Gaussian>& prior);
  // A loop closure from the node of `view_created_frame` to the node of `frame` in the
  // kViewComponent form: the absolute pose m the view's component says the robot is at
  // and that component's covariance; z = Between(x_c, m) at the creator's current pose,
  // Sigma = diag(s^2 + largest xy variance, same, closure_sigma_rad^2 + heading
  // variance), s = closure_sigma_m. Returns false (nothing added) when either node is
  // missing, the frames are less than min_loop_frames apart, or the last closure is less
  // than closure_every_frames old.
  bool AddClosure(std::int64_t view_created_frame, std::int64_t frame, const Pose2& m,
                  const Eigen::Matrix3d& component_covariance);
  // A loop closure measured directly: Between(x_from, x_to) = z with `covariance`
  // (symmetric positive semi-definite; its diagonal raised to at least 1 mm^2 for x and y
  // and 1e-8 rad^2 for the heading). The conditions of AddClosure apply.
  bool AddRelativeClosure(std::int64_t from_frame, std::int64_t frame, const Pose2& z,
                          const Eigen::Matrix3d& covariance);
  // Whether Optimize should run at `frame` (a closure since the last optimisation, and
  // optimize_every_frames passed).
  bool ShouldOptimize(std::int64_t frame) const;
  // A closure was added since the last optimisation.
  bool HasUnoptimizedClosures() const { return closure_since_optimize_; }
  // Optimises the window (file comment) and returns the nodes whose pose changed. With
  // marginal_covariances, `marginal_frames` (ascending) names the nodes whose marginal is
  // wanted (the engine's: the frames that created a view still in the map); the cost of
  // the covariance grows with their number. nullptr: every free node of the window.
  std::vector<NodeCorrection> Optimize(std::int64_t frame,
                                       const std::vector<std::int64_t>* marginal_frames = nullptr);

  // The node of `frame`, or null.
  const PoseGraphNode* FindNode(std::int64_t frame) const;
  const std::vector<PoseGraphNode>& nodes() const { return nodes_; }
  const std::vector<PoseGraphClosure>& closures() const { return closures_; }
  std::int64_t optimizations() const { return optimizations_; }
  std::int64_t rejected_closures() const { return rejected_closures_; }

  // Persistence (engine_io.cc): every field but the options.
  void Write(BinaryWriter& out) const;
  void Read(BinaryReader& in);
  bool operator==(const PoseGraph& o) const;

 private:
  struct FrameOdometry {
    std::int64_t frame = 0;
    std::int64_t segment = 0;
    Pose2 odom = Pose2::Zero();
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  };
  std::size_t IndexOf(std::int64_t frame) const;  // nodes_.size() if absent

  PoseGraphOptions options_;
  MotionNoise motion_;
  double min_translation_variance_m2_;
  double min_rotation_variance_rad2_;

  std::vector<PoseGraphNode> nodes_;
  std::vector<PoseGraphClosure> closures_;
  std::deque<FrameOdometry> recent_;  // frames not yet nodes (since the last node)
  std::size_t max_recent_frames_;
  std::int64_t segment_ = -1;   // current odometry segment
  bool new_segment_ = true;     // the next frame starts a segment
  Pose2 odom_ = Pose2::Zero();  // dead-reckoned pose of the last frame (segment frame)
  Eigen::Matrix3d odom_cov_ = Eigen::Matrix3d::Zero();  // summed increment covariances
  std::int64_t start_prior_frame_ = -1;
  std::optional<Gaussian> start_prior_;
  std::int64_t last_closure_frame_ = INT64_MIN / 2;
  std::int64_t last_optimized_frame_ = INT64_MIN / 2;
  bool closure_since_optimize_ = false;
  std::int64_t optimizations_ = 0;
  std::int64_t rejected_closures_ = 0;
};

}  // namespace omnicml

#endif  // OMNICML_ENGINE_POSE_GRAPH_H_
