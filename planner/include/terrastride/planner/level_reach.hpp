// Reach from where the robot stands, checked before anything is solved: a fresh plan's goal (and
// every foot of its start) must lie on ground the robot could walk to from the start's level, not
// on a ceiling, a table top seen from above or the top of a 2 m cupboard.
//
// The criterion: the terrain's cells are joined to their eight neighbours when the two heights
// differ by at most the robot's leg length (the longest hip-to-foot reach, HAA -> HFE -> KFE ->
// foot, fully stretched; HyQ 0.771 m, Go2 0.43 m): no gait puts a foot on a surface higher than
// that above the surface its other feet stand on, since every stance foot hangs below its hip
// within the range-of-motion box and the hips are one rigid trunk. Where the neighbour is not such
// a cell (a trench, a hole, an obstacle no higher than a leg length above the foot that steps),
// the step may reach over it to the first cell within a leg length in the same direction, up to a
// leg length away (a foot swings over a gap or a low obstacle, not over a wall). Cells with no
// walkable ground (only an overhang seen there: grid.overhead finite and no support) are not
// ground to step on. A goal foot outside the start feet's connected ground is refused. This is a
// necessary condition, generous on purpose: it never refuses a step a plan could make (every
// shipped scene, pallet_NN to 60 cm included, keeps its plans), while a surface 2 m above the
// floor is out of reach.
#pragma once

#include <Eigen/Core>

#include "terrastride/robot/robot_model.hpp"
#include "terrastride/terrain/height_field.hpp"

namespace terrastride::planner {

// The longest hip-to-foot distance of the robot's legs (the sum of each leg's joint offsets).
double leg_reach(const robot::RobotModel& robot);

// Checks that the nominal feet at `start` (x, y, yaw) stand on one connected level and that the
// nominal feet at `goal` stand on that level too, by the rule above. A foot outside the terrain's
// extent is left to the other checks. Throws RequestError("start" or "goal", ...) naming the foot,
// its position and height, and the start's ground height. A TerrainMap is judged on its own cells;
// another field (an analytic scene) is sampled on a 2 cm grid over its extent (coarser when that
// would exceed 4 M cells).
void check_level_reach(const terrain::HeightField& terrain, const robot::RobotModel& robot,
                       const Eigen::Vector3d& start, const Eigen::Vector3d& goal);

}  // namespace terrastride::planner
