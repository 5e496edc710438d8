#include "omnicml/mapping/map_events.h"

#include <utility>

namespace omnicml {

std::string ToString(MapEventType type) {
  switch (type) {
    case MapEventType::kViewInserted:
      return "view_inserted";
    case MapEventType::kViewRemoved:
      return "view_removed";
    case MapEventType::kComponentAdded:
      return "component_added";
    case MapEventType::kComponentMerged:
      return "component_merged";
    case MapEventType::kComponentRemoved:
      return "component_removed";
  }
  return "unknown";
}

void MapEventLog::Log(MapEvent e) {
  MapEventCounts& n = counts_[e.session];
  switch (e.type) {
    case MapEventType::kViewInserted:
      ++n.views_inserted;
      break;
    case MapEventType::kViewRemoved:
      ++n.views_removed;
      break;
    case MapEventType::kComponentAdded:
      ++n.components_added;
      break;
    case MapEventType::kComponentMerged:
      ++n.components_merged;
      break;
    case MapEventType::kComponentRemoved:
      ++n.components_removed;
      break;
  }
  ++events_logged_;
  events_.push_back(std::move(e));
  while (events_.size() > static_cast<std::size_t>(max_events_)) events_.pop_front();
}

void MapEventLog::Restore(std::uint64_t events_logged, std::map<int, MapEventCounts> counts,
                          std::deque<MapEvent> events) {
  events_logged_ = events_logged;
  counts_ = std::move(counts);
  events_ = std::move(events);
  while (events_.size() > static_cast<std::size_t>(max_events_)) events_.pop_front();
}

std::size_t MapEventLog::MemoryBytes() const {
  std::size_t bytes = events_.size() * sizeof(MapEvent);
  bytes += counts_.size() * (sizeof(int) + sizeof(MapEventCounts) + 4 * sizeof(void*));
  for (const MapEvent& e : events_) bytes += e.reason.capacity() > 15 ? e.reason.capacity() : 0;
  return bytes;
}

}  // namespace omnicml
