// CmlEngine::ProcessSurveyFrame: survey mapping from trusted poses (docs/design.md
// "Survey mapping"). Kept apart from cml_engine.cc so that the CML pipeline and the
// survey path can change independently.
#include <chrono>
#include <utility>

#include "omnicml/common/common.h"
#include "omnicml/engine/cml_engine.h"

namespace omnicml {

FrameResult CmlEngine::ProcessSurveyFrame(const Frame& frame, const Gaussian& trusted) {
  const auto t_start = std::chrono::steady_clock::now();
  if (!session_.in_session) throw Error("CmlEngine::ProcessSurveyFrame called before BeginSession");
  const auto where = [&] {
    return StrCat("frame ", frame.global_index, " (session ", frame.session_index, ", index ",
                  frame.index_in_session, ")");
  };
  if (!frame.odom_T_robot.allFinite()) throw Error(StrCat(where(), ": odometry is not finite"));
  if (!trusted.mean.allFinite())
    throw Error(StrCat(where(), ": trusted survey pose is not finite"));
  Gaussian state;
  state.mean = MakePose(trusted.mean.x(), trusted.mean.y(), trusted.mean.z());
  state.covariance =
      RepairCovariance(trusted.covariance, options_.tracker.min_covariance_eigenvalue,
                       StrCat(where(), ": trusted survey covariance"));
  state.weight = 1.0;

  const std::int64_t t = next_frame_;
  FrameResult result;
  result.frame = t;
  result.session = session_.session;
  // The same barrier discipline as ProcessFrame: updates due at t run while we describe.
  const Descriptor y = DescribeBehindBarrier(frame, t, &result.stats);
  result.stats.num_views = model_->NumViews();
  result.stats.num_map_components = model_->NumComponents();

  current_increment_ = session_.has_prev_odom
                           ? ComputeIncrement(session_.prev_odom, frame.odom_T_robot)
                           : OdometryIncrement{};
  if (options_.pose_graph.enabled) pose_graph_->AddFrameOdometry(t, current_increment_);
  // p(x_t) := N(trusted): the trusted pose replaces whatever the tracker believed.
  tracker_.Reset(state);
  session_.awaiting_global_seed = false;
  Estimate estimate;
  estimate.strongest = state;
  estimate.mean = state;
  estimate.unimodal = true;
  estimate.num_components = 1;
  result.estimate = estimate;
  result.stats.mixture_components = 1;
  counters_.unimodal_frames += 1;
  // A trusted pose is the most confident anchor there is: frames pending since the last
  // anchor are reconstructed up to it, then y_t is queued at the trusted pose.
  survey_prior_ = std::make_pair(t, state);  // the node of t gets the trusted pose as prior
  QueueUnimodal(t, y, estimate, &result);
  survey_prior_.reset();
  EndFrame(frame, t_start, &result);
  return result;
}

}  // namespace omnicml
