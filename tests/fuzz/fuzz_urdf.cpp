// libFuzzer target for the URDF import (`terrastride robot import`, robot/urdf_import.hpp): the
// input bytes are the URDF's text. Every failure must be a UrdfImportError (the XML nesting
// pre-scan, urdfdom's parse, the tree and number checks, the leg-chain analysis); an import that
// succeeds must have written a robot file the robot-file reader loads. Seeds: tests/fuzz/
// corpus_urdf (a small quadruped, deep nesting, joint cycles, bad masses, inertias and radii);
// the regular suite replays them (UrdfImport.FuzzCorpusReplay).
#include <cstddef>
#include <cstdint>
#include <string>

#include "terrastride/robot/robot_model.hpp"
#include "terrastride/robot/urdf_import.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  namespace r = terrastride::robot;
  const std::string xml(reinterpret_cast<const char*>(data), size);
  r::UrdfImportOptions options;
  options.name = "fuzz";
  try {
    const r::UrdfImport imported = r::import_urdf_text(xml, "fuzz.urdf", options);
    // import_urdf_text reads its output back itself; a second read must agree.
    (void)r::parse_robot(imported.yaml, "fuzz import");
  } catch (const r::UrdfImportError&) {
  }
  return 0;
}
