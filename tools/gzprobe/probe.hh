// What the probe's source files share (common.cc, physics.cc, gzprobe.cc).
#ifndef GZPROBE_PROBE_HH_
#define GZPROBE_PROBE_HH_

#include <chrono>
#include <string>

#include <ignition/math/Pose3.hh>
#include <sdf/SemanticPose.hh>
#include <sdf/World.hh>

namespace gzprobe
{
std::string Quote(const std::string &s);
std::string Num(double v);
double Seconds(std::chrono::steady_clock::time_point since);
// CPU seconds this process has spent: on a shared machine, what a figure costs apart
// from the wait for a core.
double CpuSeconds();
// A pose resolved through the frame graph (relative_to, frames), as gz-sim's
// ResolveSdfPose does; the raw pose where it cannot be resolved.
ignition::math::Pose3d Resolved(const sdf::SemanticPose &semantic, const std::string &to,
                                const ignition::math::Pose3d &raw);
// model://name/rest -> the file under the first SDF_PATH folder that holds it; a
// relative path -> beside the SDF file that names it.
std::string ResolveUri(const std::string &uri, const std::string &sdfFile);

// The world built in dartsim as gz-sim's Physics system builds it, stepped for
// `seconds` at 1 ms: a JSON object.
std::string Physics(const sdf::World &world, double seconds);
// Every JointPositionController of the world: its joint and topic, and in dartsim
// what setting that joint's position moves: a JSON array.
std::string Joints(const sdf::World &world);
}  // namespace gzprobe

#endif
