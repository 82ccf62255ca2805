// Helpers the probe's commands share: JSON text, clocks, SDF poses.
#include "probe.hh"

#include <time.h>

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

namespace gzprobe
{

std::string Quote(const std::string &s)
{
  std::string out = "\"";
  for (unsigned char c : s)
  {
    if (c == '"' || c == '\\') { out += '\\'; out += static_cast<char>(c); }
    else if (c == '\n') out += "\\n";
    else if (c < 0x20) { char buf[8]; std::snprintf(buf, sizeof buf, "\\u%04x", c); out += buf; }
    else out += static_cast<char>(c);
  }
  return out + "\"";
}

std::string Num(double v)
{
  if (!std::isfinite(v)) return "null";
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

double Seconds(std::chrono::steady_clock::time_point since)
{
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

// CPU seconds this process has spent: on a shared machine, what a figure costs apart
// from the wait for a core.
double CpuSeconds()
{
  struct timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec + t.tv_nsec * 1e-9;
}

// A pose resolved through the frame graph (relative_to, frames), as gz-sim's
// ResolveSdfPose does; the raw pose where it cannot be resolved.
ignition::math::Pose3d Resolved(const sdf::SemanticPose &semantic, const std::string &to,
                                 const ignition::math::Pose3d &raw)
{
  ignition::math::Pose3d pose;
  return semantic.Resolve(pose, to).empty() ? pose : raw;
}

// (probe.hh) A relative path resolves as gz-sim's asFullPath resolves a mesh URI.
std::string ResolveUri(const std::string &uri, const std::string &sdfFile)
{
  const std::string scheme = "model://";
  if (uri.rfind(scheme, 0) != 0)
  {
    if (uri.rfind("file://", 0) == 0) return uri.substr(7);
    if (uri.find("://") != std::string::npos || uri.empty() || uri[0] == '/') return uri;
    const auto slash = sdfFile.rfind('/');
    const std::string candidate = (slash == std::string::npos ? "" : sdfFile.substr(0, slash + 1)) + uri;
    return access(candidate.c_str(), R_OK) == 0 ? candidate : "";
  }
  const std::string rest = uri.substr(scheme.size());
  const char *env = std::getenv("SDF_PATH");
  std::stringstream folders(env ? env : "");
  std::string folder;
  while (std::getline(folders, folder, ':'))
  {
    if (folder.empty()) continue;
    const std::string candidate = folder + "/" + rest;
    if (access(candidate.c_str(), R_OK) == 0) return candidate;
  }
  return "";
}

}  // namespace gzprobe
