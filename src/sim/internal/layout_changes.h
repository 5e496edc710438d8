// The parse-time half of the layout change model (world.h LayoutChanges): the
// promotional-display spots a world with layout_intensity > 0 gets.
#ifndef OMNICML_SIM_INTERNAL_LAYOUT_CHANGES_H_
#define OMNICML_SIM_INTERNAL_LAYOUT_CHANGES_H_

#include "omnicml/sim/world.h"

namespace omnicml::internal {

// Appends world->changes.display_spots (0: one per 10 m of route) promotional-display
// spots as boxes named changes_display_<k> that are not initially present: free floor
// places 1 to 3 m beside the route, route_clearance_m + 0.2 m off the robot's path and
// 0.3 m clear of every obstacle and of each other, placed from changes.seed. Nothing for
// layout_intensity 0 (the world stays as parsed). Fewer spots when the floor has no room.
void AddDisplaySpots(World* world);

}  // namespace omnicml::internal

#endif  // OMNICML_SIM_INTERNAL_LAYOUT_CHANGES_H_
