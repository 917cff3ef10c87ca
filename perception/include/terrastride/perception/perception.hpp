// Umbrella header of the perception module.
#pragma once

#include "terrastride/perception/atomic_output.hpp"
#include "terrastride/perception/cloud_io.hpp"
#include "terrastride/perception/filters.hpp"
#include "terrastride/perception/npy.hpp"
#include "terrastride/perception/octomap_fusion.hpp"
#include "terrastride/perception/point_cloud.hpp"
