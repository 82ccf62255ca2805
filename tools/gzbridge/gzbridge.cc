// gzbridge: the twin's side of Gazebo's transport, and a stand-in for gz-sim.
//
//   gzbridge send --world NAME      reads commands on stdin, one per line, and sends each
//                                   to gz-sim's own interfaces; answers one JSON line each:
//     light NAME DX DY DZ INTENSITY R G B   /world/NAME/light_config (ignition.msgs.Light)
//     pose NAME X Y Z QX QY QZ QW           /world/NAME/set_pose (ignition.msgs.Pose)
//     joint TOPIC POSITION                  TOPIC (ignition.msgs.Double): the topic on which the
//                                           world's JointPositionController of the joint listens
//                                           (the twin names it: export.names.joint_command_topic)
//     visual NAME R G B A                   /world/NAME/visual_config (ignition.msgs.Visual),
//                                           offered by Harmonic, not by Fortress
//   gzbridge sim --world NAME --joint TOPIC ...
//                                   serves those services and listens on those topics as
//                                   gz-sim's UserCommands and JointPositionController do,
//                                   and prints one JSON line for every message that arrives.
//
// Built by .ci/install-tools against Debian's ignition-transport11 and ignition-msgs8.
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <iostream>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <ignition/msgs/boolean.pb.h>
#include <ignition/msgs/double.pb.h>
#include <ignition/msgs/light.pb.h>
#include <ignition/msgs/pose.pb.h>
#include <ignition/msgs/visual.pb.h>
#include <ignition/transport/Node.hh>

namespace msgs = ignition::msgs;
namespace transport = ignition::transport;

static std::mutex out_mutex;
static std::atomic<bool> stop{false};

static void emit(const std::string &line) {
  std::lock_guard<std::mutex> lock(out_mutex);
  std::fputs(line.c_str(), stdout);
  std::fputc('\n', stdout);
  std::fflush(stdout);
}

static std::string quoted(const std::string &s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    if (static_cast<unsigned char>(c) < 0x20) continue;
    out += c;
  }
  return out + "\"";
}

static std::string num(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

static std::string reply(const std::string &cmd, bool ok, const std::string &error = "") {
  std::string s = "{\"cmd\":" + quoted(cmd) + ",\"ok\":" + (ok ? "true" : "false");
  if (!error.empty()) s += ",\"error\":" + quoted(error);
  return s + "}";
}

template <typename Req>
static std::string call(transport::Node &node, const std::string &cmd, const std::string &service,
                        const Req &req, unsigned timeout_ms) {
  msgs::Boolean rep;
  bool result = false;
  if (!node.Request(service, req, timeout_ms, rep, result))
    return reply(cmd, false, "no answer from " + service + " within " + std::to_string(timeout_ms) + " ms");
  if (!result || !rep.data()) return reply(cmd, false, service + " refused the request");
  return reply(cmd, true);
}

static int send_mode(const std::string &world, unsigned timeout_ms) {
  transport::Node node;
  std::vector<std::pair<std::string, transport::Node::Publisher>> publishers;
  std::string line;
  while (std::getline(std::cin, line)) {
    std::istringstream in(line);
    std::string cmd;
    if (!(in >> cmd)) continue;
    if (cmd == "light") {
      std::string name;
      double dx, dy, dz, intensity, r, g, b;
      if (!(in >> name >> dx >> dy >> dz >> intensity >> r >> g >> b)) { emit(reply(cmd, false, "usage: light NAME DX DY DZ INTENSITY R G B")); continue; }
      msgs::Light light;
      light.set_name(name);
      light.set_type(msgs::Light::DIRECTIONAL);
      msgs::Set(light.mutable_direction(), ignition::math::Vector3d(dx, dy, dz));
      light.set_intensity(static_cast<float>(intensity));
      msgs::Set(light.mutable_diffuse(), ignition::math::Color(r, g, b, 1.0));
      light.set_cast_shadows(true);
      emit(call(node, cmd, "/world/" + world + "/light_config", light, timeout_ms));
    } else if (cmd == "pose") {
      std::string name;
      double x, y, z, qx, qy, qz, qw;
      if (!(in >> name >> x >> y >> z >> qx >> qy >> qz >> qw)) { emit(reply(cmd, false, "usage: pose NAME X Y Z QX QY QZ QW")); continue; }
      msgs::Pose pose;
      pose.set_name(name);
      msgs::Set(&pose, ignition::math::Pose3d(x, y, z, qw, qx, qy, qz));
      emit(call(node, cmd, "/world/" + world + "/set_pose", pose, timeout_ms));
    } else if (cmd == "joint") {
      std::string topic;
      double position;
      if (!(in >> topic >> position)) { emit(reply(cmd, false, "usage: joint TOPIC POSITION")); continue; }
      transport::Node::Publisher *pub = nullptr;
      for (auto &p : publishers) if (p.first == topic) pub = &p.second;
      if (!pub) {
        bool answered = false;  // a simulator subscribed to a topic advertised before
        for (auto &p : publishers) answered = answered || p.second.HasConnections();
        const bool first = publishers.empty();
        publishers.emplace_back(topic, node.Advertise<msgs::Double>(topic));
        pub = &publishers.back().second;
        // A new publisher's subscribers are discovered asynchronously, and a message
        // published before that is lost: wait for them, long for the first topic (a
        // loaded machine takes seconds) or while a simulator answers, briefly once none
        // answered (a world without the joint's controller, no simulator at all).
        const int wait_ms = first ? 10000 : answered ? 3000 : 500;
        for (int i = 0; i < wait_ms / 10 && !pub->HasConnections(); ++i)
          std::this_thread::sleep_for(std::chrono::milliseconds(10));
        // HasConnections() turns true when discovery reports the subscriber; the
        // subscription itself reaches this publisher's socket on its own, a little
        // later, and a message published in between is dropped (gz-transport#586):
        // the first message of a topic waits for that too.
        if (pub->HasConnections()) std::this_thread::sleep_for(std::chrono::milliseconds(200));
      }
      msgs::Double value;
      value.set_data(position);
      emit(reply(cmd, pub->Publish(value), pub->HasConnections() ? "" : "no subscriber on " + topic));
    } else if (cmd == "visual") {
      std::string name;
      double r, g, b, a;
      if (!(in >> name >> r >> g >> b >> a)) { emit(reply(cmd, false, "usage: visual NAME R G B A")); continue; }
      msgs::Visual visual;
      visual.set_name(name);
      msgs::Set(visual.mutable_material()->mutable_diffuse(), ignition::math::Color(r, g, b, a));
      emit(call(node, cmd, "/world/" + world + "/visual_config", visual, timeout_ms));
    } else {
      emit(reply(cmd, false, "unknown command"));
    }
  }
  return 0;
}

static void on_signal(int) { stop = true; }

static int sim_mode(const std::string &world, const std::vector<std::string> &joints) {
  transport::Node node;
  bool ok = node.Advertise("/world/" + world + "/light_config",
      std::function<bool(const msgs::Light &, msgs::Boolean &)>([](const msgs::Light &m, msgs::Boolean &rep) {
        emit("{\"service\":\"light_config\",\"type\":\"ignition.msgs.Light\",\"name\":" + quoted(m.name()) +
             ",\"light_type\":" + std::to_string(m.type()) +
             ",\"direction\":[" + num(m.direction().x()) + "," + num(m.direction().y()) + "," + num(m.direction().z()) +
             "],\"intensity\":" + num(m.intensity()) +
             ",\"diffuse\":[" + num(m.diffuse().r()) + "," + num(m.diffuse().g()) + "," + num(m.diffuse().b()) + "]}");
        rep.set_data(true);
        return true;
      }));
  ok = ok && node.Advertise("/world/" + world + "/set_pose",
      std::function<bool(const msgs::Pose &, msgs::Boolean &)>([](const msgs::Pose &m, msgs::Boolean &rep) {
        emit("{\"service\":\"set_pose\",\"type\":\"ignition.msgs.Pose\",\"name\":" + quoted(m.name()) +
             ",\"position\":[" + num(m.position().x()) + "," + num(m.position().y()) + "," + num(m.position().z()) +
             "],\"orientation\":[" + num(m.orientation().x()) + "," + num(m.orientation().y()) + "," +
             num(m.orientation().z()) + "," + num(m.orientation().w()) + "]}");
        rep.set_data(true);
        return true;
      }));
  ok = ok && node.Advertise("/world/" + world + "/visual_config",
      std::function<bool(const msgs::Visual &, msgs::Boolean &)>([](const msgs::Visual &m, msgs::Boolean &rep) {
        const auto &d = m.material().diffuse();
        emit("{\"service\":\"visual_config\",\"type\":\"ignition.msgs.Visual\",\"name\":" + quoted(m.name()) +
             ",\"diffuse\":[" + num(d.r()) + "," + num(d.g()) + "," + num(d.b()) + "," + num(d.a()) + "]}");
        rep.set_data(true);
        return true;
      }));
  for (const auto &topic : joints) {
    std::function<void(const msgs::Double &)> on_command = [topic](const msgs::Double &m) {
      emit("{\"topic\":" + quoted(topic) + ",\"type\":\"ignition.msgs.Double\",\"data\":" + num(m.data()) + "}");
    };
    ok = ok && node.Subscribe(topic, on_command);
  }
  if (!ok) { std::fprintf(stderr, "gzbridge: could not advertise or subscribe\n"); return 1; }
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  emit("{\"ready\":true,\"world\":" + quoted(world) + "}");
  while (!stop) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  return 0;
}

int main(int argc, char **argv) {
  if (argc < 2) { std::fprintf(stderr, "usage: gzbridge send|sim --world NAME [--timeout MS] [--joint TOPIC ...]\n"); return 2; }
  const std::string mode = argv[1];
  std::string world;
  unsigned timeout_ms = 1000;
  std::vector<std::string> joints;
  for (int i = 2; i + 1 < argc; i += 2) {
    const std::string flag = argv[i], value = argv[i + 1];
    if (flag == "--world") world = value;
    else if (flag == "--timeout") timeout_ms = static_cast<unsigned>(std::stoul(value));
    else if (flag == "--joint") joints.push_back(value);
    else { std::fprintf(stderr, "gzbridge: unknown option %s\n", flag.c_str()); return 2; }
  }
  if (world.empty()) { std::fprintf(stderr, "gzbridge: --world NAME is required\n"); return 2; }
  if (mode == "send") return send_mode(world, timeout_ms);
  if (mode == "sim") return sim_mode(world, joints);
  std::fprintf(stderr, "gzbridge: unknown mode %s\n", mode.c_str());
  return 2;
}
