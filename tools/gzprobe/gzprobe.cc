// gzprobe: reads our outputs with Gazebo Fortress's own libraries and says what it saw.
//
//   gzprobe mesh FILE...                       every mesh through MeshManager::Load
//   gzprobe world WORLD [--jobs N] [--physics SECONDS] [--joints] [--no-meshes]
//
// The world is parsed once with sdf::Root::Load and the default parser configuration, as
// gz-sim's server does; model:// URIs resolve through SDF_PATH (sdformat reads it
// itself). Every distinct mesh file is then loaded by ignition::common::MeshManager in a
// child process of its own, so a loader crash is a record ("signal": N), not the end of
// the probe (forked by a loader process started before the parse: MeshLoader). --physics builds the world in the dartsim plugin the way gz-sim's Physics
// system does (empty world, models, links, then each collision: meshes through
// AttachMeshShape, other shapes through ConstructSdfCollision; then the joints) and
// steps it at 1 ms (physics.cc). --joints lists every JointPositionController of the
// world's models (gz-sim Fortress's plugin: its <joint_name>, the topic it listens on,
// whether sdf::Model::JointByName finds its joint) and, in dartsim, which links move
// when that joint is set to its limit farthest from 0.
//
// Output: one JSON document on stdout. Per mesh: triangles, vertices, bounds, and sums
// over every triangle corner of its position, squared position, normal and texture
// coordinate, which the caller compares with the same sums over the file it wrote (a
// misread index stride or a dropped triangle changes them; a reordering does not).

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <ctime>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <ignition/common/Console.hh>
#include <ignition/common/Material.hh>
#include <ignition/common/Mesh.hh>
#include <ignition/common/MeshManager.hh>
#include <ignition/common/SubMesh.hh>
#include <ignition/math/Matrix4.hh>
#include <ignition/math/Pose3.hh>
#include <ignition/math/eigen3/Conversions.hh>
#include <ignition/physics/FeatureList.hh>
#include <ignition/physics/ForwardStep.hh>
#include <ignition/physics/RequestEngine.hh>
#include <ignition/physics/World.hh>
#include <ignition/physics/mesh/MeshShape.hh>
#include <ignition/physics/sdf/ConstructCollision.hh>
#include <ignition/physics/sdf/ConstructLink.hh>
#include <ignition/physics/sdf/ConstructModel.hh>
#include <ignition/physics/sdf/ConstructWorld.hh>
#include <ignition/plugin/Loader.hh>
#include <sdf/Collision.hh>
#include <sdf/Geometry.hh>
#include <sdf/Link.hh>
#include <sdf/Mesh.hh>
#include <sdf/Model.hh>
#include <sdf/Physics.hh>
#include <sdf/Root.hh>
#include <sdf/Visual.hh>
#include <sdf/World.hh>

#include "probe.hh"

namespace {

using namespace gzprobe;
using Matrix = ignition::math::Matrix4d;
using Vec3 = ignition::math::Vector3d;

// ---------------------------------------------------------------- JSON output

std::string Vec(const Vec3 &v)
{
  return "[" + Num(v.X()) + "," + Num(v.Y()) + "," + Num(v.Z()) + "]";
}

std::string Rgba(const ignition::math::Color &c)
{
  return "[" + Num(c.R()) + "," + Num(c.G()) + "," + Num(c.B()) + "," + Num(c.A()) + "]";
}

std::string MatrixJson(const Matrix &m)
{
  std::string out = "[";
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c)
      out += Num(m(r, c)) + (r == 3 && c == 3 ? "]" : ",");
  return out;
}

double PeakRssMb()
{
  struct rusage usage;
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0;  // Linux reports kilobytes
}

double CurrentRssMb()
{
  std::ifstream statm("/proc/self/statm");
  long pages = 0, resident = 0;
  statm >> pages >> resident;
  return resident * (sysconf(_SC_PAGESIZE) / 1048576.0);
}

// ---------------------------------------------------------------- meshes

// The report of one mesh as MeshManager gives it. Runs in the child process.
std::string MeshReport(const std::string &path)
{
  const ignition::common::Mesh *mesh = ignition::common::MeshManager::Instance()->Load(path);
  if (!mesh)
    return "{\"ok\":false,\"error\":\"MeshManager::Load returned null\"}";

  std::ostringstream out;
  Vec3 cornerSum, cornerSq, normalSum;
  double uvSum[2] = {0, 0};
  unsigned long triangles = 0, corners = 0, normals = 0, uvs = 0, badIndices = 0;
  std::string subs = "[";
  for (unsigned int s = 0; s < mesh->SubMeshCount(); ++s)
  {
    auto sub = mesh->SubMeshByIndex(s).lock();
    if (!sub) continue;
    const bool isTriangles = sub->SubMeshPrimitiveType() == ignition::common::SubMesh::TRIANGLES;
    const unsigned int indexCount = sub->IndexCount();
    const bool hasNormals = sub->NormalCount() == sub->VertexCount() && sub->NormalCount() > 0;
    const bool hasUvs = sub->TexCoordCount() == sub->VertexCount() && sub->TexCoordCount() > 0;
    unsigned long subTriangles = isTriangles ? indexCount / 3 : 0;
    for (unsigned int i = 0; isTriangles && i < subTriangles * 3; ++i)
    {
      const int index = sub->Index(i);
      if (index < 0 || static_cast<unsigned int>(index) >= sub->VertexCount())
      {
        ++badIndices;
        continue;
      }
      const Vec3 p = sub->Vertex(index);
      cornerSum += p;
      cornerSq += p * p;
      ++corners;
      if (hasNormals) { normalSum += sub->Normal(index); ++normals; }
      if (hasUvs)
      {
        const auto uv = sub->TexCoord(index);
        uvSum[0] += uv.X();
        uvSum[1] += uv.Y();
        ++uvs;
      }
    }
    triangles += subTriangles;
    if (s) subs += ",";
    subs += "{\"primitive\":" + std::to_string(static_cast<int>(sub->SubMeshPrimitiveType())) +
            ",\"triangles\":" + std::to_string(subTriangles) +
            ",\"indices\":" + std::to_string(indexCount) +
            ",\"vertices\":" + std::to_string(sub->VertexCount()) +
            ",\"material\":" + std::to_string(static_cast<int>(sub->MaterialIndex())) + "}";
  }
  subs += "]";

  std::string materials = "[";
  for (unsigned int m = 0; m < mesh->MaterialCount(); ++m)
  {
    auto mat = mesh->MaterialByIndex(m);
    if (m) materials += ",";
    if (!mat) { materials += "null"; continue; }
    materials += "{\"ambient\":" + Rgba(mat->Ambient()) + ",\"diffuse\":" + Rgba(mat->Diffuse()) +
                 ",\"specular\":" + Rgba(mat->Specular()) + ",\"emissive\":" + Rgba(mat->Emissive()) +
                 ",\"shininess\":" + Num(mat->Shininess()) +
                 ",\"transparency\":" + Num(mat->Transparency()) +
                 ",\"texture\":" + Quote(mat->TextureImage()) + "}";
  }
  materials += "]";

  out << "{\"ok\":true,\"triangles\":" << triangles << ",\"vertices\":" << mesh->VertexCount()
      << ",\"corners\":" << corners << ",\"bad_indices\":" << badIndices
      << ",\"min\":" << Vec(mesh->Min()) << ",\"max\":" << Vec(mesh->Max())
      << ",\"corner_sum\":" << Vec(cornerSum) << ",\"corner_sq\":" << Vec(cornerSq)
      << ",\"normals\":" << normals << ",\"normal_sum\":" << Vec(normalSum)
      << ",\"uvs\":" << uvs << ",\"uv_sum\":[" << Num(uvSum[0]) << "," << Num(uvSum[1]) << "]"
      << ",\"submeshes\":" << subs << ",\"materials\":" << materials << "}";
  return out.str();
}

std::string ReadFile(const std::string &path, size_t limit = std::string::npos)
{
  std::ifstream in(path, std::ios::binary);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  return text.size() > limit ? text.substr(0, limit) : text;
}

struct Child
{
  std::string mesh;
  std::string reportFile;
  std::string logFile;
};

// Loads each mesh in a child process, up to `jobs` at a time; returns path -> JSON.
std::map<std::string, std::string> LoadMeshes(const std::vector<std::string> &paths, int jobs)
{
  std::map<std::string, std::string> reports;
  std::map<pid_t, Child> running;
  size_t next = 0;
  char folderTemplate[] = "/tmp/gzprobe.XXXXXX";
  const std::string folder = mkdtemp(folderTemplate) ? folderTemplate : "/tmp";
  while (next < paths.size() || !running.empty())
  {
    while (next < paths.size() && static_cast<int>(running.size()) < jobs)
    {
      Child child{paths[next], folder + "/" + std::to_string(next) + ".json",
                  folder + "/" + std::to_string(next) + ".log"};
      ++next;
      std::cout.flush();
      std::cerr.flush();
      const pid_t pid = fork();
      if (pid == 0)
      {
        std::freopen(child.logFile.c_str(), "w", stderr);
        std::freopen(child.logFile.c_str(), "a", stdout);  // the loaders print on both
        const std::string report = MeshReport(child.mesh);
        std::ofstream(child.reportFile) << report;
        std::fflush(nullptr);
        _exit(0);
      }
      if (pid < 0)
      {
        reports[child.mesh] = "{\"ok\":false,\"error\":\"fork failed\"}";
        continue;
      }
      running[pid] = child;
    }
    int status = 0;
    const pid_t done = waitpid(-1, &status, 0);
    if (done < 0) break;
    auto it = running.find(done);
    if (it == running.end()) continue;
    const Child child = it->second;
    running.erase(it);
    const std::string log = ReadFile(child.logFile, 2000);
    std::string report;
    if (WIFSIGNALED(status))
      report = "{\"ok\":false,\"signal\":" + std::to_string(WTERMSIG(status)) + "}";
    else if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
      report = "{\"ok\":false,\"exit\":" + std::to_string(WEXITSTATUS(status)) + "}";
    else
      report = ReadFile(child.reportFile);
    if (report.empty())
      report = "{\"ok\":false,\"error\":\"no report\"}";
    // Every report is an object: the loader's own messages go in as one more field.
    report.insert(report.size() - 1, ",\"log\":" + Quote(log));
    reports[child.mesh] = report;
    std::remove(child.logFile.c_str());
    std::remove(child.reportFile.c_str());
  }
  rmdir(folder.c_str());
  return reports;
}

// ---------------------------------------------------------------- world

struct MeshUse
{
  std::string kind;  // "visual" or "collision"
  std::string uri;
  std::string path;
  Matrix modelFromMesh;
  Vec3 scale;
  std::string link;  // the names of its link and of itself
  std::string name;
};

struct ModelSummary
{
  std::string name;
  Matrix worldFromModel;
  std::vector<MeshUse> meshes;
  int primitiveCollisions = 0;
};

Matrix PoseMatrix(const ignition::math::Pose3d &pose) { return Matrix(pose); }

std::vector<ModelSummary> Summaries(const sdf::World &world)
{
  std::vector<ModelSummary> out;
  for (uint64_t m = 0; m < world.ModelCount(); ++m)
  {
    const sdf::Model *model = world.ModelByIndex(m);
    ModelSummary summary{model->Name(), PoseMatrix(model->RawPose()), {}, 0};
    for (uint64_t l = 0; l < model->LinkCount(); ++l)
    {
      const sdf::Link *link = model->LinkByIndex(l);
      const Matrix modelFromLink =
          PoseMatrix(Resolved(link->SemanticPose(), "__model__", link->RawPose()));
      auto add = [&](const std::string &kind, const std::string &name, const sdf::Geometry *geom,
                     const ignition::math::Pose3d &pose) {
        if (!geom || geom->Type() != sdf::GeometryType::MESH || !geom->MeshShape())
        {
          if (kind == "collision") ++summary.primitiveCollisions;
          return;
        }
        const sdf::Mesh *mesh = geom->MeshShape();
        summary.meshes.push_back({kind, mesh->Uri(), ResolveUri(mesh->Uri(), mesh->FilePath()),
                                  modelFromLink * PoseMatrix(pose), mesh->Scale(), link->Name(), name});
      };
      for (uint64_t v = 0; v < link->VisualCount(); ++v)
      {
        const sdf::Visual *visual = link->VisualByIndex(v);
        add("visual", visual->Name(), visual->Geom(),
            Resolved(visual->SemanticPose(), link->Name(), visual->RawPose()));
      }
      for (uint64_t c = 0; c < link->CollisionCount(); ++c)
      {
        const sdf::Collision *collision = link->CollisionByIndex(c);
        add("collision", collision->Name(), collision->Geom(),
            Resolved(collision->SemanticPose(), link->Name(), collision->RawPose()));
      }
    }
    out.push_back(summary);
  }
  return out;
}

// Model-frame bounds of the given kind of mesh, from the meshes' bounds as loaded.
bool ModelBounds(const ModelSummary &model, const std::string &kind,
                 const std::map<std::string, std::pair<Vec3, Vec3>> &meshBounds, Vec3 &lo, Vec3 &hi)
{
  bool any = false;
  for (const auto &use : model.meshes)
  {
    if (use.kind != kind) continue;
    auto it = meshBounds.find(use.path);
    if (it == meshBounds.end()) continue;
    const Vec3 &a = it->second.first, &b = it->second.second;
    for (int corner = 0; corner < 8; ++corner)
    {
      Vec3 p((corner & 1 ? b : a).X() * use.scale.X(), (corner & 2 ? b : a).Y() * use.scale.Y(),
             (corner & 4 ? b : a).Z() * use.scale.Z());
      p = use.modelFromMesh * p;
      if (!any) { lo = hi = p; any = true; }
      lo.Min(p);
      hi.Max(p);
    }
  }
  return any;
}

// ---------------------------------------------------------------- commands

std::string MeshesJson(const std::map<std::string, std::string> &reports)
{
  std::string out = "{";
  bool first = true;
  for (const auto &[path, report] : reports)
  {
    out += (first ? "" : ",\n") + Quote(path) + ":" + report;
    first = false;
  }
  return out + "}";
}

// Forking is cheap from a small process and dear from a large one: the kernel copies
// the page tables and every page the child touches. A world's parse leaves this process
// hundreds of MB of sdformat elements, and forking it once per mesh would spend most of
// a probe in the kernel. So the meshes are loaded by a process forked before the parse,
// which forks its children from its small self: it reads the paths from a pipe and
// answers with each path's report.
struct MeshLoader
{
  pid_t pid = -1;
  int paths = -1;    // we write the paths here, then close it
  int reports = -1;  // it writes "<path bytes> <report bytes>\n<path><report>" per mesh
};

bool WriteAll(int fd, const std::string &data)
{
  size_t done = 0;
  while (done < data.size())
  {
    const ssize_t n = write(fd, data.data() + done, data.size() - done);
    if (n <= 0) return false;
    done += static_cast<size_t>(n);
  }
  return true;
}

std::string ReadAll(int fd)
{
  std::string data;
  char buffer[65536];
  ssize_t n;
  while ((n = read(fd, buffer, sizeof buffer)) > 0) data.append(buffer, static_cast<size_t>(n));
  return data;
}

MeshLoader StartMeshLoader(int jobs)
{
  int toLoader[2], fromLoader[2];
  if (pipe(toLoader) != 0) return {};
  if (pipe(fromLoader) != 0)
  {
    close(toLoader[0]);
    close(toLoader[1]);
    return {};
  }
  std::cout.flush();
  std::cerr.flush();
  const pid_t pid = fork();
  if (pid == 0)
  {
    close(toLoader[1]);
    close(fromLoader[0]);
    std::vector<std::string> paths;
    std::istringstream lines(ReadAll(toLoader[0]));
    for (std::string line; std::getline(lines, line);)
      if (!line.empty()) paths.push_back(line);
    std::string answer;
    for (const auto &[path, report] : LoadMeshes(paths, jobs))
      answer += std::to_string(path.size()) + " " + std::to_string(report.size()) + "\n" + path + report;
    WriteAll(fromLoader[1], answer);
    _exit(0);
  }
  close(toLoader[0]);
  close(fromLoader[1]);
  if (pid < 0)
  {
    close(toLoader[1]);
    close(fromLoader[0]);
    return {};
  }
  return {pid, toLoader[1], fromLoader[0]};
}

// The loader's reports of `paths`; loaded here, forking this process, when the loader
// could not be started or died (paths hold no newline: they come from our own URIs).
std::map<std::string, std::string> LoadMeshesWith(MeshLoader &loader, const std::vector<std::string> &paths, int jobs)
{
  if (loader.pid < 0) return LoadMeshes(paths, jobs);
  std::string request;
  for (const auto &path : paths) request += path + "\n";
  WriteAll(loader.paths, request);
  close(loader.paths);
  const std::string answer = ReadAll(loader.reports);
  close(loader.reports);
  int status = 0;
  waitpid(loader.pid, &status, 0);
  loader.pid = -1;
  std::map<std::string, std::string> reports;
  size_t at = 0;
  while (at < answer.size())
  {
    const size_t newline = answer.find('\n', at);
    if (newline == std::string::npos) break;
    size_t pathSize = 0, reportSize = 0;
    if (std::sscanf(answer.c_str() + at, "%zu %zu", &pathSize, &reportSize) != 2) break;
    if (newline + 1 + pathSize + reportSize > answer.size()) break;
    reports[answer.substr(newline + 1, pathSize)] = answer.substr(newline + 1 + pathSize, reportSize);
    at = newline + 1 + pathSize + reportSize;
  }
  if (reports.size() != paths.size()) return LoadMeshes(paths, jobs);
  return reports;
}

void StopMeshLoader(MeshLoader &loader)
{
  if (loader.pid < 0) return;
  close(loader.paths);
  close(loader.reports);
  waitpid(loader.pid, nullptr, 0);
  loader.pid = -1;
}

int MeshCommand(const std::vector<std::string> &paths, int jobs)
{
  std::cout << "{\"meshes\":" << MeshesJson(LoadMeshes(paths, jobs)) << "}\n";
  return 0;
}

// Bounds back from a report, to place each model's meshes; a small reader of our own
// output, which is all this needs.
bool ParseBounds(const std::string &report, Vec3 &lo, Vec3 &hi)
{
  auto read = [&](const std::string &key, Vec3 &v) {
    const auto at = report.find("\"" + key + "\":[");
    if (at == std::string::npos) return false;
    double x, y, z;
    if (std::sscanf(report.c_str() + at + key.size() + 4, "%lf,%lf,%lf", &x, &y, &z) != 3)
      return false;
    v.Set(x, y, z);
    return true;
  };
  return report.find("\"ok\":true") != std::string::npos && read("min", lo) && read("max", hi);
}

int WorldCommand(const std::string &file, int jobs, double physicsSeconds, bool meshes, bool joints)
{
  MeshLoader loader = meshes ? StartMeshLoader(jobs) : MeshLoader{};
  const double rssBefore = CurrentRssMb();
  const auto start = std::chrono::steady_clock::now();
  const double cpuStart = CpuSeconds();
  sdf::Root root;
  const sdf::Errors errors = root.Load(file);
  const double parseSeconds = Seconds(start);
  const double parseCpu = CpuSeconds() - cpuStart;
  const double peakRss = PeakRssMb();
  const double rssAfter = CurrentRssMb();

  std::string errorList = "[";
  for (size_t i = 0; i < errors.size(); ++i)
    errorList += (i ? "," : "") + Quote(errors[i].Message());
  errorList += "]";
  const sdf::World *world = root.WorldCount() ? root.WorldByIndex(0) : nullptr;

  std::ostringstream out;
  out << "{\"world\":{\"file\":" << Quote(file) << ",\"parse_s\":" << Num(parseSeconds)
      << ",\"parse_cpu_s\":" << Num(parseCpu)
      << ",\"peak_rss_mb\":" << Num(peakRss) << ",\"rss_before_mb\":" << Num(rssBefore)
      << ",\"rss_after_mb\":" << Num(rssAfter) << ",\"errors\":" << errorList;
  if (!world)
  {
    out << ",\"models\":0}}\n";
    std::cout << out.str();
    StopMeshLoader(loader);
    return 1;
  }
  uint64_t links = 0, visuals = 0, collisions = 0;
  for (uint64_t m = 0; m < world->ModelCount(); ++m)
  {
    const sdf::Model *model = world->ModelByIndex(m);
    links += model->LinkCount();
    for (uint64_t l = 0; l < model->LinkCount(); ++l)
    {
      visuals += model->LinkByIndex(l)->VisualCount();
      collisions += model->LinkByIndex(l)->CollisionCount();
    }
  }
  out << ",\"models\":" << world->ModelCount() << ",\"links\":" << links
      << ",\"visuals\":" << visuals << ",\"collisions\":" << collisions << "}";

  const std::vector<ModelSummary> summaries = Summaries(*world);
  std::map<std::string, std::string> reports;
  if (meshes)
  {
    std::set<std::string> unique;
    for (const auto &model : summaries)
      for (const auto &use : model.meshes)
        if (!use.path.empty()) unique.insert(use.path);
    reports = LoadMeshesWith(loader, std::vector<std::string>(unique.begin(), unique.end()), jobs);
  }
  std::map<std::string, std::pair<Vec3, Vec3>> meshBounds;
  for (const auto &[path, report] : reports)
  {
    Vec3 lo, hi;
    if (ParseBounds(report, lo, hi)) meshBounds[path] = {lo, hi};
  }

  out << ",\n\"models\":[";
  for (size_t i = 0; i < summaries.size(); ++i)
  {
    const ModelSummary &model = summaries[i];
    out << (i ? ",\n" : "") << "{\"name\":" << Quote(model.name)
        << ",\"world_from_model\":" << MatrixJson(model.worldFromModel)
        << ",\"primitive_collisions\":" << model.primitiveCollisions << ",\"meshes\":[";
    for (size_t k = 0; k < model.meshes.size(); ++k)
    {
      const MeshUse &use = model.meshes[k];
      out << (k ? "," : "") << "{\"kind\":\"" << use.kind << "\",\"link\":" << Quote(use.link)
          << ",\"name\":" << Quote(use.name) << ",\"uri\":" << Quote(use.uri)
          << ",\"path\":" << Quote(use.path) << ",\"model_from_mesh\":"
          << MatrixJson(use.modelFromMesh) << ",\"scale\":" << Vec(use.scale) << "}";
    }
    out << "]";
    for (const std::string kind : {"visual", "collision"})
    {
      Vec3 lo, hi;
      if (ModelBounds(model, kind, meshBounds, lo, hi))
        out << ",\"" << kind << "_bounds\":[" << Vec(lo) << "," << Vec(hi) << "]";
    }
    out << "}";
  }
  out << "],\n\"meshes\":" << MeshesJson(reports);
  if (physicsSeconds > 0) out << ",\n\"physics\":" << Physics(*world, physicsSeconds);
  if (joints) out << ",\n\"joints\":" << Joints(*world);
  out << "}\n";
  std::cout << out.str();
  return 0;
}

int Usage()
{
  std::cerr << "usage: gzprobe mesh FILE... [--jobs N]\n"
               "       gzprobe world WORLD [--jobs N] [--physics SECONDS] [--joints] [--no-meshes]\n";
  return 2;
}

}  // namespace

int main(int argc, char **argv)
{
  if (argc < 3) return Usage();
  const std::string command = argv[1];
  std::vector<std::string> files;
  int jobs = 2;
  double physicsSeconds = 0;
  bool meshes = true, joints = false;
  for (int i = 2; i < argc; ++i)
  {
    const std::string arg = argv[i];
    if (arg == "--jobs" && i + 1 < argc) jobs = std::max(1, std::atoi(argv[++i]));
    else if (arg == "--physics" && i + 1 < argc) physicsSeconds = std::atof(argv[++i]);
    else if (arg == "--no-meshes") meshes = false;
    else if (arg == "--joints") joints = true;
    else files.push_back(arg);
  }
  // Loader warnings stay in each mesh's "log"; the parent prints only its JSON.
  ignition::common::Console::SetVerbosity(2);
  if (command == "mesh" && !files.empty()) return MeshCommand(files, jobs);
  if (command == "world" && files.size() == 1)
    return WorldCommand(files[0], jobs, physicsSeconds, meshes, joints);
  return Usage();
}
