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
  size_t seen_beneath = 0;      // of those, dropped: above another run, with free space right below
};

// The support surfaces of an occupancy tree as a cloud: per (x, y) column of voxels, one point at
// the centre of the top voxel of every vertical run of occupied voxels (the surface a foot stands
// on; the run's lower voxels are its side), except runs above another run with a known-free voxel
// directly beneath them: the sensor saw under those (a ceiling, a table top, an overhang) and the
// lower run is the support, as the height grid's overhang rule judges rays from beneath. (The
// lowest run of a column is always kept: free space right under it is a grazing ray under a
// surface that lies on a voxel boundary, or a ceiling over unseen ground, a conservatively high
// surface.) Unknown space stays unknown: columns without occupied
// voxels give no point. The cloud has no sensor origin (the tree keeps no rays). Throws InputError
// when the tree holds no occupied voxel, or more than `max_voxels` once its coarse occupied
// leaves are expanded.
PointCloud octree_support_cloud(const octomap::OcTree& tree, const std::string& source,
                                OctreeSupportStats* stats = nullptr,
                                size_t max_voxels = 200'000'000);

}  // namespace terrastride::perception
