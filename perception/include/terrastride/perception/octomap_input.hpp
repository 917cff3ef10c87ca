// OctoMap files as input (`terrastride map X.bt|X.ot`, `--terrain X.bt`): a mapping stack's
// occupancy tree read with OctoMap's own readers, and the support surfaces a height grid is built
// from, taken from its occupied voxels.
#pragma once

#include <octomap/OcTree.h>

#include <memory>
#include <string>

#include "terrastride/perception/point_cloud.hpp"

namespace terrastride::perception {

// True for the extensions of OctoMap files: .bt (binary, occupancy bits) and .ot (full tree),
// case-insensitive.
bool is_octomap_file(const std::string& path);

// Reads an OctoMap file as an occupancy OcTree. .bt: OctoMap's binary format, whose bit stream is
// the same for every occupancy tree type, so a .bt written by a ColorOcTree or OcTreeStamped (as
// octomap_server writes them) reads as an OcTree. .ot: the full format; OcTree, ColorOcTree and
// OcTreeStamped are read (the latter two as their occupancy bits, what a .bt of them holds). Any other tree type (a
// CountingOcTree, an unknown id) is an InputError naming the type; so are a missing file, a
// header that is not OctoMap's, a truncated body and an empty tree.
//
// OctoMap's readers trust the file (corrupt node bits recurse until the stack overflows), so the
// body is walked first: node bits within the tree's 16 levels, the body ending where the tree
// does, as many nodes as the header's size, at most 2^25 nodes; any other body is an InputError
// naming the file and the byte.
std::unique_ptr<octomap::OcTree> read_octomap_file(const std::string& path);

// read_octomap_file on bytes already in memory: `binary` for the .bt format, else .ot; `path`
// names them in errors.
std::unique_ptr<octomap::OcTree> read_octomap_bytes(const std::string& path,
                                                    const std::string& bytes, bool binary);

struct OctreeSupportStats {
  size_t occupied_voxels = 0;   // occupied leaves expanded to voxels of the tree's resolution
  size_t columns = 0;           // distinct (x, y) voxel columns with an occupied voxel
  size_t runs = 0;              // vertical runs of occupied voxels
  size_t seen_beneath = 0;      // of those, with a known-free voxel right beneath
  size_t overhangs = 0;         // of those, with the overhang free height beneath: not support
  size_t overhang_only_columns = 0;  // columns whose every run is an overhang (no ground seen)
  size_t unseen_tops = 0;       // runs seen neither from above nor from beneath: no point
  size_t free_leaves = 0;       // free leaves of the tree (none: a tree without rays)
};

// The support surfaces of an occupancy tree as a cloud: per (x, y) column of voxels, one point at
// the centre of the top voxel of every vertical run of occupied voxels (the surface a foot stands
// on; the run's lower voxels are its side), except overhangs: runs with known-free voxels beneath
// them adding up to at least `overhang_free_height` (between the run and the run below, or within
// 5 m below the lowest run; unknown voxels between them do not count either way; coarse free
// leaves count voxel by voxel), and every run above such a run in its column (a ceiling over a duct seen from beneath, a
// lamp over a table). The sensor saw under those (a ceiling, a table top, a shelf): they are not
// ground, and go into the cloud's `overhangs` as their underside (the bottom face of the run's
// lowest voxel).
// A column whose runs are all overhangs (a ceiling over a floor never scanned) gives no support
// point. Nor does a run with no free voxel within the overhang free height above its top and
// below its bottom, in a tree that holds free leaves: no ray saw its top (the edge of a ceiling
// lit from the side); a ground surface is seen from above. A run with less free space beneath (a pallet deck, a grazing ray under a surface on a
// voxel boundary) or unknown space beneath (a floor, a table top never seen from below) is support.
// Unknown space stays unknown: columns without occupied voxels give no point. The cloud has no
// sensor origin (the tree keeps no rays). Throws InputError when the tree holds no occupied voxel,
// more than `max_voxels` once its coarse occupied leaves are expanded, or no support point.
PointCloud octree_support_cloud(const octomap::OcTree& tree, const std::string& source,
                                OctreeSupportStats* stats = nullptr,
                                size_t max_voxels = 200'000'000,
                                double overhang_free_height = kOverhangFreeHeight);

}  // namespace terrastride::perception
