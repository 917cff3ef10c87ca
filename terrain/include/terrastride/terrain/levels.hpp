// Ground levels: which surfaces of a height grid a legged robot could walk onto from the floor
// (docs/design.md §5.4). Cells are joined when a leg can step from one to the other: an
// 8-neighbour whose height differs by at most `reach` (the leg length), or, where that neighbour is
// no such cell (a trench, a hole, an obstacle no higher than `reach` above the stepping foot, a cell
// without walkable ground), the first such cell farther on in the same direction within `reach`
// (a foot swings over a gap or a low obstacle, not over a wall). Cells without walkable ground
// (only an overhang seen: no support, finite overhead) are never stepped on.
#pragma once

#include <cstdint>
#include <vector>

#include "terrastride/terrain/height_grid.hpp"

namespace terrastride::terrain {

// The heights to walk over and whether each cell has ground to stand on.
struct LevelInput {
  GridGeometry geometry;
  std::vector<float> height;
  std::vector<uint8_t> ground;  // 0: no walkable ground (only an overhang was seen there)
};

// A grid's cells as LevelInput: its elevation (hole-filled cells at their filled height) and
// ground everywhere but at overhang-only cells.
LevelInput level_input(const HeightGrid& grid);

// The cells reachable from cell `from` by the steps above, walked from it (breadth first).
std::vector<uint8_t> reachable_cells(const LevelInput& in, int from, double reach);

// The grid's levels: cells joined by a step in either direction share a level. The floor level is
// the one holding the most observed cells (a map is recorded by a sensor moved over its floor);
// observed cells on any other level are unreachable: a cupboard top, a partition's crest, a
// surface seen above a ceiling, no step of at most `reach` joins them to the floor.
struct GroundLevels {
  std::vector<int32_t> level;  // per cell, its level (-1: no walkable ground)
  int32_t floor = -1;          // the floor level (-1: nothing observed)
  std::vector<uint8_t> unreachable;  // per cell: observed, not on the floor level
  size_t unreachable_cells = 0;
  size_t unreachable_levels = 0;  // levels other than the floor's holding observed cells
};
GroundLevels ground_levels(const HeightGrid& grid, double reach);

}  // namespace terrastride::terrain
