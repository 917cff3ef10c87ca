// A ROS 1 bag walked before librosbag_storage reads it (ros1_check.cpp says what is checked):
// librosbag trusts the lengths in the file, and a corrupt length aborted the process or read past
// a buffer. Runs in the core library, so the bag fuzz target covers it without librosbag.
#pragma once

#include <string>

namespace terrastride::perception::bag {

// Throws InputError naming the file and the byte of the first problem.
void check_ros1_bag(const std::string& path);

}  // namespace terrastride::perception::bag
