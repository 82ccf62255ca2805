// The probe's physics: the world in dartsim (gz-physics 5) as gz-sim Fortress's
// Physics system builds it, stepped (Physics), and what its joint position controllers
// move (Joints).
#include "probe.hh"

#include <cmath>
#include <set>
#include <sstream>
#include <vector>

#include <ignition/common/MeshManager.hh>
#include <ignition/math/eigen3/Conversions.hh>
#include <ignition/physics/FeatureList.hh>
#include <ignition/physics/ForwardStep.hh>
#include <ignition/physics/FrameSemantics.hh>
#include <ignition/physics/GetEntities.hh>
#include <ignition/physics/Joint.hh>
#include <ignition/physics/RequestEngine.hh>
#include <ignition/physics/World.hh>
#include <ignition/physics/mesh/MeshShape.hh>
#include <ignition/physics/sdf/ConstructCollision.hh>
#include <ignition/physics/sdf/ConstructJoint.hh>
#include <ignition/physics/sdf/ConstructLink.hh>
#include <ignition/physics/sdf/ConstructModel.hh>
#include <ignition/physics/sdf/ConstructWorld.hh>
#include <ignition/plugin/Loader.hh>
#include <sdf/Collision.hh>
#include <sdf/Geometry.hh>
#include <sdf/Joint.hh>
#include <sdf/JointAxis.hh>
#include <sdf/Link.hh>
#include <sdf/Mesh.hh>
#include <sdf/Model.hh>
#include <sdf/Physics.hh>

namespace gzprobe
{
namespace
{

// What building a world from its SDF takes, as gz-sim's Physics system builds it.
using BuildFeatures = ignition::physics::FeatureList<
    ignition::physics::sdf::ConstructSdfWorld,
    ignition::physics::sdf::ConstructSdfModel,
    ignition::physics::sdf::ConstructSdfLink,
    ignition::physics::sdf::ConstructSdfCollision,
    ignition::physics::sdf::ConstructSdfJoint,
    ignition::physics::mesh::AttachMeshShapeFeature,
    ignition::physics::GetModelFromWorld,
    ignition::physics::GetJointFromModel>;

using PhysicsFeatures = ignition::physics::FeatureList<
    BuildFeatures,
    ignition::physics::CollisionDetector,
    ignition::physics::ForwardStep,
    ignition::physics::SetJointVelocityCommandFeature>;

// The world's JointPositionControllers that drive their joint by velocity commands
// (<use_velocity_commands>), as (model, joint) names.
std::vector<std::pair<std::string, std::string>> VelocityControlled(const sdf::World &world)
{
  std::vector<std::pair<std::string, std::string>> out;
  for (uint64_t m = 0; m < world.ModelCount(); ++m)
  {
    const sdf::Model *model = world.ModelByIndex(m);
    if (!model->Element() || !model->Element()->HasElement("plugin")) continue;
    for (auto el = model->Element()->GetElement("plugin"); el; el = el->GetNextElement("plugin"))
      if (el->Get<std::string>("name").find("JointPositionController") != std::string::npos &&
          el->HasElement("use_velocity_commands") && el->Get<bool>("use_velocity_commands") &&
          el->HasElement("joint_name"))
        out.emplace_back(model->Name(), el->Get<std::string>("joint_name"));
  }
  return out;
}

// <physics><dart><collision_detector>, which gz-sim hands to SetCollisionDetector when
// the world names one (SdfEntityCreator reads it; Physics applies it).
std::string NamedCollisionDetector(const sdf::World &world)
{
  const sdf::Physics *physics = world.PhysicsDefault();
  if (!physics || !physics->Element() || !physics->Element()->HasElement("dart")) return "";
  sdf::ElementPtr dart = physics->Element()->GetElement("dart");
  if (!dart->HasElement("collision_detector")) return "";
  return dart->Get<std::string>("collision_detector");
}

std::string DartsimPluginPath()
{
  const char *env = std::getenv("GZPROBE_DARTSIM");
  if (env) return env;
  return "/usr/lib/x86_64-linux-gnu/ign-physics-5/engine-plugins/libignition-physics5-dartsim-plugin.so";
}

struct Counts
{
  int meshShapes = 0, primitiveShapes = 0, failedShapes = 0, joints = 0, failedJoints = 0;
};

sdf::World EmptyWorld(const sdf::World &world)
{
  sdf::World empty;
  empty.SetName(world.Name());
  empty.SetGravity(world.Gravity());
  return empty;
}

// The world's models, links, their collisions (when asked) and joints, in the order
// gz-sim's Physics system makes them (an empty world, models, links, then each
// collision: meshes through AttachMeshShape, other shapes through ConstructSdfCollision;
// then the joints).
template <typename WorldPtr>
Counts Build(WorldPtr &physicsWorld, const sdf::World &world, bool collisions)
{
  Counts counts;
  for (uint64_t m = 0; m < world.ModelCount(); ++m)
  {
    const sdf::Model *source = world.ModelByIndex(m);
    sdf::Model model;
    model.SetName(source->Name());
    model.SetRawPose(source->RawPose());
    model.SetStatic(source->Static());
    model.SetSelfCollide(source->SelfCollide());
    auto physicsModel = physicsWorld->ConstructModel(model);
    for (uint64_t l = 0; l < source->LinkCount(); ++l)
    {
      const sdf::Link *sourceLink = source->LinkByIndex(l);
      sdf::Link link;
      link.SetName(sourceLink->Name());
      link.SetRawPose(Resolved(sourceLink->SemanticPose(), "__model__", sourceLink->RawPose()));
      link.SetInertial(sourceLink->Inertial());
      auto physicsLink = physicsModel->ConstructLink(link);
      for (uint64_t c = 0; collisions && c < sourceLink->CollisionCount(); ++c)
      {
        const sdf::Collision *collision = sourceLink->CollisionByIndex(c);
        const sdf::Geometry *geom = collision->Geom();
        if (geom && geom->Type() == sdf::GeometryType::MESH && geom->MeshShape())
        {
          const sdf::Mesh *meshSdf = geom->MeshShape();
          const auto *mesh = ignition::common::MeshManager::Instance()->Load(
              ResolveUri(meshSdf->Uri(), meshSdf->FilePath()));
          if (!mesh) { ++counts.failedShapes; continue; }
          const auto pose = Resolved(collision->SemanticPose(), sourceLink->Name(), collision->RawPose());
          physicsLink->AttachMeshShape(collision->Name(), *mesh, ignition::math::eigen3::convert(pose),
                                       ignition::math::eigen3::convert(meshSdf->Scale()));
          ++counts.meshShapes;
        }
        else
        {
          // gz-sim hands dartsim a collision whose pose it resolved into the link frame
          sdf::Collision resolved = *collision;
          resolved.SetRawPose(Resolved(collision->SemanticPose(), sourceLink->Name(), collision->RawPose()));
          resolved.SetPoseRelativeTo("");
          if (physicsLink->ConstructCollision(resolved)) ++counts.primitiveShapes; else ++counts.failedShapes;
        }
      }
    }
    for (uint64_t j = 0; j < source->JointCount(); ++j)
    {
      // gz-sim's Joint components: the pose resolved in the child link's frame, the axes
      const sdf::Joint *sourceJoint = source->JointByIndex(j);
      sdf::Joint joint;
      joint.SetName(sourceJoint->Name());
      joint.SetType(sourceJoint->Type());
      joint.SetRawPose(Resolved(sourceJoint->SemanticPose(), sourceJoint->ChildLinkName(), sourceJoint->RawPose()));
      joint.SetParentLinkName(sourceJoint->ParentLinkName());
      joint.SetChildLinkName(sourceJoint->ChildLinkName());
      for (unsigned int a = 0; a < 2; ++a)
        if (sourceJoint->Axis(a)) joint.SetAxis(a, *sourceJoint->Axis(a));
      if (physicsModel->ConstructJoint(joint)) ++counts.joints; else ++counts.failedJoints;
    }
  }
  return counts;
}

}  // namespace

std::string Physics(const sdf::World &world, double seconds)
{
  ignition::plugin::Loader loader;
  const auto names = loader.LoadLib(DartsimPluginPath());
  ignition::plugin::PluginPtr plugin;
  for (const auto &name : names)
    if (name.find("dartsim") != std::string::npos) plugin = loader.Instantiate(name);
  if (!plugin)
    return "{\"ok\":false,\"error\":" + Quote("no dartsim plugin at " + DartsimPluginPath()) + "}";
  auto engine = ignition::physics::RequestEngine3d<PhysicsFeatures>::From(plugin);
  if (!engine) return "{\"ok\":false,\"error\":\"dartsim lacks a requested feature\"}";

  const auto buildStart = std::chrono::steady_clock::now();
  auto physicsWorld = engine->ConstructWorld(EmptyWorld(world));
  const std::string detector = NamedCollisionDetector(world);
  if (!detector.empty()) physicsWorld->SetCollisionDetector(detector);
  const Counts counts = Build(physicsWorld, world, true);
  // gz-sim's controller in velocity mode commands each step the velocity that reaches
  // its target within the step (0 at rest), which its Physics system hands to dartsim
  std::vector<decltype(physicsWorld->GetModel(0)->GetJoint(0))> commanded;
  for (const auto &[model, joint] : VelocityControlled(world))
    if (auto physicsModel = physicsWorld->GetModel(model))
      if (auto physicsJoint = physicsModel->GetJoint(joint)) commanded.push_back(physicsJoint);
  const double buildSeconds = Seconds(buildStart);

  ignition::physics::ForwardStep::Output output;
  ignition::physics::ForwardStep::State state;
  ignition::physics::ForwardStep::Input input;
  const auto step = std::chrono::milliseconds(1);
  input.Get<std::chrono::steady_clock::duration>() = step;
  const int steps = static_cast<int>(std::lround(seconds / 0.001));
  const auto stepStart = std::chrono::steady_clock::now();
  const double stepCpuStart = CpuSeconds();
  for (int i = 0; i < steps; ++i)
  {
    for (auto &joint : commanded) joint->SetVelocityCommand(0, 0.0);
    physicsWorld->Step(output, state, input);
  }
  const double wall = Seconds(stepStart);
  const double cpu = CpuSeconds() - stepCpuStart;
  const double simulated = steps * 0.001;
  std::ostringstream out;
  out << "{\"ok\":true,\"engine\":\"dartsim\",\"collision_detector\":"
      << Quote(physicsWorld->GetCollisionDetector()) << ",\"build_s\":" << Num(buildSeconds)
      << ",\"mesh_shapes\":" << counts.meshShapes << ",\"primitive_shapes\":" << counts.primitiveShapes
      << ",\"failed_shapes\":" << counts.failedShapes << ",\"joints\":" << counts.joints
      << ",\"failed_joints\":" << counts.failedJoints
      << ",\"velocity_commanded_joints\":" << commanded.size() << ",\"steps\":" << steps << ",\"step_s\":0.001"
      << ",\"wall_s\":" << Num(wall) << ",\"cpu_s\":" << Num(cpu)
      << ",\"real_time_factor\":" << Num(wall > 0 ? simulated / wall : 0.0)
      << ",\"real_time_factor_cpu\":" << Num(cpu > 0 ? simulated / cpu : 0.0) << "}";
  return out.str();
}

namespace
{
using JointFeatures = ignition::physics::FeatureList<
    BuildFeatures,
    ignition::physics::GetLinkFromModel,
    ignition::physics::SetBasicJointState,
    ignition::physics::LinkFrameSemantics>;

// The position a check sets a joint to: its limit farthest from 0 (a switch open), or
// half a radian (metre) where the joint has no finite limit.
double CheckPosition(const sdf::Joint &joint)
{
  const sdf::JointAxis *axis = joint.Axis(0);
  if (!axis || !std::isfinite(axis->Lower()) || !std::isfinite(axis->Upper())) return 0.5;
  const double far = std::fabs(axis->Lower()) > std::fabs(axis->Upper()) ? axis->Lower() : axis->Upper();
  return far != 0.0 ? far : 0.5;
}

// Every link of the physics world by "model::link", with its pose in the world.
template <typename WorldPtr>
std::vector<std::pair<std::string, Eigen::Isometry3d>> LinkPoses(WorldPtr &physicsWorld)
{
  std::vector<std::pair<std::string, Eigen::Isometry3d>> out;
  for (std::size_t m = 0; m < physicsWorld->GetModelCount(); ++m)
  {
    auto model = physicsWorld->GetModel(m);
    for (std::size_t l = 0; l < model->GetLinkCount(); ++l)
    {
      auto link = model->GetLink(l);
      out.emplace_back(model->GetName() + "::" + link->GetName(), link->FrameDataRelativeToWorld().pose);
    }
  }
  return out;
}

// One controller's record: what it names, and what moves when its joint is set.
template <typename WorldPtr>
std::string JointRecord(WorldPtr &physicsWorld, const sdf::Model &model, const sdf::ElementPtr &plugin)
{
  const std::string jointName = plugin->HasElement("joint_name") ? plugin->Get<std::string>("joint_name") : "";
  // the topic the controller subscribes to: <topic>, else its default (Configure)
  const std::string topic = plugin->HasElement("topic") ? plugin->Get<std::string>("topic")
                            : "/model/" + model.Name() + "/joint/" + jointName + "/0/cmd_pos";
  std::ostringstream out;
  out << "{\"model\":" << Quote(model.Name()) << ",\"joint\":" << Quote(jointName) << ",\"topic\":" << Quote(topic)
      << ",\"filename\":" << Quote(plugin->Get<std::string>("filename"))
      << ",\"velocity_commands\":"
      << (plugin->HasElement("use_velocity_commands") && plugin->Get<bool>("use_velocity_commands") ? "true" : "false")
      << ",\"static\":" << (model.Static() ? "true" : "false");
  const sdf::Joint *joint = model.JointByName(jointName);
  if (!joint) return out.str() + ",\"found\":false}";
  out << ",\"found\":true,\"type\":" << static_cast<int>(joint->Type()) << ",\"parent\":"
      << Quote(joint->ParentLinkName()) << ",\"child\":" << Quote(joint->ChildLinkName());
  auto physicsModel = physicsWorld->GetModel(model.Name());
  auto physicsJoint = physicsModel ? physicsModel->GetJoint(jointName) : nullptr;
  if (!physicsJoint) return out.str() + ",\"in_physics\":false}";
  const double position = CheckPosition(*joint);
  const auto before = LinkPoses(physicsWorld);
  physicsJoint->SetPosition(0, position);
  const auto after = LinkPoses(physicsWorld);
  physicsJoint->SetPosition(0, 0.0);
  std::string moved = "[";
  double childAngle = 0.0, childShift = 0.0;
  for (std::size_t i = 0; i < before.size(); ++i)
  {
    const Eigen::Isometry3d delta = before[i].second.inverse() * after[i].second;
    const double angle = Eigen::AngleAxisd(delta.rotation()).angle();
    const double shift = (after[i].second.translation() - before[i].second.translation()).norm();
    if (angle > 1e-9 || shift > 1e-9) moved += (moved.size() > 1 ? "," : "") + Quote(before[i].first);
    if (before[i].first == model.Name() + "::" + joint->ChildLinkName()) { childAngle = angle; childShift = shift; }
  }
  out << ",\"in_physics\":true,\"set\":" << Num(position) << ",\"child_rotation_rad\":" << Num(childAngle)
      << ",\"child_translation_m\":" << Num(childShift) << ",\"moved\":" << moved << "]}";
  return out.str();
}
}  // namespace

std::string Joints(const sdf::World &world)
{
  static ignition::plugin::Loader loader;
  ignition::plugin::PluginPtr plugin;
  for (const auto &name : loader.LoadLib(DartsimPluginPath()))
    if (name.find("dartsim") != std::string::npos) plugin = loader.Instantiate(name);
  if (!plugin) return "{\"ok\":false,\"error\":" + Quote("no dartsim plugin at " + DartsimPluginPath()) + "}";
  auto engine = ignition::physics::RequestEngine3d<JointFeatures>::From(plugin);
  if (!engine) return "{\"ok\":false,\"error\":\"dartsim lacks a requested feature\"}";
  auto physicsWorld = engine->ConstructWorld(EmptyWorld(world));
  // kinematics only: what a joint moves does not depend on what collides
  const Counts counts = Build(physicsWorld, world, false);
  std::string records;
  int controllers = 0;
  for (uint64_t m = 0; m < world.ModelCount(); ++m)
  {
    const sdf::Model *model = world.ModelByIndex(m);
    if (!model->Element() || !model->Element()->HasElement("plugin")) continue;
    for (auto el = model->Element()->GetElement("plugin"); el; el = el->GetNextElement("plugin"))
    {
      if (el->Get<std::string>("name").find("JointPositionController") == std::string::npos) continue;
      records += std::string(controllers++ ? ",\n" : "") + JointRecord(physicsWorld, *model, el);
    }
  }
  return "{\"ok\":true,\"joints_built\":" + std::to_string(counts.joints) + ",\"joints_failed\":" +
         std::to_string(counts.failedJoints) + ",\"controllers\":[" + records + "]}";
}
}  // namespace gzprobe
