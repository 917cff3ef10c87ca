// What the URDF import checks before it trusts a URDF (urdf_import.cpp): the XML's nesting before
// urdfdom parses it (urdfdom's XML parser, TinyXML 2.6, recurses once per nested element and
// overflows the stack some thousands deep), the joint graph urdfdom built (urdfdom accepts
// cycles and links with two parents; the import's walks would then never end), and every number
// the import reads (urdfdom accepts negative masses, indefinite inertias, zero radii and values
// whose compositions overflow).
#pragma once

#include <cstddef>
#include <string>

#include <urdf_model/model.h>

namespace terrastride::robot::urdf_checks {

// Refusal by what is wrong; urdf_import.cpp adds the file's name.
class Refusal : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The deepest element nesting of `xml` and the line where it is first reached, by TinyXML's
// lexical rules (comments, CDATA, <! and <? constructs to the first '>', quoted attribute
// values); the scan stops once `limit` is exceeded. Over-counting is possible on malformed text
// (which urdfdom refuses anyway), under-counting is not meant to be.
struct XmlNesting {
  int depth = 0;
  std::size_t line = 1;
};
XmlNesting xml_nesting(const std::string& xml, int limit);

// Refuses, naming it, a cycle of joints as the text has them (the root <robot>'s <joint>s, their
// first <parent> and <child> link, names as written, read by xml_nesting's rules): urdfdom
// builds its tree out of shared pointers, so a cycle leaks whenever it refuses the file (a cycle
// through the root link: "No root link found", naming nothing) or the import does. Anything else
// is left to urdfdom and check_tree.
void check_joint_cycles(const std::string& xml);

// The joint graph is a tree within the limits: no joint connects a link to itself, no link is
// the child of two joints, every link is reached from the root (a link off it lies on a cycle or
// hangs from one), at most `max_links` links and `max_joints` joints. Throws Refusal naming them.
void check_tree(const urdf::ModelInterface& model, std::size_t max_links, std::size_t max_joints);

// Every link's inertial (finite origin, mass >= 0, a finite positive semi-definite inertia) and
// collision primitives (finite origin, sphere/cylinder/box sizes > 0), every joint's origin,
// axis and limits finite, all within magnitudes that keep the import's compositions finite.
// Throws Refusal naming the link or joint and the field.
void check_numbers(const urdf::ModelInterface& model);

}  // namespace terrastride::robot::urdf_checks
