// The environment model's event log: every change of the map (a view inserted or
// removed, a component added, merged or removed) as a MapEvent, kept in a bounded ring of
// the most recent events, with exact per-session counts however many the ring dropped.
//
// Plain value; thread-compatible.
#ifndef OMNICML_MAPPING_MAP_EVENTS_H_
#define OMNICML_MAPPING_MAP_EVENTS_H_

#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <string>

#include "omnicml/geometry/pose.h"

namespace omnicml {

enum class MapEventType : std::uint8_t {
  kViewInserted = 0,
  kViewRemoved = 1,
  kComponentAdded = 2,   // only with options.events.log_component_events
  kComponentMerged = 3,  // only with options.events.log_component_events
  kComponentRemoved = 4,
};
// "view_inserted", "view_removed", "component_added", "component_merged", "component_removed".
std::string ToString(MapEventType type);
// MapEvent::reason of a component removed after active forgetting (18)-(19) lowered it.
inline constexpr const char* kActiveForgettingReason = "active forgetting (18)-(19)";
// ... of a view removed whole because its persistence belief fell below
// forgetting.persistence_min_probability (view_persistence.h).
inline constexpr const char* kPersistenceReason = "view persistence";
// Whether a removal `reason` is one of active forgetting's (either of the two above).
inline bool IsActiveForgettingReason(const std::string& reason) {
  return reason == kActiveForgettingReason || reason == kPersistenceReason;
}

// One change of the map, so a user can tell a changed place (components forgotten at a
// place, then a new view inserted there) from a newly visited one (insertion only).
struct MapEvent {
  MapEventType type = MapEventType::kViewInserted;
  std::int64_t frame = 0;  // UpdateContext of the Update that caused it
  int session = 0;
  std::uint64_t view_id = 0;
  std::uint64_t component_id = 0;  // 0 for view events
  // Where: for view insertion mu_t; for component events the component's mean (phi in
  // view orientation); for view removal the mean of its last component.
  Pose2 position = Pose2::Zero();
  // Weight of the component when removed/merged/added; view total weight otherwise.
  double weight = 0.0;
  // "no view within e_max" (inserted by Update), "added" (AddView), "passive forgetting
  // (17)", "active forgetting (18)-(19)" (the rule that last lowered the removed
  // component's weight), "weight below w_min" (raised by (16) but still below w_min),
  // "view empty", "observation" or "look-back" (component added), "merge (12)-(14)".
  std::string reason;

  bool operator==(const MapEvent&) const = default;
};

// How many events of each type one session (UpdateContext::session) logged, counted as
// they happen: exact however many events the ring (max_events) has dropped.
struct MapEventCounts {
  std::int64_t views_inserted = 0;
  std::int64_t views_removed = 0;
  std::int64_t components_added = 0;   // only with options.events.log_component_events
  std::int64_t components_merged = 0;  // only with options.events.log_component_events
  std::int64_t components_removed = 0;

  bool operator==(const MapEventCounts&) const = default;
};

class MapEventLog {
 public:
  // Keeps at most max_events events (>= 0).
  explicit MapEventLog(int max_events = 0) : max_events_(max_events) {}

  // Counts e for its session, appends it and drops the oldest events beyond max_events.
  void Log(MapEvent e);
  // The most recent events, oldest first. Event number n (0-based, counted since the
  // log began) is events()[n - first_event_number()] while
  // first_event_number() <= n < events_logged().
  const std::deque<MapEvent>& events() const { return events_; }
  std::uint64_t events_logged() const { return events_logged_; }
  std::uint64_t first_event_number() const { return events_logged_ - events_.size(); }
  // Per session (sessions without events are absent), exact.
  const std::map<int, MapEventCounts>& counts() const { return counts_; }
  // Empties the ring; events_logged() and counts() go on.
  void Clear() { events_.clear(); }

  // Restoring a saved log (environment_model_io.cc): the number logged, the counts and
  // the ring as stored, then trimmed to max_events (the most recent are kept).
  void Restore(std::uint64_t events_logged, std::map<int, MapEventCounts> counts,
               std::deque<MapEvent> events);
  std::size_t MemoryBytes() const;

 private:
  int max_events_ = 0;
  std::deque<MapEvent> events_;  // ring of the most recent events
  std::uint64_t events_logged_ = 0;
  std::map<int, MapEventCounts> counts_;
};

}  // namespace omnicml

#endif  // OMNICML_MAPPING_MAP_EVENTS_H_
